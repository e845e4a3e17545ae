"""The report's landing page is what a lab prints: counts, verdicts and headline figures on top.

The page (``enclab.report.summary_rst``) is rendered as Snakemake's report renders it (Jinja,
then docutils' HTML writer) and read back as an element sequence: the verdict table and one
figure per analysis that ran come right after the title and the counts, before the details.
The stylesheet starts the content pane at the top (Snakemake centres it vertically). The slow
test reads the landing page of a real report made by ``enclab residuals``.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from enclab import plan, report
from enclab.core.quantize import quantize
from workspace import ROOT, SNAKEMAKE

RATIOS = pd.DataFrame({
    "order": [0, 1], "level": ["1mrad"] * 2, "architecture": ["none", "joint"],
    "n_rows": [42, 1008], "ratio_pqn_min": [0.989, 0.850], "ratio_pqn_max": [0.996, 1.041],
    "ratio_exact_min": [0.997, 0.966], "ratio_exact_max": [1.003, 1.044]})


def _summaries():
    q = {"median": 5.18e-3, "q05": 5.15e-3, "q95": 5.21e-3}
    lrde = {"A12": q, "E_b": q, "offset_a": None, "bias_b": None, "reason": "not identified",
            "diagnostics": {"converged": True, "rhat_max": 1.002, "ess_min": 2456.0}}

    def residuals(measured, explained):
        return {"channels": {measured: {"measured": measured, "truth": "motor",
                                        "explained": explained, "effects": [],
                                        "before": {"std": 2e-3, "floor_std": 1e-3},
                                        "after": {"std": 1e-3, "floor_std": 1e-3}}}}

    return [{"log_id": "q1", "quantization": {"rows": []}, "warnings": []},
            {"log_id": "coarse", "lrde": lrde, "warnings": []},
            {"log_id": "rig_a", "residuals": residuals("out", True), "warnings": []},
            {"log_id": "rig_b", "residuals": residuals("out", False), "warnings": []}]


RIG = {"rig": "tool", "measured": "cui", "runs": ["rig_a", "rig_b"],
       "splits": [{"split": "load", "before_steady": 0.0136, "after_steady": 0.00056,
                   "after_all": 0.00077, "floor": 0.00022}], "spread": {}}
DESIGN_BLOCK = {"budget": [{"order": 1, "std": 0.01}],
          "chosen": {"resolution": {"q1": 4096}, "filters": [{"label": "d1 n2 fc40"}],
                     "cost": 12.0, "lag_s": 0.008, "margin": 0.1}, "check": {}}


def _run(**kwargs):
    return report.run_summary(_summaries(), ["q1", "coarse", "rig_a", "rig_b", "bad"],
                              {"bad": {"stage": "ingest", "error": "bad.csv: column 'q'"}},
                              ratios=RATIOS, violations=pd.DataFrame(), rigs=[RIG],
                              design=DESIGN_BLOCK, written={"summary.json": 4}, **kwargs)


class _Elements(HTMLParser):
    """Block elements of a page in document order, with their class and text."""

    BLOCKS = {"h1", "p", "table", "figure", "img", "div", "ul", "tr", "td"}

    def __init__(self):
        super().__init__()
        self.items: list[dict] = []
        self._open: list[dict] = []

    def handle_starttag(self, tag, attrs):
        if tag in self.BLOCKS:
            item = {"tag": tag, "class": dict(attrs).get("class") or "", "text": "",
                    "attrs": dict(attrs)}
            self.items.append(item)
            if tag != "img":
                self._open.append(item)

    def handle_endtag(self, tag):
        for k in range(len(self._open) - 1, -1, -1):
            if self._open[k]["tag"] == tag:
                del self._open[k:]
                break

    def handle_data(self, data):
        for item in self._open:
            item["text"] += data


def _landing_html(page: str) -> str:
    # as snakemake.report renders its landing page
    from docutils.core import publish_parts
    from jinja2 import Environment

    return publish_parts(Environment().from_string(page).render(files=[], categories={}),
                         writer="html")["html_body"]


def _elements(html: str) -> list[dict]:
    parser = _Elements()
    parser.feed(html)
    return parser.items


def test_verdicts_and_one_figure_per_analysis_come_first():
    items = _elements(_landing_html(report.summary_rst(_run())))
    tags = [(i["tag"], i["class"]) for i in items]
    title = tags.index(("h1", "title"))
    table = next(k for k, (t, c) in enumerate(tags) if t == "table" and "enclab-verdicts" in c)
    figures = next(k for k, (t, c) in enumerate(tags) if t == "div" and c == "enclab-figures")
    assert title < table < figures
    # nothing but the counts line between the title and the verdict table
    assert [t for t, _ in tags[title + 1:table]] == ["p"]
    assert "5 logs" in items[title + 1]["text"] and "1 failed" in items[title + 1]["text"]
    # one row per analysis that ran, in the report's order, and the failed logs
    rows = [i["text"] for i in items[table:figures] if i["tag"] == "tr"][1:]
    assert [r.strip().split("\n")[0].split(" (")[0] for r in rows] == [
        "quantization", "low-resolution encoder", "residuals", "rigs", "design", "failed"]
    assert "bad" in rows[-1]
    # one figure per analysis, in the same order, the thumbnail linking the full-size figure
    images = [i for i in items[figures:] if i["tag"] == "img"]
    captions = [i["text"] for i in items[figures:] if i["tag"] == "figure"]
    assert [i["attrs"]["alt"] for i in images] == [
        "quantization", "low-resolution encoder", "residuals", "rigs", "design"]
    assert [i["attrs"]["src"] for i in images] == [
        "report/thumbs/ratio_figure/ratios.png", "report/thumbs/lrde_bias_cycles/coarse.png",
        "report/thumbs/residual_before_after/rig_b/out.png",  # the unexplained channel
        "report/thumbs/rig_heldout/tool/cui.png", "report/thumbs/design_pareto/pareto.png"]
    assert "rig_b/out" in captions[2] and "unexplained" in captions[2]
    # the details follow the figures
    failed = next(k for k, i in enumerate(items) if i["text"].startswith("Failed logs"))
    assert figures < failed


def test_every_headline_figure_is_a_thumbnail_the_workflow_writes():
    for figure in report.headline_figures(_run()):
        kind = figure["thumbnail"].split("/")[3]
        assert kind in plan.REPORT_FIGURES, kind
        source = plan.REPORT_FIGURES[kind].pattern.removeprefix("results/")
        # the full-size figure the caption links is the thumbnail's source
        assert re.fullmatch(re.sub(r"\\\{[a-z_]+\\\}", "[^/]+", re.escape(source)),
                            figure["figure"]), (kind, figure["figure"])


def test_a_long_analysis_is_cut_in_the_table_and_listed_in_full_below():
    summaries = _summaries()[:1] + [
        {"log_id": f"l{k}", "lrde": _summaries()[1]["lrde"], "warnings": []} for k in range(6)]
    run = report.run_summary(summaries, [s["log_id"] for s in summaries], {})
    html = _landing_html(report.summary_rst(run))
    table = html[html.index("enclab-verdicts"):html.index("</table>")]
    assert "l2:" in table and "l3:" not in table and "3 more below" in table
    assert "l5: A12" in html[html.index("</table>"):]


def test_no_analysis_no_table_and_no_figures():
    run = report.run_summary([], ["bad"], {"bad": {"stage": "ingest", "error": "x"}})
    assert report.headline_figures(run) == []
    html = _landing_html(report.summary_rst(run))
    assert "enclab-figures" not in html and "failed" in html


def test_the_stylesheet_starts_the_content_pane_at_the_top():
    css = (ROOT / "workflow/report/report.css").read_text()
    rule = re.search(r"([^{}]*items-center[^{}]*)\{([^}]*)\}", css)
    assert rule and ".h-screen" in rule[1] and "align-items: flex-start" in rule[2]
    assert re.search(r"\.enclab-figures\s*\{[^}]*display: flex", css)


@pytest.mark.slow
def test_a_real_report_opens_on_the_verdicts_and_figures(tmp_path):
    if not SNAKEMAKE.exists():
        pytest.fail(f"snakemake is not installed next to {sys.executable}")
    step = 2 * np.pi / 8192
    t = np.arange(4000) / 1000.0
    truth = np.deg2rad(15) * np.sin(2 * np.pi * t + 1.0)
    pd.DataFrame({"t": t, "motor": truth, "out": step * quantize(truth, step).astype(float)}
                 ).to_csv(tmp_path / "rig1.csv", index=False, float_format="%.17g")
    # the package under test, wherever this test imported it from
    env = dict(os.environ, PYTHONPATH=str(Path(report.__file__).resolve().parents[1]))
    done = subprocess.run([sys.executable, "-m", "enclab", "residuals", "rig1.csv", "--truth",
                           "motor", "--measured", "out"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    results = tmp_path / "enclab-rig1" / "results"
    html = (results / "report.html").read_text()
    desc = json.loads(re.search(r"var workflow_desc = (.*?);\n", html).group(1))
    items = _elements(desc)
    kinds = [(i["tag"], i["class"]) for i in items]
    table = kinds.index(("table", "enclab-verdicts docutils"))
    assert table < kinds.index(("div", "enclab-figures"))
    (image,) = [i for i in items if i["tag"] == "img"]
    assert (results / image["attrs"]["src"]).is_file()  # next to report.html
    embedded = json.loads(re.search(r"var results = (\{.*?\});\n", html, re.S).group(1))
    assert embedded["results/" + image["attrs"]["src"]]["data_uri"].startswith("data:image/png")
    assert "align-items: flex-start" in html  # the stylesheet is in the report
