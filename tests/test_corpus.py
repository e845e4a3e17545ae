"""The bad-input corpus (tests/corpus/cases.py) through the real Snakemake workflow.

Every bad log fails alone with its one-line error (file, column, row or key, what was
expected) and leaves no output of the failing stage; broken manifests and configurations stop
before any job runs; good-but-odd logs (repeated or missing time stamps, a wrapping counter)
complete with the irregularity reported; files as labs have them (another encoding,
semicolons and decimal commas, gzip, a time column in ms) are read when declared, or fail with
one line naming the key to set; a file the workflow may not read, or that was moved away, a log
too short for a later stage, fail alone with a line naming the file; a disk that fills up
while a chunk writes fails that log with a line naming the file, and once the disk has room a
rerun completes with no cleaning; and no input file changes.
"""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent / "corpus"))
from cases import CASES  # noqa: E402
from run import run_corpus, unreadable_files_possible  # noqa: E402

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    return run_corpus(tmp_path_factory.mktemp("corpus"))


def test_corpus_is_large_and_covers_every_scope():
    assert len(CASES) >= 30
    assert {c.scope for c in CASES} == {"log", "manifest", "config"}
    assert len({c.name for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_case_gets_its_expected_outcome(corpus, case):
    outcomes, _ = corpus
    (outcome,) = [o for o in outcomes if o.case is case]
    if case.extra.get("unreadable") and not unreadable_files_possible():
        pytest.skip("run as root without setpriv: root reads a mode-000 file")
    if case.extra.get("fault"):
        # the fault's one line (naming the file), then the rerun completes with no cleaning
        missing = [f for f in case.expect if f not in outcome.message]
        assert not missing, f"{case.name}: {missing} not in {outcome.message!r}"
        assert "\n" not in outcome.message
        assert outcome.completed and outcome.leftovers == []
    elif case.expect is None:
        assert outcome.completed, f"{case.name} should complete: {outcome.message}"
        for key, value in case.extra.get("report", {}).items():
            assert outcome.report[key] == value
        if "warning" in case.extra:
            assert any(case.extra["warning"] in w for w in outcome.warnings), outcome.warnings
        else:
            assert outcome.warnings == []
    else:
        assert not outcome.completed
        assert outcome.leftovers == []
        missing = [f for f in case.expect if f not in outcome.message]
        assert not missing, f"{case.name}: {missing} not in {outcome.message!r}"
        assert "\n" not in outcome.message


def test_inputs_are_unchanged_after_the_whole_corpus(corpus):
    _, unchanged = corpus
    assert unchanged
