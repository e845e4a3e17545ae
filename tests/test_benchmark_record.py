"""The benchmark page and its record: tables survive a round trip through the page and a
fresh clone renders the page that is committed."""
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks import render_benchmarks as rb

ROOT = Path(__file__).resolve().parents[1]


def _table(seed):
    rng = np.random.default_rng(seed)
    return pd.DataFrame({
        "date": ["2026-01-01 10:00 UTC"] * 3 + ["2026-01-02 11:30 UTC"] * 2,
        "machine": ["AMD EPYC, 2 cores, load 0.7"] * 3 + ["vm (2 cores, x86_64)"] * 2,
        "command": ["python a.py --x 1"] * 3 + ["python a.py --cases a b; echo"] * 2,
        "case": ["clean", "drift", "a|b", "clean", "all"],
        "n": [200, 100, 64, 52, 900],
        "rate": rng.uniform(0, 1, 5),
        "big": rng.uniform(0, 1, 5) * 1e5,
        "gap": [0.5, np.nan, 0.25, np.nan, 1.0],
        "flag": [True, False, True, True, False],
    })


def test_printed_tables_come_back_from_the_page(tmp_path):
    bench = tmp_path / "bench"
    bench.mkdir()
    _table(1).to_csv(bench / "lrde_effects_summary.csv", index=False)
    _table(2).to_csv(bench / "other_summary.csv", index=False)
    page = rb.render(bench)
    tables = rb.tables_from_markdown(page)
    assert set(tables) == {"lrde_effects_summary.csv", "other_summary.csv"}
    again = tmp_path / "again"
    again.mkdir()
    for name, frame in tables.items():
        frame.to_csv(again / name, index=False)
    assert rb.render(again) == page
    back = tables["lrde_effects_summary.csv"]
    assert list(back["case"]) == ["clean", "drift", "a|b", "clean", "all"]
    assert list(back["command"][3:]) == ["python a.py --cases a b; echo"] * 2
    np.testing.assert_allclose(back["rate"], _table(1)["rate"], rtol=5e-4)


def test_per_draw_tables_are_named_not_rebuilt(tmp_path):
    bench = tmp_path / "bench"
    bench.mkdir()
    pd.concat([_table(3)] * 20).to_csv(bench / "some_draws.csv", index=False)
    page = rb.render(bench, max_rows=80)
    assert "100 rows (per draw or per log), not printed" in page
    assert rb.tables_from_markdown(page) == {}


def test_a_fresh_checkout_restores_the_record_and_renders_the_same_page(tmp_path):
    bench, record = tmp_path / "results", tmp_path / "record"
    bench.mkdir()
    _table(4).to_csv(bench / "first_run.csv", index=False)
    _table(5).to_csv(bench / "design_search.csv", index=False)
    page = rb.render(bench)
    rb.keep_record(bench, record)
    fresh = tmp_path / "fresh"
    assert sorted(rb.restore(fresh, record)) == ["design_search.csv", "first_run.csv"]
    assert rb.render(fresh) == page
    # A table measured again replaces its own record only.
    _table(6).to_csv(fresh / "first_run.csv", index=False)
    assert rb.restore(fresh, record) == []
    rb.keep_record(fresh, record)
    assert pd.read_csv(record / "first_run.csv")["rate"].iloc[0] == _table(6)["rate"].iloc[0]


def test_the_committed_page_is_the_committed_record_rendered():
    record = ROOT / "docs" / "benchmarks"
    assert rb.render(record) == (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8")


def test_rows_with_the_scripts_old_command_form_render_and_record_in_the_module_form(tmp_path):
    # A run started before the benchmarks were a package records the script's path; the page
    # and the record show the command that reruns it, with every other cell as it was.
    bench, record = tmp_path / "results", tmp_path / "record"
    bench.mkdir()
    table = _table(7).assign(command=["python workflow/benchmarks/residual_length.py --lengths 4000"] * 2
                             + ["PYTHONPATH=workflow python -m benchmarks.residual_length --lengths 4000"] * 3)
    table.to_csv(bench / "residual_length.csv", index=False)
    page = rb.render(bench)
    assert "workflow/benchmarks/residual_length.py" not in page
    assert page.count("`PYTHONPATH=workflow python -m benchmarks.residual_length --lengths 4000`") == 2
    rb.keep_record(bench, record)
    kept = pd.read_csv(record / "residual_length.csv")
    assert set(kept["command"]) == {"PYTHONPATH=workflow python -m benchmarks.residual_length --lengths 4000"}
    pd.testing.assert_frame_equal(kept.drop(columns="command"), pd.read_csv(bench / "residual_length.csv")
                                  .drop(columns="command"))
    assert rb.render(record) == page
