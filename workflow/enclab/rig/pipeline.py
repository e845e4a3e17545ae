"""The rig fit's entry point: the runs of one rig fitted together for one measured channel.

:func:`run_from_canonical` reads a run from its canonical log, :func:`rule_spec` builds the
model from the ``rig`` settings of ``config.yaml`` and a manifest's declared compliance,
:func:`analyse_rig` runs the held-out evaluation (:mod:`enclab.rig.fit`) and :func:`report_rig`
returns everything rule ``rig`` writes (block, tables, figures and report text,
:mod:`enclab.rig.report`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from enclab.core.canonical import Channel
from enclab.rig import fit as rg
from enclab.rig.report import (compliance_figure, condition_table, fit_block, heldout_figure,
                               map_figure, markdown, remains, remains_figure, split_table)

__all__ = ["run_from_canonical", "rule_spec", "analyse_rig", "report_rig", "EXTRAPOLATION_RATIO"]

#: Default of ``rig.extrapolation_ratio`` (config.yaml): a split whose held-out std exceeds this
#: multiple of the other splits' or of its training runs' own held-out std does not extrapolate.
EXTRAPOLATION_RATIO = 2.0


def run_from_canonical(df, meta: Mapping, measured: str, truth: str, torques: Sequence[str] = (),
                       conditions: Mapping | None = None, run_id: str | None = None) -> rg.Run:
    """A :class:`~enclab.rig.fit.Run` from a canonical log (:func:`enclab.core.canonical.read_canonical`):
    channel names of the measured and truth angles and of the torques (N m) the compliance uses."""
    reading, reference = Channel.named(meta, measured, df), Channel.named(meta, truth, df)
    if reading.step is None:
        raise ValueError(f"log {meta.get('log_id')!r}: measured channel {measured!r} has no quantization step")
    return rg.Run(run_id=run_id or str(meta.get("log_id")), t=df["t"].to_numpy(np.float64),
                  truth=reference.values, measured=reading.values, step=reading.step,
                  truth_step=reference.step,
                  torques={k: Channel.named(meta, k, df).values for k in torques},
                  conditions=dict(conditions or {}))


def rule_spec(settings: Mapping, compliance: Mapping) -> tuple[rg.RigSpec, list]:
    """The rig rule's model from the ``rig`` settings of ``config.yaml`` and a manifest's declared
    ``compliance``: ``(spec, candidate numbers of torque-map intervals)``. The spec starts at the
    largest knot spacing; the compliance's form, the reversal transient, a torque map's intervals
    and the spacing are then chosen per fold on its training runs (:func:`report_rig` with
    ``variants="takeup"``)."""
    knots = list(settings.get("torque_knots") or [8])
    spec = rg.RigSpec(spacing=max(settings["spacings"]), max_play=settings["max_play"],
                      travel=settings["travel"], t_skip=settings["t_skip"], transient=settings.get("transient"),
                      latency=True if settings.get("latency") == "run" else "shared",
                      torque_map_forms=tuple(settings.get("torque_map_forms") or ("linear",)),
                      **rg.declared_compliance(compliance, knots[0]))
    return spec, knots


def analyse_rig(runs: Sequence[rg.Run], spec: rg.RigSpec, splits: Sequence[Mapping],
                spacings: Sequence[float] | None, variants=None,
                torque_knots: Sequence[int] | None = None,
                extrapolation_ratio: float = EXTRAPOLATION_RATIO) -> dict:
    """Held-out evaluation of one rig and one measured channel, and the fit on every run.

    ``variants``: candidate model forms chosen per fold on its training runs
    (:func:`enclab.rig.fit.evaluate`; ``"takeup"``: the declared compliance or the play
    take-up, with or without the reversal transient). ``torque_knots``: candidate numbers of
    intervals of the torque maps of ``spec`` (:func:`enclab.rig.fit.choose_model`).

    Returns
    -------
    dict
        ``rows`` (one per fold and run, :func:`enclab.rig.fit.evaluate`), ``folds``
        (the fold results), ``spread`` (:func:`enclab.rig.fit.fold_spread` over the folds
        of condition splits), ``remains`` per split, ``final`` (the fit on all runs, its knot
        spacing chosen by leave-one-run-out), ``spacing_scores``, ``extrapolation`` (per
        condition split, :func:`enclab.rig.fit.extrapolation` with ``extrapolation_ratio``)
        and ``coverage`` (:func:`enclab.rig.fit.coverage` of all runs: where the final fit
        stops interpolating).
    """
    folds = rg.make_folds(runs, splits)
    rows, out = rg.evaluate(runs, spec, folds, spacings, keep_residuals=True, variants=variants,
                            torque_knots=torque_knots)
    rem = {}
    for split in dict.fromkeys(f["split"] for f in out):
        res = {k: v for f in out if f["split"] == split for k, v in f["residuals"].items()}
        rem[split] = remains(runs, res, spec)
    fspec, scores, _ = rg.choose_model(runs, spec, spacings, variants, torque_knots=torque_knots)
    final = rg.fit_rig(runs, fspec)
    return {"rows": rows, "folds": out, "spread": rg.fold_spread(out) if out else {}, "remains": rem,
            "final": final, "spacing_scores": scores, "spec": spec,
            "extrapolation": rg.extrapolation(runs, rows, out, extrapolation_ratio),
            "coverage": rg.coverage(runs, spec.t_skip)}


def report_rig(name: str, channel: str, runs: Sequence[rg.Run], spec: rg.RigSpec,
               splits: Sequence[Mapping], spacings: Sequence[float] | None,
               truth_counts_per_rev: float | None = None, variants=None,
               torque_knots: Sequence[int] | None = None,
               extrapolation_ratio: float = EXTRAPOLATION_RATIO) -> dict:
    """Everything the rig rule writes for one measured channel: ``block`` (JSON), ``tables``
    (``heldout`` per fold and run, ``splits``, ``conditions``), ``figures`` (``map``,
    ``compliance``, ``heldout``, ``remains``) and ``markdown``."""
    result = analyse_rig(runs, spec, splits, spacings, variants, torque_knots, extrapolation_ratio)
    conditions = list(dict.fromkeys(k for r in runs for k in r.conditions))
    torques = {ch: (float(min(np.percentile(r.torques[ch], 0.5) for r in runs)),
                    float(max(np.percentile(r.torques[ch], 99.5) for r in runs))) for ch in spec.compliance}
    title = f"rig {name}: {channel}"
    rows = [{k: v for k, v in r.items() if not k.endswith("_ss")} for r in result["rows"]]
    block = {
        "rig": name, "measured": channel, "runs": [r.run_id for r in runs],
        "metric": "std of (reading - prediction) [rad]; steady strokes and all samples after t_skip",
        "settings": {"travel": spec.travel, "t_skip": spec.t_skip, "max_play": spec.max_play,
                     "latency": "run" if spec.latency is True else spec.latency,
                     "compliance": dict(spec.compliance), "transient": spec.transient,
                     "spacings": list(spacings or []), "extrapolation_ratio": extrapolation_ratio},
        "splits": split_table(result["rows"]).to_dict("records"),
        "heldout": rows,
        "folds": [{"split": f["split"], "fold": str(f["fold"]), "test": f["test"],
                   "spacing_scores": f["spacing_scores"], "variant_scores": f.get("variant_scores"),
                   **fit_block(f["fit"])} for f in result["folds"]],
        "spread": result["spread"], "remains": result["remains"],
        "final": {**fit_block(result["final"]), "spacing_scores": result["spacing_scores"]},
        # Per condition split: whether the fit extrapolates to its test conditions, the term
        # that carries the held-out excess, and what the training and test runs covered.
        "extrapolation": result["extrapolation"],
        "coverage": result["coverage"],
    }
    return {
        "block": block,
        "tables": {"heldout": pd.DataFrame(rows), "splits": split_table(result["rows"]),
                   "conditions": condition_table(result["rows"], conditions)},
        "figures": {"map": map_figure(result, title), "compliance": compliance_figure(result, torques, title),
                    "heldout": heldout_figure(result, conditions, title),
                    "remains": remains_figure(result, runs, title)},
        "markdown": markdown(name, channel, result, conditions, truth_counts_per_rev),
    }
