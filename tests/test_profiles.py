"""The SLURM profile's job groups build a DAG on the embedded default (a dry run, no cluster).

A per-log rule left out of group ``per_log`` while its neighbours are in it makes Snakemake
refuse the whole DAG ("depends on rule(s) ... from outside the group"), which only a real
SLURM run (``make test-slurm``) would otherwise show.
"""
import re
import subprocess

import pytest
import yaml

from workspace import ROOT, SNAKEMAKE

PROFILE = ROOT / "workflow/profiles/slurm/config.yaml"
# Rules of the chunked mode (chunk_size > 0, the default): a process_chunk job is many logs by
# itself and the publish rules are local.
UNGROUPED_PER_LOG = {"process_chunk", "publish_log", "publish_figures"}


def per_log_rules() -> set[str]:
    """Rules with a ``{log_id}`` wildcard in their output, from the rule files."""
    names = set()
    for smk in (ROOT / "workflow/rules").glob("*.smk"):
        for name, body in re.findall(r"^rule (\w+):\n(.*?)(?=^rule |\Z)", smk.read_text(),
                                     flags=re.S | re.M):
            output = re.search(r"^    output:\n(.*?)(?=^    \w+:|\Z)", body, flags=re.S | re.M)
            if output and "{log_id}" in output.group(1):
                names.add(name)
    return names


def test_every_per_log_rule_is_in_the_slurm_group():
    groups = yaml.safe_load(PROFILE.read_text())["groups"]
    rules = per_log_rules()
    assert {"ingest", "residuals", "summary", "lrde_fit"} <= rules  # the parser finds rules
    missing = rules - UNGROUPED_PER_LOG - set(groups)
    assert not missing, f"per-log rules not in the groups of {PROFILE}: {sorted(missing)}"
    assert set(groups) <= rules, f"not per-log rules: {sorted(set(groups) - rules)}"


@pytest.mark.parametrize("extra", [["--config", "chunk_size=0"], []], ids=["per-stage", "chunked"])
def test_slurm_groups_build_the_embedded_default_dag(tmp_path, extra):
    # chunked: process_chunk jobs stay single SLURM jobs, publish_log runs on the submit host
    if not SNAKEMAKE.exists():
        pytest.fail(f"snakemake is not installed next to {SNAKEMAKE.parent}")
    profile = yaml.safe_load(PROFILE.read_text())
    for name in ("config.yaml", "data"):
        (tmp_path / name).symlink_to(ROOT / name)
    groups = [f"{rule}={group}" for rule, group in profile["groups"].items()]
    components = [f"{g}={n}" for g, n in profile["group-components"].items()]
    done = subprocess.run(
        [str(SNAKEMAKE), "--snakefile", str(ROOT / "Snakefile"), "--cores", "1", "--dry-run",
         "--quiet", "rules", "--groups", *groups, "--group-components", *components, *extra],
        cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    # the DAG holds the residual stage, so the group really spans it
    assert re.search(r"^residuals\s+\d+", done.stdout, flags=re.M), done.stdout[-2000:]
