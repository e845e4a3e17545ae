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
   operational space coordinates and their derivatives.
"""
from __future__ import annotations

import copy
import logging
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from enclab.core.canonical import write_canonical
from enclab.core.errors import EnclabInputError
from enclab.core.manifest import channel_axis, detect_grid_enabled
from enclab.core.readers import file_sha256, read_raw, require_finite

__all__ = [
    "ingest_log",
    "ingest_to_canonical",
    "GRID_TOLERANCE",
    "RATE_TOLERANCE",
    "SLOW_RATE_HZ",
    "TIME_UNITS",
    "UNIT_FACTORS",
    "available_memory_bytes",
    "canonicalize",
    "check_text_memory",
    "detect_grid",
    "grid_step",
    "off_grid",
    "collapse_repeats",
    "scale_ratio",
    "time_base_warnings",
    "time_report",
    "unit_factor_warnings",
    "unwrap_counter",
]

# Factor from each file unit to SI (rad or m).
UNIT_FACTORS = {"rad": 1.0, "deg": math.pi / 180.0, "mrad": 1e-3, "m": 1.0, "mm": 1e-3}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
GRID_TOLERANCE = 0.01  # values must sit on a grid within 1 % of a step (schema: native_step)
RATE_TOLERANCE = 0.05  # median step vs nominal_rate_hz (schema: nominal_rate_hz)
GAP_FACTOR = 1.5  # a time step longer than this many median steps is a gap (missed samples)
# Below this rate a log of a moving encoder is far more often a time column in ms (or a wrong
# rate) than a real recording: a warning in summary.json, not an error. Above FAST_RATE_HZ it is
# far more often a time column in s declared in a finer unit.
SLOW_RATE_HZ = 10.0
FAST_RATE_HZ = 1e5
# Two channels of one joint whose least-squares scale is within this relative distance of a
# factor between units (deg/rad, mrad, m/mm, a power of two of counts per revolution) are
# declared in the wrong unit: a physical scale error (a gear ratio, a counts-per-rev slip of a
# few counts) is a few percent at most, and no unit factor lies within 2 % of another or of 1.
UNIT_FACTOR_TOLERANCE = 0.02
# ... and only when one explains the other: r^2 of the least-squares fit at least this (two
# encoders of one joint track each other to a small fraction of the motion).
UNIT_FACTOR_MIN_R2 = 0.99
MAX_POWER_OF_TWO = 24


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


def grid_step(x, rtol: float = 1e-8) -> float:
    """The grid step of a quantized signal (the common divisor of all its jumps), or 0.

    The step is the real greatest common divisor of the sample-to-sample jumps (Euclid's
    algorithm on the distinct jump sizes, remainders below ``rtol * max|x|`` taken as zero),
    refined by least squares over every jump. It need not be the smallest jump: a fast motion
    (a rotating axis moving 32 or 33 truth steps per sample) has no jump of one step. ``rtol``
    admits the rounding of values written with 9 significant digits far from zero (60 rad of a
    10-turn log). Returns 0 when the jumps have no common divisor well above that tolerance
    and no more than 2**20 times below the largest jump (a continuous channel).
    """
    x = np.asarray(x, float)
    d = np.abs(np.diff(x))
    scale = max(float(np.max(np.abs(x))), 1e-300)
    tol = max(rtol * scale, 1e3 * np.finfo(float).eps * scale)
    d = d[d > tol]
    if d.size == 0:
        return 0.0
    sizes = np.sort(d)
    # distinct jump sizes (within the tolerance), largest first
    distinct = sizes[np.concatenate(([True], np.diff(sizes) > 2.0 * tol))][::-1]
    q = float(distinct[0])
    for b in distinct[1:]:
        a, b = max(q, float(b)), min(q, float(b))
        # nearest-integer Euclid; the rounding error of a remainder grows with the quotient
        # (a - n b carries n times b's error), so "zero" is judged against that
        while True:
            n = round(a / b)
            rem = abs(a - n * b)
            if rem <= 2.0 * tol * (1.0 + n):
                break
            a, b = b, rem
            if b <= 10.0 * tol:
                return 0.0
        q = b
    n = np.round(d / q)
    if q <= 10.0 * tol or float(np.max(n)) > 2.0**20:
        return 0.0
    q = float(np.dot(d, n) / np.dot(n, n))
    if np.max(np.abs(d / q - n)) > 0.01:
        return 0.0
    return q



def detect_grid(values: np.ndarray) -> float | None:
    """Quantization step of a signal whose values sit on ``k * step``, or None.

    Two first guesses of the step, each refined by least squares over the changes and then
    over the values (large multiples pin the step down to a relative precision far below
    ``GRID_TOLERANCE / max|k|``) and accepted when every value lies within ``GRID_TOLERANCE`` of
    a multiple: the smallest change (it survives printing, which moves values by a small
    fraction of a step and gives the printed digits a grid of their own), then the common
    divisor of the changes (:func:`grid_step`: a fast motion has no one-step change).

    Parameters
    ----------
    values : ndarray
        Finite float values (SI).

    Returns
    -------
    float or None
        The step, or None when the signal never changes or is not on a grid through zero.
    """
    values = np.asarray(values, dtype=np.float64)
    changes = np.abs(np.diff(values))
    scale = float(np.max(np.abs(values))) if values.size else 0.0
    # Changes below double rounding of the largest value are representation noise, not motion.
    changes = changes[changes > 64 * np.finfo(np.float64).eps * max(scale, np.finfo(np.float64).tiny)]
    if changes.size == 0:
        return None
    for first in (float(changes.min()), grid_step(values)):
        if first > 0.0 and scale / first <= 2.0**50:
            step = _anchored_step(values, changes, first)
            if step is not None:
                return step
    return None


def _anchored_step(values, changes, step):
    """``step`` refined over the changes and the values, if every value sits on its grid."""
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


def _fitting_time_units(fs: float, unit: str) -> list[str]:
    """Time units under which a column read as ``unit`` at ``fs`` Hz samples at a plausible rate
    (:data:`SLOW_RATE_HZ` .. :data:`FAST_RATE_HZ`), closest to 1 kHz first."""
    rates = {u: fs * TIME_UNITS[unit] / factor for u, factor in TIME_UNITS.items() if u != unit}
    fits = [u for u, rate in rates.items() if SLOW_RATE_HZ <= rate <= FAST_RATE_HZ]
    return sorted(fits, key=lambda u: abs(math.log10(rates[u] / 1e3)))


def time_base_warnings(report: dict, time_spec: dict, file: str | None = None) -> list[str]:
    """Warnings about a time base that is implausible for a moving encoder.

    A log whose median rate is below :data:`SLOW_RATE_HZ` or above :data:`FAST_RATE_HZ` is far
    more often a time column in another unit than a real recording (ms or ns declared as s:
    1 kHz read as 1 Hz or 1 uHz; s declared as ms: 1 kHz read as 1 MHz); the warning names the
    units (of ``s``, ``ms``, ``us``, ``ns``) under which the rate becomes plausible, and the key
    that would fix it. Call it only for logs with a truth or measured channel that moves.

    Parameters
    ----------
    report : dict
        :func:`time_report` of the log.
    time_spec : dict
        The entry's normalised ``time`` block.
    file : str, optional
        The data file, named in the warning.

    Returns
    -------
    list of str
        One line per warning (empty when the time base is plausible).
    """
    fs = float(report["fs_hz"])
    if SLOW_RATE_HZ <= fs <= FAST_RATE_HZ:
        return []
    unit = time_spec.get("unit")
    fix = "check time.rate_hz"
    if "column" in time_spec or "file" in time_spec:
        source = f"time column '{time_spec['column']}'" if "column" in time_spec else "time file"
        fits = _fitting_time_units(fs, unit) if unit in TIME_UNITS else []
        if len(fits) == 1:
            fix = f"is the {source} in {fits[0]}? (set time.unit: {fits[0]})"
        elif fits:
            rates = " or ".join(f"{u} ({fs * TIME_UNITS[unit] / TIME_UNITS[u]:.3g} Hz)" for u in fits)
            fix = f"is the {source} in {rates}? (set time.unit: {' or '.join(fits)})"
        else:
            fix = "check time.rate_hz and time.unit"
    where = f" in {file}" if file else ""
    if fs < SLOW_RATE_HZ:
        odd = f"implausibly slow for a moving encoder (below {SLOW_RATE_HZ:g} Hz)"
    else:
        odd = f"implausibly fast for an encoder log (above {FAST_RATE_HZ:g} Hz)"
    return [f"time base: sampled at {fs:.3g} Hz (median step {report['median_dt_s']:.3g} s){where}, "
            f"{odd}: {fix}"]


def collapse_repeats(t: np.ndarray) -> np.ndarray:
    """Indices of the samples kept when rows that repeat the time stamp of the row before are
    collapsed to the first row of each repeat (``t`` non-decreasing)."""
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0:
        return np.arange(0)
    return np.concatenate(([0], np.flatnonzero(np.diff(t) != 0) + 1))


def _repeat_warning(raw, keep: np.ndarray, repeated: np.ndarray, values: dict) -> str:
    """One line about the rows dropped by :func:`collapse_repeats` (``repeated``: positions in
    ``keep`` of the dropped rows; ``values``: each channel's kept-sample values)."""
    locate = (lambda i: raw.where(int(keep[i]), time=True)) if raw.time is not None else (
        lambda i: raw.where(int(keep[i])))
    first = locate(int(repeated[0]))
    label = first.get("row_label") or "row"
    rows = [locate(int(i))["row"] for i in repeated[:5]]
    shown = ", ".join(str(r) for r in rows) + (", ..." if repeated.size > 5 else "")
    same = all(np.array_equal(v[repeated], v[repeated - 1]) for v in values.values())
    what = ("each a copy of the row before (a logger that wrote rows twice)" if same else
            "with other values than the row before (a clock that repeated a stamp)")
    column = f" column '{first['column']}'" if first.get("column") else ""
    rows_repeat = "1 row" if repeated.size == 1 else f"{repeated.size} rows"
    verb = "repeats" if repeated.size == 1 else "repeat"
    return (f"repeated time stamps: {rows_repeat} of {first['file']}{column} {verb} the time "
            f"stamp of the row before ({label} {shown}), {what}; collapsed to the first row of each "
            f"repeat")


def scale_ratio(reference: np.ndarray, other: np.ndarray) -> tuple[float, float] | None:
    """Least-squares scale of ``other`` on ``reference`` after removing both means, and its r^2.

    Removing the means makes the scale blind to an offset between the channels (an encoder's
    zero); the sums run in float64 over mean-free values. Returns None when ``reference`` or
    ``other`` does not move.
    """
    x = np.asarray(reference, dtype=np.float64)
    y = np.asarray(other, dtype=np.float64)
    x = x - x.mean()
    y = y - y.mean()
    sxx, syy, sxy = float(np.dot(x, x)), float(np.dot(y, y)), float(np.dot(x, y))
    if sxx <= 0 or syy <= 0:
        return None
    return sxy / sxx, sxy * sxy / (sxx * syy)


_ANGLE_UNITS = ("rad", "deg", "mrad")
_LENGTH_UNITS = ("m", "mm")


def _near(ratio: float, factor: float) -> bool:
    return abs(ratio / factor - 1.0) <= UNIT_FACTOR_TOLERANCE


def _unit_fix(ratio: float, channel: dict, column: str) -> str | None:
    """How the declaration of ``channel`` would remove a scale ``ratio`` (channel / reference),
    or None when the ratio is no unit factor for that channel."""
    unit = channel["unit"]
    if unit == "counts":
        k = round(math.log2(ratio)) if ratio > 0 else 0
        if k != 0 and abs(k) <= MAX_POWER_OF_TWO and _near(ratio, 2.0 ** k):
            factor = f"2^{k}" if k > 0 else f"1/2^{-k}"
            if channel.get("counts_per_rev") is not None:
                fitted = float(channel["counts_per_rev"]) * 2.0 ** k
                return (f"{factor}, a power of two: counts_per_rev {channel['counts_per_rev']:g} "
                        f"declared, {fitted:g} fits (or a gear_ratio {2.0 ** k:g} times the declared)")
            return f"{factor}, a power of two: step {channel['step']:g} declared, {channel['step'] / 2.0 ** k:g} fits"
        return None
    family = _ANGLE_UNITS if unit in _ANGLE_UNITS else _LENGTH_UNITS
    for fits in family:
        if fits != unit and _near(ratio, UNIT_FACTORS[unit] / UNIT_FACTORS[fits]):
            factor = UNIT_FACTORS[unit] / UNIT_FACTORS[fits]
            shown = f"{factor:.6g}" if factor >= 1 else f"1/{1 / factor:.6g}"
            return f"{shown} = {fits} declared as {unit}: is column '{column}' in {fits}? (set unit: {fits})"
    return None


def unit_factor_warnings(stored: dict, metas: dict, channels: list, raw) -> list[str]:
    """Warnings about channels of one joint whose scale against the joint's truth is a unit factor.

    For each joint with a truth channel, every other truth or measured channel of the joint is
    fitted to it by :func:`scale_ratio` (SI values, signs applied). A scale within
    :data:`UNIT_FACTOR_TOLERANCE` of a factor between units (57.2958 or 1/57.2958 for deg/rad,
    1000 or 1/1000 for mrad/rad and mm/m, 17.4533 for deg/mrad, a power of two for a counts
    channel) with r^2 >= :data:`UNIT_FACTOR_MIN_R2` is a declaration error, not a physical
    scale: the residual stage would report it as a 98 % scale mismatch. The warning names the
    file, both channels and columns, the factor and the unit (or counts_per_rev) that fits.

    Parameters
    ----------
    stored : dict
        Stored column (int64 counts or float64 SI) by channel name.
    metas : dict
        Channel metadata (``storage``, ``step``) by channel name.
    channels : list of dict
        The entry's normalised channels.
    raw : enclab.core.readers.RawLog
        For the file and column names.

    Returns
    -------
    list of str
        One line per channel whose scale is a unit factor.
    """
    def si(name):
        meta = metas[name]
        values = stored[name]
        return values * meta["step"] if meta["storage"] == "counts" else values

    warnings = []
    joints: dict = {}
    for channel in channels:
        if channel["role"] in ("truth", "measured"):
            joints.setdefault(channel["joint"], []).append(channel)
    for joint, members in joints.items():
        truths = [c for c in members if c["role"] == "truth"]
        if not truths:
            continue
        reference = truths[0]
        for channel in members:
            if channel is reference:
                continue
            fit = scale_ratio(si(reference["name"]), si(channel["name"]))
            if fit is None or fit[1] < UNIT_FACTOR_MIN_R2:
                continue
            ratio = abs(fit[0])
            column, ref_column = raw.columns[channel["name"]], raw.columns[reference["name"]]
            fix = _unit_fix(ratio, channel, column)
            if fix is None:
                continue
            warnings.append(
                f"unit factor: in {raw.file}, channel '{channel['name']}' (column '{column}') moves "
                f"{ratio:.4g} times as far as the truth '{reference['name']}' (column '{ref_column}') "
                f"of joint {joint}, a declaration error rather than a physical scale; factor {fix}")
    return warnings


def _unit_hint(measured_hz: float, nominal_hz: float, spec: dict) -> str:
    """`` (the stamps fit time.unit: X)`` when another time unit gives the nominal rate."""
    unit = spec.get("unit")
    if unit not in TIME_UNITS:
        return ""
    for other, factor in TIME_UNITS.items():
        rate = measured_hz * TIME_UNITS[unit] / factor
        if other != unit and abs(rate - nominal_hz) <= RATE_TOLERANCE * nominal_hz:
            return f" (the stamps fit time.unit: {other})"
    return ""


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

    Steps: time base (column in s/ms/us/ns/samples, ``rate_hz``, or time file), crop, timestamp
    checks, collapse of rows that repeat the time stamp of the row before (the first is kept,
    a warning names the rows), unit conversion to SI with the channel's sign, counter unwrap (``wrap_bits``),
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
        native_step}], ``analysis``, ``warnings`` (lines about odd but usable input:
        :func:`time_base_warnings`, repeated time stamps, :func:`unit_factor_warnings`;
        summary.json carries them). ``time_report`` also lists ``repeated_rows`` (file rows of
        the first 20 repeated stamps).

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
    kept = collapse_repeats(t)
    repeated = np.setdiff1d(np.arange(t.size), kept) if kept.size < t.size else np.arange(0)
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
                hint="Check time.unit (s, ms, us, ns, samples) and nominal_rate_hz"
                + _unit_hint(measured, nominal, spec) + ".",
            )

    values_of = {}
    for channel in entry["channels"]:
        values = raw.channels[channel["name"]][keep]
        require_finite(values, raw, raw.columns[channel["name"]], index=keep)
        values_of[channel["name"]] = values
    warnings = []
    if repeated.size:
        # Rows that repeat the stamp of the row before are one sample: the first is kept (the
        # docs, your-logs.md); time_report keeps the file's count and their rows.
        warnings.append(_repeat_warning(raw, keep, repeated, values_of))
        report["repeated_rows"] = [int(raw.where(int(keep[i]), time=raw.time is not None)["row"])
                                   for i in repeated[:20]]
        t, keep = t[kept], keep[kept]
        values_of = {name: v[kept] for name, v in values_of.items()}
    else:
        report["repeated_rows"] = []

    columns = {"t": t.astype(np.float64)}
    channel_meta = []
    for channel in entry["channels"]:
        stored, meta = _convert_channel(values_of.pop(channel["name"]), channel, raw, keep)
        _check_plausible(stored, meta, channel, raw)
        columns[channel["name"]] = stored
        channel_meta.append(meta)
    moving = any(c["role"] in ("truth", "measured") for c in entry["channels"])
    if moving:
        warnings = time_base_warnings(report, spec, raw.time_file or raw.file) + warnings
        warnings += unit_factor_warnings(columns, {m["name"]: m for m in channel_meta},
                                         entry["channels"], raw)
    df = pd.DataFrame(columns, copy=False)
    del columns

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


# Peak memory of reading a text log, per byte of its (uncompressed) text: 5.3 measured for a
# 158 MB, 3e6-row CSV (workflow/benchmarks/bench_memory.py), rounded up.
TEXT_READ_BYTES_PER_BYTE = 6.0


def available_memory_bytes() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` (bytes), or None where there is no such file."""
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def check_text_memory(entry: dict, data_root: str | os.PathLike) -> None:
    """Refuse, with one line, a text log whose reading would need more memory than is free.

    Reading a CSV or text export holds its lines as Python strings (about
    :data:`TEXT_READ_BYTES_PER_BYTE` bytes per byte of text); a log too large for that is
    refused before it is read, instead of the job being killed by the system. A gzip file is
    judged by its uncompressed size (the last four bytes, modulo 4 GiB).
    """
    if entry["format"] not in ("csv", "text"):
        return
    path = Path(data_root) / entry["file"]
    try:
        size = path.stat().st_size
        with open(path, "rb") as handle:
            if handle.read(2) == b"\x1f\x8b":
                handle.seek(-4, os.SEEK_END)
                size = max(size, int.from_bytes(handle.read(4), "little"))
    except OSError:
        return  # the reader names the file's problem
    need, free = TEXT_READ_BYTES_PER_BYTE * size, available_memory_bytes()
    if free is not None and need > free:
        raise EnclabInputError(
            str(path), f"{size / 1e9:.2f} GB of text needs about {need / 1e9:.1f} GB of memory to "
            f"read, {free / 1e9:.1f} GB are available", expected="a log that fits in memory",
            hint="Convert it to Parquet (one float64 or int64 column per channel: about 8 bytes "
            "per value to read), or split it into several logs; see docs/long-logs.md.")


def ingest_log(entry: dict, data_root: str | os.PathLike, devices: dict) -> tuple[pd.DataFrame, dict]:
    """Read one log and convert it to the canonical form (see :func:`canonicalize`).

    A text log too large to read in the memory available is refused first
    (:func:`check_text_memory`). Also records the SHA-256 of the data file in
    ``meta["source"]["sha256"]``.
    """
    check_text_memory(entry, data_root)
    raw = read_raw(entry, data_root)
    df, meta = canonicalize(raw, entry, devices)
    meta["source"]["sha256"] = file_sha256(Path(data_root) / entry["file"])
    return df, meta


_LOG = logging.getLogger("enclab.ingest")


def ingest_to_canonical(entry: dict, data_root: str | os.PathLike, devices: dict,
                        canonical: str | os.PathLike) -> None:
    """One manifest entry -> the canonical Parquet log (:func:`ingest_log`), the file-to-file
    step of rule ``ingest`` and of the chunked mode; the log's warnings are logged too."""
    df, meta = ingest_log(entry, data_root, devices)
    for line in meta.get("warnings") or []:
        _LOG.warning("[%s] %s", meta["log_id"], line)
    write_canonical(df, meta, canonical)
