"""The quantization-error moments of logs too long for memory, one piece at a time.

A one-hour, 10 kHz, 7-joint log is 36 million samples; its canonical table alone is 2.3 GB,
and the in-memory stages (:mod:`enclab.propagation.analysis`) hold many times that. This module computes
exactly what the ``moments`` rule computes (:func:`enclab.propagation.analysis.empirical_rows`) from
consecutive pieces of the log, with memory bounded by one Parquet row group and one piece
per process:

- **re-quantization** and **kinematics** are pointwise, so each piece goes through the same
  functions as the whole log (:func:`enclab.propagation.analysis.level_counts`, the device's kinematics;
  a DH chain composed from table look-ups of ``cos``/``sin`` of the counts, bit for bit the
  values ``numpy`` computes);
- **derivative filters** are run by ``scipy.signal.lfilter`` with the same coefficients
  (:func:`enclab.propagation.filters.transfer_function`); the filter state is carried from piece to piece
  (``zi``/``zf``), which repeats the whole-signal recursion operation for operation;
- **moments** are accumulated per batch of the batch-means layout, fixed in advance from the
  number of samples (``numpy.array_split`` of the samples after each filter's start-up
  transient, as :func:`enclab.propagation.moments.error_moments` splits them). Each batch keeps its
  count, mean and sum of squared deviations, merged across pieces with the pairwise update
  of Chan, Golub and LeVeque; the global mean, variance and the batch variances about the
  global mean follow exactly from them. The start-up transient is skipped with the same
  ``settle_tol`` rule (:func:`enclab.propagation.filters.settle_samples`).
- **in parallel** (:func:`empirical_rows_from_file`, ``--workers``): the log is cut into
  contiguous time ranges, one per process. A range that does not start the log is filtered
  from rest for :func:`warmup_samples` before its first sample (the impulse responses have
  decayed below ``1e-20`` of their peak by then, so the state equals the whole-log state to
  round-off), and the ranges' batch accumulators are merged in time order. The filters hold
  the GIL (``lfilter``), so processes, not threads.

The result is every row :func:`enclab.propagation.analysis.empirical_rows` produces (every level, signal,
filter of the bank and architecture; ``mean``, ``std``, ``std_ci``, ``max_abs``, ``n``),
equal to the in-memory result to round-off (``tests/test_stream.py`` checks 1e-12). The long
path does not write the intermediate tables (``requantized``/``kinematics``/``derivatives``
Parquet, 6-23 GB for one hour) nor the theory (its exact model needs lagged products over the
whole trajectory).

Usage (see docs/long-logs.md)::

    python -m enclab.propagation.stream generate results/benchmarks/long_franka.parquet --duration-s 3600
    python -m enclab.propagation.stream moments results/benchmarks/long_franka.parquet moments.json

References
----------
.. [1] T. F. Chan, G. H. Golub and R. J. LeVeque, "Algorithms for computing the sample
   variance: analysis and recommendations", The American Statistician 37(3), 1983.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd
import scipy.signal

from enclab.core.canonical import Channel
from enclab.propagation import analysis
from enclab.propagation import filters as flt
from enclab.propagation import moments as mom
from enclab.propagation.kinematics import DHChain

__all__ = [
    "BatchMoments",
    "STAGES",
    "WARMUP_TOL",
    "empirical_rows",
    "empirical_rows_from_file",
    "franka_motion_chunks",
    "main",
    "time_ranges",
    "warmup_samples",
]

#: Timed stages of :func:`empirical_rows` (keys of its ``timings`` dict).
STAGES = ("read", "requantize", "kinematics", "filters", "moments")


class BatchMoments:
    """Mergeable moments of a k-column error signal in the batch-means layout.

    Parameters
    ----------
    n_total : int
        Samples of the whole signal, including the ``skip`` start-up samples.
    skip : int
        Leading samples left out (the filter's start-up transient).
    n_batches : int
        Batches of :func:`enclab.propagation.moments.error_moments` (``numpy.array_split`` of the
        ``n_total - skip`` kept samples).
    k : int
        Columns.
    """

    def __init__(self, n_total: int, skip: int, n_batches: int, k: int) -> None:
        n = int(n_total) - int(skip)
        if n < 2 * n_batches:
            raise ValueError(
                f"err has {n} samples, fewer than 2 per batch for n_batches={n_batches}")
        self.skip = int(skip)
        self.n = n
        q, r = divmod(n, n_batches)
        sizes = np.full(n_batches, q, dtype=np.int64)
        sizes[:r] += 1
        self.sizes = sizes
        self.bounds = np.concatenate([[0], np.cumsum(sizes)])
        self.count = np.zeros(n_batches, dtype=np.int64)
        self.mean = np.zeros((n_batches, k))
        self.m2 = np.zeros((n_batches, k))
        self.max_abs = np.zeros(k)

    def update(self, start: int, rows: np.ndarray) -> None:
        """Add ``rows`` (shape ``(k, m)``: one row per column of the signal, samples along
        the row), whose first sample is sample ``start`` of the whole signal; pieces must
        arrive in order. Rows keep the reductions on contiguous memory (about 3x faster than
        down the columns of a sample-major block)."""
        first = max(start, self.skip)
        if first >= start + rows.shape[1]:
            return
        values = rows[:, first - start:]
        pos = first - self.skip
        self.max_abs = np.maximum(self.max_abs, np.max(np.abs(values), axis=1))
        b = int(np.searchsorted(self.bounds, pos, side="right")) - 1
        i = 0
        while i < values.shape[1]:
            stop = min(i + int(self.bounds[b + 1]) - pos, values.shape[1])
            self._merge(b, values[:, i:stop])
            pos += stop - i
            i = stop
            b += 1

    def _merge(self, b: int, piece: np.ndarray) -> None:
        """Merge ``piece`` (shape ``(k, m)``) into batch ``b``."""
        mean_p = piece.mean(axis=1)
        m2_p = ((piece - mean_p[:, np.newaxis]) ** 2).sum(axis=1)
        self._combine(b, piece.shape[1], mean_p, m2_p)

    def _combine(self, b: int, n_p: int, mean_p: np.ndarray, m2_p: np.ndarray) -> None:
        """Chan's pairwise update of batch ``b`` with ``n_p`` samples of mean ``mean_p`` and
        squared deviations ``m2_p``."""
        n_a = int(self.count[b])
        if n_a == 0:
            self.mean[b], self.m2[b] = mean_p, m2_p
        else:
            n = n_a + n_p
            delta = mean_p - self.mean[b]
            self.mean[b] = self.mean[b] + delta * (n_p / n)
            self.m2[b] = self.m2[b] + m2_p + delta**2 * (n_a * n_p / n)
        self.count[b] += n_p

    def merge(self, later: "BatchMoments") -> None:
        """Add the samples another accumulator of the same layout received, all of them
        after this one's (a later time range of the same signal)."""
        if not (later.n == self.n and later.skip == self.skip
                and np.array_equal(later.sizes, self.sizes)):
            raise ValueError("cannot merge accumulators of different batch layouts")
        for b in np.flatnonzero(later.count):
            self._combine(int(b), int(later.count[b]), later.mean[b], later.m2[b])
        self.max_abs = np.maximum(self.max_abs, later.max_abs)

    def result(self, ci_level: float = 0.95) -> dict:
        """``mean``, ``std``, ``std_ci``, ``max_abs`` (arrays of shape ``(k,)``) and ``n``, as
        :func:`enclab.propagation.moments.error_moments` computes them.

        Raises
        ------
        ValueError
            When fewer samples arrived than ``n_total`` announced.
        """
        if not np.array_equal(self.count, self.sizes):
            raise ValueError(f"expected {self.n} samples after the start-up transient, "
                             f"got {int(self.count.sum())}: the log ended early")
        n = self.n
        counts = self.count.astype(np.float64)[:, None]
        mean = np.sum(counts * self.mean, axis=0) / n
        # Squared deviations of each batch about the *global* mean, as error_moments takes them.
        batch_ss = self.m2 + counts * (self.mean - mean) ** 2
        variance = batch_ss.sum(axis=0) / (n - 1)
        batch_var = batch_ss / counts
        n_batches = batch_var.shape[0]
        _, half_width = mom._t_interval(batch_var, np.full(n_batches, 1.0 / n_batches),
                                        mom._check_level(ci_level))
        return {
            "mean": mean,
            "std": np.sqrt(variance),
            "std_ci": (np.sqrt(np.maximum(variance - half_width, 0.0)),
                       np.sqrt(variance + half_width)),
            "max_abs": self.max_abs.copy(),
            "n": n,
        }


class _TrigTable:
    """``cos`` and ``sin`` of ``counts * step + offset`` by table look-up, bit for bit.

    The angles of a counts channel (and of every re-quantized level) take few distinct
    values, and ``numpy.cos``/``numpy.sin`` of float64 cost ~18 ns a value on the
    benchmark machine against ~2 ns for a look-up: trigonometry was three quarters of the
    Franka kinematics. The table holds ``numpy.cos(k * step + offset)`` computed with the
    same float operations as the angles themselves (``k.astype(float64) * step``, then
    ``+ offset``), so a value looked up equals the value computed (``tests/test_stream.py``
    checks). It grows to cover the counts seen; a channel whose counts would span more
    than :attr:`MAX_ENTRIES` entries is not tabulated (``lookup`` returns None).
    """

    MAX_ENTRIES = 1 << 22

    def __init__(self, step: float, offset: float) -> None:
        self.step, self.offset = float(step), float(offset)
        self.lo, self.cos, self.sin = 0, np.empty(0), np.empty(0)

    def lookup(self, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        k_min, k_max = int(counts.min()), int(counts.max())
        hi = self.lo + self.cos.size - 1
        if self.cos.size == 0 or k_min < self.lo or k_max > hi:
            lo = k_min if self.cos.size == 0 else min(k_min, self.lo)
            hi = k_max if self.cos.size == 0 else max(k_max, hi)
            pad = (hi - lo) // 4 + 1024
            lo, hi = lo - pad, hi + pad
            if hi - lo + 1 > self.MAX_ENTRIES:
                return None
            q = np.arange(lo, hi + 1, dtype=np.int64).astype(np.float64) * self.step + self.offset
            self.lo, self.cos, self.sin = lo, np.cos(q), np.sin(q)
        index = counts - self.lo
        return np.take(self.cos, index), np.take(self.sin, index)


class _Kinematics:
    """Forward kinematics and Jacobian of one device in the joint-major layout.

    Angles come as rows ``(n, m)``; outputs are ``x`` ``(m_out, m)`` and ``J`` ``(m_out, n,
    m)``. A DH chain is composed from the cosines and sines directly
    (:meth:`enclab.propagation.kinematics.DHChain.frames_from_trig`), with table look-ups for counts;
    any other device goes through its public ``forward`` / ``jacobian``. Either way the
    values are those of ``device.forward`` and ``device.jacobian`` on the same angles.
    """

    BLOCK = 2048

    def __init__(self, device) -> None:
        self.device = device
        self.dh = isinstance(device, DHChain)
        self.tables: dict[tuple, _TrigTable | None] = {}

    def _trig(self, key, theta: np.ndarray, counts: np.ndarray | None,
              steps: np.ndarray | None):
        offsets = self.device.theta_offset
        if counts is not None:
            cos_q, sin_q = np.empty_like(theta), np.empty_like(theta)
            for i in range(theta.shape[0]):
                table = self.tables.get((key, i), False)
                if table is False:
                    table = self.tables[(key, i)] = _TrigTable(steps[i], offsets[i])
                found = None if table is None else table.lookup(counts[i])
                if found is None:
                    self.tables[(key, i)] = None
                    q = theta[i] + offsets[i]
                    cos_q[i], sin_q[i] = np.cos(q), np.sin(q)
                else:
                    cos_q[i], sin_q[i] = found
            return cos_q, sin_q
        q = theta + offsets[:, np.newaxis]
        return np.cos(q), np.sin(q)

    def __call__(self, key, theta: np.ndarray, counts: np.ndarray | None = None,
                 steps: np.ndarray | None = None, jacobian: bool = True):
        """``(x, J or None)`` at the angles ``theta`` (rows); ``counts``/``steps`` (rows of
        int64 counts and one step per row, ``theta == counts * steps``) allow the look-up."""
        if self.dh:
            cos_q, sin_q = self._trig(key, theta, counts, steps)
            m = theta.shape[1]
            x = np.empty((3, m))
            jac = np.empty((3, theta.shape[0], m)) if jacobian else None
            # Blocks of BLOCK samples keep the frames and the Jacobian's intermediates in
            # the core's cache: whole pieces ran the Jacobian from memory, 3-4x slower.
            for lo in range(0, m, self.BLOCK):
                sl = slice(lo, min(lo + self.BLOCK, m))
                z, p, x[:, sl] = self.device.frames_from_trig(cos_q[:, sl], sin_q[:, sl])
                if jacobian:
                    DHChain.jacobian_rows(z, p, x[:, sl], out=jac[:, :, sl])
            return x, jac
        x = self.device.forward(theta.T).T
        jac = self.device.jacobian(theta.T).transpose(1, 2, 0) if jacobian else None
        return x, jac


def _joint_architecture_rows(jac_q: np.ndarray, jac: np.ndarray, phi: np.ndarray,
                             phi_err: np.ndarray) -> np.ndarray:
    """:func:`enclab.propagation.analysis.joint_architecture_error` in the joint-major layout."""
    out = np.zeros((jac.shape[0], phi.shape[1]))
    for i in range(phi.shape[0]):
        out += (jac_q[:, i] - jac[:, i]) * phi[i]
    for i in range(phi.shape[0]):
        out += jac_q[:, i] * phi_err[i]
    return out


class _Timer:
    def __init__(self, timings: dict | None) -> None:
        self.timings = timings
        self.t0 = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        if self.timings is not None:
            self.timings[stage] = self.timings.get(stage, 0.0) + now - self.t0
        self.t0 = now


def _timed(pieces: Iterable, timer: _Timer) -> Iterator:
    iterator = iter(pieces)
    while True:
        timer.lap("other")
        try:
            piece = next(iterator)
        except StopIteration:
            return
        timer.lap("read")
        yield piece


class _Accumulation:
    """The moments of every row of one log, fed piece by piece (joint-major signals).

    Holds the batch accumulators of every row block, in the order
    :func:`enclab.propagation.analysis.empirical_rows` emits them, and the filter states. Samples before
    ``record_from`` only advance the filter states (the warm-up of a time range that does not
    start the log); accumulations of consecutive time ranges combine with :meth:`merge`.
    """

    def __init__(self, meta: Mapping, levels: Sequence[Mapping],
                 bank: Sequence[flt.DerivativeFilter], architectures: Sequence[str], *,
                 settle_tol: float, n_batches: int) -> None:
        fs = analysis._fs(meta)
        self.n_total = n_total = int(meta["n_samples"])
        device = analysis.device_of(meta)
        self.units = analysis._signal_units(meta, device)
        self.chans = analysis.truth_channels(meta)
        self.joint_names = joint_names = [c["name"] for c in self.chans]
        outputs = [] if device is None else list(device.output_names)
        self.bank = list(bank)
        self.coeffs = {f.label(): flt.transfer_function(f, fs) for f in bank}
        skips = {f.label(): flt.settle_samples(f, fs, settle_tol) for f in bank}
        self.device = device
        self.joint_arch = device is not None and "joint" in architectures
        operational = device is not None and "operational" in architectures
        self.kinematics = None if device is None else _Kinematics(device)
        truths = [Channel.of(c) for c in self.chans]
        self.truth_counts = all(c.is_counts for c in truths)
        self.truth_steps = np.array([c.step if c.is_counts else 0.0 for c in truths])
        self.by_name = {c["name"]: c for c in self.chans}
        self.blocks = []

        def block(level, names, order, filt, arch, skip):
            acc = BatchMoments(n_total, skip, n_batches, len(names))
            self.blocks.append((level, names, order, filt, arch, acc))
            return acc

        self.plan = []
        for level in levels:
            label = level["label"]
            entry = {"level": level, "pos_joint": block(label, joint_names, 0, None, None, 0),
                     "pos_x": None, "filters": [],
                     "steps": np.array([float(j["step"]) for j in level["joints"]])}
            if device is not None:
                entry["pos_x"] = block(label, outputs, 0, None, None, 0)
            for filt in bank:
                skip = skips[filt.label()]
                f = {"filt": filt,
                     "joint": block(label, joint_names, filt.d, filt, "joint", skip),
                     "op": None, "ja": None}
                if operational:
                    f["op"] = block(label, outputs, filt.d, filt, "operational", skip)
                if self.joint_arch and filt.d == 1:
                    f["ja"] = block(label, outputs, filt.d, filt, "joint", skip)
                entry["filters"].append(f)
            self.plan.append(entry)
        self.states: dict[tuple, np.ndarray] = {}

    def _filter(self, key, filt, rows):
        b, a = self.coeffs[filt.label()]
        zi = self.states.get(key)
        if zi is None:
            zi = np.zeros((rows.shape[0], max(len(a), len(b)) - 1))
        y, self.states[key] = scipy.signal.lfilter(b, a, rows, axis=-1, zi=zi)
        return y

    def feed(self, piece: pd.DataFrame, start: int, timer: _Timer,
             record_from: int = 0) -> None:
        """Add ``piece``, whose first row is sample ``start`` of the log; samples before
        ``record_from`` only advance the filters."""
        m = len(piece)
        if start + m > self.n_total:
            raise ValueError(f"the log has more rows than its n_samples = {self.n_total}")
        cut = min(max(record_from - start, 0), m)

        def update(acc, rows):
            if cut < m:
                acc.update(start + cut, rows[:, cut:])

        columns = [piece[name].to_numpy() for name in self.joint_names]
        theta = np.stack([analysis._truth_values(piece, c) for c in self.chans])
        fine = np.stack(columns) if self.truth_counts else None
        level_counts = [np.stack([analysis.level_counts(columns[i], self.by_name[j["name"]], j,
                                                        entry["level"]["offset_frac"])
                                  for i, j in enumerate(entry["level"]["joints"])])
                        for entry in self.plan]
        timer.lap("requantize")
        kinematics = self.kinematics
        if kinematics is not None:
            x, J = kinematics("truth", theta, fine, self.truth_steps, jacobian=self.joint_arch)
        timer.lap("kinematics")
        phis = {}
        if self.joint_arch:
            for f in self.bank:
                if f.d == 1:
                    phis[f.label()] = self._filter(("truth", f.label()), f, theta)
            timer.lap("filters")
        for entry, counts in zip(self.plan, level_counts):
            label = entry["level"]["label"]
            theta_q = counts.astype(np.float64) * entry["steps"][:, np.newaxis]
            err = theta_q - theta
            if kinematics is not None:
                xq, Jq = kinematics(label, theta_q, counts, entry["steps"],
                                    jacobian=self.joint_arch)
                timer.lap("kinematics")
            update(entry["pos_joint"], err)
            if kinematics is not None:
                err_x = xq - x
                update(entry["pos_x"], err_x)
            timer.lap("moments")
            for f in entry["filters"]:
                filt = f["filt"]
                y = self._filter((label, filt.label(), "joint"), filt, err)
                timer.lap("filters")
                update(f["joint"], y)
                timer.lap("moments")
                if f["op"] is not None:
                    y_x = self._filter((label, filt.label(), "op"), filt, err_x)
                    timer.lap("filters")
                    update(f["op"], y_x)
                    timer.lap("moments")
                if f["ja"] is not None:
                    y_ja = _joint_architecture_rows(Jq, J, phis[filt.label()], y)
                    timer.lap("kinematics")
                    update(f["ja"], y_ja)
                    timer.lap("moments")

    def merge(self, later: "_Accumulation") -> None:
        """Add the accumulation of a later, adjacent time range of the same log."""
        for (*_, acc), (*_, other) in zip(self.blocks, later.blocks):
            acc.merge(other)

    def rows(self, ci_level: float) -> list[dict]:
        out = []
        for level, names, order, filt, arch, acc in self.blocks:
            s = acc.result(ci_level)
            for i, name in enumerate(names):
                row = analysis._row_head(level, name, order, filt, arch, self.units[name])
                row["empirical"] = {
                    "mean": float(s["mean"][i]), "std": float(s["std"][i]),
                    "std_ci": [float(s["std_ci"][0][i]), float(s["std_ci"][1][i])],
                    "max_abs": float(s["max_abs"][i]), "n": int(s["n"]),
                }
                out.append(row)
        return out

    def __getstate__(self):
        # Sent back from a worker process: the accumulators are the result; the filter
        # states and trigonometry tables are not needed any more.
        state = dict(self.__dict__)
        state["states"], state["kinematics"] = {}, None
        return state


def empirical_rows(pieces: Iterable[pd.DataFrame], meta: Mapping, levels: Sequence[Mapping],
                   bank: Sequence[flt.DerivativeFilter], architectures: Sequence[str], *,
                   settle_tol: float = 1e-9, ci_level: float = 0.95, n_batches: int = 20,
                   timings: dict | None = None) -> list[dict]:
    """:func:`enclab.propagation.analysis.empirical_rows` of a log given as consecutive pieces.

    Parameters
    ----------
    pieces : iterable of DataFrame
        The canonical log (``t`` and the truth channels) in consecutive pieces of any sizes;
        together exactly ``meta["n_samples"]`` rows.
    meta : dict
        Canonical metadata; ``n_samples`` fixes the batch layout in advance.
    levels, bank, architectures, settle_tol, ci_level, n_batches
        As for :func:`enclab.propagation.analysis.empirical_rows`.
    timings : dict, optional
        Seconds spent per stage (:data:`STAGES`) are added to it.

    Returns
    -------
    list of dict
        The rows of :func:`enclab.propagation.analysis.empirical_rows`, in the same order.

    Notes
    -----
    Every signal is held joint-major (one row per joint or output, samples along the row),
    so the filters, the kinematics and the moments all work on contiguous rows.
    """
    acc = _Accumulation(meta, levels, bank, architectures, settle_tol=settle_tol,
                        n_batches=n_batches)
    timer = _Timer(timings)
    start = 0
    for piece in _timed(pieces, timer):
        acc.feed(piece, start, timer)
        start += len(piece)
    if start != acc.n_total:
        raise ValueError(f"the log ended after {start} rows; its metadata says n_samples = "
                         f"{acc.n_total}")
    rows = acc.rows(ci_level)
    timer.lap("moments")
    return rows


#: Relative size of the impulse response below which a time range's warm-up ignores the
#: samples before it: far below float64 resolution, so a range started from rest that
#: early reaches the filter state of the whole-log recursion to round-off.
WARMUP_TOL = 1e-20


def warmup_samples(bank: Sequence[flt.DerivativeFilter], fs_hz: float) -> int:
    """Samples a time range is filtered from rest before its first recorded sample."""
    return max((flt.settle_samples(f, fs_hz, WARMUP_TOL) for f in bank), default=0)


def time_ranges(n_samples: int, workers: int, warmup: int) -> list[tuple[int, int]]:
    """Split ``[0, n_samples)`` into at most ``workers`` contiguous ranges, each at least
    ``4 * warmup`` samples long (a range much shorter than its warm-up is not worth a
    process)."""
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    count = max(1, min(workers, n_samples // max(4 * warmup, 1)))
    bounds = np.linspace(0, n_samples, count + 1).round().astype(np.int64)
    return [(int(lo), int(hi)) for lo, hi in zip(bounds[:-1], bounds[1:])]


def _range_worker(path: str, lo: int, hi: int, warmup: int, levels, bank_specs,
                  architectures, settle_tol: float, n_batches: int, chunk_rows: int) -> tuple:
    """One time range of a canonical file, in a worker process."""
    from enclab.core import canonical

    meta, _, pieces = canonical.iter_canonical(path, batch_rows=chunk_rows,
                                        start=max(lo - warmup, 0), stop=hi)
    bank = [flt.DerivativeFilter.from_dict(dict(spec)) for spec in bank_specs]
    acc = _Accumulation(meta, levels, bank, architectures, settle_tol=settle_tol,
                        n_batches=n_batches)
    timings: dict = {}
    timer = _Timer(timings)
    start = max(lo - warmup, 0)
    for piece in _timed(pieces, timer):
        acc.feed(piece, start, timer, record_from=lo)
        start += len(piece)
    if start != hi:
        raise ValueError(f"{path}: rows {lo}-{hi} ended after row {start}")
    timer.lap("other")
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return acc, timings, usage.ru_maxrss / 1024.0


def empirical_rows_from_file(path, meta: Mapping, levels: Sequence[Mapping],
                             bank: Sequence[flt.DerivativeFilter],
                             architectures: Sequence[str], *, settle_tol: float = 1e-9,
                             ci_level: float = 0.95, n_batches: int = 20, workers: int = 1,
                             chunk_rows: int = 16_384, timings: dict | None = None,
                             worker_peaks_mb: list | None = None) -> list[dict]:
    """:func:`empirical_rows` of a canonical Parquet file, split in time over processes.

    Each of ``workers`` processes reads one contiguous time range of the file and feeds it
    through the same stages; it starts :func:`warmup_samples` before its range, from rest,
    so its filters reach the state of the whole-log recursion (to round-off: the impulse
    response has decayed below ``1e-20`` of its peak) before the first sample it records.
    The pointwise stages need no warm-up. The batch accumulators of the ranges are merged
    in time order (Chan's update per batch), so the rows equal those of one pass to
    round-off (``tests/test_stream.py``). This process computes the first range itself
    while ``workers - 1`` spawned processes compute the others (one interpreter and one
    copy of the imports fewer than a pool of ``workers``); ``workers=1`` starts none.

    ``timings`` receives the seconds per stage summed over the ranges; ``worker_peaks_mb``
    the peak resident memory of each spawned process (empty with one range: this
    process's own peak is ``resource.getrusage``'s).
    """
    n_total = int(meta["n_samples"])
    fs = analysis._fs(meta)
    ranges = time_ranges(n_total, workers, warmup_samples(bank, fs))
    specs = [f.to_dict() for f in bank]
    jobs = [(str(path), lo, hi, warmup_samples(bank, fs), list(levels), specs,
             list(architectures), settle_tol, n_batches, chunk_rows) for lo, hi in ranges]
    if len(jobs) == 1:
        results = [_range_worker(*jobs[0])]
        spawned = []
    else:
        import concurrent.futures
        import multiprocessing

        # spawn, not fork: the parent may hold Arrow's thread pool, which fork does not copy.
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(len(jobs) - 1, mp_context=context) as pool:
            futures = [pool.submit(_range_worker, *job) for job in jobs[1:]]
            try:
                first = _range_worker(*jobs[0])
            except BaseException:
                for future in futures:
                    future.cancel()
                raise
            spawned = [future.result() for future in futures]
        results = [first, *spawned]
    total, _, _ = results[0]
    for acc, _, _ in results[1:]:
        total.merge(acc)
    for _, range_timings, _ in results:
        if timings is not None:
            for stage, seconds in range_timings.items():
                timings[stage] = timings.get(stage, 0.0) + seconds
    if worker_peaks_mb is not None:
        worker_peaks_mb.extend(peak for _, _, peak in spawned)
    return total.rows(ci_level)


# ----------------------------------------------------------------------------- generated log


def franka_motion_chunks(duration_s: float, fs_hz: float, seed: int, *,
                         chunk_rows: int = 1_000_000, counts_per_rev: int = 2**20,
                         log_id: str = "long_franka") -> tuple[dict, Iterator[pd.DataFrame]]:
    """A long simulated Franka Panda log, generated piece by piece.

    Each joint follows ``c + sum_m A_m sin(2 pi f_m t + phi_m)`` (three tones; centre inside
    the joint range, amplitudes 0.05-0.3 rad, frequencies 0.05-1.5 Hz, all drawn from
    ``numpy.random.default_rng(seed)``), recorded as int64 counts of an encoder with
    ``counts_per_rev`` counts per revolution. Sample ``k`` depends only on ``k``, so pieces
    can be generated independently and never all at once.

    Returns
    -------
    meta : dict
        Canonical metadata (device ``franka_panda``, counts channels ``theta1..theta7`` with
        role ``truth``).
    chunks : iterator of DataFrame
        ``t`` (s) and the seven counts columns, ``chunk_rows`` rows each (the last shorter).
    """
    n_samples = int(round(duration_s * fs_hz))
    if n_samples < 2:
        raise ValueError(f"duration_s * fs_hz must give at least 2 samples, got {n_samples}")
    rng = np.random.default_rng(seed)
    n_j, n_tones = 7, 3
    centre = rng.uniform(-0.5, 0.5, n_j)
    amp = rng.uniform(0.05, 0.3, (n_j, n_tones)) / n_tones
    freq = rng.uniform(0.05, 1.5, (n_j, n_tones))
    phase = rng.uniform(0.0, 2 * math.pi, (n_j, n_tones))
    step = 2 * math.pi / counts_per_rev
    names = [f"theta{i + 1}" for i in range(n_j)]
    meta = {
        "log_id": log_id,
        "source": {"file": None, "sha256": None, "format": "generated",
                   "generator": "enclab.propagation.stream.franka_motion_chunks",
                   "params": {"duration_s": duration_s, "fs_hz": fs_hz, "seed": seed,
                              "counts_per_rev": counts_per_rev}},
        "fs_hz": float(fs_hz),
        "n_samples": n_samples,
        "device": {"kind": "franka_panda"},
        "group": None,
        "tags": ["generated", "long"],
        "time_report": None,
        "channels": [{"name": name, "role": "truth", "joint": i + 1, "unit": "rad",
                      "storage": "counts", "step": step, "native_step": step}
                     for i, name in enumerate(names)],
        "analysis": {},
    }

    def chunks():
        for begin in range(0, n_samples, chunk_rows):
            t = np.arange(begin, min(begin + chunk_rows, n_samples)) / fs_hz
            out = {"t": t}
            for j, name in enumerate(names):
                theta = np.full(t.size, centre[j])
                for m in range(n_tones):
                    theta += amp[j, m] * np.sin(2 * math.pi * freq[j, m] * t + phase[j, m])
                out[name] = np.rint(theta / step).astype(np.int64)
            yield pd.DataFrame(out)

    return meta, chunks()


# ----------------------------------------------------------------------------- command line


def _moments_command(args) -> int:
    import yaml

    from enclab.core import atomic, canonical

    with open(args.configfile, encoding="utf-8") as handle:
        config = yaml.safe_load(handle)
    timings: dict = {}
    t0 = time.perf_counter()
    meta, n_rows, _ = canonical.iter_canonical(args.canonical)
    if n_rows != int(meta["n_samples"]):
        raise ValueError(f"{args.canonical}: {n_rows} rows but n_samples = {meta['n_samples']}")
    settings = dict(config["requantize"])
    settings.update((meta.get("analysis") or {}).get("requantize") or {})
    levels = analysis.plan_levels(meta, settings)
    derivatives = config["derivatives"]
    analysis.check_cutoffs(derivatives, meta)
    bank = (analysis.filter_bank(derivatives) if args.bank == "config" else
            [flt.DerivativeFilter.from_dict(dict(s)) for s in derivatives["export"]])
    workers = args.workers or len(os.sched_getaffinity(0))
    peaks: list = []
    rows = empirical_rows_from_file(args.canonical, meta, levels, bank,
                                    derivatives["architectures"],
                                    settle_tol=derivatives["settle_tol"],
                                    ci_level=config["moments"]["ci_level"],
                                    n_batches=config["moments"]["n_batches"], workers=workers,
                                    chunk_rows=args.chunk_rows, timings=timings,
                                    worker_peaks_mb=peaks)
    atomic.write_json({"log_id": meta["log_id"], "rows": rows}, args.out)
    if args.timings:
        own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        # The sum of every process's own peak bounds the memory in use at any moment (the
        # peaks need not coincide).
        peak = own + sum(peaks)
        atomic.write_json({"n_samples": int(meta["n_samples"]), "n_joints": len(levels[0]["joints"]),
                           "n_levels": len(levels), "n_filters": len(bank), "n_rows": len(rows),
                           "chunk_rows": args.chunk_rows, "workers": len(peaks) + 1,
                           "stages_s": timings, "stages_note": "seconds summed over workers",
                           "total_s": time.perf_counter() - t0,
                           "peak_rss_mb": peak, "worker_peak_rss_mb": peaks}, args.timings)
    return 0


def _generate_command(args) -> int:
    from enclab.core import canonical

    meta, chunks = franka_motion_chunks(args.duration_s, args.fs_hz, args.seed,
                                        chunk_rows=args.row_group_rows, log_id=args.log_id)
    canonical.write_canonical_chunks(chunks, meta, args.out)
    print(json.dumps({"out": str(args.out), "n_samples": meta["n_samples"]}))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``generate`` a long Franka log, or compute a log's ``moments`` streaming."""
    parser = argparse.ArgumentParser(prog="python -m enclab.propagation.stream", description=__doc__.split(
        "\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    g = sub.add_parser("generate", help="write a long simulated 7-joint Franka log (Parquet)")
    g.add_argument("out")
    g.add_argument("--duration-s", type=float, default=3600.0)
    g.add_argument("--fs-hz", type=float, default=10_000.0)
    g.add_argument("--seed", type=int, default=20261128)
    g.add_argument("--row-group-rows", type=int, default=1_000_000)
    g.add_argument("--log-id", default="long_franka")
    m = sub.add_parser("moments", help="moments.json of a canonical log, streaming")
    m.add_argument("canonical", help="canonical Parquet log (results/<log_id>/canonical.parquet)")
    m.add_argument("out", help="moments JSON to write (same format as the moments rule)")
    m.add_argument("--configfile", default="config.yaml")
    m.add_argument("--chunk-rows", type=int, default=16_384,
                   help="rows per piece (default 16384: pieces whose kinematics "
                        "intermediates fit in cache; much larger pieces are slower)")
    m.add_argument("--bank", choices=("config", "export"), default="config",
                   help="filters: the whole derivatives.bank (default, as the moments rule) "
                        "or only derivatives.export")
    m.add_argument("--workers", type=int, default=0,
                   help="processes, each reading one time range of the log (default 0: one "
                        "per available CPU; 1: read in this process)")
    m.add_argument("--timings", help="also write per-stage seconds and peak RSS (JSON)")
    args = parser.parse_args(argv)
    from enclab.core.errors import EnclabInputError

    try:
        return _moments_command(args) if args.command == "moments" else _generate_command(args)
    except (EnclabInputError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
