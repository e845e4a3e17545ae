"""A log too large for the memory available is refused with one line, not killed."""
import numpy as np
import pandas as pd
import pytest
from enclab.core import ingest
from enclab.core.errors import EnclabInputError
from enclab.residuals import pipeline


def test_the_residual_stage_refuses_a_log_larger_than_the_free_memory(monkeypatch):
    n = 30_000_000
    meta = {"log_id": "long", "source": {"file": "long.csv"}}
    monkeypatch.setattr(ingest, "available_memory_bytes", lambda: int(pipeline.RESIDUAL_BYTES_PER_SAMPLE * n) - 1)
    with pytest.raises(EnclabInputError) as info:
        pipeline.check_memory(n, meta)
    message = str(info.value)
    assert message.startswith("long.csv: key 'crop': 30,000,000 samples need about 15.0 GB")
    assert "Crop the log" in message and "\n" not in message
    # enough memory, or no way to know it: the stage runs
    monkeypatch.setattr(ingest, "available_memory_bytes", lambda: int(pipeline.RESIDUAL_BYTES_PER_SAMPLE * n))
    pipeline.check_memory(n, meta)
    monkeypatch.setattr(ingest, "available_memory_bytes", lambda: None)
    pipeline.check_memory(n, meta)


def test_analyse_channel_checks_before_it_allocates(monkeypatch):
    monkeypatch.setattr(ingest, "available_memory_bytes", lambda: 1000)
    df = pd.DataFrame({"t": np.arange(100) / 1000.0, "truth": np.zeros(100), "measured": np.zeros(100)})
    with pytest.raises(EnclabInputError, match="100 samples need about"):
        pipeline.analyse_channel(df, {"log_id": "x", "source": {"file": "x.csv"}, "channels": []},
                                 {"truth": "truth", "measured": "measured"})
