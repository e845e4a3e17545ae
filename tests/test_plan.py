"""The workflow's plan (enclab.plan): stages, chunks, targets and report figures from a config and
a manifest, without Snakemake."""
from __future__ import annotations

import pytest
from enclab import plan

CONFIG = {"manifest": "manifest.yaml", "chunk_size": 2, "batch_scope": "all",
          "figures": {"fig7_group": "g0"}, "design": None}


def _single(log_id, group=None, stages=None):
    """A one-joint log with one truth channel (the quantization-error stages by default)."""
    entry = {"id": log_id, "group": group,
             "channels": [{"name": "theta", "role": "truth", "joint": 1}]}
    if stages is not None:
        entry["analysis"] = {"stages": stages}
    return entry


def _pair(log_id, rig=None, stages=None):
    """A log with a truth/measured pair on joint 1 (the residual stage by default)."""
    entry = {"id": log_id, "group": None,
             "channels": [{"name": "motor", "role": "truth", "joint": 1},
                          {"name": "output", "role": "measured", "joint": 1},
                          {"name": "torque", "role": "other"}]}
    if rig is not None:
        entry["rig"] = rig
    if stages is not None:
        entry["analysis"] = {"stages": stages}
    return entry


def _entries(*entries):
    return {e["id"]: e for e in entries}


RIG = {"name": "bench", "splits": [{"name": "runs", "leave_one_run_out": True}]}
MIXED = _entries(
    _single("q1", group="g0"), _single("q2", group="g0"), _single("q3", group="g1"),
    _single("q4"), _single("lr", stages=["lrde"]),
    _pair("res"), _pair("both", stages=["quantization", "residuals"]),
    _pair("run1", rig={**RIG, "conditions": {"load": 1}}),
    _pair("run2", rig={**RIG, "conditions": {"load": 2}}),
)


def test_stages_default_to_residuals_for_a_pair_and_quantization_otherwise():
    assert plan.stages_of(_single("a")) == ["quantization"]
    assert plan.stages_of(_pair("b")) == ["residuals"]
    assert plan.stages_of(_pair("c", stages=["lrde"])) == ["lrde"]
    no_pair = _pair("d")
    no_pair["analysis"] = {"residuals": False}
    assert plan.stages_of(no_pair) == ["quantization"]


def test_chunks_hold_the_quantization_only_logs_sorted_k_per_chunk():
    assert plan.chunked_ids(MIXED, 2) == ["q1", "q2", "q3", "q4"]
    assert plan.chunk_plan(MIXED, 2) == {"chunk0000": ["q1", "q2"], "chunk0001": ["q3", "q4"]}
    assert plan.chunk_plan(MIXED, 3) == {"chunk0000": ["q1", "q2", "q3"], "chunk0001": ["q4"]}
    # 0: one job per stage and log, no chunk
    assert plan.chunk_plan(MIXED, 0) == {} and plan.chunked_ids(MIXED, 0) == []


def test_select_entries_keeps_only_logs_in_their_order_and_names_unknown_ones():
    manifest = list(MIXED.values())
    assert list(plan.select_entries(manifest, [])) == list(MIXED)
    assert list(plan.select_entries(manifest, ["q3", "q1"])) == ["q3", "q1"]
    with pytest.raises(ValueError, match=r"config key 'only_logs': unknown log id\(s\) \['nope'\]"):
        plan.select_entries(manifest, ["q1", "nope"])


def test_plan_sorts_the_logs_of_each_analysis():
    p = plan.make_plan(CONFIG, MIXED)
    assert p.log_ids == sorted(MIXED) and p.failed == []
    assert p.quantization_ids == ["both", "q1", "q2", "q3", "q4"]
    assert p.lrde_ids == ["lr"]
    assert p.residual_ids == ["both", "res", "run1", "run2"]
    assert p.residual_pairs["res"] == [{"measured": "output", "truth": "motor", "joint": 1}]
    assert p.rig_channels == [("bench", "output")]
    assert p.chunk_of == {"q1": "chunk0000", "q2": "chunk0000", "q3": "chunk0001", "q4": "chunk0001"}
    # the first log of each repeat group draws the per-log figures, every ungrouped log too
    assert p.figure_ids == ["both", "q1", "q3", "q4"]
    assert p.chunk_figure_ids == ["q1", "q3", "q4"]
    assert p.paper_figures  # the Fig. 7 group g0 is there


def test_completed_scope_leaves_failed_logs_and_their_rigs_out_but_keeps_the_chunks():
    done = {"q1", "q3", "q4", "res", "run1", "lr", "both"}
    p = plan.make_plan({**CONFIG, "batch_scope": "completed"}, MIXED, has_summary=done.__contains__)
    assert p.failed == ["q2", "run2"]
    assert "q2" not in p.log_ids and p.rigs == {}  # a rig with a failed run is left out
    assert p.chunks == plan.chunk_plan(MIXED, 2)  # the second pass finds the same chunks
    assert p.chunk_figure_ids == ["q1", "q3", "q4"]  # over every log asked for, as the chunks


def test_rig_errors_name_the_manifest():
    lonely = _entries(_pair("run1", rig={**RIG, "conditions": {"load": 1}}))
    with pytest.raises(ValueError, match=r"^manifest.yaml: log 'run1', key rig.name: rig 'bench' has one run"):
        plan.make_plan(CONFIG, lonely)


def test_all_targets_ask_for_every_analysis_output_and_the_thumbnails():
    p = plan.make_plan({**CONFIG, "design": {"budget": 1}}, MIXED)
    targets = p.all_targets()
    assert targets[:len(MIXED)] == [f"results/{i}/summary.json" for i in sorted(MIXED)]
    for expected in ("results/q1/figures/errors.png", "results/lr/lrde/report.md",
                     "results/batch/quantization.csv", "results/figures/fig6_position.png",
                     "results/batch/lrde.csv", "results/res/residuals/output/covariates.png",
                     "results/batch/residuals.csv", "results/rigs/bench/output/report.md",
                     "results/design/pareto.png", "results/summary.json",
                     "results/report/thumbs/rig_remains"):
        assert expected in targets, expected
    assert "results/q2/figures/errors.png" not in targets  # a repeat of group g0
    assert len(targets) == len(set(targets))


def test_a_lone_quantization_log_asks_for_no_other_analysis():
    p = plan.make_plan(CONFIG, _entries(_single("q1")))
    assert p.all_targets() == [
        "results/q1/summary.json", "results/q1/figures/errors.png",
        "results/batch/quantization.csv", "results/batch/pooled.csv", "results/figures/ratios.png",
        "results/summary.json", "results/report/thumbs/log_errors",
        "results/report/thumbs/log_comparison", "results/report/thumbs/ratio_figure"]
    assert p.summary_inputs("q1") == {"canonical": "results/q1/canonical.parquet",
                                      "requantized": "results/q1/requantized.parquet",
                                      "moments": "results/q1/moments.json",
                                      "theory": "results/q1/theory.json"}
    assert p.run_summary_inputs()["tables"] == [
        "results/batch/quantization.csv", "results/batch/pooled.csv", "results/batch/ratios.csv",
        "results/batch/bound_violations.csv"]
    assert "rigs" not in p.run_summary_inputs() and p.design_inputs() == {}


def test_summary_inputs_merge_the_blocks_of_the_analyses_a_log_runs():
    p = plan.make_plan(CONFIG, MIXED)
    both = p.summary_inputs("both")
    assert set(both) == {"canonical", "requantized", "moments", "theory", "residuals"}
    assert both["residuals"] == ["results/both/residuals/output/residuals.json"]
    assert p.summary_inputs("lr") == {"canonical": "results/lr/canonical.parquet",
                                      "lrde": "results/lr/lrde/lrde.json"}
    assert p.residual_blocks("lr") == []


def test_report_figures_name_thumbnails_by_log_channel_or_figure():
    p = plan.make_plan(CONFIG, MIXED)
    figures = p.report_figures()
    assert list(figures) == [k for k in plan.REPORT_FIGURES if k in figures]  # registry order
    assert figures["log_errors"][0] == ("results/both/figures/errors.png",
                                        "results/report/thumbs/log_errors/both.png")
    assert ("results/res/residuals/output/diagnostics.png",
            "results/report/thumbs/residual_diagnostics/res/output.png") in figures["residual_diagnostics"]
    assert figures["rig_map"] == [("results/rigs/bench/output/map.png",
                                   "results/report/thumbs/rig_map/bench/output.png")]
    assert figures["fig7"] == [("results/figures/fig7_derivatives.png",
                                "results/report/thumbs/fig7/fig7_derivatives.png")]
    assert "design_pareto" not in figures  # no design configured
    assert plan.thumbnail_pattern("rig_map") == "{log_id}/{channel}.png"
    assert plan.thumbnail_pattern("lrde_corner") == "{log_id}.png"
    assert plan.thumbnail_pattern("fig6") == "{name}.png"


def test_every_registered_figure_says_whose_it_is():
    instances = plan.make_plan(CONFIG, MIXED).figure_instances()
    for kind, figure in plan.REPORT_FIGURES.items():
        assert figure.drawn_for in instances, kind
        assert figure.pattern.startswith("results/") and figure.pattern.endswith(".png"), kind


def test_merged_settings_let_a_log_override_the_config():
    entry = {"analysis": {"lrde": {"seed": 3}}}
    assert plan.merged_settings({"lrde": {"seed": 1, "walkers": 8}}, entry, "lrde") == {"seed": 3, "walkers": 8}
    assert plan.merged_settings({}, {}, "residuals") == {}


def test_report_has_one_category_per_analysis():
    assert set(plan.REPORT_CATEGORIES) == {"propagation", "lrde", "residuals", "rig", "design"}
    assert {f.category for f in plan.REPORT_FIGURES.values()} == set(plan.REPORT_CATEGORIES.values())
    assert plan.REPORT_FIGURES["fig6"].category == plan.REPORT_CATEGORIES["propagation"]
    assert plan.REPORT_FIGURES["rig_map"].category == plan.REPORT_CATEGORIES["rig"]
