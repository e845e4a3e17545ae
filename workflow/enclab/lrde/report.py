"""The ``lrde`` block of ``summary.json`` (DESIGN.md section 3) and a Markdown report.

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal".
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["summary_block", "motion_model_block", "residuals_block", "report_markdown",
           "batch_rows"]

_NOT_CONVERGED = "NOT converged (R-hat > 1.01 or ESS < 1000)"


def _num(value):
    """JSON-safe float: NaN and infinities become None."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _triple(d):
    return None if d is None else {k: _num(d[k]) for k in ("median", "q05", "q95")}


def summary_block(fit, dwell: dict) -> dict:
    """The ``lrde`` block: posterior summaries, identifiability, dwell baseline, diagnostics.

    Parameters
    ----------
    fit : enclab.lrde.fit.FitResult
    dwell : dict
        :func:`enclab.lrde.dwell.dwell_summary` of the same counts.

    Returns
    -------
    dict
        Keys of DESIGN.md section 3: ``A12``, ``a_eq``, ``E_b``, ``f_hz`` each
        ``{median, q05, q95}`` (rad, Hz); ``offset_a`` and ``bias_b`` the same or None, with
        ``reason``; ``dwell_formula_A12`` (eq. 4 at the mean half-widths, rad or None);
        ``diagnostics`` ``{rhat_max, ess_min, tau_max, converged}``. Extra keys: ``sigma``,
        ``phase``, ``step``, ``steps_pp``, ``centre_count``, ``n_cycles``, ``dwell`` (the
        Proposition 1 / 2 checks of the dwell summary) and ``sampler`` settings.
    """
    s = fit.summary
    block = {
        "A12": _triple(s["A12"]),
        "a_eq": _triple(s["a_eq"]),
        "E_b": _triple(s["E_b"]),
        "f_hz": _triple(s["f_hz"]),
        "offset_a": _triple(fit.offset_a),
        "bias_b": _triple(fit.bias_b),
        "reason": fit.reason,
        "dwell_formula_A12": _num(dwell.get("dwell_formula_A12")),
        "diagnostics": {
            "rhat_max": _num(max(fit.rhat.values())),
            "ess_min": _num(min(fit.ess.values())),
            "tau_max": _num(max(fit.tau.values())),
            "converged": bool(fit.converged),
        },
        "sigma": _triple(s["sigma"]),
        "phase": _triple(s["phase"]),
        "step": _num(fit.step),
        "steps_pp": int(fit.steps_pp),
        "centre_count": _num(fit.centre_count),
        "n_cycles": int(dwell.get("n_cycles", 0)),
        "dwell": {
            "n_used": int(dwell.get("n_used", 0)),
            "A12_mean_of_cycles": _num(dwell.get("A12_mean_of_cycles")),
            "A12_std_of_cycles": _num(dwell.get("A12_std_of_cycles")),
            "E_b_dwell": _num(dwell.get("E_b_dwell")),
            "prop1_epsilon_half": _num(dwell.get("prop1_epsilon_half")),
            "prop1_in_band": dwell.get("prop1_in_band"),
            "prop1_fraction_cycles": _num(dwell.get("prop1_fraction_cycles")),
            "prop2_n_tested": int(dwell.get("prop2_n_tested", 0)),
            "prop2_sign_agreement": _num(dwell.get("prop2_sign_agreement")),
        },
        "sampler": {k: v for k, v in fit.settings.items() if k != "bounds_internal"}
        | {"acceptance": _num(fit.acceptance)},
    }
    return block


def motion_model_block(comparison: dict | None, reason: str | None = None) -> dict:
    """The ``motion_model`` entry of the ``lrde`` block from
    :func:`enclab.lrde.compare.compare_motion_models` (or why it was not run).

    Keys: ``models`` (per candidate: ``harmonics``, held-out ``elpd``, ``elpd_per_cycle``,
    ``delta_elpd``, ``delta_se``, ``z``), ``n_cycles``, ``chosen``, ``rule``, ``delta_bic``,
    ``harmonics`` (per chosen order ``k``: ``c``, ``s`` and ``amplitude = hypot(c, s)``, each
    ``{median, q05, q95}`` in rad) and ``A12_fundamental`` (twice the fundamental's amplitude
    in the chosen model), or ``reason`` when no comparison was made.
    """
    if comparison is None:
        return {"models": [], "chosen": [], "reason": reason}
    out = {k: comparison[k] for k in ("models", "n_cycles", "chosen", "rule")}
    out["delta_bic"] = _num(comparison["delta_bic"])
    out["models"] = [{k: (_num(v) if isinstance(v, float) else v) for k, v in m.items()}
                     for m in comparison["models"]]
    chosen_fit = comparison.get("fit")
    if chosen_fit is not None:
        names = list(chosen_fit.param_names)
        harmonics = {}
        for k in chosen_fit.harmonics:
            c = chosen_fit.samples[:, names.index(f"c{k}")]
            s = chosen_fit.samples[:, names.index(f"s{k}")]
            harmonics[str(k)] = {"c": _triple(chosen_fit.summary[f"c{k}"]),
                                 "s": _triple(chosen_fit.summary[f"s{k}"]),
                                 "amplitude": _quantile_triple(np.hypot(c, s))}
        out["harmonics"] = harmonics
        out["A12_fundamental"] = _triple(chosen_fit.summary["A12"])
        out["converged"] = bool(chosen_fit.converged)
    return out


def residuals_block(motion: dict) -> dict | None:
    """DESIGN's ``residuals`` block for a low-resolution log, from its ``motion_model``.

    The metric is the held-out log predictive density per cycle (nats; higher is better):
    ``before`` for the paper's sinusoid, ``after`` for the chosen model; one effect
    ``harmonic_distortion`` per chosen order with its ``c``, ``s`` (rad) and 90 % intervals.
    None when no comparison was made.
    """
    models = motion.get("models") or []
    if not models:
        return None
    chosen = next(m for m in models if m["harmonics"] == motion["chosen"])
    effects = []
    for k, h in (motion.get("harmonics") or {}).items():
        effects.append({
            "name": "harmonic_distortion",
            "params": {"order": int(k), "c": h["c"]["median"], "s": h["s"]["median"],
                       "amplitude": h["amplitude"]["median"]},
            "ci": {"c": [h["c"]["q05"], h["c"]["q95"]], "s": [h["s"]["q05"], h["s"]["q95"]],
                   "amplitude": [h["amplitude"]["q05"], h["amplitude"]["q95"]]},
            "delta_bic": motion.get("delta_bic"),
            "delta_elpd": chosen["delta_elpd"], "delta_elpd_se": chosen["delta_se"],
        })
    return {"metric": "held-out log predictive density per cycle (nats, higher is better; "
                      "two-fold by halves)",
            "before": models[0]["elpd_per_cycle"], "after": chosen["elpd_per_cycle"],
            "effects": effects}


def _quantile_triple(x):
    q05, q50, q95 = np.quantile(x, [0.05, 0.5, 0.95])
    return {"median": float(q50), "q05": float(q05), "q95": float(q95)}


def _fmt_deg(d):
    if d is None or d.get("median") is None:
        return "not identified"
    deg = 180.0 / math.pi
    return (f"{d['median'] * deg:.4f} deg (90 %: {d['q05'] * deg:.4f} .. "
            f"{d['q95'] * deg:.4f})")


def report_markdown(block: dict, log_id: str | None = None) -> str:
    """A short Markdown report of an ``lrde`` block (angles in degrees for reading)."""
    title = f"# Low-resolution encoder analysis{f': {log_id}' if log_id else ''}"
    deg = 180.0 / math.pi
    diag = block["diagnostics"]
    f = block["f_hz"]
    lines = [
        title, "",
        f"Encoder step {block['step'] * deg:.4g} deg; readings {block['steps_pp']} steps peak to "
        f"peak about count {block['centre_count']:g}; {block['n_cycles']} complete cycles.", "",
        "| quantity | posterior median and 90 % interval |", "|---|---|",
        f"| stroke A12 | {_fmt_deg(block['A12'])} |",
        f"| bias deviation E_b (eq. 14) | {_fmt_deg(block['E_b'])} |",
        f"| a_eq = a + b (eq. 13b) | {_fmt_deg(block['a_eq'])} |",
        f"| frequency | {f['median']:.5g} Hz (90 %: {f['q05']:.5g} .. {f['q95']:.5g}) |",
        f"| offset a | {_fmt_deg(block['offset_a'])} |",
        f"| bias b | {_fmt_deg(block['bias_b'])} |",
        "",
        f"Identifiability: {block['reason']}.", "",
    ]
    dwell_a12 = block["dwell_formula_A12"]
    lines.append("Eq. (4) baseline (mean dwell half-widths): "
                 + (f"{dwell_a12 * deg:.4f} deg." if dwell_a12 is not None
                    else "not available (no symmetric 2n-step cycles)."))
    d = block["dwell"]
    if d["prop1_in_band"] is not None:
        lines.append(f"Proposition 1 (|E_b| < epsilon/2 = {d['prop1_epsilon_half'] * deg:.4f} "
                     f"deg): {'holds' if d['prop1_in_band'] else 'violated'} on average, in "
                     f"{100 * d['prop1_fraction_cycles']:.0f} % of cycles.")
    lines += ["", f"Sampler diagnostics: max split R-hat {diag['rhat_max']:.4f}, min ESS "
              f"{diag['ess_min']:.0f}, max tau {diag['tau_max']:.1f} steps -> "
              f"{'converged' if diag['converged'] else _NOT_CONVERGED}."]
    lines += _motion_model_lines(block.get("motion_model"))
    return "\n".join(lines) + "\n"


# Held-out log predictive density per sample below which the report calls the fit poor: the
# interval likelihood of a model that fits gives each reading a probability near 1 (the
# embedded open-loop log -0.034, the Encos sine -0.021 nats per sample), while a motion the
# model cannot follow misses whole dwells (the DC-motor log: -0.53).
_POOR_ELPD_PER_SAMPLE = -0.2


def _motion_model_lines(motion: dict | None) -> list[str]:
    if not motion:
        return []
    lines = ["", "## What the sinusoid misses: motion models on held-out data", ""]
    if not motion.get("models"):
        return lines + [f"Not compared: {motion.get('reason')}."]
    deg = 180.0 / math.pi
    lines += ["| model | held-out elpd per cycle [nats] | gain over the sinusoid | z |",
              "|---|---|---|---|"]
    for m in motion["models"]:
        name = ("sinusoid (paper 002)" if not m["harmonics"] else
                "sinusoid + harmonic " + ", ".join(str(k) for k in m["harmonics"]))
        gain = (f"{m['delta_elpd']:.1f} +- {m['delta_se']:.1f}" if m["harmonics"] else "-")
        z = f"{m['z']:.1f}" if m.get("z") is not None else "-"
        lines.append(f"| {name} | {m['elpd_per_cycle']:.3f} | {gain} | {z} |")
    lines += ["", f"Rule: {motion['rule']}."]
    chosen = next(m for m in motion["models"] if m["harmonics"] == motion["chosen"])
    poor = (chosen.get("elpd_per_sample") is not None
            and chosen["elpd_per_sample"] < _POOR_ELPD_PER_SAMPLE)
    if poor:
        lines.append(f"Warning: the best model still predicts the held-out readings poorly "
                     f"({chosen['elpd_per_sample']:.2f} nats per sample; a model that fits "
                     "reads each sample with probability near 1, i.e. near 0 nats): the motion "
                     "is not a sinusoid plus these harmonics (see the dwell posterior-predictive "
                     "plot).")
    if not motion["chosen"]:
        lines.append("Result: no candidate predicts the held-out readings better than the "
                     "sinusoid" + (" - which itself fits poorly." if poor else
                                   "; the paper's model stands."))
        return lines
    for k, h in motion["harmonics"].items():
        lines.append(f"Result: harmonic {k} of the motion, amplitude {_fmt_deg(h['amplitude'])}"
                     f" (c = {_fmt_deg(h['c'])}, s = {_fmt_deg(h['s'])}).")
    fund = motion["A12_fundamental"]
    lines.append(f"With it the fundamental's stroke is {fund['median'] * deg:.4f} deg (90 %: "
                 f"{fund['q05'] * deg:.4f} .. {fund['q95'] * deg:.4f}); delta BIC "
                 f"{motion['delta_bic']:.1f} (positive favours the model).")
    return lines


_BATCH_QUANTITIES = (("A12", "rad"), ("E_b", "rad"), ("a_eq", "rad"), ("offset_a", "rad"),
                     ("bias_b", "rad"), ("f_hz", "Hz"), ("sigma", "rad"))


def batch_rows(log_id: str, block: dict) -> list[dict]:
    """One row per posterior quantity of an ``lrde`` block, for the batch table.

    Every row repeats the log's identification and diagnostics so that a row read alone says
    whether it can be trusted: ``log_id, quantity, unit, median, q05, q95, converged,
    rhat_max, ess_min, n_cycles, steps_pp, step, dwell_formula_A12`` (the eq. 4 baseline, on
    the ``A12`` row only) and ``reason`` (why ``offset_a``/``bias_b`` are missing, if they are).
    """
    diag = block["diagnostics"]
    rows = []
    for quantity, unit in _BATCH_QUANTITIES:
        triple = block.get(quantity) or {}
        rows.append({
            "log_id": log_id, "quantity": quantity, "unit": unit,
            "median": triple.get("median"), "q05": triple.get("q05"), "q95": triple.get("q95"),
            "converged": diag["converged"], "rhat_max": diag["rhat_max"],
            "ess_min": diag["ess_min"], "n_cycles": block["n_cycles"],
            "steps_pp": block["steps_pp"], "step": block["step"],
            "dwell_formula_A12": block["dwell_formula_A12"] if quantity == "A12" else None,
            "reason": block["reason"] if quantity in ("offset_a", "bias_b") and not triple
            else None,
        })
    return rows
