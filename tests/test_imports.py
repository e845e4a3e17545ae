"""The package's import graph: no cycles, a core that imports no analysis, analyses that do not
import each other (each answers its own question from the core) except where one builds on
another (:data:`BUILDS_ON`, itself without a cycle).
"""
from __future__ import annotations

import ast
from pathlib import Path

import enclab

ROOT = Path(enclab.__file__).resolve().parent
ANALYSES = ("propagation", "lrde", "residuals", "rig", "design")
# analysis -> the analyses it may import. The rig fit builds on the residual effects (the play
# operator, the motion sign, the calibration and compliance bases);
# design builds on the quantization-error models (filters, Table II, the exact model,
# kinematics). Neither is imported back.
BUILDS_ON = {"rig": {"residuals"}, "design": {"propagation"}}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in ROOT.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            deps.update(t for t in targets if t in modules and t != name)
        graph[name] = deps
    return graph


def _cycle(graph):
    state, stack = {}, []

    def visit(node):
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                return stack[stack.index(dep):] + [dep]
            if dep not in state and (found := visit(dep)):
                return found
        state[node] = 2
        stack.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def _package_deps(graph, package):
    """Imports of package ``enclab.<package>``'s modules (not counting the package's
    ``__init__``, which names its submodules)."""
    prefix = f"enclab.{package}"
    return {(m, d) for m, deps in graph.items() if m == prefix or m.startswith(prefix + ".")
            for d in deps if not (d == prefix or d.startswith(prefix + "."))}


def test_no_import_cycle():
    assert _cycle(_graph()) is None, f"import cycle: {' -> '.join(_cycle(_graph()))}"


def test_core_imports_no_analysis():
    outside = {(m, d) for m, d in _package_deps(_graph(), "core")
               if d != "enclab" and not d.startswith("enclab.core")}
    assert not outside, f"enclab.core imports outside the core: {sorted(outside)}"


def test_analyses_do_not_import_each_other():
    graph = _graph()
    for package in ANALYSES:
        allowed = BUILDS_ON.get(package, set())
        others = {(m, d) for m, d in _package_deps(graph, package)
                  if any(d == f"enclab.{o}" or d.startswith(f"enclab.{o}.") for o in ANALYSES
                         if o != package and o not in allowed)}
        assert not others, f"enclab.{package} imports another analysis: {sorted(others)}"


def test_analyses_build_on_each_other_without_a_cycle():
    layers = {package: set(BUILDS_ON.get(package, ())) for package in ANALYSES}
    assert _cycle(layers) is None, f"analyses build on each other in a cycle: {_cycle(layers)}"


def test_graph_sees_the_packages():
    graph = _graph()
    for package in ("core", *ANALYSES):
        assert any(m.startswith(f"enclab.{package}.") for m in graph), package
    assert "enclab.core.readers" in graph["enclab.core.ingest"]
