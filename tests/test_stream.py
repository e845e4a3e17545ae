"""Tests for enclab.propagation.stream: streamed moments equal the in-memory moments rule.

The streamed path (pieces of a Parquet file, filter state carried across pieces, per-batch
mergeable accumulators) must reproduce :func:`enclab.propagation.analysis.empirical_rows` on the whole
log up to round-off. Both compute the same sums in a different order, so the differences
are a few ulps of each sum (largest seen on the Franka case: 9e-16 relative); 1e-12 leaves
a margin of ~1e3 over that and still catches a misplaced sample: starting every filtered row
one sample late changes some std by 1.6e-8 relative and most by far more.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from enclab.core import atomic, canonical
from enclab.propagation import analysis, stream
from enclab.propagation import filters as flt
from enclab.propagation.moments import error_moments

ROOT = Path(__file__).resolve().parents[1]
REL = 1e-12


@pytest.fixture(scope="module")
def config():
    with open(ROOT / "config.yaml", encoding="utf-8") as handle:
        return yaml.safe_load(handle)


def assert_rows_equal(streamed, in_memory):
    assert len(streamed) == len(in_memory)
    for s, m in zip(streamed, in_memory):
        assert {k: s[k] for k in s if k != "empirical"} == {k: m[k] for k in m if k != "empirical"}
        es, em = s["empirical"], m["empirical"]
        assert es["n"] == em["n"]
        for key in ("std", "max_abs"):
            assert es[key] == pytest.approx(em[key], rel=REL, abs=0.0), (s, key)
        for a, b in zip(es["std_ci"], em["std_ci"]):
            assert a == pytest.approx(b, rel=REL, abs=0.0), s
        # A mean near zero is a difference of nearly equal sums: its round-off scales with
        # the size of the samples, not with the mean itself.
        assert abs(es["mean"] - em["mean"]) <= REL * em["max_abs"], s


def pq_row_groups(path) -> int:
    import pyarrow.parquet as pq

    return pq.ParquetFile(path).metadata.num_row_groups


def in_memory_rows(df, meta, levels, bank, derivatives, moments):
    req = analysis.requantize(df, meta, levels)
    kin = analysis.kinematics_table(req, meta, levels)
    return analysis.empirical_rows(
        req, kin, meta, levels, bank, derivatives["architectures"],
        settle_tol=derivatives["settle_tol"], ci_level=moments["ci_level"],
        n_batches=moments["n_batches"])


def test_streamed_franka_log_equals_in_memory_moments(tmp_path, config):
    """20 s of the generated 7-joint log at 1 kHz, the whole configured filter bank and both
    architectures; Parquet row groups of 3000 rows read in pieces of 997 rows, so pieces
    straddle row groups, batch boundaries and the start-up transients."""
    meta, chunks = stream.franka_motion_chunks(20.0, 1000.0, seed=7, chunk_rows=3000)
    path = tmp_path / "long.parquet"
    assert canonical.write_canonical_chunks(chunks, meta, path) == 20_000
    df, meta_read = canonical.read_canonical(path)
    assert meta_read["n_samples"] == 20_000 and len(df) == 20_000
    assert pq_row_groups(path) == 7
    levels = analysis.plan_levels(meta_read, config["requantize"])
    derivatives, moments = config["derivatives"], config["moments"]
    bank = analysis.filter_bank(derivatives)
    expected = in_memory_rows(df, meta_read, levels, bank, derivatives, moments)

    meta_s, n_rows, pieces = canonical.iter_canonical(path, batch_rows=997)
    assert n_rows == 20_000 and meta_s == meta_read
    timings = {}
    got = stream.empirical_rows(pieces, meta_s, levels, bank, derivatives["architectures"],
                                settle_tol=derivatives["settle_tol"],
                                ci_level=moments["ci_level"], n_batches=moments["n_batches"],
                                timings=timings)
    assert_rows_equal(got, expected)
    assert set(stream.STAGES) <= set(timings)
    # The bank really was exercised: every filter, both architectures, 3 levels.
    assert len(got) == 3 * (10 + len(bank) * 10 + 24 * 3)


def test_time_ranges_in_worker_processes_equal_in_memory_moments(tmp_path, config):
    """The log split in time over 3 processes (each warmed up from rest before its range,
    ranges starting inside row groups and inside batches) gives the in-memory rows; the
    merge of the accumulators is exact up to round-off."""
    meta, chunks = stream.franka_motion_chunks(12.0, 1000.0, seed=5, chunk_rows=2500)
    path = tmp_path / "split.parquet"
    canonical.write_canonical_chunks(chunks, meta, path)
    df, meta = canonical.read_canonical(path)
    levels = analysis.plan_levels(meta, config["requantize"])
    derivatives, moments = config["derivatives"], config["moments"]
    bank = [flt.DerivativeFilter.from_dict(dict(s)) for s in derivatives["export"]]
    expected = in_memory_rows(df, meta, levels, bank, derivatives, moments)
    warmup = stream.warmup_samples(bank, 1000.0)
    ranges = stream.time_ranges(12_000, 3, warmup)
    assert len(ranges) == 3 and ranges[0][0] == 0 and ranges[-1][1] == 12_000
    assert all(hi - lo >= 4 * warmup for lo, hi in ranges)
    timings, peaks = {}, []
    got = stream.empirical_rows_from_file(
        path, meta, levels, bank, derivatives["architectures"],
        settle_tol=derivatives["settle_tol"], ci_level=moments["ci_level"],
        n_batches=moments["n_batches"], workers=3, chunk_rows=733, timings=timings,
        worker_peaks_mb=peaks)
    assert_rows_equal(got, expected)
    # this process computes the first range, two spawned processes the others
    assert len(peaks) == 2 and set(stream.STAGES) <= set(timings)


def test_time_ranges_are_fewer_when_the_log_is_short():
    assert stream.time_ranges(1000, 4, 300) == [(0, 1000)]
    assert stream.time_ranges(10_000, 2, 300) == [(0, 5000), (5000, 10_000)]
    with pytest.raises(ValueError, match="workers must be at least 1"):
        stream.time_ranges(10, 0, 1)


def test_reading_a_row_range_gives_those_rows(tmp_path):
    meta, chunks = stream.franka_motion_chunks(3.0, 1000.0, seed=2, chunk_rows=700)
    path = tmp_path / "rows.parquet"
    canonical.write_canonical_chunks(chunks, meta, path)
    df, _ = canonical.read_canonical(path)
    for start, stop in [(0, 3000), (650, 1450), (700, 1400), (2999, 3000), (1200, 1200)]:
        _, n_rows, pieces = canonical.iter_canonical(path, batch_rows=300, start=start, stop=stop)
        got = pd.concat(list(pieces) or [df.iloc[:0]], ignore_index=True)
        assert n_rows == 3000
        pd.testing.assert_frame_equal(got, df.iloc[start:stop].reset_index(drop=True))
    with pytest.raises(ValueError, match="not inside its 3000 rows"):
        canonical.iter_canonical(path, start=10, stop=3001)


def test_trigonometry_table_equals_numpy_bit_for_bit():
    """Look-ups of cos/sin of counts * step + offset are the values numpy computes, also after
    the table grows; a span too large for a table is declined."""
    rng = np.random.default_rng(9)
    step, offset = 2 * np.pi / 2**20, 0.125
    table = stream._TrigTable(step, offset)
    for centre in (0, 50_000, -400_000):
        counts = centre + np.cumsum(rng.integers(-40, 41, 20_000))
        angle = counts.astype(np.float64) * step + offset
        cos_q, sin_q = table.lookup(counts)
        assert np.array_equal(cos_q, np.cos(angle)) and np.array_equal(sin_q, np.sin(angle))
    assert table.lookup(np.array([0, stream._TrigTable.MAX_ENTRIES])) is None


def test_joint_major_kinematics_equal_the_device_methods():
    """The stream's kinematics (table trigonometry, frames composed column by column) give
    device.forward and device.jacobian of the same angles."""
    from enclab.propagation.kinematics import PhantomPremium15, franka_panda

    rng = np.random.default_rng(4)
    for device, step in ((franka_panda(), 2 * np.pi / 2**18), (PhantomPremium15(), 1e-4)):
        n = device.n_joints
        counts = np.cumsum(rng.integers(-30, 31, (n, 5000)), axis=1) + rng.integers(-9000, 9000, (n, 1))
        theta = counts.astype(np.float64) * step
        x, J = stream._Kinematics(device)("level", theta, counts, np.full(n, step))
        np.testing.assert_allclose(x.T, device.forward(theta.T), rtol=0, atol=1e-15)
        np.testing.assert_allclose(J.transpose(2, 0, 1), device.jacobian(theta.T),
                                   rtol=0, atol=1e-15)


def test_streamed_single_joint_without_device_and_random_pieces(config):
    """A single joint without kinematics (device rows absent), an offset quantizer, pieces of
    random sizes including 1-row pieces shorter than every start-up transient."""
    rng = np.random.default_rng(11)
    n, fs, step = 7_321, 2000.0, 1e-4
    t = np.arange(n) / fs
    theta = 0.02 * np.sin(2 * np.pi * 3.1 * t) + 0.004 * np.sin(2 * np.pi * 17.3 * t + 1.0)
    df = pd.DataFrame({"t": t, "q": np.rint(theta / step).astype(np.int64)})
    meta = {"log_id": "one", "fs_hz": fs, "n_samples": n, "device": {"kind": "single_joint"},
            "channels": [{"name": "q", "role": "truth", "joint": 1, "unit": "rad",
                          "storage": "counts", "step": step, "native_step": step}]}
    levels = analysis.plan_levels(meta, {"multiples": [4, 16], "offset_frac": 0.3})
    derivatives = dict(config["derivatives"])
    bank = [flt.DerivativeFilter(1, 1, 25.0, "exponential"),
            flt.DerivativeFilter(2, 3, 40.0, "bilinear"),
            flt.DerivativeFilter(1, 2, 300.0, "bilinear")]
    moments = {"ci_level": 0.9, "n_batches": 7}
    expected = in_memory_rows(df, meta, levels, bank, derivatives, moments)
    cuts = np.sort(np.concatenate([[1, 2, 3], rng.choice(np.arange(4, n), 40, replace=False)]))
    pieces = [df.iloc[a:b] for a, b in zip(np.r_[0, cuts], np.r_[cuts, n])]
    got = stream.empirical_rows(pieces, meta, levels, bank, derivatives["architectures"],
                                settle_tol=derivatives["settle_tol"], ci_level=0.9, n_batches=7)
    assert_rows_equal(got, expected)
    assert {r["architecture"] for r in got} == {None, "joint"}


@pytest.mark.parametrize("skip", [0, 5, 333])
def test_batch_moments_equal_error_moments_for_any_split(skip):
    """The accumulator against enclab.propagation.moments.error_moments on an AR(1) signal with a
    non-zero mean, split at random places (including inside the skipped samples)."""
    rng = np.random.default_rng(skip)
    n = 10_007
    e = np.empty((n, 3))
    e[0] = rng.standard_normal(3)
    for k in range(1, n):
        e[k] = 0.9 * e[k - 1] + rng.standard_normal(3)
    e += np.array([5.0, -0.1, 0.0])
    acc = stream.BatchMoments(n, skip, 20, 3)
    cuts = np.sort(rng.choice(np.arange(1, n), 25, replace=False))
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, n]):
        acc.update(int(a), e[a:b].T)
    got = acc.result(0.95)
    for i in range(3):
        ref = error_moments(e[skip:, i], ci_level=0.95, n_batches=20)
        assert got["n"] == ref["n"] == n - skip
        assert got["std"][i] == pytest.approx(ref["std"], rel=REL, abs=0.0)
        assert got["max_abs"][i] == ref["max_abs"]
        assert abs(got["mean"][i] - ref["mean"]) <= REL * ref["max_abs"]
        for a, b in zip(got["std_ci"], ref["std_ci"]):
            assert a[i] == pytest.approx(b, rel=REL, abs=0.0)


def test_batch_moments_of_adjacent_ranges_merge_to_the_whole():
    rng = np.random.default_rng(3)
    n, skip = 5_003, 40
    e = rng.standard_normal((2, n)) + np.array([[3.0], [-0.2]])
    whole = stream.BatchMoments(n, skip, 9, 2)
    whole.update(0, e)
    parts = [stream.BatchMoments(n, skip, 9, 2) for _ in range(3)]
    for acc, (a, b) in zip(parts, [(0, 1_000), (1_000, 1_001), (1_001, n)]):
        acc.update(a, e[:, a:b])
    for acc in parts[1:]:
        parts[0].merge(acc)
    got, ref = parts[0].result(), whole.result()
    assert got["n"] == ref["n"]
    np.testing.assert_allclose(got["std"], ref["std"], rtol=REL)
    np.testing.assert_array_equal(got["max_abs"], ref["max_abs"])
    np.testing.assert_allclose(got["std_ci"], ref["std_ci"], rtol=REL)
    with pytest.raises(ValueError, match="different batch layouts"):
        parts[0].merge(stream.BatchMoments(n, skip, 8, 2))


def test_batch_moments_reject_a_short_log():
    acc = stream.BatchMoments(100, 10, 5, 1)
    acc.update(0, np.ones((1, 60)))
    with pytest.raises(ValueError, match="expected 90 samples .* got 50"):
        acc.result()
    with pytest.raises(ValueError, match="fewer than 2 per batch"):
        stream.BatchMoments(20, 15, 5, 1)


def test_generated_pieces_do_not_depend_on_the_piece_size():
    meta, a = stream.franka_motion_chunks(1.0, 1000.0, seed=3, chunk_rows=128)
    _, b = stream.franka_motion_chunks(1.0, 1000.0, seed=3, chunk_rows=1000)
    a, b = pd.concat(list(a), ignore_index=True), pd.concat(list(b), ignore_index=True)
    pd.testing.assert_frame_equal(a, b)
    assert len(a) == meta["n_samples"] == 1000
    assert all(a[f"theta{i}"].dtype == np.int64 for i in range(1, 8))


def test_cli_moments_equal_the_in_memory_result(tmp_path, config):
    """The command line (generate, then moments with the export bank) end to end."""
    log = tmp_path / "log.parquet"
    assert stream.main(["generate", str(log), "--duration-s", "4", "--fs-hz", "1000",
                        "--row-group-rows", "1500"]) == 0
    out, timings = tmp_path / "moments.json", tmp_path / "timings.json"
    assert stream.main(["moments", str(log), str(out), "--configfile",
                        str(ROOT / "config.yaml"), "--bank", "export", "--chunk-rows", "701",
                        "--timings", str(timings)]) == 0
    df, meta = canonical.read_canonical(log)
    levels = analysis.plan_levels(meta, config["requantize"])
    bank = [flt.DerivativeFilter.from_dict(dict(s)) for s in config["derivatives"]["export"]]
    expected = in_memory_rows(df, meta, levels, bank, config["derivatives"], config["moments"])
    result = atomic.read_json(out)
    assert result["log_id"] == meta["log_id"]
    assert_rows_equal(result["rows"], expected)
    assert atomic.read_json(timings)["n_samples"] == 4000


def test_cli_reports_a_file_that_is_not_a_canonical_log(tmp_path, capsys):
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not parquet")
    assert stream.main(["moments", str(bad), str(tmp_path / "m.json"), "--configfile",
                        str(ROOT / "config.yaml")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.parquet" in err[0] and "Parquet" in err[0]
    assert not (tmp_path / "m.json").exists()


def test_reading_in_pieces_holds_about_one_row_group(tmp_path):
    """Arrow memory while reading 12 row groups stays near one decoded row group, instead of
    growing with the file (pyarrow's ParquetFile.iter_batches keeps every compressed row
    group it read: the bound below fails for it by the 12th group)."""
    import pyarrow as pa

    rng = np.random.default_rng(5)
    rows, groups = 40_000, 12
    meta = {"log_id": "mem", "n_samples": rows * groups}
    # Random counts do not compress, so a leaked compressed group is as big as a decoded one.
    chunks = (pd.DataFrame({f"c{j}": rng.integers(-2**40, 2**40, rows) for j in range(8)})
              for _ in range(groups))
    path = tmp_path / "mem.parquet"
    canonical.write_canonical_chunks(chunks, meta, path)
    group_bytes = rows * 8 * 8
    base = pa.total_allocated_bytes()
    peak, n = 0, 0
    _, _, pieces = canonical.iter_canonical(path, batch_rows=7_000)
    for piece in pieces:
        n += len(piece)
        peak = max(peak, pa.total_allocated_bytes() - base)
    assert n == rows * groups
    # O(one group): the compressed group, the decoded group and a converted piece (measured
    # 2.4-2.7 groups), where iter_batches reaches 17 groups of this 12-group file.
    assert peak <= 4 * group_bytes
