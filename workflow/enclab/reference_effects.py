"""What the residual stage found on a coarse channel, in the terms of the low-resolution fit.

A log with a fine (truth) channel beside its coarse one runs both analyses: the residual stage
(:mod:`enclab.residuals`) compares the coarse readings with the exact quantizer model of the
truth and names the encoder's own effects, with a reference far finer than the readings; the
low-resolution fit (:mod:`enclab.lrde`) sees only the coarse readings and must tell an effect
of the encoder from one of the motion. This module carries the first stage's findings into the
second, so that an effect found against the truth enters the fit even when it is too small for
the fit's own held-out comparison, and so that the fit's report can say which of its terms the
reference confirms. It lives above both packages, which do not import each other.

Each residual-stage effect either has a term of the low-resolution model (the same physical
effect, the same parameter in SI units) or is listed with the reason it has none.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

__all__ = ["lrde_reference", "references_by_channel"]

# Effects of the encoder (or of its clock) that the low-resolution model has a term for.
# A play before the encoder and a dead band of the reading give identical readings, and both
# are the low-resolution model's ``hysteresis`` of the same width.
_TERM = {"backlash": ("hysteresis", "w"), "hysteresis": ("hysteresis", "h"),
         "timestamp_jitter": ("time_jitter", "sigma_t")}

# Why the others have no term: what they do to the low-resolution fit's estimates.
_NO_TERM = {
    "latency": "a constant delay shifts the phase of the motion only; A12, a_eq and E_b are "
               "unaffected",
    "scale_mismatch": "a scale error of the reading rescales the stroke; the fit reports the "
                      "stroke as read",
    "angle_harmonics": "a once- or twice-per-turn error of the disc; over a stroke of a few "
                       "steps it acts as a scale and offset error of the reading",
    "line_pitch_harmonics": "an interpolation error far below one coarse step",
    "quadrature_edges": "unequal edge spacing: the levels of the reading are not evenly "
                        "spaced, which the model's uniform levels cannot represent",
    "compliance": "a torque-dependent lag between the motion and the encoder; it distorts "
                  "the motion the encoder sees, as a motion harmonic would",
    "slow_drift": "a slow drift of the reading moves a_eq over the log; the model's a_eq is "
                  "constant, so its a_eq and E_b hold only as averages over the log",
    "wrap_around": "a counter wrap; not expected on a stroke of a few steps",
    "level_shift": "a change of the reading's offset during the log; the model's a_eq is "
                   "constant, so its a_eq and E_b hold only as averages over the log",
    "harmonic_map": "an angle error of three or more cycles per turn; over a stroke of a few "
                    "steps it acts as a scale and offset error of the reading",
    "truth_quantization": "the reference channel's own quantization",
}


# Effects without a term that break an assumption the estimates rest on: the quantities they
# bias. (The others shift only the phase, rescale the stroke as read, or distort the motion as
# a harmonic would, which the comparison's motion terms cover.)
_BREAKS = {
    "slow_drift": ("a_eq", "E_b", "offset_a"),          # a_eq is constant in the model
    "quadrature_edges": ("A12", "a_eq", "E_b", "offset_a"),  # the levels are evenly spaced
    "missed_counts": ("a_eq", "E_b", "offset_a"),       # more than the one modelled jump
    "level_shift": ("a_eq", "E_b", "offset_a"),         # a_eq is constant in the model
}


def _interval(effect: Mapping, key: str) -> list[float] | None:
    ci = (effect.get("ci") or {}).get(key)
    if ci is None:
        return None
    lo, hi = sorted(abs(float(v)) for v in ci)
    if float(ci[0]) * float(ci[1]) < 0:  # a signed width whose interval spans zero
        lo = 0.0
    return [lo, hi]


def lrde_reference(residual_block: Mapping) -> dict:
    """The residual stage's findings on one measured channel as low-resolution model terms.

    Parameters
    ----------
    residual_block : mapping
        One channel's ``residuals.json`` (:func:`enclab.residuals.pipeline.analyse_channel`):
        ``measured``, ``truth`` and ``selection`` with ``explained`` and ``effects`` (each
        ``name``, ``params``, ``ci``).

    Returns
    -------
    dict
        ``channel`` and ``truth`` (names), ``explained`` (the residual stage's verdict),
        ``effects`` (the low-resolution terms to add, in the order found, each once),
        ``found`` (per term: ``term``, ``residual_effect``, ``value`` and ``ci`` in SI units),
        ``not_modelled`` (per residual-stage effect without a term: ``residual_effect``,
        ``why`` and ``biases``, the estimates it breaks an assumption of).

    A single missed or extra count becomes the ``count_jump`` term; several become a
    ``not_modelled`` entry, since the model holds one jump.
    """
    selection = residual_block.get("selection")
    if not isinstance(selection, Mapping):
        raise ValueError(f"the residuals block of channel {residual_block.get('measured')!r} "
                         "has no 'selection'")
    found, not_modelled, terms = [], [], []
    for effect in selection.get("effects") or []:
        name = effect.get("name")
        params = effect.get("params") or {}
        if name in _TERM:
            term, key = _TERM[name]
            if key not in params:
                raise ValueError(f"residual effect {name!r} has no parameter {key!r}: "
                                 f"{sorted(params)}")
            entry = {"term": term, "residual_effect": name, "value": abs(float(params[key])),
                     "ci": _interval(effect, key)}
        elif name == "missed_counts":
            jumps = [v for k, v in params.items() if k.startswith("n_")]
            if len(jumps) != 1 or abs(round(float(jumps[0]))) != 1:
                not_modelled.append({
                    "residual_effect": name,
                    "why": f"{len(jumps)} count steps found (sizes "
                           f"{', '.join(f'{float(j):+.0f}' for j in jumps)}); the model holds "
                           "one step of one count",
                    "biases": list(_BREAKS[name])})
                continue
            entry = {"term": "count_jump", "residual_effect": name,
                     "value": float(params.get("t_1", float("nan"))), "ci": None,
                     "unit": "s (time of the step)"}
        else:
            not_modelled.append({"residual_effect": name,
                                 "why": _NO_TERM.get(name, "no term of the low-resolution "
                                                           "model describes it"),
                                 "biases": list(_BREAKS.get(name, ()))})
            continue
        found.append(entry)
        if entry["term"] not in terms:
            terms.append(entry["term"])
    return {"channel": residual_block.get("measured"), "truth": residual_block.get("truth"),
            "explained": bool(selection.get("explained")), "effects": terms,
            "found": found, "not_modelled": not_modelled}


def references_by_channel(residual_blocks: Iterable[Mapping]) -> dict[str, dict]:
    """:func:`lrde_reference` of each ``residuals.json``, keyed by its measured channel."""
    out = {}
    for block in residual_blocks:
        ref = lrde_reference(block)
        if ref["channel"] is None:
            raise ValueError("a residuals block names no measured channel")
        out[ref["channel"]] = ref
    return out
