"""A canonical channel in SI (enclab.core.canonical.Channel): counts times step, floats as
stored, the grid, and the channel read back from a canonical Parquet file."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from enclab.core.canonical import Channel, read_canonical, write_canonical

STEP = 2 * np.pi / 4096
META = {"log_id": "log", "channels": [
    {"name": "motor", "role": "truth", "joint": 1, "unit": "rad", "storage": "counts",
     "step": STEP, "native_step": STEP},
    {"name": "output", "role": "measured", "joint": 1, "unit": "rad", "storage": "float",
     "step": None, "native_step": 1e-3},
    {"name": "torque", "role": "aux", "joint": None, "unit": "N m", "storage": "float",
     "step": None, "native_step": None},
]}
DF = pd.DataFrame({"t": [0.0, 0.001, 0.002],
                   "motor": np.array([-3, 0, 4097], dtype=np.int64),
                   "output": [0.001, 0.002, 0.003], "torque": [0.5, -0.5, 0.25]})


def test_counts_channel_is_counts_times_step_bit_for_bit():
    motor = Channel.named(META, "motor", DF)
    assert motor.is_counts and motor.step == STEP and motor.grid == STEP
    assert motor.counts.dtype == np.int64 and motor.counts.tolist() == [-3, 0, 4097]
    expected = DF["motor"].to_numpy().astype(np.float64) * STEP
    assert motor.values.dtype == np.float64 and np.array_equal(motor.values, expected)
    assert (motor.unit, motor.role, motor.joint) == ("rad", "truth", 1)


def test_float_channel_keeps_its_values_and_its_native_grid():
    output = Channel.named(META, "output", DF)
    assert not output.is_counts and output.step is None and output.counts is None
    assert output.grid == 1e-3  # declared or detected at ingest, values stay floats
    assert np.array_equal(output.values, DF["output"].to_numpy())
    assert Channel.named(META, "torque", DF).grid is None


def test_a_stored_column_or_metadata_alone():
    chan = META["channels"][0]
    column = np.array([1, 2], dtype=np.int64)
    assert np.array_equal(Channel.of(chan, column=column).values, column * STEP)
    bare = Channel.of(chan)
    assert bare.grid == STEP
    with pytest.raises(ValueError, match="'motor' was built without its column"):
        bare.values


def test_an_unknown_channel_names_the_log_and_its_channels():
    with pytest.raises(ValueError, match=r"log 'log' has no channel 'x'; channels \['motor', 'output', 'torque'\]"):
        Channel.named(META, "x", DF)


def test_channel_read_back_from_a_canonical_file(tmp_path):
    path = tmp_path / "canonical.parquet"
    write_canonical(DF, META, path)
    df, meta = read_canonical(path)
    motor = Channel.named(meta, "motor", df)
    assert np.array_equal(motor.values, Channel.named(META, "motor", DF).values)
