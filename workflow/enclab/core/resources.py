"""Where the workflow's own files are: the checkout's, or the copy a plain install carries.

The ``enclab`` command and the manifest validator need files that are not Python modules: the
Snakefile, the rule files and their scripts, the schemas, ``config.yaml``, the default profile
and the report templates. The repository holds them (``make run`` uses them in place). A plain
install (``pip install .``) gets a copy of them, with the same layout, as the package data
``enclab/_workflow/`` (``setup.py`` copies them at build time); :func:`workflow_root` finds
either with :mod:`importlib.resources`.
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["PACKAGED_WORKFLOW", "workflow_root"]

# The folder of the package that holds the workflow files in a plain install.
PACKAGED_WORKFLOW = "_workflow"


def workflow_root() -> Path:
    """The folder that holds ``Snakefile``, ``config.yaml``, ``workflow/`` and ``scripts/``.

    Returns
    -------
    Path
        The repository's root when the package is imported from a checkout (an editable
        install, or ``PYTHONPATH=workflow``: the package is ``<root>/workflow/enclab``), so that
        an edit there is what runs; otherwise the package's ``_workflow`` folder (it may be
        missing if the package was installed without its data: callers check for the file
        they need and say so).
    """
    package = Path(str(resources.files("enclab")))
    checkout = package.resolve().parents[1]
    if (checkout / "Snakefile").is_file() and checkout / "workflow" / "enclab" == package.resolve():
        return checkout
    return package / PACKAGED_WORKFLOW
