"""Tests for enclab.core.readers, canonical and atomic: readers (csv, text, sample-major, parquet, mat), error locations, writers.

The fixtures in tests/fixtures/ingest are written by make_fixtures.py in that folder; they all
hold the integer counts COUNTS at 100 Hz (see its docstring), so each reader is checked
against the same exact numbers.
"""
from __future__ import annotations

import importlib.util
import json
import math
import os
import stat
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pyarrow as pa  # noqa: E402
import pyarrow.parquet as pq  # noqa: E402
import pytest  # noqa: E402
import scipy.io  # noqa: E402
from enclab.core import atomic, canonical, readers  # noqa: E402
from enclab.core.errors import EnclabInputError  # noqa: E402
from enclab.core.manifest import validate_manifest  # noqa: E402

FIXTURES = Path(__file__).parent / "fixtures" / "ingest"
_spec = importlib.util.spec_from_file_location("make_fixtures", FIXTURES / "make_fixtures.py")
fixtures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fixtures)
COUNTS = np.asarray(fixtures.COUNTS, dtype=float)
THETA = fixtures.STEP * COUNTS
N = COUNTS.size


def entry(**fields) -> dict:
    """A normalised manifest entry (defaults filled by the real validator)."""
    base = {"id": "fx", "time": {"rate_hz": 100}}
    base.update(fields)
    _, (normalised,) = validate_manifest({"logs": [base]}, {}, "test.yaml")
    return normalised


def aux(name, column, **extra) -> dict:
    return {"name": name, "column": column, "role": "aux", **extra}


def read(data_root, **fields) -> readers.RawLog:
    return readers.read_raw(entry(**fields), data_root)


def input_error(data_root, **fields) -> EnclabInputError:
    with pytest.raises(EnclabInputError) as info:
        read(data_root, **fields)
    return info.value


# ----------------------------------------------------------------------------- readers


def test_csv_reader_columns_by_name_and_index():
    raw = read(FIXTURES, file="basic.csv", format="csv", time={"column": "time_ms", "unit": "ms"},
               channels=[aux("deg", "theta_deg"), aux("enc", 3)])
    np.testing.assert_array_equal(raw.time, 10.0 * np.arange(N))
    np.testing.assert_allclose(raw.channels["deg"], np.degrees(THETA), rtol=1e-15)
    np.testing.assert_array_equal(raw.channels["enc"], COUNTS)
    assert raw.columns == {"deg": "theta_deg", "enc": "enc"}
    # data starts on line 2 (line 1 is the header)
    np.testing.assert_array_equal(raw.locations, np.arange(2, N + 2))
    assert raw.row_label == "line" and raw.time_column == "time_ms"


def test_text_reader_names_from_last_comment_line():
    raw = read(FIXTURES, file="mrd_style.txt", format="text",
               reader={"comment": "%", "column_names": "last_comment"},
               time={"column": "Time [s]"}, channels=[aux("a", "Encoder A [counts]"), aux("b", 2)])
    np.testing.assert_array_equal(raw.channels["a"], COUNTS)
    np.testing.assert_array_equal(raw.channels["b"], -2 * COUNTS)
    np.testing.assert_allclose(raw.time, np.arange(N) / 100, atol=5e-4)
    assert raw.locations[0] == 4  # three '%' lines before the data


def test_whitespace_text_with_listed_column_names():
    raw = read(FIXTURES, file="whitespace.txt", format="text",
               reader={"delimiter": "whitespace", "column_names": ["t_us", "theta", "enc"]},
               time={"column": "t_us", "unit": "us"}, channels=[aux("theta", "theta"), aux("enc", 2)])
    np.testing.assert_array_equal(raw.channels["theta"], THETA)
    np.testing.assert_array_equal(raw.channels["enc"], COUNTS)
    np.testing.assert_array_equal(raw.locations, np.arange(1, N + 1))


def test_auto_delimiter_falls_back_to_whitespace():
    raw = read(FIXTURES, file="whitespace.txt", format="text", channels=[aux("enc", 2)])
    np.testing.assert_array_equal(raw.channels["enc"], COUNTS)


def test_sample_major_text_with_a_time_file():
    raw = read(FIXTURES, file="sample_major.txt", format="text",
               reader={"values_per_sample": 2, "column_names": ["q1", "q2"]},
               time={"file": "sample_major_time.txt"}, channels=[aux("q2", "q2"), aux("q1", 0)])
    np.testing.assert_array_equal(raw.channels["q1"], THETA)
    np.testing.assert_array_equal(raw.channels["q2"], -THETA)
    assert raw.row_label == "sample"
    np.testing.assert_array_equal(raw.locations, np.arange(1, N + 1))
    assert raw.time.size == N and raw.time_row_label == "line"
    assert raw.time_file == str(FIXTURES / "sample_major_time.txt")


def test_parquet_reader():
    raw = read(FIXTURES, file="table.parquet", format="parquet",
               time={"column": "index", "unit": "samples", "rate_hz": 100},
               channels=[aux("theta", "theta"), aux("counter", 2)])
    np.testing.assert_array_equal(raw.channels["theta"], THETA)
    np.testing.assert_array_equal(raw.time, np.arange(N))
    assert raw.row_label == "row" and raw.locations[0] == 1


def test_mat_vectors_row_and_column_orientation():
    raw = read(FIXTURES, file="vectors.mat", format="mat", time={"column": "t"},
               channels=[aux("qm", "qm", unit="m"), aux("qg", "qg", unit="m")])
    np.testing.assert_allclose(raw.channels["qm"], 5e-5 * COUNTS, rtol=1e-15)
    np.testing.assert_allclose(raw.channels["qg"] - raw.channels["qm"], 1e-6, rtol=1e-9)
    assert raw.time.shape == (N,)


def test_mat_matrix_variable_with_column_names():
    raw = read(FIXTURES, file="matrix.mat", format="mat",
               reader={"variable": "data", "column_names": ["t", "qm", "qg"]},
               time={"column": 0}, channels=[aux("qm", "qm", unit="m")])
    np.testing.assert_allclose(raw.channels["qm"], 5e-5 * COUNTS, rtol=1e-15)


def test_trailing_empty_rows_are_dropped_and_counted():
    raw = read(FIXTURES, file="trailing.csv", format="csv", time={"column": "t", "unit": "samples", "rate_hz": 1},
               channels=[aux("pos", "pos"), aux("cmd", "cmd")])
    assert raw.trailing_empty_dropped == 3
    assert raw.n_samples == N and raw.time.size == N


def test_trailing_empty_rows_are_errors_when_not_skipped():
    err = input_error(FIXTURES, file="trailing.csv", format="csv", reader={"skip_trailing_empty": False},
                      channels=[aux("pos", "pos")])
    assert err.column == "pos" and err.row == N + 2 and err.row_label == "line"


def test_entry_files_lists_data_and_time_file():
    e = entry(file="sample_major.txt", format="text", reader={"values_per_sample": 2},
              time={"file": "sample_major_time.txt"}, channels=[aux("q1", 0)])
    assert readers.entry_files(e, "root") == [os.path.join("root", "sample_major.txt"),
                                              os.path.join("root", "sample_major_time.txt")]
    assert readers.entry_files(entry(file="a.csv", format="csv", channels=[aux("q", 0)]), "r") == [
        os.path.join("r", "a.csv")]


# ----------------------------------------------------------------------------- bad input


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


CSV_FIELDS = dict(file="bad.csv", format="csv", time={"column": "t"}, channels=[aux("q", "q"), aux("r", "r")])


@pytest.mark.parametrize(
    ("text", "column", "line", "words"),
    [
        ("t,q,r\n0,1,2\n1,n/a,2\n", "q", 3, "text 'n/a' in a numeric column"),
        ("t,q,r\n0,1,2\n1,2,3\n2,nan,3\n", "q", 4, "empty or NaN value"),
        ("t,q,r\n0,1,2\n1,2,inf\n", "r", 3, "infinite value"),
        ("t,q,r\n0,1,2\n\n1,,2\n2,3,4\n", "q", 4, "empty or NaN value"),  # blank line still counted
    ],
)
def test_bad_values_name_file_column_and_line(tmp_path, text, column, line, words):
    path = write(tmp_path, "bad.csv", text)
    err = input_error(tmp_path, **CSV_FIELDS)
    assert (err.file, err.column, err.row, err.row_label) == (str(path), column, line, "line")
    assert str(err).startswith(f"{path}: column '{column}', line {line}: {words}")


def test_ragged_row_names_the_line(tmp_path):
    write(tmp_path, "bad.csv", "t,q,r\n0,1,2\n1,2\n")
    err = input_error(tmp_path, **CSV_FIELDS)
    assert err.row == 3 and "2 values on this line" in str(err) and "3 values" in str(err)


def test_missing_column_lists_the_available_ones(tmp_path):
    write(tmp_path, "bad.csv", "t,q,x\n0,1,2\n")
    err = input_error(tmp_path, **CSV_FIELDS)
    assert err.column == "r" and "column not found" in str(err) and "'x'" in str(err)


def test_column_index_out_of_range(tmp_path):
    write(tmp_path, "bad.csv", "t,q,r\n0,1,2\n")
    err = input_error(tmp_path, file="bad.csv", format="csv", channels=[aux("q", 5)])
    assert err.column == 5 and "out of range" in str(err)


def test_missing_data_file(tmp_path):
    err = input_error(tmp_path, **CSV_FIELDS)
    assert err.file == str(tmp_path / "bad.csv") and "data file not found" in str(err)


def test_time_column_nan_names_the_time_column(tmp_path):
    write(tmp_path, "bad.csv", "t,q,r\n0,1,2\n,2,3\n")
    err = input_error(tmp_path, **CSV_FIELDS)
    assert (err.column, err.row) == ("t", 3)


def test_sample_major_bad_value_names_the_sample(tmp_path):
    write(tmp_path, "q.txt", "1.0\n2.0\n3.0\nabc\n5.0\n6.0\n")
    err = input_error(tmp_path, file="q.txt", format="text", reader={"values_per_sample": 2},
                      channels=[aux("q1", 0), aux("q2", 1)])
    # value j=1 of sample 2 is on line (2-1)*2 + 1 + 1 = 4
    assert (err.column, err.row, err.row_label) == ("1", 2, "sample")


def test_sample_major_incomplete_last_sample(tmp_path):
    write(tmp_path, "q.txt", "1\n2\n3\n4\n5\n")
    err = input_error(tmp_path, file="q.txt", format="text", reader={"values_per_sample": 2},
                      channels=[aux("q1", 0)])
    assert (err.row, err.row_label) == (3, "sample") and "line 5" in str(err)


def test_time_file_length_mismatch(tmp_path):
    write(tmp_path, "q.txt", "1\n2\n3\n4\n")
    time_path = write(tmp_path, "t.txt", "0\n0.001\n0.002\n")
    err = input_error(tmp_path, file="q.txt", format="text", reader={"values_per_sample": 2},
                      time={"file": "t.txt"}, channels=[aux("q1", 0)])
    assert err.file == str(time_path) and "3 time values for 2 samples" in str(err)


def test_time_file_bad_value_names_its_line(tmp_path):
    write(tmp_path, "q.txt", "1\n2\n3\n")
    time_path = write(tmp_path, "t.txt", "time\n0\n0.001\nx\n")
    err = input_error(tmp_path, file="q.txt", format="text", reader={"values_per_sample": 1},
                      time={"file": "t.txt"}, channels=[aux("q1", 0)])
    assert (err.file, err.row, err.row_label) == (str(time_path), 4, "line")


def test_parquet_null_names_the_row(tmp_path):
    pq.write_table(pa.table({"q": pa.array([0.0, 1.0, None, 3.0])}), tmp_path / "x.parquet")
    err = input_error(tmp_path, file="x.parquet", format="parquet", channels=[aux("q", "q")])
    assert (err.column, err.row, err.row_label) == ("q", 3, "row")


def test_parquet_text_column_is_rejected(tmp_path):
    pd.DataFrame({"q": ["a", "b"]}).to_parquet(tmp_path / "x.parquet")
    err = input_error(tmp_path, file="x.parquet", format="parquet", channels=[aux("q", "q")])
    assert err.column == "q" and "not numeric" in str(err)


def test_mat_missing_variable_and_length_mismatch(tmp_path):
    scipy.io.savemat(tmp_path / "x.mat", {"t": np.arange(4.0), "qm": np.arange(3.0)})
    err = input_error(tmp_path, file="x.mat", format="mat", channels=[aux("qg", "qg", unit="m")])
    assert err.column == "qg" and "variable not found" in str(err) and "'qm'" in str(err)
    err = input_error(tmp_path, file="x.mat", format="mat", time={"column": "t"},
                      channels=[aux("qm", "qm", unit="m")])
    assert err.column == "t" and "4 samples but variable 'qm' has 3" in str(err)


def test_mat_nan_names_the_row(tmp_path):
    scipy.io.savemat(tmp_path / "x.mat", {"qm": np.array([0.0, 1.0, 2.0, np.nan, 4.0])})
    err = input_error(tmp_path, file="x.mat", format="mat", channels=[aux("qm", "qm", unit="m")])
    assert (err.column, err.row, err.row_label) == ("qm", 4, "row")


def test_last_comment_with_wrong_name_count(tmp_path):
    write(tmp_path, "m.txt", "%a, b\n%t, q\n1,2,3\n")
    err = input_error(tmp_path, file="m.txt", format="text",
                      reader={"comment": "%", "column_names": "last_comment"}, channels=[aux("q", "q")])
    assert (err.row, err.row_label) == (2, "line") and "names 2 columns" in str(err)


# ----------------------------------------------------------------------------- file forms
# The same numbers written as labs' loggers write them: each form is read to the same values,
# or, when the entry does not declare it, fails with one line that names the key to set.

FORM_TEXT = "t,q,r\n0,1.5,2\n0.001,-2.25,3\n0.002,3,4e-3\n"
FORM_VALUES = {"q": [1.5, -2.25, 3.0], "r": [2.0, 3.0, 4e-3]}


def read_form(tmp_path, name, data: bytes, **reader):
    (tmp_path / name).write_bytes(data)
    raw = read(tmp_path, file=name, format="csv", time={"column": "t"},
               channels=[aux("q", "q"), aux("r", "r")], **({"reader": reader} if reader else {}))
    return {k: v.tolist() for k, v in raw.channels.items()}, raw.time.tolist()


def test_latin1_header_needs_reader_encoding(tmp_path):
    # A Windows logger's header "angle [°]" in Latin-1: the degree sign is the single byte 0xb0.
    data = FORM_TEXT.replace("q", "q [\u00b0]", 1).encode("latin-1")
    (tmp_path / "w.csv").write_bytes(data)
    err = input_error(tmp_path, file="w.csv", format="csv", time={"column": "t"},
                      channels=[aux("q", "q [\u00b0]")])
    assert (err.row, err.row_label) == (1, "line")
    assert "not a UTF-8 text file (byte 0xb0" in str(err) and "reader.encoding" in str(err)
    assert "latin-1" in str(err) and "\n" not in str(err)
    raw = read(tmp_path, file="w.csv", format="csv", time={"column": "t"},
               reader={"encoding": "latin-1"}, channels=[aux("q", "q [\u00b0]")])
    assert raw.channels["q"].tolist() == FORM_VALUES["q"] and raw.columns["q"] == "q [\u00b0]"


def test_utf8_with_byte_order_mark_and_utf16_hint(tmp_path):
    values, _ = read_form(tmp_path, "bom.csv", b"\xef\xbb\xbf" + FORM_TEXT.encode())
    assert values == FORM_VALUES
    (tmp_path / "u16.csv").write_bytes(FORM_TEXT.encode("utf-16"))
    err = input_error(tmp_path, file="u16.csv", format="csv", channels=[aux("q", "q")])
    assert "reader.encoding: utf-16" in str(err)
    values, _ = read_form(tmp_path, "u16.csv", FORM_TEXT.encode("utf-16"), encoding="utf-16")
    assert values == FORM_VALUES


def test_semicolons_with_decimal_commas_are_read_when_declared(tmp_path):
    text = FORM_TEXT.replace(",", ";").replace(".", ",")
    values, t = read_form(tmp_path, "de.csv", text.encode(), delimiter=";", decimal=",")
    assert values == FORM_VALUES and t == [0.0, 0.001, 0.002]
    # auto finds the semicolons itself; the decimal comma must be declared
    values, _ = read_form(tmp_path, "de.csv", text.encode(), decimal=",")
    assert values == FORM_VALUES


def test_decimal_commas_not_declared_name_reader_decimal(tmp_path):
    text = FORM_TEXT.replace(",", ";").replace(".", ",")
    (tmp_path / "de.csv").write_text(text)
    err = input_error(tmp_path, file="de.csv", format="csv", time={"column": "t"},
                      channels=[aux("q", "q")])
    assert (err.column, err.row) == ("q", 2) and "text '1,5'" in str(err)
    assert "decimal commas: set reader.decimal: ','" in str(err)


def test_semicolons_read_as_commas_name_reader_delimiter(tmp_path):
    (tmp_path / "sc.csv").write_text(FORM_TEXT.replace(",", ";"))
    err = input_error(tmp_path, file="sc.csv", format="csv", reader={"delimiter": ","},
                      channels=[aux("q", "q")])
    assert "column not found" in str(err) and "set reader.delimiter: ';'" in str(err)
    values, _ = read_form(tmp_path, "sc.csv", FORM_TEXT.replace(",", ";").encode())  # auto
    assert values == FORM_VALUES


def test_gzip_files_are_read_transparently(tmp_path):
    import gzip

    values, t = read_form(tmp_path, "z.csv.gz", gzip.compress(FORM_TEXT.encode()))
    assert values == FORM_VALUES and t == [0.0, 0.001, 0.002]
    table = pd.DataFrame({"q": FORM_VALUES["q"]})
    table.to_parquet(tmp_path / "p.parquet", index=False)
    (tmp_path / "p.parquet.gz").write_bytes(gzip.compress((tmp_path / "p.parquet").read_bytes()))
    raw = read(tmp_path, file="p.parquet.gz", format="parquet", channels=[aux("q", "q")])
    assert raw.channels["q"].tolist() == FORM_VALUES["q"]
    scipy.io.savemat(tmp_path / "m.mat", {"q": np.array(FORM_VALUES["q"])})
    (tmp_path / "m.mat.gz").write_bytes(gzip.compress((tmp_path / "m.mat").read_bytes()))
    raw = read(tmp_path, file="m.mat.gz", format="mat", channels=[aux("q", "q")])
    assert raw.channels["q"].tolist() == FORM_VALUES["q"]


def test_truncated_gzip_names_the_file_and_the_fix(tmp_path):
    import gzip

    data = gzip.compress((FORM_TEXT * 50).encode())
    (tmp_path / "cut.csv.gz").write_bytes(data[: len(data) // 2])
    err = input_error(tmp_path, file="cut.csv.gz", format="csv", channels=[aux("q", "q")])
    assert err.file == str(tmp_path / "cut.csv.gz")
    assert "not a complete gzip file" in str(err) and "copy it again" in str(err)


# ----------------------------------------------------------------------------- writers


def test_write_json_converts_numpy_and_non_finite(tmp_path):
    path = tmp_path / "deep" / "dir" / "x.json"
    atomic.write_json({"a": np.float64(1.5), "b": np.arange(3), "c": [math.nan, np.inf], "d": np.int64(7),
                       "e": (1, 2), "f": Path("p")}, path)
    assert atomic.read_json(path) == {"a": 1.5, "b": [0, 1, 2], "c": [None, None], "d": 7, "e": [1, 2], "f": "p"}
    assert path.read_text().startswith('{\n  "a"')
    assert [p.name for p in path.parent.iterdir()] == ["x.json"]  # no temporary file left


def test_atomic_writer_leaves_old_file_on_failure(tmp_path):
    path = tmp_path / "x.json"
    atomic.write_json({"ok": 1}, path)
    with pytest.raises(TypeError):
        atomic.write_json({"bad": object()}, path)
    assert atomic.read_json(path) == {"ok": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]


def test_rewriting_an_output_removes_what_a_killed_writer_left(tmp_path):
    # A SIGKILL mid-write runs no cleanup: its temporary file stays until the output is
    # written again. Temporary files of other outputs are not touched.
    (tmp_path / ".x.json.k3j9.tmp.json").write_text("partial")
    (tmp_path / ".y.json.k3j9.tmp.json").write_text("another output's")
    atomic.write_json({"ok": 1}, tmp_path / "x.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == [".y.json.k3j9.tmp.json", "x.json"]


def test_atomic_outputs_get_the_mode_of_a_plain_open(tmp_path):
    # What a plain open() / mkdir gives under this process's umask, not mkstemp's 0600.
    mask = os.umask(0o027)
    try:
        atomic._umask.cache_clear()
        atomic.write_json({"ok": 1}, tmp_path / "x.json")
        with atomic.atomic_folder(tmp_path / "staged") as folder:
            (folder / "a.txt").write_text("a")
        (tmp_path / "plain.json").write_text("{}")  # a plain open()
        (tmp_path / "plain_dir").mkdir()
    finally:
        os.umask(mask)
        atomic._umask.cache_clear()
    assert stat.S_IMODE((tmp_path / "x.json").stat().st_mode) == 0o640
    assert stat.S_IMODE((tmp_path / "plain.json").stat().st_mode) == 0o640
    assert stat.S_IMODE((tmp_path / "staged").stat().st_mode) == 0o750
    assert stat.S_IMODE((tmp_path / "plain_dir").stat().st_mode) == 0o750


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_write_and_read_table(tmp_path, suffix):
    df = pd.DataFrame({"a": [1, 2, 3], "b": [0.5, 1.5, 2.5]})
    atomic.write_table(df, tmp_path / f"t{suffix}")
    pd.testing.assert_frame_equal(atomic.read_table(tmp_path / f"t{suffix}"), df)


def test_write_table_rejects_unknown_suffix(tmp_path):
    with pytest.raises(ValueError, match="csv or .parquet"):
        atomic.write_table(pd.DataFrame({"a": [1]}), tmp_path / "t.xlsx")


def test_canonical_round_trip_keeps_dtypes_and_metadata(tmp_path):
    df = pd.DataFrame({"t": np.arange(3) / 10.0, "theta": np.array([1, 2, 3], dtype=np.int64)})
    meta = {"log_id": "x", "fs_hz": 10.0, "channels": [{"name": "theta", "step": 1e-3}], "jitter": math.nan}
    canonical.write_canonical(df, meta, tmp_path / "c.parquet")
    back, back_meta = canonical.read_canonical(tmp_path / "c.parquet")
    pd.testing.assert_frame_equal(back, df)
    assert back_meta == {**meta, "jitter": None}
    assert json.loads(pq.read_schema(tmp_path / "c.parquet").metadata[b"enclab"]) == back_meta


def test_read_canonical_without_metadata(tmp_path):
    atomic.write_parquet(pd.DataFrame({"t": [0.0]}), tmp_path / "p.parquet")
    with pytest.raises(EnclabInputError, match="without enclab metadata"):
        canonical.read_canonical(tmp_path / "p.parquet")


def test_save_figure_writes_png_and_closes(tmp_path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    atomic.save_figure(fig, tmp_path / "f" / "a.png", dpi=50)
    assert (tmp_path / "f" / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not plt.fignum_exists(fig.number)


def test_save_figure_pdf_is_reproducible(tmp_path):
    def save(name):
        fig, ax = plt.subplots()
        ax.plot([0, 1], [1, 0])
        atomic.save_figure(fig, tmp_path / name)
        return (tmp_path / name).read_bytes()

    assert save("a.pdf") == save("b.pdf")


def test_write_text_and_file_sha256(tmp_path):
    atomic.write_text("abc", tmp_path / "a.txt")
    assert readers.file_sha256(tmp_path / "a.txt") == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
