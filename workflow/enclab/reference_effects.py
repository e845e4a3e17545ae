"""What the residual stage found on a coarse channel, in the terms of the low-resolution fit.

A log with a fine (truth) channel beside its coarse one runs both analyses: the residual stage
(:mod:`enclab.residuals`) compares the coarse readings with the exact quantizer model of the
truth and names the encoder's own effects, with a reference far finer than the readings; the
low-resolution fit (:mod:`enclab.lrde`) sees only the coarse readings and must tell an effect
of the encoder from one of the motion. This module carries the first stage's findings into the
second, so that an effect found against the truth enters the fit even when it is too small for
the fit's own held-out comparison, and so that the fit's report can say which of its terms the
reference confirms. It lives above both packages, which do not import each other.

Each residual-stage effect class (:data:`enclab.residuals.effects.REGISTRY`) declares its
counterpart term of the low-resolution model (:data:`enclab.lrde.effects.REGISTRY`), or why it
has none and which of that model's estimates it biases (:meth:`Effect.lrde_finding
<enclab.residuals.effects.Effect.lrde_finding>`); this module only walks the two registries.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

from enclab.lrde import effects as lrde_effects
from enclab.residuals import effects as residual_effects

__all__ = ["lrde_reference", "references_by_channel"]


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

    Each effect's class says what it becomes
    (:meth:`enclab.residuals.effects.Effect.lrde_finding`): e.g. a single missed or extra count
    becomes the ``count_jump`` term; several become a ``not_modelled`` entry, since the model
    holds one jump.
    """
    selection = residual_block.get("selection")
    if not isinstance(selection, Mapping):
        raise ValueError(f"the residuals block of channel {residual_block.get('measured')!r} "
                         "has no 'selection'")
    found, not_modelled, terms = [], [], []
    for effect in selection.get("effects") or []:
        name = effect.get("name")
        # an effect no class of the registry names (written by another version of the stage)
        # takes the base class's words: no counterpart
        cls = residual_effects.REGISTRY.get(name, residual_effects.Effect)
        finding = cls.lrde_finding(effect.get("params") or {}, effect.get("ci"))
        if "term" not in finding:
            not_modelled.append({"residual_effect": name, **finding})
            continue
        term = lrde_effects.effect(finding["term"]).name
        entry = {"term": term, "residual_effect": name,
                 **{k: v for k, v in finding.items() if k != "term"}}
        found.append(entry)
        if term not in terms:
            terms.append(term)
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
