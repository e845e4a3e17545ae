"""Tests for enclab.core.manifest.validate_manifest and enclab.core.readers.read_manifest."""
from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml
from enclab.core import readers
from enclab.core.errors import EnclabInputError
from enclab.core.manifest import SCHEMA_PATH, validate_manifest

DEVICES = {"axis": {"kind": "single_joint"}, "franka_panda": {"kind": "franka_panda"}}
SOURCE = "data/m.yaml"


def log(**overrides) -> dict:
    base = {
        "id": "run1",
        "file": "run1.csv",
        "format": "csv",
        "time": {"column": "t"},
        "channels": [{"name": "theta1", "column": "q", "role": "truth", "joint": 1}],
    }
    base.update(overrides)
    return base


def validate(*logs, **top):
    return validate_manifest({"logs": list(logs), **top}, DEVICES, SOURCE)


def error_of(*logs, **top) -> EnclabInputError:
    with pytest.raises(EnclabInputError) as info:
        validate(*logs, **top)
    assert info.value.file == SOURCE
    return info.value


def test_schema_file_is_found_next_to_the_package():
    assert SCHEMA_PATH.is_file()
    assert SCHEMA_PATH.name == "manifest.schema.yaml"


def test_defaults_are_filled_for_a_minimal_csv_entry():
    data_root, (entry,) = validate(log())
    assert data_root == "."
    assert entry["time"] == {"column": "t", "unit": "s", "nominal_rate_hz": None}
    assert entry["reader"] == {"delimiter": "auto", "decimal": ".", "encoding": "utf-8", "comment": None,
                               "header": 0, "column_names": None, "skip_trailing_empty": True}
    assert entry["analysis"] == {} and entry["tags"] == [] and entry["crop"] is None
    assert entry["device"] is None and entry["group"] is None and entry["description"] is None
    channel = entry["channels"][0]
    assert channel["unit"] == "rad" and channel["sign"] == 1 and channel["gear_ratio"] == 1
    assert channel["wrap_bits"] is None and channel["native_step"] is None and channel["detect_grid"] is None


def test_text_header_defaults_to_none_and_rate_form_gets_no_unit():
    _, (entry,) = validate(log(format="text", time={"rate_hz": 500}))
    assert entry["reader"]["header"] is None
    assert entry["reader"]["values_per_sample"] is None
    assert entry["time"] == {"rate_hz": 500, "nominal_rate_hz": None}


def test_crop_bounds_and_mat_reader_defaults():
    _, (entry,) = validate(log(format="mat", crop={"t_end": 2.0},
                               channels=[{"name": "x", "column": "qm", "role": "truth", "joint": 1, "unit": "m"}]))
    assert entry["crop"] == {"t_start": None, "t_end": 2.0}
    assert entry["reader"] == {"variable": None, "column_names": None, "skip_trailing_empty": True}


def test_input_document_is_not_modified():
    doc = {"logs": [log()]}
    before = copy.deepcopy(doc)
    validate_manifest(doc, DEVICES, SOURCE)
    assert doc == before


def test_named_and_inline_devices_are_accepted():
    _, entries = validate(log(device="axis"), log(id="run2", device={"kind": "planar_2r", "l1": 0.2}))
    assert entries[0]["device"] == "axis"
    assert entries[1]["device"]["kind"] == "planar_2r"


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        ({"channels": [{"name": "a", "column": "q", "role": "truth", "joint": 1, "unit": "furlong"}]},
         "logs[0].channels[0].unit"),
        ({"format": "xlsx"}, "logs[0].format"),
        ({"id": "-bad"}, "logs[0].id"),
        ({"time": {"column": "t", "unit": "samples"}}, "logs[0].time"),
        ({"time": {"column": "t", "rate_hz": 100}}, "logs[0].time"),
        ({"colour": "red"}, "logs[0]"),
    ],
)
def test_schema_errors_name_the_key(overrides, key):
    err = error_of(log(**overrides))
    assert err.key == key
    assert f"key '{key}'" in str(err)


def test_truth_channel_without_joint_is_rejected():
    err = error_of(log(channels=[{"name": "a", "column": "q", "role": "truth"}]))
    assert err.key.startswith("logs[0].channels[0]")
    assert "joint" in str(err)


@pytest.mark.parametrize(
    ("channels", "key", "words"),
    [
        ([{"name": "a", "column": "q", "role": "truth", "joint": 1, "unit": "counts"}],
         "logs[0].channels[0].counts_per_rev", "counts_per_rev or step"),
        ([{"name": "a", "column": "q", "role": "truth", "joint": 1, "unit": "counts", "axis": "linear",
           "counts_per_rev": 100}], "logs[0].channels[0].step", "needs step"),
        ([{"name": "t", "column": "q", "role": "aux"}], "logs[0].channels[0].name", "reserved"),
        ([{"name": "a", "column": "q", "role": "aux"}, {"name": "a", "column": "r", "role": "aux"}],
         "logs[0].channels[1].name", "already used"),
        ([{"name": "a", "column": "q", "role": "truth", "joint": 1},
          {"name": "b", "column": "r", "role": "truth", "joint": 1}], "logs[0].channels[1].role", "truth"),
        ([{"name": "a", "column": "q", "role": "truth", "joint": 1, "wrap_bits": 16}],
         "logs[0].channels[0].wrap_bits", "counts channels only"),
        ([{"name": "a", "column": "q", "role": "truth", "joint": 1, "unit": "mm", "axis": "rotary"}],
         "logs[0].channels[0].axis", "length"),
        ([{"name": "a", "column": "q", "role": "truth", "joint": 1, "unit": "counts", "counts_per_rev": 10,
           "native_step": 0.1}], "logs[0].channels[0].native_step", "float channels"),
        ([{"name": "a", "column": "q", "role": "truth", "joint": 1, "gear_ratio": 35}],
         "logs[0].channels[0].gear_ratio", "counts_per_rev"),
    ],
)
def test_semantic_channel_checks(channels, key, words):
    err = error_of(log(channels=channels))
    assert err.key == key
    assert words in str(err)


def test_duplicate_log_ids_are_rejected():
    err = error_of(log(), log(file="other.csv"))
    assert err.key == "logs[1].id"
    assert "logs[0]" in str(err)


def test_unknown_device_name_lists_the_known_ones():
    err = error_of(log(device="phantom"))
    assert err.key == "logs[0].device"
    assert "'axis'" in str(err) and "franka_panda" in str(err)


@pytest.mark.parametrize("path", ["../outside.csv", "/abs/run.csv", "a/../../b.csv"])
def test_files_must_stay_inside_data_root(path):
    assert error_of(log(file=path)).key == "logs[0].file"


def test_reader_keys_must_apply_to_the_format():
    err = error_of(log(reader={"values_per_sample": 7}))
    assert err.key == "logs[0].reader.values_per_sample"
    err = error_of(log(format="text", reader={"column_names": "last_comment"}))
    assert err.key == "logs[0].reader.column_names" and "reader.comment" in str(err)


def test_crop_must_be_ordered():
    assert error_of(log(crop={"t_start": 2.0, "t_end": 1.0})).key == "logs[0].crop"


def test_mat_vectors_need_variable_names():
    err = error_of(log(format="mat", channels=[{"name": "x", "column": 1, "role": "aux"}]))
    assert err.key == "logs[0].channels[0].column"


def test_devices_must_be_a_dict():
    with pytest.raises(ValueError, match="devices"):
        validate_manifest({"logs": [log()]}, ["axis"], SOURCE)


def test_read_manifest_returns_a_path_and_entries(tmp_path: Path):
    path = tmp_path / "m.yaml"
    path.write_text("data_root: data\nlogs:\n  - {id: a, file: a.csv, format: csv, time: {rate_hz: 10},\n"
                    "     channels: [{name: x, column: 0, role: aux}]}\n")
    data_root, entries = readers.read_manifest(path, DEVICES)
    assert data_root == Path("data")
    assert [e["id"] for e in entries] == ["a"]


def test_read_manifest_missing_file(tmp_path: Path):
    with pytest.raises(EnclabInputError, match="manifest file not found"):
        readers.read_manifest(tmp_path / "none.yaml", DEVICES)


def test_read_manifest_yaml_syntax_error_names_the_line(tmp_path: Path):
    path = tmp_path / "m.yaml"
    path.write_text("logs:\n  - id: a\n    file: [unclosed\n")
    with pytest.raises(EnclabInputError) as info:
        readers.read_manifest(path, DEVICES)
    assert info.value.file == str(path) and info.value.row_label == "line"
    assert info.value.row is not None and 3 <= info.value.row <= 4
    assert "YAML syntax error" in str(info.value)


def test_read_manifest_parses_as_pyyaml_safe_load():
    # read_manifest uses libyaml's parser when PyYAML has it: the same entries as the
    # pure-Python safe_load, checked on the embedded default (72 logs).
    root = Path(__file__).resolve().parents[1]
    path = root / "data/manifest.yaml"
    devices = yaml.safe_load((root / "config.yaml").read_text())["devices"]
    expected = validate_manifest(yaml.safe_load(path.read_text()), devices, str(path))
    data_root, entries = readers.read_manifest(path, devices)
    assert len(entries) == 72 and (str(data_root), entries) == expected


def test_read_manifest_schema_error_names_the_file(tmp_path: Path):
    path = tmp_path / "m.yaml"
    path.write_text("logs: []\n")
    with pytest.raises(EnclabInputError) as info:
        readers.read_manifest(path, DEVICES)
    assert str(info.value).startswith(f"{path}: key 'logs'")


def test_reader_encoding_and_decimal_are_checked():
    err = error_of(log(reader={"encoding": "latin-9x"}))
    assert err.key == "logs[0].reader.encoding" and "unknown encoding" in str(err)
    err = error_of(log(reader={"delimiter": ",", "decimal": ","}))
    assert err.key == "logs[0].reader.decimal"
    _, (entry,) = validate(log(reader={"delimiter": ";", "decimal": ",", "encoding": "cp1252"}))
    assert entry["reader"]["decimal"] == "," and entry["reader"]["encoding"] == "cp1252"
    err = error_of(log(format="parquet", file="x.parquet", reader={"encoding": "latin-1"}))
    assert err.key == "logs[0].reader.encoding" and "does not apply" in str(err)
