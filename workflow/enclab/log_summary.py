"""A log's ``summary.json``: the blocks of every analysis the log ran, merged.

The quantization-error block (or the log's header) comes from
:func:`enclab.propagation.pipeline.summary_block`; the low-resolution encoder's block and the
residual-effects block are added beside it. This module sits above the analyses, which do not
import each other.
"""
from __future__ import annotations

import os
from collections.abc import Mapping

from enclab.core import atomic
from enclab.propagation.pipeline import summary_block as quantization_summary_block
from enclab.residuals.pipeline import summary_block as residual_summary_block

__all__ = ["summary"]

PathLike = str | os.PathLike


def summary(inputs: Mapping[str, PathLike], out: PathLike) -> None:
    """``summary.json`` from the blocks of the stages the log ran.

    ``inputs`` holds ``canonical`` and, for the quantization-error stages, ``requantized``,
    ``moments`` and ``theory``; for the low-resolution encoder, ``lrde``; for the residual
    stage, ``residuals`` (one ``residuals.json`` path or a list of them, one per measured
    channel). A coarse log without a truth/measured pair takes its ``residuals`` block from the
    held-out motion-model comparison of its ``lrde`` block (:mod:`enclab.lrde.compare`).
    """
    block = quantization_summary_block(inputs)
    if "lrde" in inputs:
        block["lrde"] = atomic.read_json(inputs["lrde"])
    if "residuals" in inputs:
        paths = inputs["residuals"]
        paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
        block["residuals"] = residual_summary_block([atomic.read_json(p) for p in paths])
    elif (block.get("lrde") or {}).get("residuals"):
        block["residuals"] = block["lrde"]["residuals"]
    atomic.write_json(block, out)
