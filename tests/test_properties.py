"""Property tests (hypothesis): readers, the quantizer and dwell extraction, and a short fuzz
run of the CSV reader (any bytes give a table or an EnclabInputError, never a crash)."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from enclab.core import readers
from enclab.core.errors import EnclabInputError
from enclab.core.manifest import validate_manifest
from enclab.core.quantize import quantize, requantize_counts
from enclab.lrde import dwell
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

DEVICES = {"axis": {"kind": "single_joint"}}
finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


def _entry(file: str, unit: str = "rad") -> dict:
    doc = {"logs": [{"id": "p", "file": file, "format": "csv", "device": "axis",
                     "time": {"column": "t", "unit": "s"},
                     "channels": [{"name": "q", "column": "q", "role": "aux", "unit": unit}]}]}
    return validate_manifest(doc, DEVICES, "m.yaml")[1][0]


# ----------------------------------------------------------------------------- quantizer
@settings(max_examples=200, deadline=None)
@given(counts=arrays(np.int64, st.integers(1, 50), elements=st.integers(-(2**30), 2**30)),
       exponent=st.integers(-12, 0))
def test_quantizing_a_reading_gives_back_its_counts(counts, exponent):
    step = 3.0 * 2.0**exponent * 1.7  # not a power of two
    np.testing.assert_array_equal(quantize(counts * step, step), counts)


@settings(max_examples=200, deadline=None)
@given(theta=arrays(np.float64, st.integers(1, 50), elements=finite),
       step=st.floats(1e-6, 10.0), offset=st.floats(0.0, 1.0, exclude_max=True))
def test_quantization_error_lies_in_its_interval(theta, step, offset):
    # reading - theta lies in (a - step, a] with a = offset * step, up to the rounding of the
    # float evaluation of theta/step (a few eps of |theta|/step steps).
    err = quantize(theta, step, offset) * step - theta
    slack = 8 * np.finfo(float).eps * (np.abs(theta) + step)
    assert np.all(err <= offset * step + slack)
    assert np.all(err > offset * step - step - slack)


@settings(max_examples=200, deadline=None)
@given(coarse=arrays(np.int64, st.integers(1, 50), elements=st.integers(-(2**40), 2**40)),
       ratio=st.integers(1, 4096))
def test_requantizing_coarse_counts_is_idempotent(coarse, ratio):
    # Coarse counts written on the fine grid and rounded back are unchanged.
    np.testing.assert_array_equal(requantize_counts(coarse * ratio, ratio, 0.5), coarse)


# ----------------------------------------------------------------------------- dwell
@settings(max_examples=200, deadline=None)
@given(counts=arrays(np.int64, st.integers(1, 300), elements=st.integers(-3, 3)))
def test_run_lengths_round_trip(counts):
    values, starts, lengths = dwell.run_lengths(counts)
    np.testing.assert_array_equal(np.repeat(values, lengths), counts)
    np.testing.assert_array_equal(starts, np.concatenate(([0], np.cumsum(lengths)[:-1])))
    assert np.all(values[1:] != values[:-1]) and np.all(lengths > 0)


# ----------------------------------------------------------------------------- readers
@settings(max_examples=60, deadline=None)
@given(q=arrays(np.float64, st.integers(2, 40), elements=finite))
def test_csv_reader_round_trips_written_values(q):
    with tempfile.TemporaryDirectory() as folder:
        table = pd.DataFrame({"t": np.arange(q.size) * 1e-3, "q": q})
        table.to_csv(Path(folder) / "x.csv", index=False, float_format="%.17g")
        raw = readers.read_raw(_entry("x.csv"), folder)
    np.testing.assert_array_equal(raw.channels["q"], q)
    np.testing.assert_array_equal(raw.time, table["t"].to_numpy())
    np.testing.assert_array_equal(raw.locations, np.arange(q.size) + 2)  # header is line 1


@settings(max_examples=60, deadline=None)
@given(q=arrays(np.float64, st.integers(2, 40), elements=finite))
def test_parquet_reader_round_trips_written_values(q):
    with tempfile.TemporaryDirectory() as folder:
        pd.DataFrame({"t": np.arange(q.size) * 1e-3, "q": q}).to_parquet(Path(folder) / "x.parquet")
        entry = _entry("x.parquet") | {"format": "parquet", "reader": {}}
        raw = readers.read_raw(entry, folder)
    np.testing.assert_array_equal(raw.channels["q"], q)


_csv_alphabet = st.sampled_from(list("0123456789.,-+eE naNinf\t\n\"%;#x"))


@settings(max_examples=300, deadline=None)
@given(body=st.text(alphabet=_csv_alphabet, max_size=300),
       header=st.sampled_from(["t,q\n", "q,t\n", "t;q\n", "", "t,q,r\n"]))
def test_csv_reader_fuzz_gives_a_table_or_a_clear_error(body, header):
    with tempfile.TemporaryDirectory() as folder:
        (Path(folder) / "x.csv").write_text(header + body)
        try:
            raw = readers.read_raw(_entry("x.csv"), folder)
        except EnclabInputError as err:
            message = str(err)
            assert "x.csv" in message and "\n" not in message
            return
    assert np.all(np.isfinite(raw.channels["q"])) and raw.channels["q"].size == raw.time.size
