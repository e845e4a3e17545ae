"""The ``lrde`` block of ``summary.json`` (docs/architecture.md, "summary.json") and a Markdown report.

References
----------
.. [1] Z. Zhang and Q. Gao, "Characterization of Extreme Low-Resolution Digital Encoder for
   Control System with Sinusoidal Reference Signal".
"""
from __future__ import annotations

import math

import numpy as np

from enclab.lrde import effects as lrde_effects

__all__ = ["summary_block", "report_markdown",
           "batch_rows", "effect_model_block", "estimates_block", "trust_block",
           "effect_residuals_block", "reference_block", "effect_params"]

_NOT_CONVERGED = "NOT converged (R-hat > 1.01 or ESS < 1000)"


def _num(value):
    """JSON-safe float: NaN and infinities become None."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _fmt(value, spec) -> str:
    """``value`` formatted, or "not defined" for a value the block holds as None (not
    finite: an autocorrelation time no walker's chain defines is infinite)."""
    return "not defined" if value is None else format(value, spec)


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
        Keys of summary.json (docs/architecture.md): ``A12``, ``a_eq``, ``E_b``, ``f_hz`` each
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


_ESTIMATES = ("A12", "E_b", "a_eq", "f_hz", "offset_a", "bias_b")


def estimates_block(fit) -> dict:
    """``A12, E_b, a_eq, f_hz, offset_a, bias_b`` of one fit (triples or None) and its model
    (for a pooled posterior, :func:`enclab.lrde.fit.pool_fits`, ``"averaged: <labels>"`` and
    ``models``)."""
    s = fit.summary
    out = {k: _triple(s.get(k)) for k in _ESTIMATES}
    pooled = fit.settings.get("pooled")
    if pooled:
        out["model"] = "averaged: " + ", ".join(pooled)
        out["models"] = list(pooled)
    else:
        out["model"] = fit.label
    out["converged"] = bool(fit.converged)
    return out


def effect_model_block(comparison: dict | None, chosen_fit=None, reason: str | None = None,
                       duration_s: float | None = None, jump: dict | None = None,
                       averaged_over: list | None = None) -> dict:
    """The ``model`` entry of the ``lrde`` block from
    :func:`enclab.lrde.compare.compare_effect_models` (or why it was not run).

    Keys: ``chosen`` (label, ``"sinusoid"`` when no term is added), ``harmonics``,
    ``effects``, ``signature`` (per chosen effect), ``params`` (the chosen fit's effect and
    harmonic parameters, ``{median, q05, q95}`` in SI units: hysteresis rad, drift 1/s,
    time_jitter s, ``c<k>``/``s<k>`` rad and, with harmonics, ``A12_fundamental``, twice the
    fundamental's amplitude, beside the reported ``A12``, the distorted motion's peak-to-peak
    stroke; plus ``drift_over_log`` (relative frequency change
    over ``duration_s``) and ``jump`` as given: ``{index, time_s, delta, probability}``),
    ``indistinguishable``, ``not_ruled_out`` and ``note``, ``delta_bic``, ``models``
    (held-out scores per candidate), ``check`` (the calibrated predictive check), ``rule``;
    with ``averaged_over`` (the labels of the fits whose posteriors the reported estimates
    pool, :func:`enclab.lrde.fit.pool_fits`) that list, and the note says so.
    """
    if comparison is None:
        return {"chosen": "sinusoid", "harmonics": [], "effects": [], "models": [],
                "reason": reason}
    out = {"chosen": comparison["chosen"], "harmonics": comparison["chosen_harmonics"],
           "effects": comparison["chosen_effects"],
           "signature": {e: lrde_effects.effect_signature(e)
                         for e in comparison["chosen_effects"]},
           "indistinguishable": list(comparison["indistinguishable"]),
           "not_ruled_out": list(comparison.get("not_ruled_out", [])),
           "delta_bic": _num(comparison["delta_bic"]),
           "models": [{k: (_num(v) if isinstance(v, float) else v) for k, v in m.items()}
                      for m in comparison["models"]],
           "check": {k: (_num(v) if isinstance(v, float) else v)
                     for k, v in comparison["check"].items()},
           "rule": comparison["rule"], "n_cycles": comparison["n_cycles"]}
    out["note"] = None
    if out["indistinguishable"] or out["not_ruled_out"]:
        which = "the estimates are those of the chosen model"
        if averaged_over:
            out["averaged_over"] = list(averaged_over)
            which = (f"the reported estimates pool the posteriors of "
                     f"{', '.join(averaged_over[:-1])} and {averaged_over[-1]} with equal "
                     f"weights ('after' is {out['chosen']} alone)")
        if out["indistinguishable"]:
            out["note"] = (f"{out['chosen']} is not distinguishable from "
                           f"{', '.join(out['indistinguishable'])} on held-out cycles (no more "
                           f"than two standard errors below it, or better); {which}")
        else:
            out["note"] = (f"no effect clears the rule, but {', '.join(out['not_ruled_out'])} "
                           f"predict{'s' if len(out['not_ruled_out']) == 1 else ''} each "
                           f"held-out fold better than the sinusoid: the readings do not rule "
                           f"{'it' if len(out['not_ruled_out']) == 1 else 'them'} out; "
                           f"{which}")
    out["params"] = effect_params(chosen_fit, duration_s, jump)
    return out


def effect_params(chosen_fit=None, duration_s: float | None = None,
                  jump: dict | None = None) -> dict:
    """The ``params`` entry of the ``model`` block: the fit's effect and harmonic parameters
    (see :func:`effect_model_block`)."""
    params = {}
    if chosen_fit is not None:
        extra = list(chosen_fit.param_names[5:])
        for name in extra:
            params[name] = _triple(chosen_fit.summary[name])
        if "A12_fundamental" in chosen_fit.summary:
            # A12 reports the distorted motion's stroke; this is its fundamental's.
            params["A12_fundamental"] = _triple(chosen_fit.summary["A12_fundamental"])
        for name in extra:
            if name in lrde_effects.REGISTRY:
                params.update(lrde_effects.effect(name).derived(chosen_fit.summary[name],
                                                                duration_s))
    if jump is not None:
        params["jump"] = jump
    return params


def reference_block(reference: dict | None, model_block: dict, added: list) -> dict | None:
    """The ``reference`` entry of the ``model`` block: the truth channel's findings and the fit.

    Parameters
    ----------
    reference : dict or None
        :func:`enclab.reference_effects.lrde_reference` of the measured channel.
    model_block : dict
        :func:`effect_model_block` of the final fit (its ``effects`` and ``params``).
    added : list of str
        Terms the held-out comparison did not choose and the reference added to the fit.

    Returns
    -------
    dict or None
        ``truth``, ``explained``, ``found``, ``not_modelled``, ``added`` and ``terms``: per
        encoder or clock term of either side, ``status`` (``"found by both"``, ``"added from
        the truth channel"``, ``"not confirmed by the truth channel"``, ``"not in this fit"``:
        found by the truth channel, no room for it in the fitted structure), the fit's value
        ``{median, q05, q95}`` (SI), the reference's ``value`` and ``ci`` where it has one,
        ``consistent`` (the two 90 % intervals overlap; None without both) and ``note``.
    """
    if reference is None:
        return None
    params = model_block.get("params") or {}
    by_term = {}
    for f in reference["found"]:
        by_term.setdefault(f["term"], f)
    terms = []
    for term in list(dict.fromkeys(list(reference["effects"]) + list(model_block["effects"]))):
        if not lrde_effects.effect(term).of_the_reading:  # e.g. the motion's frequency
            continue
        ref = by_term.get(term)
        fit_q = params.get(term) if isinstance(params.get(term), dict) else None
        row = {"term": term, "fit": fit_q, "reference_value": ref and ref["value"],
               "reference_ci": ref and ref["ci"], "consistent": None, "note": None}
        if ref is None:
            row["status"] = "not confirmed by the truth channel"
            row["note"] = lrde_effects.effect(term).unconfirmed
        elif term not in model_block["effects"]:
            row["status"] = "not in this fit"
            row["note"] = ("the truth channel shows it; the fitted model has no room for it "
                           "beside its own terms")
        else:
            row["status"] = ("added from the truth channel" if term in added
                             else "found by both")
            if fit_q is not None and ref["ci"] is not None:
                row["consistent"] = bool(fit_q["q05"] <= ref["ci"][1]
                                         and ref["ci"][0] <= fit_q["q95"])
        terms.append(row)
    return {"truth": reference["truth"], "explained": reference["explained"],
            "found": reference["found"], "not_modelled": reference["not_modelled"],
            "added": list(added), "terms": terms}


def _whole_log_check_passed(check: dict) -> bool:
    """The predictive check alone (``trusted`` also holds the localized one)."""
    return check["z"] >= check.get("threshold_z", -np.inf)


def trust_block(fit, model_block: dict) -> dict:
    """Per reported quantity ``{trusted, reason}``.

    A quantity is untrusted when the chosen model fails the predictive check (its readings
    are explained worse than its own simulations are), when its sampler did not converge,
    when the truth channel (``model_block["reference"]``) shows an effect that breaks an
    assumption the quantity rests on, leaves the readings unexplained or does not confirm a
    term the quantity rests on (the dead band: the stroke), when the fit has no term for an
    encoder effect the truth channel shows (every quantity), or (``offset_a``,
    ``bias_b``) when it is not identified at all.
    """
    reasons = []
    check = model_block.get("check") or {}
    if check and not check.get("trusted", True):
        trace = check.get("trace") or {}
        where = (f"; the misfit is worst {trace['where']} (z = {trace['z']:.1f})"
                 if trace.get("where") else "")
        if not _whole_log_check_passed(check):
            reasons.append(f"no candidate model explains the readings: the chosen model "
                           f"({model_block.get('chosen')}) scores {check['z']:.1f} standard "
                           f"deviations below its own simulated readings{where}")
        else:
            reasons.append(f"the chosen model ({model_block.get('chosen')}) leaves a misfit "
                           f"{trace.get('where')}: there the readings lie {-trace['z']:.1f} "
                           "standard deviations from what it expects, an effect none of the "
                           "candidates describes (its name may be a stand-in)")
    if not fit.converged:
        reasons.append("the sampler did not converge (R-hat > 1.01 or ESS < 1000)")
    ref = model_block.get("reference") or {}
    if ref and not ref.get("explained", True):
        reasons.append(f"against the truth channel ({ref.get('truth')}) the readings hold more "
                       "than any named effect explains")
    # what a term the truth channel does not confirm leaves the fitted motion unable to say:
    # the estimates that rest on the term's reading being the encoder's
    unconfirmed = [lrde_effects.effect(row["term"]).unconfirmed_biases
                   for row in ref.get("terms", [])
                   if row["status"] == "not confirmed by the truth channel"
                   and lrde_effects.effect(row["term"]).unconfirmed_biases]
    missing = [row["term"] for row in ref.get("terms", []) if row["status"] == "not in this fit"]
    out = {}
    for key in _ESTIMATES:
        r = list(reasons)
        r += [f"the truth channel shows {e['residual_effect']}, which this model has no term "
              f"for ({e['why']})" for e in ref.get("not_modelled", []) if key in e["biases"]]
        r += [why for biases, why in unconfirmed if key in biases]
        r += [f"the truth channel shows {term}, which this fit has no term for"
              for term in missing]
        if fit.summary.get(key) is None:
            r = ["not identified (readings give only a_eq = a + b)"]
        out[key] = {"trusted": not r, "reason": "; ".join(r) if r else None}
    return out


def effect_residuals_block(model_block: dict) -> dict | None:
    """The ``residuals`` block of docs/output-contract.md for a low-resolution log, from its
    effect comparison."""
    models = model_block.get("models") or []
    if not models:
        return None
    # A loop structure (enclab.lrde.loop) that replaced the periodic pick is in "loop".
    chosen = next(m for m in models + list(model_block.get("loop") or [])
                  if m["label"] == model_block["chosen"])
    effects = []
    if model_block["effects"] or model_block["harmonics"]:
        params = model_block.get("params") or {}
        for name in list(model_block["effects"]) + [f"harmonic{k}"
                                                     for k in model_block["harmonics"]]:
            keys = ([name] if name in params else
                    [f"c{name[8:]}", f"s{name[8:]}"] if name.startswith("harmonic") else [])
            effects.append({
                "name": name if not name.startswith("harmonic") else "harmonic_distortion",
                "params": {k: params[k]["median"] for k in keys if params.get(k)},
                "ci": {k: [params[k]["q05"], params[k]["q95"]] for k in keys if params.get(k)},
                "delta_bic": model_block.get("delta_bic"),
                "delta_elpd": chosen["delta_elpd"], "delta_elpd_se": chosen["delta_se"]})
    return {"metric": "held-out log predictive density per cycle (nats, higher is better; "
                      "point fits, even/odd cycles as folds)",
            "before": models[0]["elpd_per_cycle"], "after": chosen["elpd_per_cycle"],
            "effects": effects}


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
    averaged = block.get("averaged")
    if averaged:
        models = averaged["models"]
        why = ("the held-out comparison keeps the sinusoid but does not rule the others out"
               if (block.get("model") or {}).get("chosen") == "sinusoid"
               else "the held-out comparison cannot tell these models apart")
        lines[-1:-1] = ["", f"These estimates pool the posteriors of {', '.join(models[:-1])} "
                        f"and {models[-1]} (equal weights): {why}."]
    dwell_a12 = block["dwell_formula_A12"]
    lines.append("Eq. (4) baseline (mean dwell half-widths): "
                 + (f"{dwell_a12 * deg:.4f} deg." if dwell_a12 is not None
                    else "not available (no symmetric 2n-step cycles)."))
    d = block["dwell"]
    if d["prop1_in_band"] is not None:
        lines.append(f"Proposition 1 (|E_b| < epsilon/2 = {d['prop1_epsilon_half'] * deg:.4f} "
                     f"deg): {'holds' if d['prop1_in_band'] else 'violated'} on average, in "
                     f"{100 * d['prop1_fraction_cycles']:.0f} % of cycles.")
    lines += ["", f"Sampler diagnostics: max split R-hat {_fmt(diag['rhat_max'], '.4f')}, "
              f"min ESS {_fmt(diag['ess_min'], '.0f')}, max tau {_fmt(diag['tau_max'], '.1f')} "
              f"steps -> {'converged' if diag['converged'] else _NOT_CONVERGED}."]
    lines += _effect_lines(block)
    return "\n".join(lines) + "\n"


def _effect_lines(block: dict) -> list[str]:
    m = block.get("model")
    if not m:
        return []
    lines = ["", "## What the sinusoid misses: encoder, clock and motion effects", ""]
    if not m.get("models"):
        return lines + [f"Not compared: {m.get('reason')}."] + _before_after_lines(block) \
            + _reference_lines(m.get("reference"))
    lines += ["| model | held-out score per cycle [nats] | gain over the sinusoid | z | "
              "delta BIC |", "|---|---|---|---|---|"]
    for r in m["models"]:
        gain = "-" if r["label"] == "sinusoid" else f"{r['delta_elpd']:.1f} +- {r['delta_se']:.1f}"
        z = f"{r['z']:.1f}" if r.get("z") is not None else "-"
        bic = f"{r['delta_bic']:.1f}" if r.get("delta_bic") is not None else "-"
        lines.append(f"| {r['label']} | {r['elpd_per_cycle']:.3f} | {gain} | {z} | {bic} |")
    # With a loop structure chosen, the block's rule is the loop comparison's and the
    # periodic comparison's is under "periodic".
    periodic = m.get("periodic") or {}
    lines += ["", f"Rule: {periodic.get('rule', m['rule'])}.", ""]
    lines += _loop_lines(m.get("loop"), m["rule"] if periodic else m.get("loop_rule"))
    if m.get("loop_not_offered"):
        lines += [f"Loop structures not offered: {m['loop_not_offered']}.", ""]
    localized = (m.get("check") or {}).get("localized")
    if m["chosen"] == "sinusoid" and not m.get("not_ruled_out"):
        lines.append("Result: no effect predicts the held-out readings better than the "
                     "sinusoid; " + ("yet it leaves a misfit (localized check below) that "
                                     "no candidate describes." if localized
                                     else "the paper's model stands."))
    elif m["chosen"] == "sinusoid":
        lines.append("Result: no effect clears the rule; the paper's model is kept.")
        lines.append(f"Note: {m['note']}.")
    else:
        sig = "; ".join(f"{k}: {v}" for k, v in (m.get("signature") or {}).items())
        lines.append(f"Result: **{m['chosen']}**" + (f" ({sig})" if sig else "") + (
            ": the best of the candidates, but it leaves a misfit (localized check below), "
            "so the name may stand in for an effect outside the catalogue."
            if localized else "."))
        for name, q in (m.get("params") or {}).items():
            if isinstance(q, dict) and "median" in q:
                lines.append(f"- {name}: {q['median']:.4g} (90 %: {q['q05']:.4g} .. "
                             f"{q['q95']:.4g}) SI units")
        if m.get("note"):
            lines.append(f"Note: {m['note']}.")
    lines += _before_after_lines(block)
    lines += _reference_lines(m.get("reference"))
    check = m.get("check") or {}
    if check:
        verdict = ("passed" if _whole_log_check_passed(check)
                   else "FAILED: estimates untrusted")
        lines += ["", f"Predictive check: the chosen model's log-likelihood is "
                  f"{check['z']:.1f} standard deviations from that of its own simulated readings "
                  f"-> {verdict}."]
        trace = check.get("trace") or {}
        if trace.get("where"):
            worst = "; ".join(f"{r['covariate']}: {r['where']} ({r['z']:.1f})"
                              for r in trace.get("by_covariate", []))
            lines.append(f"Localized check (worst part per covariate, z): {worst} -> "
                         + ("FAILED: the misfit acts "
                            f"{trace['where']}, where no candidate explains the readings."
                            if check.get("localized") else "passed."))
    untrusted = {k: v["reason"] for k, v in (block.get("trust") or {}).items()
                 if not v["trusted"] and block.get(k) is not None}
    for k, reason in untrusted.items():
        lines.append(f"- {k} untrusted: {reason}.")
    return lines


def _loop_lines(rows, rule) -> list[str]:
    """The loop structures' held-out scores against the periodic pick (and, for one with an
    encoder term, against the structure without it)."""
    if not rows:
        return []
    lines = [f"| loop structure | held-out score per cycle [nats] | gain over {rows[0]['over']} "
             "| z | delta BIC | gain over the structure without | passes |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        z = f"{r['z']:.1f}" if r.get("z") is not None else "-"
        plain = r.get("over_plain")
        without = (f"{plain['delta_elpd']:.1f} +- {plain['delta_se']:.1f} ({plain['label']})"
                   if plain else "-")
        lines.append(f"| {r['label']} | {r['elpd_per_cycle']:.3f} | {r['delta_elpd']:.1f} +- "
                     f"{r['delta_se']:.1f} | {z} | {r['delta_bic']:.1f} | {without} | "
                     f"{'yes' if r.get('passed') else 'no'} |")
    return lines + ([""] + ([f"Rule: {rule}.", ""] if rule else []))


def _before_after_lines(block: dict) -> list[str]:
    before, after = block.get("before"), block.get("after")
    if not (before and after) or before["model"] == after["model"]:
        return []
    columns = [("before (sinusoid)", before), (f"after ({after['model']})", after)]
    if block.get("averaged"):
        columns.append((f"reported ({block['averaged']['model']})", block["averaged"]))
    lines = ["", "| quantity | " + " | ".join(c[0] for c in columns) + " |",
             "|---|" + "---|" * len(columns)]
    for key, label in (("A12", "stroke A12"), ("E_b", "E_b"), ("a_eq", "a_eq"),
                       ("offset_a", "offset a"), ("bias_b", "bias b")):
        lines.append(f"| {label} | " + " | ".join(_fmt_deg(c[1].get(key)) for c in columns)
                     + " |")
    return lines


def _reference_lines(ref: dict | None) -> list[str]:
    if not ref:
        return []
    lines = ["", f"### Against the truth channel ({ref['truth']})", "",
             "The residual stage compares these readings with the exact quantizer model of the "
             "truth channel: " + ("they match it within the quantization floor."
                                  if ref["explained"] else "they do not match it fully.")]
    if ref["added"]:
        lines.append(f"Added to the fit from its findings: {', '.join(ref['added'])} "
                     "(too small for the held-out comparison of the readings alone); the "
                     "'after' estimates above include it.")
    if ref["terms"]:
        lines += ["", "| term | status | this fit (90 %) | truth channel (90 %) | consistent |",
                  "|---|---|---|---|---|"]
        for r in ref["terms"]:
            q = r["fit"]
            fit_txt = "-" if q is None else f"{q['median']:.4g} ({q['q05']:.4g} .. {q['q95']:.4g})"
            ci = r["reference_ci"]
            ref_txt = ("-" if r["reference_value"] is None else f"{r['reference_value']:.4g}"
                       + (f" ({ci[0]:.4g} .. {ci[1]:.4g})" if ci else ""))
            agree = {True: "yes", False: "NO", None: "-"}[r["consistent"]]
            lines.append(f"| {r['term']} | {r['status']} | {fit_txt} | {ref_txt} | {agree} |")
        lines += [f"- {r['term']}: {r['note']}." for r in ref["terms"] if r["note"]]
    lines += [f"- {e['residual_effect']} (truth channel): no term here; {e['why']}."
              for e in ref["not_modelled"]]
    return lines


_BATCH_QUANTITIES = (("A12", "rad"), ("E_b", "rad"), ("a_eq", "rad"), ("offset_a", "rad"),
                     ("bias_b", "rad"), ("f_hz", "Hz"), ("sigma", "rad"))


def batch_rows(log_id: str, block: dict) -> list[dict]:
    """One row per posterior quantity of an ``lrde`` block, for the batch table.

    Every row repeats the log's identification and diagnostics so that a row read alone says
    whether it can be trusted: ``log_id, quantity, unit, median, q05, q95, converged,
    rhat_max, ess_min, n_cycles, steps_pp, step, dwell_formula_A12`` (the eq. 4 baseline, on
    the ``A12`` row only), ``reason`` (why ``offset_a``/``bias_b`` are missing, if they are),
    ``trusted`` and ``model`` (the chosen model, or ``"averaged: <models>"`` when the values
    pool several).
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
            "trusted": ((block.get("trust") or {}).get(quantity) or {}).get("trusted"),
            # the model the values come from (pooled: every model, see estimates_block)
            "model": (block.get("averaged") or {}).get("model")
            or (block.get("model") or {}).get("chosen"),
        })
    return rows
