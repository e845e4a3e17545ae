"""Manifest validation and normalisation (pure: the document is already parsed).

The manifest contract is ``workflow/schemas/manifest.schema.yaml``; every key is documented
there. :func:`validate_manifest` checks a parsed document against it (JSON Schema Draft
2020-12), fills the defaults the rest of the package relies on, and runs the checks a schema
cannot express. Reading the YAML file is :func:`enclab.core.readers.read_manifest`'s job.
"""
from __future__ import annotations

import codecs
import copy
import functools
import posixpath
from typing import Any

import jsonschema
import yaml

from enclab.core.errors import EnclabInputError
from enclab.core.resources import workflow_root

__all__ = [
    "READER_KEYS",
    "SCHEMA_PATH",
    "channel_axis",
    "detect_grid_enabled",
    "format_key",
    "load_schema",
    "validate_manifest",
]

# The repository's schema, or the copy a plain install carries (enclab.core.resources).
SCHEMA_PATH = workflow_root() / "workflow" / "schemas" / "manifest.schema.yaml"

# Reader keys that apply to each format (the schema says the others must be left out).
READER_KEYS = {
    "csv": ("delimiter", "decimal", "encoding", "comment", "header", "column_names",
            "skip_trailing_empty"),
    "text": (
        "delimiter",
        "decimal",
        "encoding",
        "comment",
        "header",
        "column_names",
        "values_per_sample",
        "skip_trailing_empty",
    ),
    "parquet": ("skip_trailing_empty",),
    "mat": ("variable", "column_names", "skip_trailing_empty"),
}

_READER_DEFAULTS = {
    "delimiter": "auto",
    "decimal": ".",
    "encoding": "utf-8",
    "comment": None,
    "column_names": None,
    "values_per_sample": None,
    "skip_trailing_empty": True,
    "variable": None,
}

_LOG_DEFAULTS = {
    "description": None,
    "group": None,
    "tags": [],
    "provenance": None,
    "device": None,
    "crop": None,
    "analysis": {},
}

_CHANNEL_DEFAULTS = {
    "joint": None,
    "unit": "rad",
    "axis": None,
    "counts_per_rev": None,
    "gear_ratio": 1,
    "step": None,
    "sign": 1,
    "wrap_bits": None,
    "native_step": None,
    "detect_grid": None,
    "multi_turn": False,
}

_LINEAR_UNITS = ("m", "mm")
_ROTARY_UNITS = ("rad", "deg", "mrad")
_JOINT_ROLES = ("truth", "measured", "command")


@functools.lru_cache(maxsize=1)
def load_schema() -> dict:
    """The manifest JSON schema (parsed once from :data:`SCHEMA_PATH`)."""
    with open(SCHEMA_PATH, encoding="utf-8") as handle:
        return yaml.safe_load(handle)


def format_key(path: Any) -> str | None:
    """Dotted key of a document location, e.g. ``("logs", 3, "unit") -> "logs[3].unit"``."""
    text = ""
    for part in path:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text or None


def channel_axis(channel: dict) -> str:
    """``"rotary"`` or ``"linear"`` for a normalised channel (explicit axis, else from the unit)."""
    if channel.get("axis") is not None:
        return channel["axis"]
    return "linear" if channel["unit"] in _LINEAR_UNITS else "rotary"


def detect_grid_enabled(channel: dict) -> bool:
    """Whether to look for a quantization grid (null means: yes for truth/measured only)."""
    if channel.get("detect_grid") is None:
        return channel["role"] in ("truth", "measured")
    return bool(channel["detect_grid"])


def check_document(doc: Any, schema: dict, source: str, schema_name: str) -> None:
    """Raise :class:`EnclabInputError` naming the dotted key of the first schema violation.

    Used for the configuration before Snakemake's own validation (which fills defaults but
    reports a violation without saying where it is).
    """
    validator = jsonschema.Draft202012Validator(schema)
    error = jsonschema.exceptions.best_match(validator.iter_errors(doc))
    if error is not None:
        raise EnclabInputError(source, error.message, key=format_key(error.absolute_path),
                               hint=f"See {schema_name} for the allowed keys and values.")


def validate_manifest(doc: dict, devices: dict, source: str) -> tuple[str, list[dict]]:
    """Validate a parsed manifest, fill its defaults and check what the schema cannot.

    Parameters
    ----------
    doc : dict
        The parsed manifest document.
    devices : dict
        Device specifications by name (``config["devices"]``); string ``device`` values of the
        manifest must be keys of it.
    source : str
        Name of the manifest file, used in error messages.

    Returns
    -------
    data_root : str
        The ``data_root`` value (default ``"."``), not yet resolved.
    entries : list of dict
        One normalised entry per log (deep copies with every default filled in, including
        ``reader``, ``time.unit`` = ``"s"`` for a time column/file, ``crop`` bounds, channel
        keys and ``analysis``).

    Raises
    ------
    EnclabInputError
        With ``file=source`` and the dotted ``key`` of the first problem found.
    """
    if not isinstance(devices, dict):
        raise ValueError(f"devices must be a dict of device specifications, got {type(devices).__name__}")
    if not isinstance(doc, dict):
        raise EnclabInputError(
            source, f"the manifest is a {type(doc).__name__}", expected="a mapping with a 'logs' list"
        )
    check_document(doc, load_schema(), source, "workflow/schemas/manifest.schema.yaml")
    doc = copy.deepcopy(doc)
    data_root = doc.get("data_root", ".")
    entries = [_normalise_log(log) for log in doc["logs"]]
    _check_semantics(entries, devices, source)
    return data_root, entries


def _normalise_log(log: dict) -> dict:
    entry = {**copy.deepcopy(_LOG_DEFAULTS), **log}
    if entry["crop"] is not None:
        entry["crop"] = {"t_start": None, "t_end": None, **entry["crop"]}
    time = {"nominal_rate_hz": None, **entry["time"]}
    if ("column" in time or "file" in time) and "unit" not in time:
        time["unit"] = "s"
    entry["time"] = time
    reader = dict(entry.get("reader") or {})
    for key in READER_KEYS[entry["format"]]:
        if key == "header":
            reader.setdefault("header", 0 if entry["format"] == "csv" else None)
        else:
            reader.setdefault(key, _READER_DEFAULTS[key])
    entry["reader"] = reader
    entry["channels"] = [{**_CHANNEL_DEFAULTS, **channel} for channel in entry["channels"]]
    return entry


def _check_semantics(entries: list[dict], devices: dict, source: str) -> None:
    def fail(key: str, problem: str, expected: str | None = None, hint: str | None = None):
        raise EnclabInputError(source, problem, key=key, expected=expected, hint=hint)

    seen_ids: dict[str, int] = {}
    for i, entry in enumerate(entries):
        where = f"logs[{i}]"
        if entry["id"] in seen_ids:
            fail(f"{where}.id", f"log id '{entry['id']}' is already used by logs[{seen_ids[entry['id']]}]",
                 expected="a unique id per log")
        seen_ids[entry["id"]] = i
        _check_relative(entry["file"], f"{where}.file", fail)
        if "file" in entry["time"]:
            _check_relative(entry["time"]["file"], f"{where}.time.file", fail)
        device = entry["device"]
        if isinstance(device, str) and device not in devices:
            fail(f"{where}.device", f"unknown device '{device}'",
                 expected=f"one of {sorted(devices)} (config.yaml devices) or an inline {{kind: ...}}")
        crop = entry["crop"]
        if crop and crop["t_start"] is not None and crop["t_end"] is not None \
                and crop["t_start"] >= crop["t_end"]:
            fail(f"{where}.crop", f"t_start {crop['t_start']} is not before t_end {crop['t_end']}",
                 expected="t_start < t_end")
        _check_reader(entry, where, fail)
        _check_channels(entry, where, fail)


def _check_relative(path: str, key: str, fail) -> None:
    normal = posixpath.normpath(path.replace("\\", "/"))
    if posixpath.isabs(normal) or normal == ".." or normal.startswith("../"):
        fail(key, f"path '{path}' leaves data_root", expected="a path relative to data_root inside it")


def _check_reader(entry: dict, where: str, fail) -> None:
    fmt = entry["format"]
    reader = entry["reader"]
    for key in reader:
        if key not in READER_KEYS[fmt]:
            fail(f"{where}.reader.{key}", f"reader key '{key}' does not apply to format '{fmt}'",
                 expected=f"only {list(READER_KEYS[fmt])}")
    if reader.get("column_names") == "last_comment":
        if fmt == "mat":
            fail(f"{where}.reader.column_names", "'last_comment' needs a text file",
                 expected="a list of names for a mat matrix")
        if reader.get("comment") is None:
            fail(f"{where}.reader.column_names", "'last_comment' needs reader.comment",
                 expected="reader.comment set, e.g. '%'")
        if reader.get("header") is not None:
            fail(f"{where}.reader.header", "a header line and column_names 'last_comment' both name "
                 "the columns", expected="header: null with column_names")
    encoding = reader.get("encoding")
    if encoding is not None:
        try:
            codecs.lookup(encoding)
        except LookupError:
            fail(f"{where}.reader.encoding", f"unknown encoding '{encoding}'",
                 expected="a Python codec name such as utf-8, latin-1, cp1252 or utf-16")
    if reader.get("decimal") == "," and reader.get("delimiter") == ",":
        fail(f"{where}.reader.decimal", "a decimal comma in comma-separated fields",
             expected="reader.delimiter ';', '\\t' or whitespace with decimal ','")
    names = reader.get("column_names")
    if isinstance(names, list) and len(set(names)) != len(names):
        fail(f"{where}.reader.column_names", "column names repeat", expected="unique names")
    k = reader.get("values_per_sample")
    if k is not None:
        if reader.get("header") is not None:
            fail(f"{where}.reader.header", "a one-value-per-line file has no header line",
                 expected="header: null with values_per_sample")
        if isinstance(names, list) and len(names) != k:
            fail(f"{where}.reader.column_names", f"{len(names)} names for {k} values per sample",
                 expected=f"{k} names")
    if fmt == "mat" and reader.get("variable") is None:
        for j, channel in enumerate(entry["channels"]):
            if not isinstance(channel["column"], str):
                fail(f"{where}.channels[{j}].column", "a mat channel without reader.variable must name "
                     "its vector variable", expected="a variable name (string)")
        if "column" in entry["time"] and not isinstance(entry["time"]["column"], str):
            fail(f"{where}.time.column", "a mat time column without reader.variable must name a "
                 "variable", expected="a variable name (string)")
    if fmt == "mat" and names is not None and reader.get("variable") is None:
        fail(f"{where}.reader.column_names", "column_names name the columns of reader.variable",
             expected="reader.variable set, or no column_names")


def _check_channels(entry: dict, where: str, fail) -> None:
    names: dict[str, int] = {}
    truth_of_joint: dict[int, int] = {}
    for j, channel in enumerate(entry["channels"]):
        key = f"{where}.channels[{j}]"
        name = channel["name"]
        if name == "t":
            fail(f"{key}.name", "channel name 't' is reserved for the time column", expected="another name")
        if name in names:
            fail(f"{key}.name", f"channel name '{name}' is already used by channels[{names[name]}]",
                 expected="unique channel names")
        names[name] = j
        role = channel["role"]
        if role in _JOINT_ROLES and channel["joint"] is None:
            fail(f"{key}.joint", f"a {role} channel needs a joint", expected="a 1-based joint index")
        if role == "truth":
            joint = channel["joint"]
            if joint in truth_of_joint:
                fail(f"{key}.role", f"joint {joint} already has a truth channel "
                     f"(channels[{truth_of_joint[joint]}])", expected="at most one truth channel per joint",
                     hint="Use role 'measured' for the coarser channel.")
            truth_of_joint[joint] = j
        unit, axis = channel["unit"], channel["axis"]
        if axis == "rotary" and unit in _LINEAR_UNITS:
            fail(f"{key}.axis", f"unit '{unit}' is a length but axis is 'rotary'",
                 expected="axis linear or null")
        if axis == "linear" and unit in _ROTARY_UNITS:
            fail(f"{key}.axis", f"unit '{unit}' is an angle but axis is 'linear'",
                 expected="axis rotary or null")
        if unit == "counts":
            if channel["counts_per_rev"] is not None and channel["step"] is not None:
                fail(f"{key}.step", "both counts_per_rev and step give the resolution",
                     expected="only one of them")
            if channel_axis(channel) == "linear":
                if channel["step"] is None:
                    fail(f"{key}.step", "a linear counts channel needs step",
                         expected="the SI length of one count [m]")
                if channel["counts_per_rev"] is not None:
                    fail(f"{key}.counts_per_rev", "counts_per_rev does not apply to a linear channel",
                         expected="step [m] instead")
            elif channel["counts_per_rev"] is None and channel["step"] is None:
                fail(f"{key}.counts_per_rev", "a counts channel needs counts_per_rev or step",
                     expected="the encoder's counts per (motor) revolution")
            if channel["native_step"] is not None:
                fail(f"{key}.native_step", "native_step is for float channels; counts already have a step",
                     expected="native_step left out")
        else:
            for opt in ("counts_per_rev", "step", "wrap_bits"):
                if channel[opt] is not None:
                    fail(f"{key}.{opt}", f"{opt} applies to counts channels only, unit is '{unit}'",
                         expected="unit: counts, or no " + opt)
        if channel["gear_ratio"] != 1 and channel["counts_per_rev"] is None:
            fail(f"{key}.gear_ratio", "gear_ratio applies only with counts_per_rev",
                 expected="counts_per_rev set, or gear_ratio left out")
