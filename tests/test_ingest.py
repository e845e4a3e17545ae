"""Tests for enclab.core.ingest (pure conversions) and the end-to-end enclab.core.ingest.ingest_log on fixtures."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from enclab.core import canonical, ingest, readers
from enclab.core.errors import EnclabInputError
from enclab.core.ingest import (
    canonicalize,
    detect_grid,
    off_grid,
    time_report,
    unwrap_counter,
)
from enclab.core.manifest import validate_manifest
from enclab.core.readers import RawLog

FIXTURES = Path(__file__).parent / "fixtures" / "ingest"
_spec = importlib.util.spec_from_file_location("make_fixtures", FIXTURES / "make_fixtures.py")
fixtures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fixtures)
COUNTS = np.asarray(fixtures.COUNTS)
N = COUNTS.size
DEVICES = {"axis": {"kind": "single_joint"}, "rail": {"kind": "single_joint", "unit": "m"}}
META_KEYS = {"log_id", "source", "fs_hz", "n_samples", "device", "group", "tags", "time_report", "channels",
             "analysis", "warnings"}
REPORT_KEYS = {"fs_hz", "median_dt_s", "n_samples", "n_repeated", "n_backwards", "n_gaps", "max_gap_s",
               "jitter_rms_s", "trailing_empty_dropped", "nominal_rate_hz"}


def entry(channels, time=None, **fields) -> dict:
    base = {"id": "log1", "file": "x.csv", "format": "csv", "time": time or {"rate_hz": 100},
            "channels": channels}
    base.update(fields)
    _, (normalised,) = validate_manifest({"logs": [base]}, DEVICES, "test.yaml")
    return normalised


def raw_log(values: dict, time=None, trailing=0) -> RawLog:
    """A RawLog as the csv reader makes it: header on line 1, sample i on line i + 2."""
    n = len(next(iter(values.values())))
    lines = np.arange(2, n + 2)
    return RawLog(file="x.csv", format="csv", channels={k: np.asarray(v, dtype=float) for k, v in values.items()},
                  columns={k: f"col_{k}" for k in values}, locations=lines, row_label="line",
                  time=None if time is None else np.asarray(time, dtype=float),
                  time_file=None if time is None else "x.csv", time_column=None if time is None else "t",
                  time_locations=None if time is None else lines, time_row_label="line",
                  trailing_empty_dropped=trailing)


def ch(name, **fields) -> dict:
    return {"name": name, "column": name, "role": "aux", **fields}


def convert(values, time=None, time_spec=None, **fields):
    channels = [ch(name, **spec) for name, spec in fields.items()]
    return canonicalize(raw_log(values, time), entry(channels, time_spec), DEVICES)


# ----------------------------------------------------------------------------- units


@pytest.mark.parametrize(
    ("unit", "factor", "si"),
    [("rad", 1.0, "rad"), ("deg", math.pi / 180, "rad"), ("mrad", 1e-3, "rad"), ("m", 1.0, "m"),
     ("mm", 1e-3, "m")],
)
def test_float_units_are_converted_to_si(unit, factor, si):
    values = np.array([0.0, 1.25, -3.5, 90.0])
    df, meta = convert({"a": values}, a={"unit": unit})
    assert df["a"].dtype == np.float64
    np.testing.assert_allclose(df["a"], values * factor, rtol=1e-15)
    assert meta["channels"][0] == {"name": "a", "role": "aux", "joint": None, "unit": si, "storage": "float",
                                   "step": None, "native_step": None}


def test_sign_flips_a_float_channel():
    df, _ = convert({"a": [1.0, 2.0]}, a={"unit": "deg", "sign": -1})
    np.testing.assert_allclose(df["a"], [-math.pi / 180, -math.pi / 90], rtol=1e-15)


def test_counts_with_counts_per_rev_and_gear_ratio():
    df, meta = convert({"m": [0.0, 5.0, -7.0]}, m={"unit": "counts", "counts_per_rev": 4196, "gear_ratio": 35,
                                                  "sign": -1})
    assert df["m"].dtype == np.int64
    np.testing.assert_array_equal(df["m"], [0, -5, 7])
    info = meta["channels"][0]
    assert info["storage"] == "counts" and info["unit"] == "rad"
    assert info["step"] == pytest.approx(2 * math.pi / (4196 * 35), rel=1e-15)


def test_linear_counts_with_step():
    df, meta = convert({"x": [3.0, 4.0]}, x={"unit": "counts", "axis": "linear", "step": 1e-6})
    np.testing.assert_array_equal(df["x"], [3, 4])
    assert meta["channels"][0]["unit"] == "m" and meta["channels"][0]["step"] == 1e-6


def test_non_integer_counts_name_the_line():
    with pytest.raises(EnclabInputError) as info:
        convert({"m": [0.0, 1.0, 2.5]}, m={"unit": "counts", "counts_per_rev": 100})
    assert (info.value.column, info.value.row, info.value.row_label) == ("col_m", 4, "line")
    assert "not a whole number of counts" in str(info.value)


# ----------------------------------------------------------------------------- counters and grids


def test_unwrap_counter_8_bit_both_directions():
    # every change is below half the 256-count range, so each wrap is recoverable
    true = np.array([250, 253, 256, 260, 255, 249, 240, 300, 200, 100])
    np.testing.assert_array_equal(unwrap_counter(true % 256, 8) - (true[0] % 256), true - true[0])


def test_unwrap_counter_random_walk_matches_the_unwrapped_walk():
    rng = np.random.default_rng(20240611)
    # Steps below half the 12-bit range (2048) are recoverable; use up to 2000 counts.
    true = np.cumsum(rng.integers(-2000, 2001, size=5000)) + 123_456
    np.testing.assert_array_equal(unwrap_counter(true % 4096, 12), true - true[0] + true[0] % 4096)


def test_unwrap_counter_rejects_bad_width():
    with pytest.raises(ValueError, match="wrap_bits"):
        unwrap_counter(np.arange(3), 1)


def test_wrap_bits_in_a_channel_via_the_parquet_fixture():
    e = entry([ch("c", unit="counts", counts_per_rev=1024, wrap_bits=8)],
              time={"column": "index", "unit": "samples", "rate_hz": 100}, file="table.parquet", format="parquet")
    e["channels"][0]["column"] = "counter"
    df, _ = canonicalize(readers.read_raw(e, FIXTURES), e, DEVICES)
    # the fixture writes (250 + 4 * COUNTS) mod 256
    np.testing.assert_array_equal(df["c"], 250 + 4 * COUNTS)


def test_detect_grid_finds_an_exact_step_and_its_multiples():
    step = 25 / 65536
    rng = np.random.default_rng(7)
    k = np.cumsum(rng.integers(-3, 4, size=2000)) + 40
    found = detect_grid(k * step)
    # the values carry only double rounding, so the least-squares step is exact to ~1e-15
    assert found == pytest.approx(step, rel=1e-12)


def test_detect_grid_with_large_multiples_and_print_rounding():
    # 5e-8 m grid, positions near 0.245 m (4.9e6 multiples) as in the EMPS benchmark
    rng = np.random.default_rng(11)
    k = 4_900_000 + np.cumsum(rng.integers(-5, 6, size=3000))
    found = detect_grid(k * 5e-8)
    assert found == pytest.approx(5e-8, rel=1e-12)
    assert off_grid(k * 5e-8, found).max() < 1e-6


def test_detect_grid_finds_the_step_of_a_motion_without_one_step_jumps():
    # a fast axis moving 32 or 33 steps per sample never shows a one-step jump: the step is the
    # common divisor of the jumps, not the smallest jump
    step = 2 * np.pi / 32768
    rng = np.random.default_rng(5)
    k = np.cumsum(rng.choice([32, 33], size=4000))
    assert detect_grid(k * step) == pytest.approx(step, rel=1e-12)
    # the same jumps off a grid through zero (an offset of a third of a step) are no grid
    assert detect_grid((k + 1 / 3) * step) is None


def test_detect_grid_rejects_smooth_and_constant_signals():
    assert detect_grid(np.sin(np.linspace(0, 3, 500))) is None
    assert detect_grid(np.full(10, 0.3)) is None


def test_truth_channel_on_a_grid_is_stored_as_counts():
    step = math.radians(450 / 128)  # the 10-bit potentiometer of the dcmotor log
    values = np.round(np.degrees(step * COUNTS), 2)  # printed with 2 decimals, as in the log
    df, meta = convert({"y": values}, y={"unit": "deg", "role": "truth", "joint": 1})
    np.testing.assert_array_equal(df["y"], COUNTS)
    # 2-decimal printing moves a value by at most 0.005 deg = 0.0014 step; the fitted step keeps
    # sum(k * error) / sum(k^2) ~ 1e-4 relative at most for these 12 samples
    assert meta["channels"][0]["step"] == pytest.approx(step, rel=2e-4)
    assert meta["channels"][0]["storage"] == "counts"


def test_detect_grid_false_keeps_float():
    df, meta = convert({"y": COUNTS * 0.01}, y={"role": "truth", "joint": 1, "detect_grid": False})
    assert meta["channels"][0]["storage"] == "float" and df["y"].dtype == np.float64


def test_declared_native_step():
    df, meta = convert({"y": COUNTS * 1e-3 + 4e-3}, y={"unit": "mrad", "native_step": 1e-6, "sign": -1})
    np.testing.assert_array_equal(df["y"], -(COUNTS + 4))
    assert meta["channels"][0]["step"] == 1e-6 and meta["channels"][0]["native_step"] == 1e-6


def test_off_declared_grid_names_the_worst_line():
    values = COUNTS * 1e-3
    values[5] += 0.03e-3  # 0.03 step off
    with pytest.raises(EnclabInputError) as info:
        convert({"y": values}, y={"native_step": 1e-3})
    assert (info.value.column, info.value.row) == ("col_y", 7)
    assert "0.030 steps off the declared grid" in str(info.value)


# ----------------------------------------------------------------------------- time base


@pytest.mark.parametrize(("unit", "scale"), [("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9)])
def test_time_column_units(unit, scale):
    stamps = np.arange(5) * 0.002 / scale
    df, meta = convert({"a": np.zeros(5)}, time=stamps, time_spec={"column": "t", "unit": unit}, a={})
    np.testing.assert_allclose(df["t"], np.arange(5) * 0.002, rtol=1e-12)
    assert meta["fs_hz"] == pytest.approx(500.0, rel=1e-9)


def test_sample_index_time_and_rate_only_time():
    df, meta = convert({"a": np.zeros(4)}, time=[10, 11, 12, 13],
                       time_spec={"column": "t", "unit": "samples", "rate_hz": 1000}, a={})
    np.testing.assert_allclose(df["t"], [0.010, 0.011, 0.012, 0.013])
    assert meta["fs_hz"] == 1000.0
    df, meta = convert({"a": np.zeros(4)}, time_spec={"rate_hz": 250}, a={})
    np.testing.assert_array_equal(df["t"], np.arange(4) / 250)
    assert meta["fs_hz"] == 250.0 and meta["time_report"]["n_gaps"] == 0


@pytest.mark.parametrize(("unit", "fix"), [("s", "in ms? (set time.unit: ms)"),
                                         ("ms", "in us? (set time.unit: us)")])
def test_a_moving_encoder_below_10_hz_gets_a_time_base_warning(unit, fix):
    # 1 kHz stamps written in ms (or us) but declared one unit coarser: a 1 Hz "log" of a
    # moving joint. It is read (the numbers may be right) and the warning names the fix.
    stamps = np.arange(50) * (1.0 if unit == "s" else 1000.0)
    moving = {"theta": np.sin(np.arange(50) / 5.0)}
    _, meta = convert(moving, time=stamps, time_spec={"column": "t", "unit": unit},
                      theta={"role": "truth", "joint": 1})
    (line,) = meta["warnings"]
    assert line.startswith("time base: sampled at 1 Hz") and line.endswith(f"column 't' {fix}")
    # the same log at 1 kHz, or a slow log of an aux channel only, is not warned about
    _, meta = convert(moving, time=stamps / 1000.0, time_spec={"column": "t", "unit": unit},
                      theta={"role": "truth", "joint": 1})
    assert meta["warnings"] == []
    _, meta = convert(moving, time=stamps, time_spec={"column": "t", "unit": unit}, theta={})
    assert meta["warnings"] == []


@pytest.mark.parametrize(("unit", "factor", "fits"), [
    ("s", 1e9, "ns"), ("s", 1e6, "us"), ("ms", 1e6, "ns"),   # too slow: a finer unit fits
    ("ms", 1e-3, "s"), ("us", 1e-3, "ms"), ("ns", 1e-6, "ms"),  # too fast: a coarser one
])
def test_a_time_base_off_by_a_power_of_1000_names_the_unit_that_fits(unit, factor, fits):
    # 1 kHz stamps written in one unit, declared in another (1e3, 1e6 or 1e9 apart): only the
    # unit that brings the rate between 10 Hz and 100 kHz is named (1 kHz in it).
    seconds = np.arange(50) / 1000.0
    stamps = seconds / {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[unit] * factor
    _, meta = convert({"theta": np.sin(np.arange(50) / 5.0)}, time=stamps,
                      time_spec={"column": "t", "unit": unit}, theta={"role": "truth", "joint": 1})
    (line,) = meta["warnings"]
    assert line.startswith("time base: ") and " in x.csv, implausibly " in line
    assert line.endswith(f"is the time column 't' in {fits}? (set time.unit: {fits})")


def test_a_time_base_that_fits_two_units_names_both_with_their_rates():
    # 20 kHz stamps in ns declared as s read as 2e-5 Hz: us (20 Hz) and ns (20 kHz) both fall in
    # the plausible range; both are named, the rate nearer 1 kHz on a log scale first.
    stamps = np.arange(50) / 20000.0 * 1e9
    _, meta = convert({"theta": np.sin(np.arange(50) / 5.0)}, time=stamps,
                      time_spec={"column": "t", "unit": "s"}, theta={"role": "truth", "joint": 1})
    assert meta["warnings"][0].endswith("in ns (2e+04 Hz) or us (20 Hz)? (set time.unit: ns or us)")


def test_a_nominal_rate_contradicted_by_a_unit_factor_names_the_unit():
    with pytest.raises(EnclabInputError) as info:
        convert({"a": np.zeros(6)}, time=np.arange(6) * 1e6, a={},
                time_spec={"column": "t", "unit": "s", "nominal_rate_hz": 1000.0})
    assert "(the stamps fit time.unit: ns)" in str(info.value)


def test_time_base_warning_of_a_rate_only_log_names_rate_hz():
    _, meta = convert({"theta": np.sin(np.arange(20.0))}, time_spec={"rate_hz": 2},
                      theta={"role": "truth", "joint": 1})
    assert meta["warnings"][0].endswith("check time.rate_hz")


def test_crop_keeps_the_closed_interval():
    df, _ = convert({"a": np.arange(10.0)}, time_spec={"rate_hz": 10}, a={})
    assert len(df) == 10
    e = entry([ch("a")], {"rate_hz": 10}, crop={"t_start": 0.2, "t_end": 0.5})
    df, meta = canonicalize(raw_log({"a": np.arange(10.0)}), e, DEVICES)
    np.testing.assert_array_equal(df["a"], [2.0, 3.0, 4.0, 5.0])
    assert meta["n_samples"] == 4 == meta["time_report"]["n_samples"]


def test_crop_excludes_nan_outside_but_not_inside():
    values = np.arange(10.0)
    values[8] = np.nan
    e = entry([ch("a")], {"rate_hz": 10}, crop={"t_end": 0.7})
    df, _ = canonicalize(raw_log({"a": values}), e, DEVICES)
    assert len(df) == 8
    e = entry([ch("a")], {"rate_hz": 10}, crop={"t_end": 0.85})
    with pytest.raises(EnclabInputError) as info:
        canonicalize(raw_log({"a": values}), e, DEVICES)
    assert (info.value.column, info.value.row) == ("col_a", 10)


def test_crop_leaving_too_few_samples():
    e = entry([ch("a")], {"rate_hz": 10}, crop={"t_start": 5.0})
    with pytest.raises(EnclabInputError, match="0 samples left after the crop"):
        canonicalize(raw_log({"a": np.arange(10.0)}), e, DEVICES)


def test_backwards_time_names_the_row():
    with pytest.raises(EnclabInputError) as info:
        convert({"a": np.zeros(5)}, time=[0.0, 0.1, 0.2, 0.15, 0.3], time_spec={"column": "t"}, a={})
    assert (info.value.file, info.value.column, info.value.row) == ("x.csv", "t", 5)
    assert "time goes backwards" in str(info.value)


def test_repeats_gaps_and_jitter_are_reported():
    # steps: 0.01, 0.011, 0.009 repeated (median 0.01), one repeated stamp, one 0.05 s gap
    dt = np.tile([0.01, 0.011, 0.009], 10)
    dt[4] = 0.0
    dt[20] = 0.05
    t = np.concatenate(([0.0], np.cumsum(dt)))
    report = time_report(t, 100.0, trailing_empty_dropped=2)
    assert set(report) == REPORT_KEYS
    assert report["n_repeated"] == 1 and report["n_gaps"] == 1 and report["n_backwards"] == 0
    assert report["max_gap_s"] == pytest.approx(0.05)
    assert report["median_dt_s"] == pytest.approx(0.01) and report["fs_hz"] == pytest.approx(100.0)
    # regular steps: 28 left, deviations of 0, +1 ms, -1 ms in equal shares up to the removed ones
    regular = np.delete(dt, [4, 20])
    assert report["jitter_rms_s"] == pytest.approx(np.sqrt(np.mean((regular - 0.01) ** 2)), rel=1e-9)
    assert report["n_samples"] == 31 and report["trailing_empty_dropped"] == 2
    assert report["nominal_rate_hz"] == 100.0


def test_time_file_fixture_reports_the_repeat_and_the_gap():
    e = entry([ch("q1", column=0)], {"file": "sample_major_time.txt", "nominal_rate_hz": 100},
              file="sample_major.txt", format="text", reader={"values_per_sample": 2})
    df, meta = ingest.ingest_log(e, FIXTURES, DEVICES)
    report = meta["time_report"]
    # the repeated stamp of sample 5 makes the next step a double one: two gaps in all
    assert (report["n_repeated"], report["n_gaps"]) == (1, 2)
    assert report["max_gap_s"] == pytest.approx(0.03, abs=2e-6)  # stamps printed with 6 decimals
    # the repeat is collapsed to its first row (sample 4, 0-based), and the warning names it
    assert report["repeated_rows"] == [5]
    np.testing.assert_array_equal(df["q1"], fixtures.STEP * np.delete(COUNTS, 4))
    assert np.all(np.diff(df["t"]) > 0) and meta["n_samples"] == N - 1
    (line,) = meta["warnings"]
    assert line.startswith("repeated time stamps: 1 row of ") and "sample_major_time.txt" in line
    assert "(line 5), with other values than the row before" in line


@pytest.mark.parametrize(("nominal", "ok"), [(104.0, True), (96.0, True), (106.0, False), (50.0, False)])
def test_nominal_rate_tolerance_is_five_percent(nominal, ok):
    time_spec = {"column": "t", "nominal_rate_hz": nominal}
    args = ({"a": np.zeros(6)},)
    kwargs = dict(time=np.arange(6) / 100.0, time_spec=time_spec, a={})
    if ok:
        convert(*args, **kwargs)
    else:
        with pytest.raises(EnclabInputError) as info:
            convert(*args, **kwargs)
        assert info.value.key == "time.nominal_rate_hz" and "not the nominal" in str(info.value)


def test_all_equal_time_stamps_are_an_error():
    with pytest.raises(EnclabInputError, match="every time stamp is the same"):
        convert({"a": np.zeros(3)}, time=[1.0, 1.0, 1.0], time_spec={"column": "t"}, a={})


# ----------------------------------------------------------------------------- metadata


def test_metadata_layout_and_device_resolution():
    e = entry([ch("theta", role="truth", joint=1, unit="counts", counts_per_rev=8192)], device="axis",
              group="g1", tags=["a", "b"], analysis={"requantize": {"multiples": [8]}})
    df, meta = canonicalize(raw_log({"theta": COUNTS}), e, DEVICES)
    assert set(meta) == META_KEYS
    assert list(df.columns) == ["t", "theta"] and df["t"].dtype == np.float64
    assert meta["source"] == {"file": "x.csv", "sha256": None, "format": "csv"}
    assert meta["device"] == {"kind": "single_joint"} and meta["device"] is not DEVICES["axis"]
    assert (meta["log_id"], meta["group"], meta["tags"]) == ("log1", "g1", ["a", "b"])
    assert meta["analysis"] == {"requantize": {"multiples": [8]}}
    assert meta["n_samples"] == N and meta["fs_hz"] == 100.0


def test_inline_and_missing_device():
    e = entry([ch("a")], device={"kind": "planar_2r", "l1": 0.2})
    assert canonicalize(raw_log({"a": [0.0, 1.0]}), e, DEVICES)[1]["device"] == {"kind": "planar_2r", "l1": 0.2}
    assert canonicalize(raw_log({"a": [0.0, 1.0]}), entry([ch("a")]), DEVICES)[1]["device"] is None
    e = entry([ch("a")], device="axis")
    with pytest.raises(EnclabInputError, match="unknown device 'axis'"):
        canonicalize(raw_log({"a": [0.0, 1.0]}), e, {})


def test_ingest_log_end_to_end_on_the_mrdlab_style_fixture(tmp_path):
    e = entry([ch("a", column="Encoder A [counts]", role="truth", joint=1, unit="counts", counts_per_rev=4096),
               ch("b", column="Encoder B [counts]", role="measured", joint=1, unit="counts", counts_per_rev=8192,
                  sign=-1)],
              {"column": "Time [s]", "nominal_rate_hz": 100}, file="mrd_style.txt", format="text",
              reader={"comment": "%", "column_names": "last_comment"})
    df, meta = ingest.ingest_log(e, FIXTURES, DEVICES)
    assert meta["source"]["sha256"] == readers.file_sha256(FIXTURES / "mrd_style.txt")
    steps = {c["name"]: c["step"] for c in meta["channels"]}
    # channel b counts -2 * COUNTS on an encoder twice as fine with the opposite sign: same angle
    np.testing.assert_allclose(df["a"] * steps["a"], df["b"] * steps["b"], rtol=1e-15)
    canonical.write_canonical(df, meta, tmp_path / "c.parquet")
    back, back_meta = canonical.read_canonical(tmp_path / "c.parquet")
    assert back_meta == meta
    assert back["a"].dtype == np.int64


def test_ingest_csv_fixture_in_every_unit():
    e = entry([ch("deg", column="theta_deg", unit="deg"), ch("mrad", column="theta_mrad", unit="mrad"),
               ch("enc", unit="counts", counts_per_rev=fixtures.CPR), ch("x", column="x_mm", unit="mm")],
              {"column": "time_ms", "unit": "ms"}, file="basic.csv")
    df, meta = ingest.ingest_log(e, FIXTURES, DEVICES)
    theta = fixtures.STEP * COUNTS
    np.testing.assert_allclose(df["deg"], theta, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(df["mrad"], theta, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(df["enc"] * meta["channels"][2]["step"], theta, rtol=1e-15)
    np.testing.assert_allclose(df["x"], 0.5e-3 * COUNTS, rtol=1e-15)
    np.testing.assert_allclose(df["t"], np.arange(N) / 100, rtol=1e-15)


# ----------------------------------------------------------------------------- plausibility
def test_a_truth_channel_that_never_moves_is_rejected_but_an_aux_one_is_kept():
    with pytest.raises(EnclabInputError, match=r"column 'col_q'.*never moves \(all 5 samples"):
        convert({"q": [0.3] * 5}, q={"role": "truth", "joint": 1, "unit": "rad", "detect_grid": False})
    df, _ = convert({"q": [0.3] * 5}, q={"role": "aux", "unit": "rad"})
    assert df["q"].tolist() == [0.3] * 5


def test_degrees_declared_as_radians_are_rejected_unless_multi_turn():
    degrees = np.linspace(-90.0, 90.0, 50)  # 180 "rad" = 28.6 turns
    spec = {"role": "truth", "joint": 1, "unit": "rad", "detect_grid": False}
    with pytest.raises(EnclabInputError, match=r"spans 180 rad = 28.6 turns.*set unit: deg"):
        convert({"q": degrees}, q=spec)
    df, _ = convert({"q": degrees}, q=spec | {"multi_turn": True})
    np.testing.assert_array_equal(df["q"], degrees)
    df, _ = convert({"q": degrees}, q=spec | {"unit": "deg"})
    np.testing.assert_allclose(df["q"], np.deg2rad(degrees))


# ----------------------------------------------------------------------------- repeated stamps


def test_rows_written_twice_are_collapsed_and_reported():
    # a logger that wrote 40 rows twice (each row followed by its copy): 40 repeated stamps,
    # collapsed to the first of each, the log as if written once; the warning names the rows
    t = np.arange(200) / 100.0
    theta = np.sin(2 * np.pi * t)
    twice = np.concatenate((np.arange(60), np.repeat(np.arange(60, 100), 2), np.arange(100, 200)))
    df, meta = convert({"theta": theta[twice]}, time=t[twice], time_spec={"column": "t"},
                       theta={"role": "truth", "joint": 1})
    np.testing.assert_array_equal(df["t"], t)
    np.testing.assert_array_equal(df["theta"], theta)
    report = meta["time_report"]
    assert report["n_repeated"] == 40 and meta["n_samples"] == 200
    # sample 61 (0-based) is the copy of sample 60, on line 63 (header on line 1)
    assert report["repeated_rows"][:3] == [63, 65, 67] and len(report["repeated_rows"]) == 20
    (line,) = meta["warnings"]
    assert line.startswith("repeated time stamps: 40 rows of x.csv column 't'")
    assert "(line 63, 65, 67, 69, 71, ...)" in line and "a copy of the row before" in line


def test_a_repeated_stamp_with_another_value_keeps_the_first_row():
    df, meta = convert({"theta": [0.0, 0.1, 0.2, 0.3, 0.4]}, time=[0.0, 0.01, 0.01, 0.03, 0.04],
                       time_spec={"column": "t"}, theta={"role": "truth", "joint": 1, "detect_grid": False})
    np.testing.assert_array_equal(df["theta"], [0.0, 0.1, 0.3, 0.4])
    assert "other values than the row before" in meta["warnings"][-1]
    assert meta["time_report"]["repeated_rows"] == [4]


# ----------------------------------------------------------------------------- unit factors


def _pair(measured_values, truth_unit="rad", n=3000, **measured):
    """A truth/measured pair of one joint: 0.3 rad sine, measured on a 1 mrad grid."""
    t = np.arange(n) / 1000.0
    truth = 0.3 * np.sin(2 * np.pi * 2 * t) + 0.1
    truth_values = truth / ingest.UNIT_FACTORS[truth_unit]
    return convert({"truth": truth_values, "meas": measured_values(truth)}, time=t,
                   time_spec={"column": "t"}, truth={"role": "truth", "joint": 1, "unit": truth_unit},
                   meas={"role": "measured", "joint": 1, **measured})


def _grid(theta, step=1e-3):
    return np.floor(theta / step + 0.5) * step


@pytest.mark.parametrize(("values", "declared", "factor", "fix"), [
    (lambda th: _grid(th), "deg", "1/57.2958 = rad declared as deg", "(set unit: rad)"),
    (lambda th: np.rad2deg(_grid(th)), "rad", "57.2958 = deg declared as rad", "(set unit: deg)"),
    (lambda th: _grid(th), "mrad", "1/1000 = rad declared as mrad", "(set unit: rad)"),
    (lambda th: 1e3 * _grid(th), "deg", "17.4533 = mrad declared as deg", "(set unit: mrad)"),
])
def test_a_measured_channel_in_another_angle_unit_is_warned_about(values, declared, factor, fix):
    _, meta = _pair(values, unit=declared, multi_turn=True)
    (line,) = meta["warnings"]
    assert line.startswith("unit factor: in x.csv, channel 'meas' (column 'col_meas') moves ")
    assert "the truth 'truth' (column 'col_truth') of joint 1" in line
    assert f"factor {factor}" in line and line.endswith(fix)


@pytest.mark.parametrize("k", [-3, -1, 1, 2, 10])
def test_counts_per_rev_off_by_a_power_of_two_is_warned_about(k):
    # an encoder of 4096 counts per rev declared with 4096 / 2**k: the angle is 2**k too large
    counts = lambda th: np.floor(th / (2 * np.pi / 4096) + 0.5)  # noqa: E731
    _, meta = _pair(counts, unit="counts", counts_per_rev=4096 / 2.0**k, multi_turn=True)
    (line,) = meta["warnings"]
    power = f"2^{k}" if k > 0 else f"1/2^{-k}"
    assert f"factor {power}, a power of two: counts_per_rev {4096 / 2.0**k:g} declared, 4096 fits" in line


@pytest.mark.parametrize(("scale", "extra"), [
    (1.0, {}),                      # the same angle on two grids
    (1.0005, {}),                   # a real scale error of 5e-4 (a counts-per-rev slip)
    (1.0 / 57.2958 * 1.05, {"unit": "deg"}),  # 5 % from the unit factor: physical, not a unit
])
def test_no_unit_factor_warning_for_a_physical_scale(scale, extra):
    _, meta = _pair(lambda th: _grid(th * scale), **extra)
    assert meta["warnings"] == []


def test_a_geared_pair_declared_with_its_gear_ratio_is_not_warned_about():
    # motor-side counts through a 32:1 gearbox (a power of two), declared: the angles agree
    cpr, gear = 2048, 32.0
    motor = lambda th: np.floor(th * gear / (2 * np.pi / cpr) + 0.5)  # noqa: E731
    _, meta = _pair(motor, unit="counts", counts_per_rev=cpr, gear_ratio=gear)
    assert meta["warnings"] == []
    # ... the same gearbox left out of the declaration is a power of two: warned about
    _, meta = _pair(motor, unit="counts", counts_per_rev=cpr, multi_turn=True)
    assert "factor 2^5, a power of two" in meta["warnings"][0]


def test_channels_that_do_not_track_each_other_are_not_compared():
    # a measured channel that is noise (r^2 far below 0.99) says nothing about units
    rng = np.random.default_rng(3)
    _, meta = _pair(lambda th: rng.normal(0.0, 0.3 / 57.3, th.size), unit="rad")
    assert meta["warnings"] == []


def test_scale_ratio_is_blind_to_an_offset_and_exact_on_a_line():
    x = np.linspace(-1.0, 1.0, 101)
    ratio, r2 = ingest.scale_ratio(x, 3.0 * x + 7.0)
    # mean-free sums of 101 values of order 1: float64 rounding of the sums, a few ulp each
    assert ratio == pytest.approx(3.0, rel=1e-13) and r2 == pytest.approx(1.0, rel=1e-13)
    assert ingest.scale_ratio(np.ones(5), x[:5]) is None


# ----------------------------------------------------------------------------- memory


def test_a_text_log_too_large_for_the_memory_is_refused_before_reading(tmp_path, monkeypatch):
    (tmp_path / "x.csv").write_text("t,a\n" + "".join(f"{i / 100},{i}\n" for i in range(100)))
    e = entry([ch("a")], {"column": "t"})
    size = (tmp_path / "x.csv").stat().st_size
    # just enough free memory: read; a byte less than the estimate: refused, naming the fix
    monkeypatch.setattr(ingest, "available_memory_bytes", lambda: int(ingest.TEXT_READ_BYTES_PER_BYTE * size))
    df, _ = ingest.ingest_log(e, tmp_path, DEVICES)
    assert len(df) == 100
    monkeypatch.setattr(ingest, "available_memory_bytes",
                        lambda: int(ingest.TEXT_READ_BYTES_PER_BYTE * size) - 1)
    with pytest.raises(EnclabInputError) as info:
        ingest.ingest_log(e, tmp_path, DEVICES)
    message = str(info.value)
    assert "x.csv" in message and "of text needs about" in message and "Parquet" in message
    assert "\n" not in message
    # no /proc/meminfo (another system): nothing to judge by, the log is read
    monkeypatch.setattr(ingest, "available_memory_bytes", lambda: None)
    assert len(ingest.ingest_log(e, tmp_path, DEVICES)[0]) == 100


def test_available_memory_is_read_where_the_system_reports_it():
    free = ingest.available_memory_bytes()
    assert free is None or free > 0
