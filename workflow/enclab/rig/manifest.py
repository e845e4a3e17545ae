"""Which logs of a manifest form a rig, and the rig's settings.

A log joins a rig with a ``rig`` key in its manifest entry::

    rig:
      name: mrdlab_tool4                       # the rig: results/rigs/<name>/
      conditions: {frequency_hz: 0.1, load_pct: 10}
      measured: [theta_cui]                    # default: every measured channel with a truth pair
      compliance: {torque_back: [linear, signed_square], torque_front: [linear]}
      splits:
        - {name: frequency, by: frequency_hz, train: [0.1, 0.3, 0.5], test: [0.2, 0.4]}
        - {name: load, by: load_pct}           # leave one load out
        - {name: runs, leave_one_run_out: true}

Every key but ``conditions`` must be the same in every run of the rig (a YAML anchor keeps the
manifest short). Imported by the workflow on every DAG build: numpy-free, no I/O.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

__all__ = ["rig_groups", "SHARED_KEYS"]

#: Keys of a log's ``rig`` block that every run of the rig must share.
SHARED_KEYS = ("measured", "truth", "compliance", "splits")


def _pairs(entry: Mapping) -> list[dict]:
    chans = entry["channels"]
    truths = {c.get("joint"): c["name"] for c in chans if c.get("role") == "truth"}
    return [{"measured": c["name"], "truth": truths[c.get("joint")]}
            for c in chans if c.get("role") == "measured" and c.get("joint") in truths]


def rig_groups(entries: Sequence[Mapping]) -> dict:
    """``{rig name: {"runs": [{"log_id", "conditions"}], "pairs": [{"measured", "truth"}],
    "compliance", "splits"}}`` of the manifest entries that carry a ``rig`` key.

    Raises
    ------
    ValueError
        Naming the log and the key: a rig with fewer than 2 runs, runs that disagree on a
        shared key, a channel that is not in the log, a split on a condition a run lacks.
    """
    rigs: dict = {}
    for entry in entries:
        block = entry.get("rig")
        if not block:
            continue
        log_id = entry["id"]
        name = block["name"]
        chans = {c["name"]: c for c in entry["channels"]}
        pairs = _pairs(entry)
        if block.get("measured"):
            want = list(block["measured"])
            pairs = [p for p in pairs if p["measured"] in want]
            missing = sorted(set(want) - {p["measured"] for p in pairs})
            if missing:
                raise ValueError(f"log {log_id!r}, key rig.measured: {missing} is not a measured channel "
                                 f"with a truth channel on the same joint")
        if block.get("truth"):
            pairs = [{**p, "truth": block["truth"]} for p in pairs]
        if not pairs:
            raise ValueError(f"log {log_id!r}, key rig: no measured channel with a truth channel to fit")
        for channel in (block.get("compliance") or {}):
            if channel not in chans:
                raise ValueError(f"log {log_id!r}, key rig.compliance: no channel {channel!r} in the log; "
                                 f"channels {sorted(chans)}")
        shared = {k: block.get(k) for k in SHARED_KEYS}
        run = {"log_id": log_id, "conditions": dict(block.get("conditions") or {})}
        if name not in rigs:
            rigs[name] = {"runs": [run], "pairs": pairs, "compliance": dict(block.get("compliance") or {}),
                          "splits": list(block.get("splits") or []), "_shared": shared, "_first": log_id}
            continue
        rig = rigs[name]
        for key in SHARED_KEYS:
            if shared[key] != rig["_shared"][key]:
                raise ValueError(f"log {log_id!r}, key rig.{key}: differs from log {rig['_first']!r} of "
                                 f"rig {name!r} (every run of a rig shares it)")
        rig["runs"].append(run)
    for name, rig in rigs.items():
        if len(rig["runs"]) < 2:
            raise ValueError(f"log {rig['_first']!r}, key rig.name: rig {name!r} has one run; a rig "
                             "needs at least 2 (shared effects are proven on held-out runs)")
        for split in rig["splits"]:
            by = split.get("by")
            if by is None:
                continue
            for run in rig["runs"]:
                if by not in run["conditions"]:
                    raise ValueError(f"log {run['log_id']!r}, key rig.conditions: no {by!r}, which "
                                     f"split {split.get('name', by)!r} of rig {name!r} needs")
        del rig["_shared"], rig["_first"]
    return rigs
