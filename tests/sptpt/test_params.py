"""Parameters: presets, mapping overrides, validation."""

from __future__ import annotations

import dataclasses

import pytest

from sptpt.params import PRESETS, TrackerParams, UnknownParameterError, get_preset, params_from_mapping


def test_paper_preset_is_the_spec():
    p = get_preset("paper")
    assert (p.template_size, p.n_superpixels, p.compactness, p.n_bins, p.n_atoms) == (32, 30, 20.0, 8, 50)
    assert (p.lasso_lambda, p.n_particles, p.n_negatives, p.update_every) == (0.01, 600, 200, 5)
    assert p.motion_sigma == (10.0, 10.0, 0.015, 0.0, 0.0, 0.0)
    assert (p.ranks, p.forgetting, p.gamma, p.re_mode, p.accept_threshold) == ((40, 5, 40), 0.9, 0.5, "paper", 0.0)
    assert p.negative_every == 1 and p.seeding == "official"


def test_every_field_is_documented():
    import inspect

    source = inspect.getsource(TrackerParams)
    for field in dataclasses.fields(TrackerParams):
        after = source.split(f"    {field.name}:", 1)[1]
        assert '"""' in after.split("\n    ", 2)[1] or '"""' in after.split("\n", 2)[1], field.name


def test_mapping_overrides_and_converts():
    p = params_from_mapping({"n_particles": 300, "motion_sigma": [4, 4, 0.01, 0, 0, 0], "forgetting": 1})
    assert p.n_particles == 300 and p.motion_sigma == (4.0, 4.0, 0.01, 0.0, 0.0, 0.0) and p.forgetting == 1.0
    assert isinstance(p.forgetting, float)


def test_unknown_key_names_the_closest_valid_one():
    with pytest.raises(UnknownParameterError, match="did you mean 'n_particles'"):
        params_from_mapping({"n_particle": 10})


@pytest.mark.parametrize(
    "mapping, message",
    [
        ({"n_particles": 0}, "n_particles=0"),
        ({"n_particles": 2.5}, "expected an integer"),
        ({"forgetting": 1.5}, r"\(0, 1\]"),
        ({"re_mode": "x"}, "re_mode"),
        ({"motion_sigma": [1, 2]}, "list of 6"),
        ({"seeding": "grid"}, "official"),
        ({"run_choice": "best"}, r"run_choice='best' is invalid: expected 'confidence' or 'contrast' or 'consensus'"),
        ({"run_choice": 1}, "expected a str"),
    ],
)
def test_invalid_values_are_rejected_with_the_name(mapping, message):
    with pytest.raises(ValueError, match=message):
        params_from_mapping(mapping)


def test_unknown_preset_lists_the_valid_ones():
    with pytest.raises(ValueError, match="paper"):
        get_preset("slow")


def test_presets_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        PRESETS["paper"].n_particles = 1


def test_fast_preset_differs_from_paper_only_in_cost_parameters():
    paper, fast = get_preset("paper"), get_preset("fast")
    changed = {f.name for f in dataclasses.fields(TrackerParams) if getattr(paper, f.name) != getattr(fast, f.name)}
    assert changed <= {"n_particles", "refine_particles", "n_negatives", "negative_every"}
    assert fast.n_particles + fast.refine_particles < paper.n_particles
