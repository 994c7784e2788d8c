"""Which box a frame between two human boxes takes where the forward and backward passes disagree.

Pure logic with exact answers (features, each pass's own p_fail, the choice
wired into the merge, the section's file format and its fit), then the real
re-tracking on a tiny synthetic clip with a model file that holds a section.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from annotator.config import resolve_config
from annotator.failure import SIGNALS, FailureModelError, load_model, score_track
from annotator.failure.fit import fit_pass_choice
from annotator.failure.model import PASS_CHOICE_FEATURES, PassChoice, logit
from annotator.review import ArrayFrames, PassResult, PreviousTrack, merge_passes, retrack_tracks
from annotator.review.merge import PASS_CHOICE, filled_signals, pass_choice_features, pass_p_fail
from sptpt_dev.synthetic import make_clip

K = len(PASS_CHOICE_FEATURES)
FORWARD, BACKWARD, INTERPOLATION = range(3)


def section(intercept=(0.0, 0.0, 0.0), coef=None, *, disagree_below=0.5, max_gap=10) -> PassChoice:
    """A hand-made section on unstandardised features (mean 0, scale 1)."""
    return PassChoice(mean=np.zeros(K), scale=np.ones(K), coef=np.zeros((3, K)) if coef is None else np.asarray(coef),
                      intercept=np.asarray(intercept, dtype=np.float64), disagree_below=disagree_below,
                      max_gap=max_gap, info={"data": "hand-made"})


def a_pass(x, seed: int) -> PassResult:
    """A pass with boxes at ``x`` (10 x 10) and made-up signals."""
    n = len(x)
    rng = np.random.default_rng(seed)
    signals = rng.normal(0.5, 0.3, (n, len(SIGNALS)))
    signals[:, list(SIGNALS).index("bootstrap")] = 0.0
    return PassResult(boxes_xywh=np.array([[xi, 0.0, 10.0, 10.0] for xi in x], dtype=np.float64),
                      confidence=np.linspace(0.9, 0.5, n) if seed % 2 else np.linspace(0.5, 0.9, n),
                      log_likelihood=rng.normal(5, 1, n), accepted=np.ones(n, bool),
                      scoring=np.array(["subspace"] * n, dtype=object), seconds=np.full(n, 0.5), signals=signals)


def model_with(choice: PassChoice | None):
    return dataclasses.replace(load_model(), pass_choice=choice)


# Human boxes at x = 0 (frame 0) and x = 40 (frame 5): the interpolation is x = 8, 16, 24, 32 on frames 1-4.
ENDS = ((0.0, 0.0, 10.0, 10.0), (40.0, 0.0, 10.0, 10.0))
FWD_X, BWD_X = [0, 8, 60, 34], [0, 30, 90, 32]  # agree on frames 1 and 4 (IoU 1 and 2/3), not on 2 and 3


def test_features_of_rows_between_two_human_boxes_are_exact():
    fwd, bwd = a_pass(FWD_X, 1), a_pass(BWD_X, 2)
    p_f, p_b = np.array([0.1, 0.2, 0.3, 0.4]), np.array([0.5, 0.6, 0.7, 0.8])
    features, interpolation = pass_choice_features(p_f, p_b, fwd.boxes_xywh, bwd.boxes_xywh, ENDS)
    np.testing.assert_allclose(interpolation[:, 0], [8, 16, 24, 32])
    column = {name: features[:, k] for k, name in enumerate(PASS_CHOICE_FEATURES)}
    np.testing.assert_allclose(column["logit_p_forward"], np.log(p_f / (1 - p_f)))
    np.testing.assert_allclose(column["logit_p_backward"], np.log(p_b / (1 - p_b)))
    # Box 10 wide, 10 high: shifted by d, IoU = (10 - d) / (10 + d); 0 when d >= 10.
    np.testing.assert_allclose(column["forward_iou_interpolation"], [1 / 9, 1 / 9, 0.0, 2 / 3])
    np.testing.assert_allclose(column["backward_iou_interpolation"], [1 / 9, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(column["pass_iou"], [1.0, 0.0, 0.0, 2 / 3])
    np.testing.assert_allclose(column["position"], [0.2, 0.4, 0.6, 0.8])
    np.testing.assert_allclose(column["edge_distance"], [0.2, 0.4, 0.4, 0.2])


def test_a_pass_is_scored_from_the_human_box_it_started_at_in_the_order_it_ran():
    model = load_model()
    fwd = a_pass([0, 1, 2, 3, 4, 5], 3)
    # The reference: the pass as a track of its own, the human box first.
    rows = np.vstack([np.full((1, len(SIGNALS)), np.nan), fwd.signals])
    keyframe = np.arange(7) == 0
    expected, _ = score_track(filled_signals({n: rows[:, k] for k, n in enumerate(SIGNALS)}), keyframe,
                              np.zeros(7, bool), model)
    np.testing.assert_array_equal(pass_p_fail(fwd, model, backward=False), expected[1:])
    # Backward: the same rows, run from the other end.
    flipped = dataclasses.replace(fwd, signals=fwd.signals[::-1].copy())
    np.testing.assert_array_equal(pass_p_fail(flipped, model, backward=True),
                                  pass_p_fail(fwd, model, backward=False)[::-1])
    assert not np.allclose(pass_p_fail(fwd, model, backward=True), pass_p_fail(fwd, model, backward=False))


def test_without_a_section_chosen_is_anchored_to_the_bit():
    fwd, bwd = a_pass(FWD_X, 1), a_pass(BWD_X, 2)
    anchored = merge_passes(fwd, bwd, "anchored")
    for kwargs in ({}, {"model": model_with(None), "ends": ENDS}, {"model": model_with(section((0, 0, 9)))}):
        chosen = merge_passes(fwd, bwd, "chosen", **kwargs)
        for field in ("boxes_xywh", "confidence", "log_likelihood", "accepted", "scoring", "signals", "pass_iou"):
            np.testing.assert_array_equal(getattr(chosen, field), getattr(anchored, field))
        assert np.isnan(chosen.choice).all()


@pytest.mark.parametrize("method", ["anchored", "confidence", "blend", "handover"])
def test_other_merges_ignore_the_section(method):
    fwd, bwd = a_pass(FWD_X, 1), a_pass(BWD_X, 2)
    plain = merge_passes(fwd, bwd, method)
    with_section = merge_passes(fwd, bwd, method, model=model_with(section((-9.0, -9.0, 9.0))), ends=ENDS)
    for field in ("boxes_xywh", "confidence", "log_likelihood", "accepted", "scoring", "signals", "pass_iou"):
        np.testing.assert_array_equal(getattr(with_section, field), getattr(plain, field))
    assert np.isnan(with_section.choice).all()
    # The same section makes the chosen merge interpolate there: the test would see a leak.
    assert (merge_passes(fwd, bwd, "chosen", model=model_with(section((-9.0, -9.0, 9.0))), ends=ENDS).choice[1:3]
            == INTERPOLATION).all()


@pytest.mark.parametrize("winner", [FORWARD, BACKWARD, INTERPOLATION])
def test_where_the_passes_disagree_the_most_probable_option_is_taken(winner):
    fwd, bwd = a_pass(FWD_X, 1), a_pass(BWD_X, 2)
    intercept = np.full(3, -5.0)
    intercept[winner] = 5.0
    model = model_with(section(intercept))
    merged = merge_passes(fwd, bwd, "chosen", model=model, ends=ENDS)
    anchored = merge_passes(fwd, bwd, "anchored")
    disagree = anchored.pass_iou < 0.5
    assert disagree.tolist() == [False, True, True, False]
    # Rows where they agree are the anchored merge's.
    np.testing.assert_array_equal(merged.boxes_xywh[~disagree], anchored.boxes_xywh[~disagree])
    assert np.isnan(merged.choice[~disagree]).all() and (merged.choice[disagree] == winner).all()
    expected = {FORWARD: [8, 60], BACKWARD: [30, 90], INTERPOLATION: [16, 24]}[winner]
    assert merged.boxes_xywh[disagree, 0].tolist() == expected
    # The other fields come from the pass whose box it took; an interpolated row from the pass that doubts itself
    # less.
    p_f, p_b = pass_p_fail(fwd, model, backward=False), pass_p_fail(bwd, model, backward=True)
    for row in np.flatnonzero(disagree):
        source = {FORWARD: fwd, BACKWARD: bwd}.get(winner, fwd if p_f[row] <= p_b[row] else bwd)
        np.testing.assert_array_equal(merged.signals[row], source.signals[row])
        assert merged.log_likelihood[row] == source.log_likelihood[row]
        assert merged.confidence[row] == source.confidence[row]
    # The passes' IoU is the comparison of the two passes, whichever box was kept.
    np.testing.assert_array_equal(merged.pass_iou, anchored.pass_iou)


def test_interpolation_only_between_human_boxes_at_most_max_gap_apart():
    fwd, bwd = a_pass(FWD_X, 1), a_pass(BWD_X, 2)
    # Interpolation would win, backward is second: with the boxes 5 frames apart and max_gap 4, backward.
    model = model_with(section((-5.0, 1.0, 5.0), max_gap=4))
    merged = merge_passes(fwd, bwd, "chosen", model=model, ends=ENDS)
    assert merged.boxes_xywh[[1, 2], 0].tolist() == [30, 90] and merged.choice[[1, 2]].tolist() == [1, 1]
    merged = merge_passes(fwd, bwd, "chosen", model=model_with(section((-5.0, 1.0, 5.0), max_gap=5)), ends=ENDS)
    assert merged.choice[[1, 2]].tolist() == [2, 2]


def test_the_choice_reads_the_features_through_its_coefficients():
    # Forward is right when its own p_fail is low, backward likewise; the interpolation never.
    coef = np.zeros((3, K))
    coef[FORWARD, PASS_CHOICE_FEATURES.index("logit_p_forward")] = -1.0
    coef[BACKWARD, PASS_CHOICE_FEATURES.index("logit_p_backward")] = -1.0
    choice = section((0.0, 0.0, -50.0), coef)
    features = np.zeros((3, K))
    features[:, 0] = logit(np.array([0.1, 0.8, 0.5]))
    features[:, 1] = logit(np.array([0.3, 0.2, 0.5]))
    assert choice.choose(features, np.ones(3, bool)).tolist() == [FORWARD, BACKWARD, FORWARD]  # ties: forward
    np.testing.assert_allclose(choice.p_right(features)[:, FORWARD], [0.9, 0.2, 0.5])  # sigmoid(-logit p) = 1 - p


def test_the_section_round_trips_through_the_file_and_is_optional(tmp_path):
    model = model_with(section((0.5, -0.5, 1.0), np.arange(3 * K, dtype=float).reshape(3, K) / 10))
    path = tmp_path / "m.json"
    path.write_text(json.dumps(model.to_json()))
    again = load_model(path)
    assert again.to_json() == model.to_json()
    np.testing.assert_array_equal(again.pass_choice.coef, model.pass_choice.coef)
    data = model.to_json()
    data.pop("pass_choice")
    path.write_text(json.dumps(data))
    assert load_model(path).pass_choice is None


@pytest.mark.parametrize("edit, fragment", [
    (lambda s: s.pop("coef"), "pass_choice section lacks or garbles"),
    (lambda s: s.update(features=s["features"][:-1]), "pass_choice section is for features"),
    (lambda s: s.update(options=["forward", "backward"]), "pass_choice section is for features"),
    (lambda s: s.update(coef=s["coef"][:2]), "pass_choice coef must be 3 x 7 finite numbers"),
    (lambda s: s.update(intercept=[0.0, float("nan"), 0.0]), "pass_choice intercept must be 3 finite numbers"),
    (lambda s: s.update(scale=[0.0] * K), "scales must be > 0"),
    (lambda s: s.update(max_gap=True), "max_gap an integer >= 2"),
    (lambda s: s.update(max_gap=1), "max_gap an integer >= 2"),
    (lambda s: s.update(disagree_below=0.0), "disagree_below in (0, 1]"),
    (lambda s: s.update(disagree_below="half"), "garbles"),
])
def test_a_damaged_section_is_refused_in_one_line(tmp_path, edit, fragment):
    data = model_with(section()).to_json()
    edit(data["pass_choice"])
    path = tmp_path / "model.json"
    path.write_text(json.dumps(data))
    with pytest.raises(FailureModelError, match=str(path)) as info:
        load_model(path)
    assert fragment in str(info.value) and "pass_choice.py" in str(info.value) and "\n" not in str(info.value)


def _choice_data(n: int = 3000, seed: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows where forward is right when its p_fail is low, backward likewise, and the interpolation when both
    passes doubt themselves; human boxes 10 or 20 frames apart."""
    rng = np.random.default_rng(seed)
    features = rng.normal(0, 1, (n, K))
    gaps = rng.choice([10, 20], n)
    z_f, z_b = features[:, 0], features[:, 1]
    right = np.stack([rng.uniform(size=n) < 1 / (1 + np.exp(2 * z_f)), rng.uniform(size=n) < 1 / (1 + np.exp(2 * z_b)),
                      rng.uniform(size=n) < 1 / (1 + np.exp(-(z_f + z_b)))], axis=1)
    return features, right, gaps


def test_fitting_the_section_recovers_a_known_choice_and_is_reproducible():
    features, right, gaps = _choice_data()
    first = fit_pass_choice(features, right, gaps, disagree_below=0.5, max_gap=20, info={"data": "fixed"})
    again = fit_pass_choice(features, right, gaps, disagree_below=0.5, max_gap=20, info={"data": "fixed"})
    assert json.dumps(first.to_json()) == json.dumps(again.to_json())
    assert first.coef[FORWARD, 0] < -1 and first.coef[BACKWARD, 1] < -1
    assert first.coef[INTERPOLATION, 0] > 0.5 and first.coef[INTERPOLATION, 1] > 0.5
    picks = first.choose(np.array([[-2, 2] + [0] * (K - 2), [2, -2] + [0] * (K - 2), [2, 2] + [0] * (K - 2)], float),
                         np.ones(3, bool))
    assert picks.tolist() == [FORWARD, BACKWARD, INTERPOLATION]
    # Interpolation rows are fitted only where the boxes are at most max_gap apart: with 10, half the rows.
    only_ten = fit_pass_choice(features, right, gaps, disagree_below=0.5, max_gap=10)
    assert not np.allclose(only_ten.coef[INTERPOLATION], first.coef[INTERPOLATION])
    np.testing.assert_array_equal(only_ten.coef[FORWARD], first.coef[FORWARD])


def test_fitting_refuses_rows_that_cannot_teach_an_option():
    features, right, gaps = _choice_data(200)
    right[:, BACKWARD] = True
    with pytest.raises(ValueError, match="the backward option needs frames where it was right and frames where it "
                                         "was wrong"):
        fit_pass_choice(features, right, gaps, disagree_below=0.5, max_gap=20)
    with pytest.raises(ValueError, match=r"features must be \(n, 7\), right \(n, 3\) and gaps \(n,\)"):
        fit_pass_choice(features[:, :3], right, gaps, disagree_below=0.5, max_gap=20)
    with pytest.raises(ValueError, match=r"gaps \(n,\)"):
        fit_pass_choice(features, right, gaps[:-1], disagree_below=0.5, max_gap=20)
    features[0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        fit_pass_choice(features, _choice_data(200)[1], gaps, disagree_below=0.5, max_gap=20)


# --------------------------------------------------------------------------- re-tracking with a section

CONFIG = resolve_config({"seed": 1, "tracker": {"n_particles": 60, "n_negatives": 20}})
CLIP = make_clip(16, size=(96, 72), object_size=(24, 20))
INDICES = np.arange(16)


@pytest.fixture(scope="module")
def first():
    return retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {0: tuple(CLIP.boxes_xywh[0])}}, CONFIG)


def _corrected(first, config):
    previous = {1: PreviousTrack(first.tracks[0], first.scoring[1])}
    return retrack_tracks(ArrayFrames(CLIP.frames), INDICES, {1: {10: tuple(CLIP.boxes_xywh[10])}}, config,
                          previous=previous, width=96, height=72)


def test_retrack_takes_the_chosen_box_between_two_human_boxes_and_records_the_choice(first, tmp_path):
    shipped = _corrected(first, CONFIG)
    # Every row whose passes are not identical counts as a disagreement, and the interpolation always wins.
    path = tmp_path / "model.json"
    path.write_text(json.dumps(model_with(section((-9, -9, 9), disagree_below=1.0, max_gap=10)).to_json()))
    result = _corrected(first, dataclasses.replace(CONFIG, failure_model=str(path)))
    track, before = result.tracks[0], shipped.tracks[0]
    pass_iou = track.signals["pass_iou"]
    between = np.zeros(16, bool)
    between[1:10] = True
    taken = between & (pass_iou < 1.0)
    assert taken.sum() >= 3  # the synthetic passes differ somewhere: the test has something to check
    t = np.arange(16)[taken] / 10
    expected = (1 - t)[:, None] * CLIP.boxes_xywh[0] + t[:, None] * CLIP.boxes_xywh[10]
    np.testing.assert_allclose(track.boxes_xywh[taken], expected)
    choice = track.signals[PASS_CHOICE]
    assert (choice[taken] == INTERPOLATION).all() and np.isnan(choice[~taken]).all()
    np.testing.assert_array_equal(track.boxes_xywh[~taken], before.boxes_xywh[~taken])
    np.testing.assert_array_equal(pass_iou, before.signals["pass_iou"])  # the same passes were run
    # The same seed and input give the same boxes.
    again = _corrected(first, dataclasses.replace(CONFIG, failure_model=str(path))).tracks[0]
    np.testing.assert_array_equal(again.boxes_xywh, track.boxes_xywh)


def test_retrack_with_the_shipped_model_chooses_only_where_the_passes_disagree(first):
    track = _corrected(first, CONFIG).tracks[0]
    pass_iou = track.signals["pass_iou"]
    model = load_model()
    choice = track.signals.get(PASS_CHOICE, np.full(16, np.nan))
    if model.pass_choice is None:
        assert PASS_CHOICE not in track.signals
    else:
        chosen = ~np.isnan(choice)
        np.testing.assert_array_equal(chosen, np.nan_to_num(pass_iou, nan=1.0) < model.pass_choice.disagree_below)
        assert set(choice[chosen]) <= {0.0, 1.0, 2.0}


def test_the_script_refuses_bad_input_in_one_line(tmp_path):
    from _benchmark_scripts import run_benchmark

    for argv, code, fragment in ((["--every", "1"], 2, "--every intervals of at least 2 frames"),
                                 (["--seeds", "x"], 2, "must be comma-separated integers"),
                                 (["--data", str(tmp_path)], 1, "no data in")):
        done = run_benchmark("pass_choice", "--no-record", *argv)
        assert done.returncode == code, done.stderr
        assert fragment in done.stderr.strip().splitlines()[-1] and "Traceback" not in done.stderr


def test_the_benchmark_chooses_each_videos_frames_with_a_section_fitted_without_that_video():
    from _benchmark_scripts import load_script

    script = load_script("pass_choice")
    rng = np.random.default_rng(2)
    n = 600
    sequence = np.repeat(["A", "B.1", "B.2", "C"], [100, 150, 150, 200])
    features = rng.normal(0, 1, (n, K))
    features[:, PASS_CHOICE_FEATURES.index("pass_iou")] = rng.uniform(0, 0.4, n)  # every row disagrees
    z = features[:, 0]
    # Video A's forward pass is right where the others' is wrong, and the other way round: held out, A is
    # chosen badly, and B and C, whose rows outnumber A's in each other's folds, well.
    forward_right = np.where(sequence == "A", z < 0, z > 0)
    options = np.stack([forward_right, ~forward_right, rng.uniform(size=n) < 0.1], axis=1)
    data = dict(sequence=sequence, seed=np.zeros(n, int), every=np.full(n, 10), features=features,
                anchored=options[:, 0].copy(), options=options, gap=np.full(n, 10))
    right, folds, _ = script.held_out(data, max_gap=10)
    in_a = sequence == "A"
    without_a = script.fit_section(data, ~in_a, 10, {})
    # Every row disagrees and may interpolate: A's rows take the option the section without A picks.
    picks = without_a.choose(features[in_a], np.ones(in_a.sum(), bool))
    np.testing.assert_array_equal(right[in_a], options[in_a][np.arange(in_a.sum()), picks])
    assert right[in_a].mean() < 0.3 < 0.7 < right[~in_a].mean()
    # Jogging.1 and Jogging.2 are one video: B.1 and B.2 are one fold, each with a model file naming it.
    assert folds["B.1"].info == {"held_out": "B.1", "fold": "B"} and folds["A"].info["fold"] == "A"
    np.testing.assert_array_equal(folds["B.1"].coef, folds["B.2"].coef)
    assert not np.allclose(folds["A"].coef, folds["B.1"].coef)


def test_the_benchmark_refuses_rows_scored_by_another_main_model(tmp_path):
    from _benchmark_scripts import load_script

    script = load_script("pass_choice")
    installed = load_model(guided=script.GUIDED)  # the model of the benchmark's runs' kind
    rows = dict(stop=200, feature_names=np.array(PASS_CHOICE_FEATURES), features=np.zeros((2, K)),
                anchored=np.ones(2, bool), options=np.ones((2, 3), bool), gap=np.full(2, 10))
    np.savez(tmp_path / "Seq__s0__m10.npz", main_model=script.main_model_digest(installed), **rows)
    assert len(script.load_data(tmp_path, {"Seq"}, [0], [10], 200)["gap"]) == 2
    # The installed main part with its pass_choice section is the same main part; another threshold is not.
    with_section = dataclasses.replace(installed, pass_choice=section())
    assert script.main_model_digest(with_section) == script.main_model_digest(installed)
    other = dataclasses.replace(installed, threshold=0.5)
    np.savez(tmp_path / "Seq__s0__m10.npz", main_model=script.main_model_digest(other), **rows)
    with pytest.raises(SystemExit, match="another main failure model than the installed one"):
        script.load_data(tmp_path, {"Seq"}, [0], [10], 200)


def test_the_benchmark_builds_a_fold_file_on_the_main_model_fitted_without_that_sequence(tmp_path):
    import argparse

    from _benchmark_scripts import load_script

    script = load_script("pass_choice")
    parser = argparse.ArgumentParser()
    fold = dataclasses.replace(model_with(section()), info={"held_out": "B.1", "fold": "B"}, threshold=0.31)
    (tmp_path / "B.1.json").write_text(json.dumps(fold.to_json()), encoding="utf-8")
    (tmp_path / "B.2.json").write_text(json.dumps(fold.to_json()), encoding="utf-8")  # B.1's, under B.2's name
    main = script.held_out_main(tmp_path, "B.1", parser)
    # The main part only: the fold's own pass_choice section is added by --write.
    assert main.threshold == 0.31 and main.info["held_out"] == "B.1" and main.pass_choice is None
    assert script.held_out_main(tmp_path, "A", parser) is None  # no fold model: the installed one is used
    with pytest.raises(SystemExit):
        script.held_out_main(tmp_path, "B.2", parser)
