"""Pure conversions of a raw log to the canonical form (time base, units, counters, grids).

:func:`canonicalize` takes the raw numbers read by :func:`enclab.core.readers.read_raw` and one
normalised manifest entry and returns the canonical DataFrame and its metadata (see
``docs/architecture.md``, "Canonical log"). Quantized signals are stored as int64 counts
plus an SI step, because re-quantizing re-rounded floats is not idempotent; the
re-quantization of the truth channel (Colonnese & Okamura's quantizer on fine counts)
relies on that.

References
----------
.. [1] Colonnese, N., & Okamura, A. M. Propagation of joint space quantization error to
   operational space coordinates and their derivatives (``/work/shared/papers/000_*``).
"""
from __future__ import annotations

import copy
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from enclab.core.errors import EnclabInputError
from enclab.core.manifest import channel_axis, detect_grid_enabled
from enclab.core.readers import file_sha256, read_raw, require_finite

__all__ = [
    "ingest_log",
    "GRID_TOLERANCE",
    "RATE_TOLERANCE",
    "SLOW_RATE_HZ",
    "TIME_UNITS",
    "UNIT_FACTORS",
    "canonicalize",
    "detect_grid",
    "off_grid",
    "time_base_warnings",
    "time_report",
    "unwrap_counter",
]

# Factor from each file unit to SI (rad or m).
UNIT_FACTORS = {"rad": 1.0, "deg": math.pi / 180.0, "mrad": 1e-3, "m": 1.0, "mm": 1e-3}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
GRID_TOLERANCE = 0.01  # values must sit on a grid within 1 % of a step (schema: native_step)
RATE_TOLERANCE = 0.05  # median step vs nominal_rate_hz (schema: nominal_rate_hz)
GAP_FACTOR = 1.5  # a time step longer than this many median steps is a gap (missed samples)
# Below this rate a log of a moving encoder is far more often a time column in ms (or a wrong
# rate) than a real recording: a warning in summary.json, not an error.
SLOW_RATE_HZ = 10.0


def unwrap_counter(counts: np.ndarray, wrap_bits: int) -> np.ndarray:
    """Undo the wrap-around of a modular counter of ``wrap_bits`` bits.

    Every sample-to-sample change is taken modulo ``2**wrap_bits`` into
    ``[-2**(wrap_bits-1), 2**(wrap_bits-1))``, which is exact as long as the counter moves less
    than half its range between samples.

    Parameters
    ----------
    counts : ndarray of int
        Counter readings.
    wrap_bits : int
        Counter width, 2..62.

    Returns
    -------
    ndarray of int64
        Unwrapped counts starting at ``counts[0]``.
    """
    if not 2 <= int(wrap_bits) <= 62:
        raise ValueError(f"wrap_bits must be in 2..62, got {wrap_bits!r}")
    counts = np.asarray(counts, dtype=np.int64)
    if counts.size == 0:
        return counts.copy()
    modulus = np.int64(1) << np.int64(wrap_bits)
    half = modulus >> np.int64(1)
    steps = (np.diff(counts) + half) % modulus - half
    return np.concatenate(([counts[0]], counts[0] + np.cumsum(steps)))


def off_grid(values: np.ndarray, step: float) -> np.ndarray:
    """Distance of each value from the nearest multiple of ``step``, in steps (0..0.5)."""
    scaled = np.asarray(values, dtype=np.float64) / step
    return np.abs(scaled - np.rint(scaled))


def detect_grid(values: np.ndarray) -> float | None:
    """Quantization step of a signal whose values sit on ``k * step``, or None.

    The smallest non-zero sample-to-sample change gives a first step; it is refined by least
    squares over the changes and then over the values (large multiples pin the step down to a
    relative precision far below ``GRID_TOLERANCE / max|k|``). The grid is accepted when every
    value lies within ``GRID_TOLERANCE`` of a multiple.

    Parameters
    ----------
    values : ndarray
        Finite float values (SI).

    Returns
    -------
    float or None
        The step, or None when the signal never changes or is not on a grid.
    """
    values = np.asarray(values, dtype=np.float64)
    changes = np.abs(np.diff(values))
    scale = float(np.max(np.abs(values))) if values.size else 0.0
    # Changes below double rounding of the largest value are representation noise, not motion.
    changes = changes[changes > 64 * np.finfo(np.float64).eps * max(scale, np.finfo(np.float64).tiny)]
    if changes.size == 0:
        return None
    step = float(changes.min())
    if scale / step > 2.0**50:
        return None
    multiples = np.rint(changes / step)
    step = float(changes.sum() / multiples.sum())
    for _ in range(2):
        k = np.rint(values / step)
        if not np.any(k):
            return None
        step = float(np.dot(k, values) / np.dot(k, k))
    if not np.all(off_grid(values, step) <= GRID_TOLERANCE):
        return None
    return step


def time_report(t: np.ndarray, nominal_rate_hz: float | None = None, *,
                trailing_empty_dropped: int = 0, rate_hz: float | None = None) -> dict:
    """Summary of a time axis: rate, repeated samples, gaps and jitter.

    Parameters
    ----------
    t : ndarray
        Non-decreasing time stamps [s], at least two.
    nominal_rate_hz : float, optional
        Expected rate, copied into the report.
    trailing_empty_dropped : int
        Copied into the report.
    rate_hz : float, optional
        Exact rate of a synthetic time base (``index / rate_hz``); used as ``fs_hz``.

    Returns
    -------
    dict
        ``fs_hz`` (1 / median positive step, or ``rate_hz``), ``median_dt_s``, ``n_samples``,
        ``n_repeated`` (steps of exactly 0), ``n_backwards`` (negative steps), ``n_gaps`` (steps
        longer than 1.5 median steps), ``max_gap_s`` (longest step), ``jitter_rms_s`` (RMS
        deviation of the regular steps, i.e. neither repeats nor gaps, from the median step),
        ``trailing_empty_dropped``, ``nominal_rate_hz``.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size < 2:
        raise ValueError(f"t must hold at least two time stamps, got {t.size}")
    dt = np.diff(t)
    positive = dt[dt > 0]
    median_dt = float(np.median(positive)) if positive.size else 0.0
    gaps = dt > GAP_FACTOR * median_dt
    regular = (dt > 0) & ~gaps
    jitter = float(np.sqrt(np.mean((dt[regular] - median_dt) ** 2))) if regular.any() else 0.0
    if rate_hz is not None:
        fs = float(rate_hz)
    else:
        fs = 1.0 / median_dt if median_dt > 0 else float("nan")
    return {
        "fs_hz": fs,
        "median_dt_s": median_dt,
        "n_samples": int(t.size),
        "n_repeated": int(np.count_nonzero(dt == 0)),
        "n_backwards": int(np.count_nonzero(dt < 0)),
        "n_gaps": int(np.count_nonzero(gaps)),
        "max_gap_s": float(dt.max()),
        "jitter_rms_s": jitter,
        "trailing_empty_dropped": int(trailing_empty_dropped),
        "nominal_rate_hz": None if nominal_rate_hz is None else float(nominal_rate_hz),
    }


_FINER_UNIT = {"s": "ms", "ms": "us"}


def time_base_warnings(report: dict, time_spec: dict) -> list[str]:
    """Warnings about a time base that is implausible for a moving encoder.

    A log whose median rate is below :data:`SLOW_RATE_HZ` is far more often a time column in
    ms declared as s (1 kHz read as 1 Hz) than a real recording; the warning names the key
    that would fix it. Call it only for logs with a truth or measured channel that moves.

    Parameters
    ----------
    report : dict
        :func:`time_report` of the log.
    time_spec : dict
        The entry's normalised ``time`` block.

    Returns
    -------
    list of str
        One line per warning (empty when the time base is plausible).
    """
    fs = float(report["fs_hz"])
    if not fs < SLOW_RATE_HZ:
        return []
    unit = time_spec.get("unit")
    if "column" in time_spec or "file" in time_spec:
        source = f"time column '{time_spec['column']}'" if "column" in time_spec else "time file"
        if unit in _FINER_UNIT:
            fix = f"is the {source} in {_FINER_UNIT[unit]}? (set time.unit: {_FINER_UNIT[unit]})"
        else:
            fix = "check time.rate_hz and time.unit"
    else:
        fix = "check time.rate_hz"
    return [f"time base: sampled at {fs:.3g} Hz (median step {report['median_dt_s']:.3g} s), "
            f"implausibly slow for a moving encoder (below {SLOW_RATE_HZ:g} Hz): {fix}"]


def _time_base(raw, entry: dict) -> tuple[np.ndarray, float | None]:
    spec = entry["time"]
    if "column" not in spec and "file" not in spec:
        return np.arange(raw.n_samples, dtype=np.float64) / spec["rate_hz"], float(spec["rate_hz"])
    if raw.time is None:
        raise ValueError("raw.time is None but the entry's time base has a column or file")
    if spec["unit"] == "samples":
        return raw.time / spec["rate_hz"], float(spec["rate_hz"])
    return raw.time * TIME_UNITS[spec["unit"]], None


def _convert_channel(values: np.ndarray, channel: dict, raw, keep: np.ndarray) -> tuple[np.ndarray, dict]:
    """Return (stored column, channel metadata) for one channel of the kept samples."""
    name = channel["name"]
    column = raw.columns[name]
    axis = channel_axis(channel)
    unit_si = "m" if axis == "linear" else "rad"
    sign = int(channel["sign"])
    meta = {"name": name, "role": channel["role"], "joint": channel["joint"], "unit": unit_si}

    if channel["unit"] == "counts":
        fraction = off_grid(values, 1.0)
        bad = np.flatnonzero(fraction > 1e-6)
        if bad.size:
            i = int(bad[0])
            raise EnclabInputError(problem=f"value {values[i]!r} is not a whole number of counts", column=column,
                                   expected="integer counts (or a unit other than counts)",
                                   **raw.where(int(keep[i])))
        counts = np.rint(values).astype(np.int64)
        if channel["wrap_bits"] is not None:
            counts = unwrap_counter(counts, channel["wrap_bits"])
        if channel["step"] is not None:
            step = float(channel["step"])
        else:
            step = 2.0 * math.pi / (float(channel["counts_per_rev"]) * float(channel["gear_ratio"]))
        return sign * counts, {**meta, "storage": "counts", "step": step, "native_step": step}

    si = values * (UNIT_FACTORS[channel["unit"]] * sign)
    step = None
    if channel["native_step"] is not None:
        step = float(channel["native_step"])
        distance = off_grid(si, step)
        worst = int(np.argmax(distance))
        if distance[worst] > GRID_TOLERANCE:
            raise EnclabInputError(
                problem=f"value {values[worst]!r} is {distance[worst]:.3f} steps off the declared grid "
                f"native_step = {step!r}", column=column,
                expected=f"values within {GRID_TOLERANCE} step of a multiple of native_step",
                hint="Check native_step, or leave it out to store the channel as float.",
                **raw.where(int(keep[worst])),
            )
    elif detect_grid_enabled(channel):
        step = detect_grid(si)
    if step is None:
        return si.astype(np.float64), {**meta, "storage": "float", "step": None, "native_step": None}
    return np.rint(si / step).astype(np.int64), {**meta, "storage": "counts", "step": step, "native_step": step}


MAX_TURNS = 4


def _check_plausible(stored: np.ndarray, meta: dict, channel: dict, raw) -> None:
    """Reject a position channel that cannot be what the manifest says it is.

    A truth or measured channel that never changes has no quantization error to analyse; an
    angle channel spanning more than ``MAX_TURNS`` revolutions is far more often degrees (or
    counts) declared as rad than a multi-turn axis, which the entry can declare
    (``multi_turn: true``).
    """
    if channel["role"] not in ("truth", "measured"):
        return
    column = raw.columns[channel["name"]]
    lo, hi = stored.min(), stored.max()
    if lo == hi:
        raise EnclabInputError(
            raw.file, f"the {channel['role']} channel '{channel['name']}' never moves (all "
            f"{stored.size} samples equal)", column=column,
            expected="a joint that moves by at least one step",
            hint="Use role: aux for a constant channel, or crop to the part of the log with motion.")
    span = float(hi - lo) * (meta["step"] if meta["storage"] == "counts" else 1.0)
    if meta["unit"] == "rad" and not channel["multi_turn"] and span > MAX_TURNS * 2 * math.pi:
        raise EnclabInputError(
            raw.file, f"channel '{channel['name']}' spans {span:.4g} rad = "
            f"{span / (2 * math.pi):.3g} turns as {channel['unit']}", column=column,
            expected=f"an angle within {MAX_TURNS} turns",
            hint="If the values are degrees set unit: deg (counts: unit: counts with "
            "counts_per_rev); if the axis really turns this far set multi_turn: true.")


def canonicalize(raw, entry: dict, devices: dict) -> tuple[pd.DataFrame, dict]:
    """Convert a raw log to the canonical DataFrame and its metadata.

    Steps: time base (column in s/ms/us/samples, ``rate_hz``, or time file), crop, timestamp
    checks, unit conversion to SI with the channel's sign, counter unwrap (``wrap_bits``),
    and integer storage of counts channels and of float channels on a declared
    (``native_step``) or detected grid.

    Parameters
    ----------
    raw : enclab.core.readers.RawLog
        Raw numbers of the entry's columns with their file locations.
    entry : dict
        Normalised manifest entry (:func:`enclab.core.manifest.validate_manifest`).
    devices : dict
        Device specifications by name (``config["devices"]``).

    Returns
    -------
    df : pandas.DataFrame
        Column ``t`` (float64 s), then one column per channel: int64 counts or float64 SI.
    meta : dict
        ``log_id``, ``source`` {file, sha256 (None; set by :func:`enclab.core.ingest.ingest_log`),
        format}, ``fs_hz``, ``n_samples``, ``device``, ``group``, ``tags``, ``time_report``
        (see :func:`time_report`), ``channels`` [{name, role, joint, unit, storage, step,
        native_step}], ``analysis``, ``warnings`` (lines about odd but usable input, e.g.
        :func:`time_base_warnings`; summary.json carries them).

    Raises
    ------
    EnclabInputError
        Time going backwards (naming the row), fewer than two samples after the crop, a median
        rate more than 5 % off ``nominal_rate_hz``, non-integer counts, values off a declared
        grid, a truth/measured channel that never moves or an angle channel spanning more than
        ``MAX_TURNS`` turns without ``multi_turn``, or an unknown device name.
    """
    t_all, synthetic_rate = _time_base(raw, entry)
    keep = np.arange(raw.n_samples)
    crop = entry.get("crop")
    if crop:
        mask = np.ones(raw.n_samples, dtype=bool)
        if crop.get("t_start") is not None:
            mask &= t_all >= crop["t_start"]
        if crop.get("t_end") is not None:
            mask &= t_all <= crop["t_end"]
        keep = np.flatnonzero(mask)
    if keep.size < 2:
        raise EnclabInputError(raw.file, f"{keep.size} samples left after the crop", key="crop",
                               expected="at least two samples", hint="Check crop.t_start/t_end (seconds).")
    t = t_all[keep]
    dt = np.diff(t)
    backwards = np.flatnonzero(dt < 0)
    if backwards.size:
        i = int(backwards[0]) + 1
        located = {**raw.where(int(keep[i]), time=True)} if raw.time is not None else {}
        raise EnclabInputError(
            problem=f"time goes backwards: {float(t[i]):.9g} s after {float(t[i - 1]):.9g} s",
            expected="non-decreasing time stamps", **located,
        )
    spec = entry["time"]
    report = time_report(t, spec.get("nominal_rate_hz"), trailing_empty_dropped=raw.trailing_empty_dropped,
                         rate_hz=synthetic_rate)
    if report["median_dt_s"] <= 0:
        raise EnclabInputError(raw.time_file or raw.file, "every time stamp is the same", column=raw.time_column,
                               expected="increasing time stamps")
    nominal = spec.get("nominal_rate_hz")
    if nominal is not None:
        measured = 1.0 / report["median_dt_s"]
        if abs(measured - nominal) > RATE_TOLERANCE * nominal:
            raise EnclabInputError(
                raw.time_file or raw.file,
                f"median time step {report['median_dt_s']:.6g} s is {measured:.6g} Hz, not the nominal "
                f"{nominal:.6g} Hz", column=raw.time_column, key="time.nominal_rate_hz",
                expected=f"within {RATE_TOLERANCE:.0%} of nominal_rate_hz",
                hint="Check time.unit (s, ms, us, samples) and nominal_rate_hz.",
            )

    columns = {"t": t.astype(np.float64)}
    channel_meta = []
    for channel in entry["channels"]:
        values = raw.channels[channel["name"]][keep]
        require_finite(values, raw, raw.columns[channel["name"]], index=keep)
        stored, meta = _convert_channel(values, channel, raw, keep)
        _check_plausible(stored, meta, channel, raw)
        columns[channel["name"]] = stored
        channel_meta.append(meta)
    df = pd.DataFrame(columns)
    moving = any(c["role"] in ("truth", "measured") for c in entry["channels"])
    warnings = time_base_warnings(report, spec) if moving else []

    device = entry.get("device")
    if isinstance(device, str):
        if device not in devices:
            raise EnclabInputError(raw.file, f"unknown device '{device}'", key="device",
                                   expected=f"one of {sorted(devices)}")
        device = copy.deepcopy(devices[device])
    else:
        device = copy.deepcopy(device)
    meta = {
        "log_id": entry["id"],
        "source": {"file": entry["file"], "sha256": None, "format": entry["format"]},
        "fs_hz": report["fs_hz"],
        "n_samples": int(t.size),
        "device": device,
        "group": entry.get("group"),
        "tags": list(entry.get("tags") or []),
        "time_report": report,
        "channels": channel_meta,
        "analysis": copy.deepcopy(entry.get("analysis") or {}),
        "warnings": warnings,
    }
    return df, meta


def ingest_log(entry: dict, data_root: str | os.PathLike, devices: dict) -> tuple[pd.DataFrame, dict]:
    """Read one log and convert it to the canonical form (see :func:`canonicalize`).

    Also records the SHA-256 of the data file in ``meta["source"]["sha256"]``.
    """
    raw = read_raw(entry, data_root)
    df, meta = canonicalize(raw, entry, devices)
    meta["source"]["sha256"] = file_sha256(Path(data_root) / entry["file"])
    return df, meta
