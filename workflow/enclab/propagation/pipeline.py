"""The per-log stages of the quantization-error analysis as file-to-file steps, shared by both
execution modes.

Each function reads its inputs with :mod:`enclab.core.canonical` and :mod:`enclab.core.atomic`,
calls :mod:`enclab.propagation.analysis` and writes its output with :mod:`enclab.core.atomic`.
The rule scripts (``scripts/<rule>.py``, one Snakemake job per stage and log) and the chunked
mode (:func:`quantization_log`, every stage of several logs in one job, see
``workflow/rules/chunks.smk``) call the same functions in the same order on the same files, so
both modes write byte-identical outputs. A log's ``summary.json`` merges the blocks of every
analysis it ran: :mod:`enclab.log_summary` adds the other analyses' blocks to
:func:`summary_block`.
"""
from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from pathlib import Path

from enclab.core import atomic
from enclab.core.canonical import Channel, read_canonical, write_canonical
from enclab.core.errors import EnclabInputError
from enclab.core.ingest import ingest_to_canonical
from enclab.propagation import analysis
from enclab.propagation import filters as flt

__all__ = [
    "FIGURE_OUTPUTS",
    "QUANTIZATION_OUTPUTS",
    "check_cutoffs",
    "requantize",
    "kinematics",
    "derivatives",
    "moments",
    "theory",
    "summary_block",
    "summary",
    "log_figures",
    "quantization_log",
]

# Output name -> file name under results/<log_id>/ of the per-log figures (rule log_figures),
# which the chunked mode draws for the logs that show them.
FIGURE_OUTPUTS = {
    "errors": "figures/errors.png",
    "comparison": "figures/comparison.png",
}
# Output name -> file name under results/<log_id>/ of the quantization-error stages, in
# stage order.
QUANTIZATION_OUTPUTS = {
    "canonical": "canonical.parquet",
    "requantized": "requantized.parquet",
    "kinematics": "kinematics.parquet",
    "derivatives": "derivatives.parquet",
    "moments": "moments.json",
    "theory": "theory.json",
    "summary": "summary.json",
}

PathLike = str | os.PathLike


@functools.lru_cache(maxsize=64)
def _filter_memory(fs: float, bank: tuple) -> int:
    """Samples of the longest impulse response of a bank, as the theory stage computes them
    (the same for every log sampled at ``fs``: computed once per process)."""
    filters = analysis.filter_bank({"bank": dict(bank)})
    return max(flt.impulse_response(f, fs, tol=analysis._IMPULSE_TOL).size for f in filters)


def check_cutoffs(settings: Mapping, meta: Mapping) -> None:
    """The log suits the derivative filters: :func:`enclab.propagation.analysis.check_cutoffs`, and longer
    than the longest filter memory (the theory stage's own check, made before the moments stage
    too, so that every stage names the same fix). When the log's time base is implausible, the
    error names that fix instead (a cutoff above Nyquist is then its symptom)."""
    try:
        analysis.check_cutoffs(settings, meta)
    except EnclabInputError as err:
        time_base = [w for w in meta.get("warnings") or [] if w.startswith("time base:")]
        if not time_base:
            raise
        fix = time_base[0][len("time base: "):]
        raise EnclabInputError(err.file, err.problem, key=err.key, expected=err.expected,
                               hint=fix[0].upper() + fix[1:]) from None
    bank = tuple((k, tuple(v)) for k, v in sorted(settings["bank"].items()))
    memory = _filter_memory(float(meta["fs_hz"]), bank)
    if int(meta["n_samples"]) < memory:
        raise EnclabInputError(
            "configuration", f"log '{meta.get('log_id')}' has {int(meta['n_samples'])} samples, "
            f"fewer than the longest derivative filter's memory ({memory} samples)",
            key="derivatives.bank.fc_hz", expected="a log longer than every filter's memory",
            hint="Use higher cutoffs, or leave the log out.")


def requantize(canonical: PathLike, settings: Mapping, requantized: PathLike) -> None:
    """Truth channels -> integer counts at every level (``settings``: ``config["requantize"]``,
    updated with the log's own ``analysis.requantize``)."""
    df, meta = read_canonical(canonical)
    merged = dict(settings)
    merged.update((meta.get("analysis") or {}).get("requantize") or {})
    levels = analysis.plan_levels(meta, merged)
    meta = dict(meta, levels=levels)
    write_canonical(analysis.requantize(df, meta, levels), meta, requantized)


def kinematics(requantized: PathLike, out: PathLike) -> None:
    """Operational positions of truth and levels, Jacobian at the truth."""
    req, meta = read_canonical(requantized)
    write_canonical(analysis.kinematics_table(req, meta, meta["levels"]), meta, out)


def derivatives(requantized: PathLike, settings: Mapping, export: list, out: PathLike) -> None:
    """The exported derivative estimators (``settings``: ``config["derivatives"]``)."""
    req, meta = read_canonical(requantized)
    check_cutoffs(settings, meta)
    write_canonical(analysis.export_derivatives(req, meta, meta["levels"], export), meta, out)


def moments(requantized: PathLike, kinematics_path: PathLike, settings: Mapping,
            moment_settings: Mapping, out: PathLike) -> None:
    """Empirical error moments over the whole derivative-filter bank."""
    req, meta = read_canonical(requantized)
    kin, _ = read_canonical(kinematics_path)
    check_cutoffs(settings, meta)
    rows = analysis.empirical_rows(
        req, kin, meta, meta["levels"], analysis.filter_bank(settings),
        settings["architectures"], settle_tol=settings["settle_tol"],
        ci_level=moment_settings["ci_level"], n_batches=moment_settings["n_batches"])
    atomic.write_json({"log_id": meta["log_id"], "rows": rows}, out)


def theory(requantized: PathLike, kinematics_path: PathLike, settings: Mapping,
           out: PathLike) -> None:
    """Table II, the exact model and the trajectory worst case for every row."""
    req, meta = read_canonical(requantized)
    kin, _ = read_canonical(kinematics_path)
    check_cutoffs(settings, meta)
    rows = analysis.theory_rows(req, kin, meta, meta["levels"], analysis.filter_bank(settings),
                                settings["architectures"], settle_tol=settings["settle_tol"])
    atomic.write_json({"log_id": meta["log_id"], "rows": rows}, out)


def summary_block(inputs: Mapping[str, PathLike]) -> dict:
    """The quantization-error block of ``summary.json``, with the log's ingest warnings.

    ``inputs`` holds ``canonical`` and, when the log ran the quantization-error stages,
    ``requantized``, ``moments`` and ``theory``; without them the block is the log's header.
    """
    if "moments" in inputs:
        req, meta = read_canonical(inputs["requantized"])
        block = analysis.build_summary(
            meta, meta["levels"], atomic.read_json(inputs["moments"])["rows"],
            atomic.read_json(inputs["theory"])["rows"], analysis.centre_of(req, meta))
    else:
        _, meta = read_canonical(inputs["canonical"])
        block = analysis.log_header(meta)
    block["warnings"] = list(meta.get("warnings") or [])
    return block


def summary(inputs: Mapping[str, PathLike], out: PathLike) -> None:
    """``summary.json`` of a log that ran the quantization-error stages alone
    (:func:`summary_block`; :func:`enclab.log_summary.summary` adds other analyses' blocks)."""
    atomic.write_json(summary_block(inputs), out)


def log_figures(inputs: Mapping[str, PathLike], export: list, settle_tol: float,
                errors: PathLike, comparison: PathLike) -> None:
    """The per-log figures: error traces and the theory-vs-measured comparison.

    ``inputs`` holds ``requantized``, ``kinematics``, ``derivatives`` and ``summary``;
    ``export`` and ``settle_tol`` are ``config["derivatives"]`` keys.
    """
    from enclab.propagation import plots  # matplotlib: only jobs that draw import it

    req, meta = read_canonical(inputs["requantized"])
    kin, _ = read_canonical(inputs["kinematics"])
    deriv, _ = read_canonical(inputs["derivatives"])
    summary_block = atomic.read_json(inputs["summary"])
    level = meta["levels"][0]["label"]
    tr = analysis.error_traces(req, kin, deriv, meta, level, export, settle_tol)
    title = f"{meta['log_id']}: {tr['signal']} error at {level}"
    atomic.save_figure(plots.error_trace_figure(tr["t"], tr["errors"], title, tr["unit"],
                                                step=tr["step"]), errors)
    table = analysis.summary_table(summary_block)
    truth = Channel.of(analysis.truth_channels(meta)[0])
    fig = plots.real_log_figure(table, f"{meta['log_id']}: measured vs theory",
                                native_step=truth.grid, step_unit=truth.unit)
    atomic.save_figure(fig, comparison)


def quantization_log(entry: Mapping, folder: PathLike, config: Mapping,
                     data_root: PathLike, figures: bool = False) -> None:
    """Every quantization-error stage of one log, ``ingest`` to ``summary``, into ``folder``.

    The same calls, in the same order, as the per-stage rules of
    ``workflow/rules/{ingest,propagation}.smk``; ``folder`` receives the files of
    :data:`QUANTIZATION_OUTPUTS`, and with ``figures`` those of :data:`FIGURE_OUTPUTS`.

    Parameters
    ----------
    entry : dict
        The log's normalised manifest entry.
    folder : path-like
        Output folder (created if needed).
    config : dict
        The workflow configuration (``devices``, ``requantize``, ``derivatives``, ``moments``).
    data_root : path-like
        The manifest's data root.
    figures : bool
        Also draw the per-log figures (rule ``log_figures``).
    """
    folder = Path(folder)
    out = {name: folder / file for name, file in QUANTIZATION_OUTPUTS.items()}
    d = config["derivatives"]
    ingest_to_canonical(entry, data_root, config["devices"], out["canonical"])
    requantize(out["canonical"], config["requantize"], out["requantized"])
    kinematics(out["requantized"], out["kinematics"])
    derivatives(out["requantized"], d, d["export"], out["derivatives"])
    moments(out["requantized"], out["kinematics"], d, config["moments"], out["moments"])
    theory(out["requantized"], out["kinematics"], d, out["theory"])
    summary({k: out[k] for k in ("canonical", "requantized", "moments", "theory")},
            out["summary"])
    if figures:
        log_figures(out, d["export"], d["settle_tol"], folder / FIGURE_OUTPUTS["errors"],
                    folder / FIGURE_OUTPUTS["comparison"])
