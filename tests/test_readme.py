"""The README's commands, run as written on the project's sample: the re-track example must improve it.

Issue #14: the README's correction example once made the sample worse
(success AUC 0.873 -> 0.502). This runs the quick start's labelling command,
the example's ``fixes.csv``, ``retrack`` and ``eval`` exactly as the README
prints them, in a copy of ``samples/``, and checks the figures it quotes.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from annotator.evaluation import evaluate_result_file
from annotator.exports import read_flags_csv

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _command(prefix: str) -> list[str]:
    """The README's indented command line that starts with ``prefix`` (after any ``... &&``)."""
    for line in README.splitlines():
        text = line.strip()
        if "&&" in text:
            text = text.split("&&")[-1].strip()
        if line.startswith("    ") and text.startswith(prefix):
            return shlex.split(text)
    raise AssertionError(f"README has no command starting with {prefix!r}")


def _fixes_csv() -> str:
    lines = README.splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "frame,x,y,w,h,track_id")
    block = []
    for line in lines[start:]:
        if not line.startswith("    "):
            break
        block.append(line.strip())
    return "\n".join(block) + "\n"


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    assert argv[0] == "sptpt-annotate"
    exe = Path(sys.executable).with_name("sptpt-annotate")  # installed with this Python, not the first on PATH
    command = [str(exe)] if exe.exists() else [sys.executable, "-m", "annotator.cli"]
    return subprocess.run([*command, *argv[1:]], cwd=cwd, capture_output=True, text=True, timeout=600,
                          stdin=subprocess.DEVNULL)


@pytest.fixture(scope="module")
def sample(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("readme")
    shutil.copytree(ROOT / "samples", work / "samples", ignore=shutil.ignore_patterns("clip_sptpt"))
    return work


def test_readme_retrack_example_improves_the_sample(sample):
    label = _command("sptpt-annotate samples/clip.mp4 --box 136,129,48,40 --preset robust")
    done = _run(label, sample)
    assert done.returncode == 0, done.stderr
    out = sample / "samples" / "clip_robust"
    truth = sample / "samples" / "clip_groundtruth.txt"
    before = evaluate_result_file(out, truth).auc

    (sample / "fixes.csv").write_text(_fixes_csv())
    done = _run(_command("sptpt-annotate retrack"), sample)
    assert done.returncode == 0, done.stderr
    assert "1 new or changed correction" in done.stdout + done.stderr
    done = _run(_command("sptpt-annotate eval samples/clip_robust samples/clip_groundtruth.txt"), sample)
    assert done.returncode == 0, done.stderr
    after = evaluate_result_file(out, truth).auc

    assert after > before, (before, after)
    quoted = re.search(r"success AUC (\d\.(\d{3,4})) before the correction, (\d\.\d{3,4}) after", README)
    assert quoted, "the README quotes the example's effect"
    digits = len(quoted[2])  # as many decimals as the README quotes (4 where 3 would not show the change)
    assert (float(quoted[1]), float(quoted[3])) == (round(before, digits), round(after, digits))
    assert f"{after:.3f}" in done.stdout


def test_readme_quick_start_scores_and_flags_the_sample_as_it_says(sample):
    done = _run(_command("sptpt-annotate samples/clip.mp4"), sample)
    assert done.returncode == 0, done.stderr
    result = evaluate_result_file(sample / "samples" / "clip_sptpt", sample / "samples" / "clip_groundtruth.txt")
    quoted = re.search(r"follows the sample's object to the end \(success AUC (\d\.\d{3}) ", README)
    assert quoted, "the README quotes the default's figure on the sample"
    # NanoTrack's CNN runs in OpenCV's DNN module, whose arithmetic differs a little between OpenCV releases: the
    # figure was measured on the newest (0.908); the lowest version pyproject allows gives 0.902.
    assert abs(float(quoted[1]) - result.auc) <= 0.01
    table = read_flags_csv(sample / "samples" / "clip_sptpt" / "flags.csv")
    flagged = {int(frame) for frame in table.frame[table.flagged]}
    wrong = {int(k) for k in np.flatnonzero(result.ious < 0.5)}  # the run starts at frame 0: position = frame
    assert wrong <= flagged, "every wrong box of the sample is flagged"
    assert len(flagged) <= 5, "and little else"
    assert f"{len(flagged)} of 100 frame boxes flagged" in done.stdout + done.stderr
    span = re.search(r"on frame (\d+) where the look-alike covers the object, is flagged, in frames (\d+)-(\d+)\.",
                     " ".join(README.split()))
    assert span, "the README says which frames the default flags"
    if abs(float(quoted[1]) - result.auc) < 0.0005:  # the OpenCV the README's figures were measured with
        assert wrong == {int(span[1])}
        assert flagged == set(range(int(span[2]), int(span[3]) + 1))
