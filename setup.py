"""Build hook: a plain install (``pip install .``) carries the workflow the ``enclab`` command runs.

``enclab residuals FILE`` and ``enclab lrde FILE`` run the Snakemake workflow: the Snakefile,
the rule files, the rule scripts, the schemas, ``config.yaml``, the default profile and the
report templates. Those files live in the repository (the single source, edited there, used
there by ``make run``); the build copies them, with their layout, into the package as
``enclab/_workflow/``, where :func:`enclab.core.resources.workflow_root` finds them with
:mod:`importlib.resources` when the package is not in a checkout. Everything else about the
build is in ``pyproject.toml``.
"""
from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
# Paths relative to the repository root, kept relative under enclab/_workflow/ (the rule files
# name their scripts and captions relative to themselves).
WORKFLOW_FILES = ("Snakefile", "config.yaml", "scripts/*.py", "workflow/rules/*.smk",
                  "workflow/schemas/*.yaml", "workflow/profiles/*/config.yaml",
                  "workflow/report/*.rst", "workflow/report/*.css")
PACKAGED_WORKFLOW = Path("enclab") / "_workflow"


def workflow_files() -> list[Path]:
    """The repository's workflow files, relative to its root, in a stable order."""
    found = sorted({p.relative_to(HERE) for pattern in WORKFLOW_FILES for p in HERE.glob(pattern)
                    if p.is_file()})
    if not any(p.name == "Snakefile" for p in found):
        raise FileNotFoundError(f"no Snakefile in {HERE}: build enclab from its repository")
    return found


class BuildWithWorkflow(build_py):
    """``build_py`` that also copies the workflow files into ``enclab/_workflow/``.

    An editable install needs no copy: the package sits in the checkout, next to its files.
    """

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return
        target = Path(self.build_lib) / PACKAGED_WORKFLOW
        if target.exists():  # a stale copy from an earlier build must not survive
            shutil.rmtree(target)
        for rel in workflow_files():
            dest = target / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(HERE / rel, dest)


setup(cmdclass={"build_py": BuildWithWorkflow})
