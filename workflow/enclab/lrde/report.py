"""The ``lrde`` block of ``summary.json`` (DESIGN.md section 3) and a Markdown report.

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal".
"""
from __future__ import annotations

import math

__all__ = ["summary_block", "report_markdown", "batch_rows"]

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
    return "\n".join(lines) + "\n"


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
