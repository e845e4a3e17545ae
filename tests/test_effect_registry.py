"""The two effect registries: every effect is one class with its parameters, signature,
counterpart and a test against a brute-force simulation; nothing else lists them.

The simulation tests themselves live beside their analysis (each class's ``test`` names its
own); this file only checks, by reading the test files, that each one exists and exercises its
effect, so it stays fast however many effects there are.
"""
from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest
import yaml

from enclab.lrde import effects as lrde_effects
from enclab.residuals import effects as residual_effects

ROOT = Path(__file__).resolve().parents[1]
RESIDUAL = sorted(residual_effects.REGISTRY.values(), key=lambda c: c.name)
LRDE = sorted(lrde_effects.REGISTRY.values(), key=lambda e: e.name)


def _test_functions(path: Path) -> dict:
    """Test functions of a test file by name: their source with their decorators (a
    parametrization names what they exercise)."""
    lines = path.read_text().splitlines()
    return {node.name: "\n".join(lines[min([d.lineno for d in node.decorator_list]
                                             + [node.lineno]) - 1:node.end_lineno])
            for node in ast.parse("\n".join(lines)).body
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test_")}


def _named_test(test: str) -> str:
    path, _, name = test.partition("::")
    assert path.startswith("tests/") and name, f"{test!r} is not 'tests/<file>.py::<test>'"
    functions = _test_functions(ROOT / path)
    assert name in functions, f"{test!r}: no such test"
    return functions[name]


@pytest.mark.parametrize("cls", RESIDUAL, ids=lambda c: c.name)
def test_every_residual_effect_is_described_in_its_class_and_names_its_simulation_test(cls):
    assert cls.__doc__ and "Signature" in inspect.getdoc(cls), "the docstring names the signature"
    effect = cls()
    assert len(effect.param_names) == len(set(effect.param_names))
    assert effect.kind in ("shift", "noise", "discrete")
    source = _named_test(cls.test)
    # the named test simulates (a log, or the effect's definition by brute force) with this
    # effect, named or by its class
    assert cls.name in source or cls.__name__ in source, f"{cls.test} does not use {cls.name}"


@pytest.mark.parametrize("term", LRDE, ids=lambda e: e.name)
def test_every_lrde_effect_is_described_in_its_class_and_names_its_simulation_test(term):
    assert type(term).__doc__ and "Signature" in inspect.getdoc(type(term))
    assert term.signature
    source = _named_test(term.test)
    assert "simulate_counts" in source and term.name in source
    if term.sampled:
        lo, hi = term.bounds(10.0, 1e-3)
        assert lo < hi and term.si_scale(1e-3, 1e-3) > 0
        assert lo <= term.start <= hi


def test_counterparts_are_declared_on_both_sides_and_agree():
    for cls in RESIDUAL:
        if cls.counterpart is None:
            assert cls.lrde_no_term, cls.name
            continue
        term = lrde_effects.effect(cls.counterpart)
        assert cls.name in term.counterparts, (cls.name, term.name)
    for term in LRDE:
        for name in term.counterparts:
            assert residual_effects.REGISTRY[name].counterpart == term.name, (term.name, name)


def test_the_config_schema_enum_is_the_lrde_registry():
    schema = yaml.safe_load((ROOT / "workflow/schemas/config.schema.yaml").read_text())
    effects = schema["properties"]["lrde"]["properties"]["effects"]
    assert effects["items"]["enum"] == list(lrde_effects.EFFECTS)
    assert effects["default"] == list(lrde_effects.EFFECTS)


def test_every_candidate_is_registered_under_its_name():
    assert set(residual_effects.EFFECTS) <= set(residual_effects.REGISTRY.values())
    assert all(residual_effects.REGISTRY[c.name] is c for c in residual_effects.EFFECTS)
    assert lrde_effects.EFFECTS == tuple(lrde_effects.REGISTRY)
    with pytest.raises(ValueError, match="unknown effect 'nope'"):
        lrde_effects.effect("nope")
