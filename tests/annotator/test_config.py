"""Run configuration: defaults < config file < command-line values, and errors that name the closest key."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
import yaml
from _paths import ROOT

from annotator.config import DEFAULT_PRESET, ConfigError, RunConfig, load_config_file, resolve_config
from annotator.flagging import FlagParams
from sptpt.boxes import iou_xywh
from sptpt.params import get_preset
from sptpt.tracker import Tracker
from sptpt_dev.synthetic import make_clip

PRESETS_PAGE = ROOT / "docs" / "presets.md"


def write_yaml(tmp_path, text: str, name: str = "run.yaml"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_defaults():
    config = resolve_config()
    assert config == RunConfig(preset="fused", tracker=get_preset("fused"), flags=FlagParams(), seed=0)


PRECEDENCE = [
    # file values, command-line keywords, expected (seed, n_particles, merge_gap)
    ({}, {}, (0, get_preset(DEFAULT_PRESET).n_particles, FlagParams().merge_gap)),
    ({"seed": 5, "tracker": {"n_particles": 80}, "flags": {"merge_gap": 2}}, {}, (5, 80, 2)),
    ({"seed": 5}, {"seed": 7}, (7, get_preset(DEFAULT_PRESET).n_particles, FlagParams().merge_gap)),
    ({"seed": 5}, {"seed": 0}, (0, get_preset(DEFAULT_PRESET).n_particles, FlagParams().merge_gap)),  # 0 is a value too
    ({"tracker": {"n_particles": 80}}, {"tracker_overrides": {"n_particles": 90}}, (0, 90, FlagParams().merge_gap)),
    ({"flags": {"merge_gap": 2}}, {"flag_overrides": {"merge_gap": 4}}, (0, get_preset(DEFAULT_PRESET).n_particles, 4)),
]


@pytest.mark.parametrize("file_values, flags, expected", PRECEDENCE)
def test_precedence_defaults_file_flags(file_values, flags, expected):
    config = resolve_config(file_values, **flags)
    assert (config.seed, config.tracker.n_particles, config.flags.merge_gap) == expected


def test_file_values_are_read_from_yaml(tmp_path):
    path = write_yaml(tmp_path, "preset: paper\nseed: 3\ntracker:\n  n_particles: 60\n"
                                "  motion_sigma: [4, 4, 0.01, 0, 0, 0]\n"
                                "flags:\n  threshold: 0.25\n  min_span: 2\n")
    config = resolve_config(load_config_file(path), source=str(path), seed=None)
    assert config.seed == 3 and config.preset == "paper"
    assert config.tracker.n_particles == 60 and config.tracker.motion_sigma == (4.0, 4.0, 0.01, 0.0, 0.0, 0.0)
    assert config.flags.threshold == 0.25 and config.flags.min_span == 2
    # Everything not named keeps its default.
    assert (config.tracker.n_negatives == get_preset("paper").n_negatives
            and config.flags.merge_gap == FlagParams().merge_gap)


def test_flag_threshold_and_budget_default_to_none_and_take_numbers():
    assert resolve_config().flags.threshold is None and resolve_config().flags.review_budget is None
    both = resolve_config({"flags": {"threshold": 0.4, "review_budget": 5}})
    assert both.flags.threshold == 0.4 and both.flags.review_budget == 5.0


def test_keyframe_request_settings_take_numbers_and_null_turns_it_off():
    assert resolve_config().flags.lost_threshold == 0.6 and resolve_config().flags.keyframe_every == 10
    off = resolve_config({"flags": {"lost_threshold": None, "keyframe_every": 5}})
    assert off.flags.lost_threshold is None and off.flags.keyframe_every == 5
    again = resolve_config(yaml.safe_load(yaml.safe_dump(off.to_dict())))
    assert again == off


def test_recorded_config_reproduces_the_run():
    """run.json records ``RunConfig.to_dict()``; fed back as a config file it gives the same configuration."""
    config = resolve_config({"seed": 9, "tracker": {"n_particles": 70, "ranks": [10, 4, 10]},
                             "flags": {"threshold": 0.3}})
    again = resolve_config(yaml.safe_load(yaml.safe_dump(config.to_dict())))
    assert again == config


UNKNOWN_KEYS = [
    # YAML text, words the one-line message must hold
    ("sed: 3\n", ["unknown top-level key 'sed'", "did you mean 'seed'?"]),
    ("trackr:\n  n_particles: 5\n", ["'trackr'", "did you mean 'tracker'?"]),
    ("tracker:\n  n_particle: 5\n", ["unknown tracker parameter 'n_particle'", "did you mean 'n_particles'?"]),
    ("flags:\n  merge_gapp: 2\n", ["unknown flag parameter 'merge_gapp'", "did you mean 'merge_gap'?"]),
    ("zzzz: 1\n", ["unknown top-level key 'zzzz'", "valid keys: preset, seed, tracker, flags"]),
]


@pytest.mark.parametrize("text, needles", UNKNOWN_KEYS)
def test_unknown_key_names_the_closest_valid_key(tmp_path, text, needles):
    path = write_yaml(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        resolve_config(load_config_file(path), source=str(path))
    message = str(caught.value)
    assert "\n" not in message and message.startswith(str(path))
    for needle in needles:
        assert needle in message


BAD_VALUES = [
    ({"seed": -1}, "seed must be a non-negative integer"),
    ({"seed": "abc"}, "seed must be a non-negative integer"),
    ({"seed": 1.5}, "seed must be a non-negative integer"),
    ({"seed": True}, "seed must be a non-negative integer"),
    ({"preset": "turbo"}, "unknown preset 'turbo'"),
    ({"tracker": [1, 2]}, "'tracker' must be a mapping"),
    ({"flags": "strict"}, "'flags' must be a mapping"),
    ({"tracker": {"n_particles": "many"}}, "n_particles='many' is invalid"),
    ({"tracker": {"n_particles": 0}}, "n_particles=0 is invalid"),
    ({"tracker": {"reported_translation_filter": "sometimes"}},
     "reported_translation_filter='sometimes' is invalid: expected a bool"),
    ({"tracker": {"ranks": [40, 30, 40]}}, "ranks=(40, 30, 40) is invalid: the superpixel rank 30 exceeds"),
    ({"flags": {"threshold": 1.5}}, "threshold=1.5 is invalid"),
    ({"flags": {"review_budget": 0}}, "review_budget=0.0 is invalid: expected a percentage in (0, 100]"),
    ({"flags": {"merge_gap": 1.5}}, "merge_gap=1.5 is invalid: expected an integer"),
    ({"flags": {"min_span": "3"}}, "min_span='3' is invalid"),
    ({"flags": {"min_span": True}}, "min_span=True is invalid"),
    ({"flags": {"merge_gap": None}}, "merge_gap=None is invalid: expected an integer"),
    ({"flags": {"lost_threshold": 1.5}}, "lost_threshold=1.5 is invalid: expected a probability in (0, 1), or null"),
    ({"flags": {"keyframe_every": 1}}, "keyframe_every=1 is invalid: expected an integer >= 2"),
]


@pytest.mark.parametrize("values, needle", BAD_VALUES)
def test_bad_values_name_source_key_and_value(values, needle):
    with pytest.raises(ConfigError) as caught:
        resolve_config(values, source="my.yaml")
    message = str(caught.value)
    assert message.startswith("my.yaml: ") and needle in message and "\n" not in message
    assert "my.yaml: my.yaml" not in message


@pytest.mark.parametrize(
    "text, needle",
    [
        ("seed: [1, 2\n", "is not valid YAML"),
        ("- a\n- b\n", "must hold a mapping"),
        ("just a string\n", "must hold a mapping"),
    ],
)
def test_bad_files(tmp_path, text, needle):
    path = write_yaml(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        load_config_file(path)
    assert str(path) in str(caught.value) and needle in str(caught.value)


def test_invalid_yaml_names_the_line(tmp_path):
    path = write_yaml(tmp_path, "seed: 1\ntracker:\n  n_particles: [1, 2\n")
    with pytest.raises(ConfigError, match=rf"{path.name}:\d+ is not valid YAML"):
        load_config_file(path)


def test_missing_file_and_empty_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config_file(tmp_path / "nope.yaml")
    assert load_config_file(write_yaml(tmp_path, "# nothing here\n")) == {}


def test_run_config_is_frozen():
    config = resolve_config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.seed = 3  # type: ignore[misc]


def test_a_config_saved_as_utf16_reads_as_utf8(tmp_path):
    text = "preset: fast\nseed: 7\nflags:\n  threshold: 0.4\n"
    (tmp_path / "a.yaml").write_text(text, encoding="utf-8")
    (tmp_path / "b.yaml").write_bytes(text.replace("\n", "\r\n").encode("utf-16"))
    assert load_config_file(tmp_path / "b.yaml") == load_config_file(tmp_path / "a.yaml") != {}


def test_a_binary_file_is_not_a_config(tmp_path):
    path = tmp_path / "clip.mp4"
    path.write_bytes(b"\x00\xff\xfe\x9c" * 50)
    with pytest.raises(ConfigError, match=r"clip.mp4 is not text \(UTF-8, or UTF-16 with a byte-order mark\): give a "
                                          r"YAML file"):
        load_config_file(path)


def _yaml_blocks(page: str) -> list[str]:
    return re.findall(r"^```yaml\n(.*?)^```$", page, flags=re.S | re.M)


def test_the_config_examples_of_the_presets_page_are_valid_configs():
    blocks = _yaml_blocks(PRESETS_PAGE.read_text(encoding="utf-8"))
    assert len(blocks) >= 2  # the config file's example and "Going faster"
    for block in blocks:
        resolve_config(yaml.safe_load(block), source="docs/presets.md")


def _going_faster() -> str:
    """The YAML block of the presets page's "Going faster": the one whose comments name robust's values."""
    return next(block for block in _yaml_blocks(PRESETS_PAGE.read_text(encoding="utf-8")) if "(robust:" in block)


def test_going_faster_compares_with_robusts_own_values():
    """Each line of the faster config names robust's value for that key (``# ... (robust: VALUE)``, or ``(robust:
    VALUE, what it means)``): they must be robust's, and the config must change each of them."""
    faster = _going_faster()
    tracker = resolve_config(yaml.safe_load(faster)).tracker
    robust = get_preset("robust")
    commented = re.findall(r"^\s+(\w+): (\S+)\s+#.*\(robust: ([^)]+)\)$", faster, flags=re.M)
    assert {key for key, _, _ in commented} == set(yaml.safe_load(faster)["tracker"])
    for key, value, said in commented:
        assert getattr(tracker, key) == yaml.safe_load(value) != getattr(robust, key)
        assert yaml.safe_load(said.split(",")[0]) == getattr(robust, key), key


def test_the_going_faster_config_follows_the_object():
    """What a user who copies the page's config gets: all its switches at once in one tracker, on two synthetic clips.

    Not "as well as robust": on these clips it follows less well (HISTORY.md, 2026-12-04), as the page says. A box
    that never moves scores 0.12 on each; a tracker the switches broke would score about that, this config 0.37."""
    faster = resolve_config(yaml.safe_load(_going_faster())).tracker
    overlaps, stills = [], []
    for clip in (make_clip(20, seed=3), make_clip(20, seed=5)):
        tracker = Tracker(faster, seed=9)
        boxes = [tracker.init(clip.frames[0], clip.boxes_xywh[0]).box_xywh]
        boxes += [tracker.update(frame).box_xywh for frame in clip.frames[1:]]
        overlaps.append(iou_xywh(np.array(boxes), clip.boxes_xywh).mean())
        stills.append(iou_xywh(np.repeat(clip.boxes_xywh[:1], len(clip.boxes_xywh), axis=0), clip.boxes_xywh).mean())
    assert np.mean(overlaps) >= np.mean(stills) + 0.1, (np.round(overlaps, 2), np.round(stills, 2))
