"""The two effect registries: every effect is one class with its parameters, signature and
counterpart; nothing else lists them.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from enclab.lrde import effects as lrde_effects
from enclab.residuals import effects as residual_effects

ROOT = Path(__file__).resolve().parents[1]
RESIDUAL = sorted(residual_effects.REGISTRY.values(), key=lambda c: c.name)
LRDE = sorted(lrde_effects.REGISTRY.values(), key=lambda e: e.name)


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
