"""The paper-000 error moments of logs too long for memory, one piece at a time.

A one-hour, 10 kHz, 7-joint log is 36 million samples; its canonical table alone is 2.3 GB,
and the in-memory stages (:mod:`enclab.analysis`) hold many times that. This module computes
exactly what the ``moments`` rule computes (:func:`enclab.analysis.empirical_rows`) from
consecutive pieces of the log, with memory bounded by one piece:

- **re-quantization** and **kinematics** are pointwise, so each piece goes through the same
  functions as the whole log (:func:`enclab.analysis.requantize`,
  :func:`enclab.analysis.kinematics_table`);
- **derivative filters** are run by ``scipy.signal.lfilter`` with the same coefficients
  (:func:`enclab.filters.transfer_function`); the filter state is carried from piece to piece
  (``zi``/``zf``), which repeats the whole-signal recursion operation for operation;
- **moments** are accumulated per batch of the batch-means layout, fixed in advance from the
  number of samples (``numpy.array_split`` of the samples after each filter's start-up
  transient, as :func:`enclab.moments.error_moments` splits them). Each batch keeps its
  count, mean and sum of squared deviations, merged across pieces with the pairwise update
  of Chan, Golub and LeVeque; the global mean, variance and the batch variances about the
  global mean follow exactly from them. The start-up transient is skipped with the same
  ``settle_tol`` rule (:func:`enclab.filters.settle_samples`).

The result is every row :func:`enclab.analysis.empirical_rows` produces (every level, signal,
filter of the bank and architecture; ``mean``, ``std``, ``std_ci``, ``max_abs``, ``n``),
equal to the in-memory result to round-off (``tests/test_stream.py`` checks 1e-12). The long
path does not write the intermediate tables (``requantized``/``kinematics``/``derivatives``
Parquet, 6-23 GB for one hour) nor the theory (its exact model needs lagged products over the
whole trajectory).

Usage (see the README, "Long logs")::

    python -m enclab.stream generate results/benchmarks/long_franka.parquet --duration-s 3600
    python -m enclab.stream moments results/benchmarks/long_franka.parquet moments.json

References
----------
.. [1] T. F. Chan, G. H. Golub and R. J. LeVeque, "Algorithms for computing the sample
   variance: analysis and recommendations", The American Statistician 37(3), 1983.
"""
from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd

from enclab import analysis
from enclab import filters as flt
from enclab import moments as mom
from enclab.kinematics import DHChain

__all__ = [
    "BatchMoments",
    "STAGES",
    "empirical_rows",
    "franka_motion_chunks",
    "main",
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
        Batches of :func:`enclab.moments.error_moments` (``numpy.array_split`` of the
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

    def update(self, start: int, values: np.ndarray) -> None:
        """Add ``values`` (shape ``(m, k)``), whose first row is sample ``start`` of the
        whole signal; pieces must arrive in order."""
        first = max(start, self.skip)
        if first >= start + values.shape[0]:
            return
        # One row per column: the reductions then run over contiguous memory (about 3x
        # faster than down the columns of a row-major block) and sum pairwise.
        values = np.ascontiguousarray(values[first - start:].T)
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
        n_p = piece.shape[1]
        mean_p = piece.mean(axis=1)
        m2_p = ((piece - mean_p[:, np.newaxis]) ** 2).sum(axis=1)
        n_a = int(self.count[b])
        if n_a == 0:
            self.mean[b], self.m2[b] = mean_p, m2_p
        else:
            n = n_a + n_p
            delta = mean_p - self.mean[b]
            self.mean[b] = self.mean[b] + delta * (n_p / n)
            self.m2[b] = self.m2[b] + m2_p + delta**2 * (n_a * n_p / n)
        self.count[b] += n_p

    def result(self, ci_level: float = 0.95) -> dict:
        """``mean``, ``std``, ``std_ci``, ``max_abs`` (arrays of shape ``(k,)``) and ``n``, as
        :func:`enclab.moments.error_moments` computes them.

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


def _forward_and_jacobian(device, theta: np.ndarray, jacobian: bool = True):
    """``device.forward(theta)`` and ``device.jacobian(theta)`` (or None), bit for bit.

    A DH chain computes both from the same frames (``DHChain._axes``); computing those once
    halves the cost of the kinematics, the most expensive stage for the Franka arm, while
    the arithmetic stays exactly that of the two public methods.
    """
    if isinstance(device, DHChain):
        z, p, end = device._axes(theta)
        if not jacobian:
            return end, None
        return end, np.swapaxes(np.cross(z, end[:, np.newaxis, :] - p), 1, 2)
    return device.forward(theta), (device.jacobian(theta) if jacobian else None)


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


def empirical_rows(pieces: Iterable[pd.DataFrame], meta: Mapping, levels: Sequence[Mapping],
                   bank: Sequence[flt.DerivativeFilter], architectures: Sequence[str], *,
                   settle_tol: float = 1e-9, ci_level: float = 0.95, n_batches: int = 20,
                   timings: dict | None = None) -> list[dict]:
    """:func:`enclab.analysis.empirical_rows` of a log given as consecutive pieces.

    Parameters
    ----------
    pieces : iterable of DataFrame
        The canonical log (``t`` and the truth channels) in consecutive pieces of any sizes;
        together exactly ``meta["n_samples"]`` rows.
    meta : dict
        Canonical metadata; ``n_samples`` fixes the batch layout in advance.
    levels, bank, architectures, settle_tol, ci_level, n_batches
        As for :func:`enclab.analysis.empirical_rows`.
    timings : dict, optional
        Seconds spent per stage (:data:`STAGES`) are added to it.

    Returns
    -------
    list of dict
        The rows of :func:`enclab.analysis.empirical_rows`, in the same order.
    """
    fs = analysis._fs(meta)
    n_total = int(meta["n_samples"])
    device = analysis.device_of(meta)
    units = analysis._signal_units(meta, device)
    joint_names = [c["name"] for c in analysis.truth_channels(meta)]
    outputs = [] if device is None else list(device.output_names)
    coeffs = {f.label(): flt.transfer_function(f, fs) for f in bank}
    skips = {f.label(): flt.settle_samples(f, fs, settle_tol) for f in bank}
    joint_arch = device is not None and "joint" in architectures
    operational = device is not None and "operational" in architectures

    # One accumulator per block of rows, in the order empirical_rows emits them.
    blocks = []

    def block(level, names, order, filt, arch, skip):
        acc = BatchMoments(n_total, skip, n_batches, len(names))
        blocks.append((level, names, order, filt, arch, acc))
        return acc

    plan = []
    for level in levels:
        label = level["label"]
        entry = {"level": level, "pos_joint": block(label, joint_names, 0, None, None, 0),
                 "pos_x": None, "filters": []}
        if device is not None:
            entry["pos_x"] = block(label, outputs, 0, None, None, 0)
        for filt in bank:
            skip = skips[filt.label()]
            f = {"filt": filt, "joint": block(label, joint_names, filt.d, filt, "joint", skip),
                 "op": None, "ja": None}
            if operational:
                f["op"] = block(label, outputs, filt.d, filt, "operational", skip)
            if joint_arch and filt.d == 1:
                f["ja"] = block(label, outputs, filt.d, filt, "joint", skip)
            entry["filters"].append(f)
        plan.append(entry)

    states: dict[tuple, np.ndarray] = {}

    def run(key, filt, x):
        b, a = coeffs[filt.label()]
        zi = states.get(key)
        if zi is None:
            zi = np.zeros((max(len(a), len(b)) - 1, x.shape[1]))
        import scipy.signal

        y, states[key] = scipy.signal.lfilter(b, a, x, axis=0, zi=zi)
        return y

    timer = _Timer(timings)
    start = 0
    for piece in _timed(pieces, timer):
        m = len(piece)
        if start + m > n_total:
            raise ValueError(f"the log has more rows than its n_samples = {n_total}")
        req = analysis.requantize(piece, meta, levels)
        theta = analysis._angles(req, meta, None)
        timer.lap("requantize")
        if device is not None:
            x, J = _forward_and_jacobian(device, theta)
        timer.lap("kinematics")
        phis = {}
        if joint_arch:
            for f in bank:
                if f.d == 1:
                    phis[f.label()] = run(("truth", f.label()), f, theta)
            timer.lap("filters")
        for entry in plan:
            level = entry["level"]
            label = level["label"]
            theta_q = analysis._angles(req, meta, level)
            err = theta_q - theta
            xq = Jq = None
            if device is not None:
                xq, Jq = _forward_and_jacobian(device, theta_q, jacobian=joint_arch)
                timer.lap("kinematics")
            entry["pos_joint"].update(start, err)
            if device is not None:
                entry["pos_x"].update(start, xq - x)
            timer.lap("moments")
            for f in entry["filters"]:
                filt = f["filt"]
                y = run((label, filt.label(), "joint"), filt, err)
                timer.lap("filters")
                f["joint"].update(start, y)
                timer.lap("moments")
                if f["op"] is not None:
                    y = run((label, filt.label(), "op"), filt, xq - x)
                    timer.lap("filters")
                    f["op"].update(start, y)
                    timer.lap("moments")
                if f["ja"] is not None:
                    phi_q = run((label, filt.label(), "ja"), filt, theta_q)
                    y = (np.einsum("kji,ki->kj", Jq, phi_q)
                         - np.einsum("kji,ki->kj", J, phis[filt.label()]))
                    timer.lap("filters")
                    f["ja"].update(start, y)
                    timer.lap("moments")
        start += m
    if start != n_total:
        raise ValueError(f"the log ended after {start} rows; its metadata says n_samples = "
                         f"{n_total}")

    rows = []
    for level, names, order, filt, arch, acc in blocks:
        s = acc.result(ci_level)
        for i, name in enumerate(names):
            row = analysis._row_head(level, name, order, filt, arch, units[name])
            row["empirical"] = {
                "mean": float(s["mean"][i]), "std": float(s["std"][i]),
                "std_ci": [float(s["std_ci"][0][i]), float(s["std_ci"][1][i])],
                "max_abs": float(s["max_abs"][i]), "n": int(s["n"]),
            }
            rows.append(row)
    timer.lap("moments")
    return rows


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
                   "generator": "enclab.stream.franka_motion_chunks",
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

    from enclab import io

    with open(args.configfile, encoding="utf-8") as handle:
        config = yaml.safe_load(handle)
    timings: dict = {}
    t0 = time.perf_counter()
    meta, n_rows, pieces = io.iter_canonical(args.canonical, batch_rows=args.chunk_rows)
    if n_rows != int(meta["n_samples"]):
        raise ValueError(f"{args.canonical}: {n_rows} rows but n_samples = {meta['n_samples']}")
    settings = dict(config["requantize"])
    settings.update((meta.get("analysis") or {}).get("requantize") or {})
    levels = analysis.plan_levels(meta, settings)
    derivatives = config["derivatives"]
    analysis.check_cutoffs(derivatives, meta)
    bank = (analysis.filter_bank(derivatives) if args.bank == "config" else
            [flt.DerivativeFilter.from_dict(dict(s)) for s in derivatives["export"]])
    rows = empirical_rows(pieces, meta, levels, bank, derivatives["architectures"],
                          settle_tol=derivatives["settle_tol"],
                          ci_level=config["moments"]["ci_level"],
                          n_batches=config["moments"]["n_batches"], timings=timings)
    io.write_json({"log_id": meta["log_id"], "rows": rows}, args.out)
    if args.timings:
        usage = resource.getrusage(resource.RUSAGE_SELF)
        io.write_json({"n_samples": int(meta["n_samples"]), "n_joints": len(levels[0]["joints"]),
                       "n_levels": len(levels), "n_filters": len(bank), "n_rows": len(rows),
                       "chunk_rows": args.chunk_rows, "stages_s": timings,
                       "total_s": time.perf_counter() - t0,
                       "peak_rss_mb": usage.ru_maxrss / 1024.0}, args.timings)
    return 0


def _generate_command(args) -> int:
    from enclab import io

    meta, chunks = franka_motion_chunks(args.duration_s, args.fs_hz, args.seed,
                                        chunk_rows=args.row_group_rows, log_id=args.log_id)
    io.write_canonical_chunks(chunks, meta, args.out)
    print(json.dumps({"out": str(args.out), "n_samples": meta["n_samples"]}))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``generate`` a long Franka log, or compute a log's ``moments`` streaming."""
    parser = argparse.ArgumentParser(prog="python -m enclab.stream", description=__doc__.split(
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
    m.add_argument("--timings", help="also write per-stage seconds and peak RSS (JSON)")
    args = parser.parse_args(argv)
    from enclab.errors import EnclabInputError

    try:
        return _moments_command(args) if args.command == "moments" else _generate_command(args)
    except (EnclabInputError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
