"""The run summary (enclab.report), the progress display (enclab.progress) and thumbnails.

Built from hand-made summaries, so every number on the page can be checked against its source.
"""
from __future__ import annotations

import io as stdio
import logging

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from enclab import progress, report
from enclab.core import atomic  # noqa: E402
from PIL import Image  # noqa: E402
from snakemake_interface_logger_plugins.common import LogEvent  # noqa: E402


def _quant_summary(log_id, warnings=()):
    return {"log_id": log_id, "quantization": {"rows": []}, "warnings": list(warnings)}


def _lrde_summary(log_id):
    q = {"median": 5.18e-3, "q05": 5.15e-3, "q95": 5.21e-3}
    return {"log_id": log_id, "warnings": [],
            "lrde": {"A12": q, "E_b": {"median": -3.4e-6, "q05": -1.5e-5, "q95": 7.9e-6},
                     "offset_a": None, "bias_b": None, "reason": "not identified",
                     "diagnostics": {"converged": True, "rhat_max": 1.002, "ess_min": 2456.0}}}


RATIOS = pd.DataFrame({
    "order": [0, 1, 1], "level": ["1mrad"] * 3, "architecture": ["none", "joint", "operational"],
    "n_rows": [42, 1008, 504], "ratio_pqn_min": [0.989, 0.850, 0.866],
    "ratio_pqn_max": [0.996, 1.041, 1.040], "ratio_exact_min": [0.997, 0.966, 0.970],
    "ratio_exact_max": [1.003, 1.044, 1.041]})


def test_failure_of_takes_the_first_error_line_without_stamp_and_id():
    texts = {"quantization.log": "2026-12-02 07:00:00,1 enclab.quantization INFO [bad] start\n"
                                 "2026-12-02 07:00:01,2 enclab.quantization ERROR [bad] bad.csv: "
                                 "column 'q', line 3: empty or NaN value.\n"}
    assert report.failure_of(texts) == {"stage": "quantization",
                                        "error": "bad.csv: column 'q', line 3: empty or NaN value."}
    assert report.failure_of({})["stage"] is None


def test_run_summary_headlines_failures_and_warnings():
    summaries = [_quant_summary("a", ["time base: sampled at 1 Hz ..."]), _quant_summary("b"),
                 _lrde_summary("l")]
    failures = {"bad": {"stage": "ingest", "error": "bad.csv: column 'q', line 3: NaN."}}
    run = report.run_summary(summaries, ["a", "b", "bad", "l"], failures, ratios=RATIOS,
                             violations=pd.DataFrame(), written={"summary.json": 3})
    assert run["logs"] == {"total": 4, "completed": 3, "failed": 1}
    assert run["completed"] == ["a", "b", "l"] and run["not_run"] == []
    q = run["analyses"]["quantization"]
    assert q["logs"] == 2 and q["bound_violations"] == 0
    assert q["ratios"][1] == {"order": 1, "name": "velocity", "n_rows": 1512,
                              "exact": [0.966, 1.044], "pqn": [0.850, 1.041]}
    assert run["analyses"]["lrde"]["rows"][0]["A12"]["median"] == 5.18e-3
    assert run["analyses"]["residuals"] is None
    assert run["failed"] == [{"log_id": "bad", **failures["bad"]}]
    assert run["warnings"] == [{"log_id": "a", "warning": "time base: sampled at 1 Hz ..."}]

    text = report.summary_text(run)
    assert text.startswith("enclab: 4 logs, 3 completed, 1 failed\n")
    assert "velocity: measured/exact std 0.966-1.044, measured/PQN 0.850-1.041 (1512 rows)" in text
    assert "max|error| within the trajectory worst case in every row" in text
    assert "l: A12 5.18 mrad [5.15 mrad, 5.21 mrad]" in text and "converged" in text
    assert "bad [ingest]: bad.csv: column 'q', line 3: NaN." in text
    assert "a: time base: sampled at 1 Hz" in text
    assert "  completed (3): a, b, l\n" in text and "NOT RUN" not in text

    page = report.summary_rst(run)
    assert page.startswith("{% raw %}") and page.rstrip().endswith("{% endraw %}")
    assert "max\\|error\\|" in page and "``bad`` [ingest]" in page
    assert report.report_metadata(run) == {"logs completed": 3, "logs failed": 1}


def test_run_summary_rejects_failures_of_completed_logs():
    with pytest.raises(ValueError, match="completed or are not in the run"):
        report.run_summary([_quant_summary("a")], ["a"], {"a": {"stage": "x", "error": "y"}})


def test_run_summary_design_headline():
    design = {"budget": [{"order": 1, "axes": ["x"], "std": 0.01, "worst": 0.05}],
              "chosen": {"resolution": {"q1": 4096, "q2": 8192},
                         "filters": [{"label": "d1 n2 fc40 tustin joint"}],
                         "cost": 35.0, "lag_s": 0.0079, "margin": 0.124},
              "check": {"trajectories": 200, "exact_design": {"pass_rate": 1.0},
                        "table2_design": {"pass_rate": 0.485}}}
    run = report.run_summary([_quant_summary("a")], ["a"], {}, design=design)
    block = run["analyses"]["design"]
    assert block["chosen"]["resolution"] == {"q1": 4096, "q2": 8192}
    assert block["pass_rate"] == {"exact_design": 1.0, "table2_design": 0.485}
    text = report.summary_text(run)
    assert "velocity std <= 0.01 and worst <= 0.05" in text
    assert "q1 4096, q2 8192; d1 n2 fc40 tustin joint; cost 35, lag 7.9 ms, margin 12.4 %" in text
    assert "chosen design within budget in 100.0 %, PQN/Table II design within budget in 48.5 %" in text
    infeasible = report.run_summary([_quant_summary("a")], ["a"], {},
                                    design={**design, "chosen": None, "check": {},
                                            "message": "no design meets the budget"})
    assert "no design meets the budget" in report.summary_text(infeasible)
    assert report.run_summary([_quant_summary("a")], ["a"], {})["analyses"]["design"] is None


def test_run_summary_rig_headline():
    rig = {"rig": "tool", "measured": "cui", "runs": ["r1", "r2", "r3"],
           "splits": [{"split": "frequency", "test_runs": 1, "before_steady": 0.0136,
                       "before_all": 0.0138, "after_steady": 0.00056, "after_all": 0.00077,
                       "floor": 0.00022}],
           "spread": {"scale": {"rel_dev": 0.05}, "torque_back:linear": {"rel_dev": 1.48}}}
    run = report.run_summary([_quant_summary("a")], ["a"], {}, rigs=[rig])
    row = run["analyses"]["rigs"]["rows"][0]
    assert row["runs"] == 3 and row["not_pinned_down"] == ["torque_back:linear"]
    text = report.summary_text(run)
    assert ("tool/cui (3 runs), held out by frequency: 13.6 mrad -> 0.56 mrad steady, "
            "0.77 mrad all (floor 0.22 mrad)") in text
    assert "not pinned down across folds: torque_back:linear" in text
    assert report.run_summary([_quant_summary("a")], ["a"], {})["analyses"]["rigs"] is None


def test_summary_page_renders_through_the_report_template():
    # The report renders the page with Jinja, then docutils: markup in messages stays text.
    from docutils.core import publish_parts
    from jinja2 import Environment

    run = report.run_summary([_quant_summary("a")], ["a", "x"],
                             {"x": {"stage": "ingest", "error": "{{ not a template }} *stars* `q`"}})
    html = publish_parts(Environment().from_string(report.summary_rst(run)).render(),
                         writer="html")["html_body"]
    assert "{{ not a template }} *stars* `q`" in html.replace("&quot;", '"')


# ----------------------------------------------------------------------------- progress


def _record(msg=None, level=logging.INFO, **extra):
    record = logging.LogRecord("snakemake", level, "", 0, msg, None, None)
    record.__dict__.update(extra)
    return record


def test_progress_prints_one_line_per_job_and_failure(tmp_path, monkeypatch):
    # the handler sets the variable for the jobs it starts: restored after this test
    monkeypatch.setenv(progress.QUIET_JOBS_ENV, "")
    log = tmp_path / "ingest.log"
    log.write_text("2026 enclab.core.ingest ERROR [bad] bad.csv: line 3: NaN value.\n")
    out = stdio.StringIO()
    handler = progress.ProgressHandler(stream=out)
    emit = handler.emit
    emit(_record("Job stats...", event=LogEvent.RUN_INFO,
                 stats={"ingest": 2, "publish_log": 1, "total": 3}))
    emit(_record(event=LogEvent.JOB_INFO, jobid=1, rule_name="ingest", wildcards={"log_id": "a"},
                 log=[]))
    emit(_record(event=LogEvent.JOB_INFO, jobid=2, rule_name="publish_log",
                 wildcards={"log_id": "a"}, log=[]))
    emit(_record(event=LogEvent.JOB_INFO, jobid=3, rule_name="ingest", wildcards={"log_id": "bad"},
                 log=[str(log)]))
    emit(_record("Finished jobid: 1", event=LogEvent.JOB_FINISHED, job_id=1))
    emit(_record("Finished jobid: 2", event=LogEvent.JOB_FINISHED, job_id=2))
    emit(_record("Error in rule ingest", level=logging.ERROR, event=LogEvent.JOB_ERROR,
                 rule_name="ingest", jobid=3, log=[str(log)]))
    emit(_record("Select jobs to execute..."))
    emit(_record("Nothing to be done (all requested files are present and up to date)."))
    emit(_record("batch_scope=completed: leaving out 1 log(s)", level=logging.WARNING))
    lines = out.getvalue().splitlines()
    assert lines[0] == "enclab: 3 jobs: ingest 2, publish_log 1"
    assert lines[1].startswith("[1/3]  ingest") and lines[1].rstrip().endswith(" s")
    assert lines[2] == (f"[2/3]  FAILED ingest              bad: bad.csv: line 3: NaN value. "
                        f"(log: {log})")
    assert lines[3:] == ["Nothing to be done (all requested files are present and up to date).",
                         "batch_scope=completed: leaving out 1 log(s)"]
    # while the handler is active, jobs keep their messages to their log files
    assert __import__("os").environ[progress.QUIET_JOBS_ENV] == "1"


def test_error_line_of_falls_back_to_the_last_line():
    assert progress.error_line_of(["a\n", "Traceback\nKeyError: 'x'\n\n"]) == "KeyError: 'x'"
    assert progress.error_line_of([]) is None


def test_logger_plugin_is_found_by_snakemake():
    from snakemake_interface_logger_plugins.registry import LoggerPluginRegistry

    assert LoggerPluginRegistry().get_plugin("enclab").log_handler is progress.ProgressHandler


# ----------------------------------------------------------------------------- thumbnails


def test_thumbnail_is_small_deterministic_and_keeps_the_aspect(tmp_path):
    fig, ax = plt.subplots(figsize=(10, 8))
    ax.plot(np.random.default_rng(0).normal(size=20000))
    atomic.save_figure(fig, tmp_path / "full.png", dpi=150)
    atomic.save_thumbnail(tmp_path / "full.png", tmp_path / "a" / "thumb.png", max_width=480)
    atomic.save_thumbnail(tmp_path / "full.png", tmp_path / "b.png", max_width=480)
    with Image.open(tmp_path / "a" / "thumb.png") as thumb:
        assert thumb.size == (480, 384) and thumb.mode == "P"
    assert (tmp_path / "a" / "thumb.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    # a tenth of the pixels, a 64-colour palette: well under a third of the bytes
    assert (tmp_path / "b.png").stat().st_size < (tmp_path / "full.png").stat().st_size / 3
    with pytest.raises(ValueError, match="max_width"):
        atomic.save_thumbnail(tmp_path / "full.png", tmp_path / "c.png", max_width=4)


def test_logs_that_never_ran_are_listed_apart_from_the_failed_ones():
    # A run stopped before some logs (e.g. Snakemake itself failed): those logs have no error
    # line; they are "not run", not failed with no reason.
    failures = {"bad": report.failure_of({"ingest.log": "t enclab.ingest ERROR [bad] logs/bad.csv: "
                                                        "permission denied; give ..."}),
                "later": report.failure_of({})}
    run = report.run_summary([_quant_summary("a")], ["a", "bad", "later"], failures)
    assert run["logs"] == {"total": 3, "completed": 1, "failed": 1}
    assert run["failed"] == [{"log_id": "bad", "stage": "ingest",
                              "error": "logs/bad.csv: permission denied; give ..."}]
    assert run["not_run"] == ["later"] and run["completed"] == ["a"]
    text = report.summary_text(run)
    assert text.startswith("enclab: 3 logs, 1 completed, 1 failed, 1 not run\n")
    assert "    bad [ingest]: logs/bad.csv: permission denied" in text
    assert "NOT RUN (1; the run stopped before them: rerun)\n    later\n" in text
    assert "no error line" not in text
    page = report.summary_rst(run)
    assert "**Not run**" in page and "- ``later``" in page
    assert report.report_metadata(run)["logs not run"] == 1
