"""The benchmarks are a package: every module imports without running anything, opens with its
question, exposes ``main(argv)``, and is listed in docs/development.md with a command that
parses; no file edits ``sys.path``; the record's commands rerun from the repository root."""
import argparse
import csv
import importlib
import inspect
import json
import os
import pkgutil
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import benchmarks
from benchmarks import helpers

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "workflow" / "benchmarks"
# Modules of the package that are not benchmarks (no question, no table of their own).
TOOLS = {"helpers", "render_benchmarks"}
NAMES = sorted(m.name for m in pkgutil.iter_modules([str(PACKAGE)]))
BENCHMARKS = [name for name in NAMES if name not in TOOLS]
DEVELOPMENT = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
RUN = "PYTHONPATH=workflow python -m benchmarks."


def test_the_package_is_this_checkouts():
    assert Path(benchmarks.__file__).resolve().parent == PACKAGE
    assert len(BENCHMARKS) >= 25


def test_importing_every_module_runs_nothing(tmp_path):
    # A fresh interpreter in an empty directory: no output, no file, no change to the
    # environment or to sys.path.
    # threadpoolctl sets KMP_DUPLICATE_LIB_OK on its own import (a library's doing, not
    # the package's): imported first, so that the check sees only what the modules do.
    code = (
        "import importlib, json, os, sys\n"
        "import threadpoolctl  # noqa: F401\n"
        "env, path = dict(os.environ), list(sys.path)\n"
        f"for name in {NAMES!r}:\n"
        "    importlib.import_module('benchmarks.' + name)\n"
        "print(json.dumps({'env': dict(os.environ) == env, 'path': sys.path == path}))\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / "workflow"), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    # nothing printed but the check's own line (stderr may carry a library's first-use notice)
    assert out.stdout.count("\n") == 1
    assert json.loads(out.stdout) == {"env": True, "path": True}
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", BENCHMARKS)
def test_benchmark_opens_with_its_question_and_has_main(name):
    module = importlib.import_module(f"benchmarks.{name}")
    first = (module.__doc__ or "").splitlines()[0] if module.__doc__ else ""
    assert first.endswith("?"), f"{name}: the docstring's first line is not a question: {first!r}"
    params = list(inspect.signature(module.main).parameters)
    assert params[:1] == ["argv"], f"{name}.main takes {params}"


@pytest.mark.parametrize("name", BENCHMARKS)
def test_benchmark_is_listed_with_its_question_and_command(name):
    module = importlib.import_module(f"benchmarks.{name}")
    question = module.__doc__.splitlines()[0].replace("``", "`")
    assert f"- `{name}`: {question}" in DEVELOPMENT
    assert f"`{RUN}{name}" in DEVELOPMENT


def test_documented_commands_parse(monkeypatch):
    # Each command's arguments are the benchmark's own: main stops right after parsing them.
    class Parsed(Exception):
        pass

    parse = argparse.ArgumentParser.parse_args

    def parse_only(self, args=None, namespace=None):
        raise Parsed(parse(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_only)
    commands = re.findall(rf"`({re.escape(RUN)}\w+[^`]*)`", DEVELOPMENT)
    assert {shlex.split(c)[3].split(".", 1)[1] for c in commands} >= set(BENCHMARKS)
    for text in commands:
        words = shlex.split(text)
        module = importlib.import_module(words[3])
        with pytest.raises(Parsed):
            module.main(words[4:])


def test_no_file_of_the_package_touches_sys_path():
    offenders = [p.name for p in PACKAGE.rglob("*.py") if "sys.path" in p.read_text(encoding="utf-8")]
    assert offenders == []


def test_no_benchmark_uses_a_private_name_of_another_module():
    # ``module._name`` of the library or of another benchmark: only public entry points.
    private = re.compile(r"\b(?!self\b)[a-z_][a-z0-9_]*\._[a-zA-Z][A-Za-z0-9_]*")
    found = {p.name: private.findall(p.read_text(encoding="utf-8"))
             for p in PACKAGE.glob("*.py")}
    assert {k: v for k, v in found.items() if v} == {}


def test_command_is_the_module_form_from_the_repository_root():
    argv = [str(PACKAGE / "bench_lrde.py"), "--draws", "10", "--label", "a b"]
    assert helpers.command(argv) == (
        "PYTHONPATH=workflow python -m benchmarks.bench_lrde --draws 10 --label 'a b'")
    assert helpers.command([str(ROOT / "tools" / "x.py"), "-v"]) == "python tools/x.py -v"


@pytest.mark.parametrize("old, new", [
    ("python workflow/benchmarks/residual_length.py --lengths 4000 --draws 100 --pilots 5",
     "PYTHONPATH=workflow python -m benchmarks.residual_length --lengths 4000 --draws 100 --pilots 5"),
    ("design_check.py", "PYTHONPATH=workflow python -m benchmarks.design_check"),
    ("git clone <this repository> && make run", "git clone <this repository> && make run"),
    ("python workflow/benchmarks/no_such_script.py", "python workflow/benchmarks/no_such_script.py"),
])
def test_rerun_command_rewrites_the_old_form_only(old, new):
    assert helpers.rerun_command(old) == new
    assert helpers.rerun_command(new) == new


# A scratch directory of one machine (the temporary or the work tree).
SCRATCH_PATH = re.compile(r"/(?:tmp|work)/")


def test_recorded_commands_rerun_from_the_repository_root():
    for path in sorted((ROOT / "docs" / "benchmarks").glob("*.csv")):
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
        for row in rows:
            cells = " ".join(v or "" for v in row.values())
            assert not SCRATCH_PATH.search(cells), path.name
            if "command" in row:
                assert helpers.rerun_command(row["command"]) == row["command"], path.name


def test_the_renderer_runs_from_the_repository_root():
    env = dict(os.environ, PYTHONPATH="workflow")
    out = subprocess.run(shlex.split(f"{sys.executable} -m benchmarks.render_benchmarks --check"),
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
