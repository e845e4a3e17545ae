"""The residual stage's findings as terms of the low-resolution fit."""
import pytest

from enclab.reference_effects import lrde_reference, references_by_channel


def _block(*effects, explained=True, measured="coarse"):
    return {"measured": measured, "truth": "fine",
            "selection": {"explained": explained, "effects": list(effects)}}


def test_play_and_dead_band_are_one_term_of_the_same_width():
    play = {"name": "backlash", "params": {"w": -0.0002}, "ci": {"w": [-0.00021, -0.00019]}}
    band = {"name": "hysteresis", "params": {"h": 0.0003}, "ci": {"h": [0.00029, 0.00031]}}
    ref = lrde_reference(_block(play, band))
    assert ref["effects"] == ["hysteresis"]
    assert [f["value"] for f in ref["found"]] == pytest.approx([0.0002, 0.0003])
    assert ref["found"][0]["ci"] == pytest.approx([0.00019, 0.00021])
    assert ref["channel"] == "coarse" and ref["explained"]


def test_a_signed_interval_across_zero_starts_at_zero_width():
    play = {"name": "backlash", "params": {"w": 1e-5}, "ci": {"w": [-2e-5, 4e-5]}}
    assert lrde_reference(_block(play))["found"][0]["ci"] == pytest.approx([0.0, 4e-5])


def test_one_missed_count_is_the_jump_term_and_several_are_not():
    one = {"name": "missed_counts", "params": {"t_1": 2.5, "n_1": -1.0}}
    ref = lrde_reference(_block(one))
    assert ref["effects"] == ["count_jump"] and ref["found"][0]["value"] == 2.5
    two = {"name": "missed_counts", "params": {"t_1": 2.5, "n_1": -1.0, "t_2": 3.0, "n_2": 1.0}}
    ref = lrde_reference(_block(two))
    assert ref["effects"] == [] and ref["not_modelled"][0]["residual_effect"] == "missed_counts"
    assert "2 count steps" in ref["not_modelled"][0]["why"]


def test_effects_without_a_term_are_listed_with_the_reason():
    ref = lrde_reference(_block({"name": "latency", "params": {"tau": 1e-3}},
                                {"name": "timestamp_jitter", "params": {"sigma_t": 1e-5}},
                                {"name": "something_new", "params": {}}, explained=False))
    assert ref["effects"] == ["time_jitter"]
    why = {e["residual_effect"]: e["why"] for e in ref["not_modelled"]}
    assert "phase" in why["latency"] and why["something_new"]
    assert not ref["explained"]
    biases = lrde_reference(_block({"name": "slow_drift", "params": {"c1": 1e-4}},
                                   {"name": "latency", "params": {"tau": 1e-3}}))
    assert [e["biases"] for e in biases["not_modelled"]] == [["a_eq", "E_b", "offset_a"], []]


def test_a_clean_channel_adds_nothing():
    ref = lrde_reference(_block())
    assert ref["effects"] == [] and ref["found"] == [] and ref["not_modelled"] == []


def test_blocks_are_keyed_by_measured_channel_and_a_malformed_one_is_named():
    refs = references_by_channel([_block(measured="a"), _block(measured="b")])
    assert sorted(refs) == ["a", "b"]
    with pytest.raises(ValueError, match="no measured channel"):
        references_by_channel([{"selection": {"effects": []}}])
    with pytest.raises(ValueError, match="channel 'c' has no 'selection'"):
        lrde_reference({"measured": "c", "effects": []})
    with pytest.raises(ValueError, match="'w'"):
        lrde_reference(_block({"name": "backlash", "params": {"width": 1.0}}))
