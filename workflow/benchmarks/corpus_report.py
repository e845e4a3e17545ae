"""Does every case of the bad-input corpus end as expected through the real workflow?

Run the bad-input corpus through the real workflow and print case / expected / got / pass.

The cases are defined in tests/corpus/cases.py (the same ones tests/test_corpus.py asserts);
this prints the Markdown table of the README's troubleshooting section. About two minutes on
2 cores. Usage::

    PYTHONPATH=workflow python -m benchmarks.corpus_report [--keep DIR]
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
from pathlib import Path

from .helpers import ROOT


def _run_corpus():
    """``run_corpus`` of ``tests/corpus/run.py``: the corpus belongs to the tests, which are no
    package, so it is loaded from its file when the report runs (never on import)."""
    spec = importlib.util.spec_from_file_location("corpus_run", ROOT / "tests" / "corpus" / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.run_corpus


def _cell(text: str, width: int = 150) -> str:
    text = text.replace("|", "\\|")
    return text if len(text) <= width else text[: width - 1] + "…"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", help="run in this directory and keep it (default: a temp dir)")
    args = parser.parse_args(argv)
    work = Path(args.keep or tempfile.mkdtemp(prefix="enclab_corpus_"))
    work.mkdir(parents=True, exist_ok=True)
    outcomes, unchanged = _run_corpus()(work)
    print("| case | input | expected | got | pass |")
    print("|---|---|---|---|---|")
    for o in outcomes:
        if o.case.expect is None:
            expected = "completes" + (f", reports {o.case.extra['report']}"
                                      if o.case.extra.get("report") else "")
            got = "completed" + (f", {dict((k, o.report[k]) for k in o.case.extra.get('report', {}))}"
                                 if o.completed and o.case.extra.get("report") else "")
        else:
            where = "before any job" if o.case.up_front else f"rule {o.case.stage or 'ingest'}"
            expected = f"{where}: " + " … ".join(f"`{f}`" for f in o.case.expect)
            got = o.message or "(no message)"
        print(f"| {o.case.name} | {_cell(o.case.what, 60)} | {_cell(expected, 80)} | "
              f"{_cell(got)} | {'yes' if o.passed else '**NO**'} |")
    print(f"\n{sum(o.passed for o in outcomes)}/{len(outcomes)} cases pass; input checksums "
          f"{'unchanged' if unchanged else 'CHANGED'} after the whole corpus ({work}).")
    return 0 if unchanged and all(o.passed for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
