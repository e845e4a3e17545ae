"""enclab.core.allocator: a job process reuses the large blocks it frees instead of refaulting them."""
import subprocess
import sys
from pathlib import Path

import pytest

WORKFLOW = Path(__file__).resolve().parents[1] / "workflow"

_CHURN = """
import resource, sys
sys.path.insert(0, {workflow!r})
import numpy as np
if {keep}:
    from enclab.core.allocator import keep_freed_memory
    assert keep_freed_memory()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(50):
    arrays = [np.ones(1 << 19) for _ in range(4)]  # 4 x 4 MiB, every page written
    del arrays
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(keep: bool) -> int:
    out = subprocess.run([sys.executable, "-c", _CHURN.format(workflow=str(WORKFLOW), keep=keep)],
                         capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_blocks_are_reused_not_refaulted():
    pages = 4 * (1 << 22) // 4096
    kept, default = _faults(True), _faults(False)
    # Kept: the first round's pages serve all the others.
    assert kept < 3 * pages
    # Default glibc: the memory freed at the heap's top is trimmed (or the blocks were mapped),
    # so round after round faults its pages in again (about half of the 50 rounds' pages here).
    assert default > 10 * pages


def test_is_idempotent():
    from enclab.core.allocator import keep_freed_memory
    assert keep_freed_memory() == keep_freed_memory()
