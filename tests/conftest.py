"""Shared end-to-end workflow runs and test order.

Quick tests run first and the ``slow`` ones (workflow runs, long Monte Carlo) after them, so
that a broken unit shows within seconds. The standard workspace (tests/workspace.py) runs once
per pytest session in the default mode and once with one job per stage and log; the workflow tests
read these runs (they must not change them).
"""
from __future__ import annotations

import sys

import pytest

from workspace import SNAKEMAKE, run_two_passes, run_workflow, standard_workspace


def pytest_collection_modifyitems(session, config, items):
    # stable: files and tests keep their order within each of the two groups
    items.sort(key=lambda item: item.get_closest_marker("slow") is not None)


def _require_snakemake():
    if not SNAKEMAKE.exists():
        pytest.fail(f"snakemake is not installed next to {sys.executable}")


@pytest.fixture(scope="session")
def default_run(tmp_path_factory):
    """The standard workspace through the two passes of `make run`, default (chunked) mode."""
    _require_snakemake()
    work, params = standard_workspace(tmp_path_factory.mktemp("standard_default"))
    return run_two_passes(work, params)


@pytest.fixture(scope="session")
def per_rule_run(tmp_path_factory):
    """The same with one job per stage and log (chunk_size=0). That mode writes
    derivatives.parquet only for logs with figures: good2's is built too, to compare it."""
    _require_snakemake()
    work, params = standard_workspace(tmp_path_factory.mktemp("standard_per_rule"))
    run = run_two_passes(work, params, "chunk_size=0")
    extra = run_workflow(work, "--config", "chunk_size=0", "batch_scope=completed", "--",
                         "results/good2/derivatives.parquet")
    assert extra.returncode == 0, extra.stderr[-3000:]
    return run
