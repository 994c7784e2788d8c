"""Finding and loading OTB ground truth and result files for evaluation.

Ground truth
    An OTB-layout root holds one folder per sequence with a
    ``groundtruth*.txt`` file (``groundtruth_rect.txt``). A folder with
    several non-empty files (``groundtruth_rect.1.txt``, ``.2.txt``: Jogging,
    Skating2) gives one sequence per file, named ``Jogging.1``,
    ``Jogging.2`` in sorted file order; empty files are skipped (Human4's
    ``groundtruth_rect.1.txt``). This is got10k's ``datasets.OTB`` naming.
    Folders already split that way (``../shared/otb/Jogging.1/``) keep
    their own name. Frame sub-ranges (David 300-770, ...) are not applied:
    the ground-truth file defines the frames, and results must have one row
    per ground-truth row.
Results
    An sptpt-annotate output folder is read from its track store
    (``tracks.npz``, full precision, never its exports); any other tracker's
    results from one OTB result file per sequence, 1-based ``x,y,w,h`` rows.
    Where to find it is decided by a *locator*, a function ``(folder, name)
    -> candidate paths`` tried in order; :func:`default_result_candidates`
    accepts ``<folder>/<Name>.txt`` (got10k and pysot layout), a per-sequence
    output folder ``<folder>/<Name>/`` holding a track store (what batch
    writes), or ``<folder>/<Name>/`` holding one of
    :data:`OUTPUT_FOLDER_RESULT_NAMES`. Pass another locator
    to adapt.
Partial runs
    A track store knows which source frames it holds (a run made with
    ``--start``/``--stop``/``--step``, or cut short): exactly those frames
    are scored, against the ground-truth rows of the same index, and
    :attr:`SequencePair.note` says so. An OTB file has no such record and
    must have one row per ground-truth row.

Every error names the file (and line, via :class:`~annotator.otb_format.OTBFormatError`)
or the missing path, and says how to fix it.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from annotator.evaluation.metrics import (
    DatasetScore,
    EvaluationError,
    MissingInputError,
    SequenceScore,
    evaluate_sequence,
)
from annotator.flagging import keyframe_rows
from annotator.otb_format import OTBFormatError, read_otb_boxes
from annotator.text_input import TEXT_ENCODINGS, read_text
from annotator.track_store import STORE_NAME, StoreError, read_store
from annotator.tracks import TrackResult
from annotator.wording import ordinal, plural

__all__ = [
    "OUTPUT_FOLDER_RESULT_NAMES",
    "ResultLocator",
    "SequencePair",
    "default_result_candidates",
    "discover_otb_sequences",
    "find_result_file",
    "load_sequence_pair",
    "load_dataset_pairs",
    "evaluate_result_file",
    "evaluate_results_dir",
]

#: File names tried inside a per-sequence output folder, in order; ``{name}`` is the sequence name.
OUTPUT_FOLDER_RESULT_NAMES: tuple[str, ...] = ("{name}.txt",)

#: ``(folder, sequence name) -> candidate result paths``, most preferred first.
ResultLocator = Callable[[Path, str], Sequence[Path]]


def default_result_candidates(folder: Path, name: str) -> list[Path]:
    """Candidate result files for sequence ``name`` under a results ``folder``.

    ``<folder>/<name>.txt`` first, then the per-sequence output folder
    ``<folder>/<name>/`` with its track store, then with each of
    :data:`OUTPUT_FOLDER_RESULT_NAMES`.
    """
    folder = Path(folder)
    inside = [folder / name / pattern.format(name=name) for pattern in OUTPUT_FOLDER_RESULT_NAMES]
    return [folder / f"{name}.txt", folder / name / STORE_NAME, *inside]


def _output_folder_candidates(folder: Path, name: str | None) -> list[Path]:
    names = [pattern.format(name=n) for n in (name, folder.name) if n for pattern in OUTPUT_FOLDER_RESULT_NAMES]
    return [folder / n for n in dict.fromkeys(names)]


def find_result_file(path: str | os.PathLike, *, name: str | None = None) -> Path:
    """Resolve a single-sequence result argument: a file, or an output folder holding one.

    Parameters
    ----------
    path : path-like
        An OTB result file, or a per-sequence output folder. In a folder,
        :data:`OUTPUT_FOLDER_RESULT_NAMES` are tried with ``name`` and with
        the folder's own name; failing those, the folder's only ``*.txt``
        file is taken (several are ambiguous and refused).
    name : str, optional
        Sequence name, used to look for ``<name>.txt`` inside a folder.

    Returns
    -------
    Path
        The result file.

    Raises
    ------
    EvaluationError
        The path does not exist, or the folder holds none of the expected files.
    """
    path = Path(path)
    if path.is_file():
        return path
    if not path.exists():
        raise MissingInputError(f"{path}: no such result file or output folder; pass an OTB result file x,y,w,h "
                                "per row")
    if (path / STORE_NAME).is_file():
        return path / STORE_NAME
    candidates = _output_folder_candidates(path, name)
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    texts = sorted(p for p in path.glob("*.txt") if p.is_file() and not p.name.startswith("."))
    if len(texts) == 1:
        return texts[0]
    tried = ", ".join(c.name for c in candidates)
    listing = ", ".join(p.name for p in texts)
    found = f"it holds {len(texts)} .txt files ({listing})" if texts else "it holds no .txt file"
    raise EvaluationError(
        f"{path}: cannot tell which file is the OTB result (looked for {tried}; {found}); pass the file itself"
    )


def _sequence_gt_files(folder: Path) -> list[Path]:
    files = sorted(f for f in folder.glob("groundtruth*.txt") if f.is_file())
    kept = []
    for f in files:
        try:
            text = read_text(f)
        except UnicodeDecodeError:
            raise OTBFormatError(f"{f} is not text ({TEXT_ENCODINGS}): expected one 'x,y,w,h' row per frame "
                                 "(OTB ground truth)") from None
        if text.strip():
            kept.append(f)
        else:
            warnings.warn(f"{f}: empty ground-truth file skipped (as got10k does)", stacklevel=3)
    return kept


def _sequence_name(gt_path: Path) -> str:
    """The name :func:`discover_otb_sequences` would give this ground-truth file."""
    folder = gt_path.resolve().parent
    siblings = [f.resolve() for f in _sequence_gt_files(folder)] if gt_path.is_file() else []
    if len(siblings) > 1 and gt_path.resolve() in siblings:
        return f"{folder.name}.{siblings.index(gt_path.resolve()) + 1}"
    return folder.name


def discover_otb_sequences(root: str | os.PathLike) -> dict[str, Path]:
    """Sequences of an OTB-layout root and their ground-truth files.

    Parameters
    ----------
    root : path-like
        Folder holding ``<Name>/groundtruth*.txt``.

    Returns
    -------
    dict[str, Path]
        Sequence name -> ground-truth file, sorted by name; multi-target
        folders give ``Name.1``, ``Name.2`` (see the module notes).

    Raises
    ------
    EvaluationError
        ``root`` is not a folder or holds no sequence.
    """
    root = Path(root)
    if not root.is_dir():
        raise MissingInputError(f"{root}: not a folder; pass an OTB-layout root holding <Name>/groundtruth_rect.txt")
    sequences: dict[str, Path] = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        files = _sequence_gt_files(folder)
        if len(files) == 1:
            sequences[folder.name] = files[0]
        else:
            for index, f in enumerate(files, start=1):
                sequences[f"{folder.name}.{index}"] = f
    if not sequences:
        raise EvaluationError(
            f"{root}: no sequence found; expected folders <Name>/ holding groundtruth_rect.txt (OTB layout)"
        )
    return dict(sorted(sequences.items()))


@dataclass(frozen=True)
class SequencePair:
    """Result and ground-truth boxes of one sequence, 0-based ``xywh``, with their files."""

    name: str
    pred: np.ndarray
    gt: np.ndarray
    pred_path: Path
    gt_path: Path
    #: Source frames scored (rows of the ground-truth file), when the result says which; None: every row.
    frames: np.ndarray | None = None
    #: Rows of the ground-truth file.
    gt_rows: int = 0
    #: From a track store: the failure probability and the flags of each scored frame (else None).
    p_fail: np.ndarray | None = None
    flagged: np.ndarray | None = None
    #: The track's flags ask for keyframes (it looked lost), so they are not its doubtful frames: ``flagged`` is
    #: then None and the flag metrics leave the sequence out.
    keyframes_asked: bool = False
    #: Frames of the run past the ground truth's last row, left out under ``overlap``.
    beyond_gt: int = 0

    @property
    def note(self) -> str | None:
        """Sentences for the output when only part of the ground truth was scored, or the flags were left out."""
        parts = []
        if self.frames is not None and len(self.frames) != self.gt_rows:
            f = self.frames
            steps = np.unique(np.diff(f))
            step = f", every {ordinal(int(steps[0]))}" if len(steps) == 1 and steps[0] > 1 else ""
            parts.append(f"{self.name}: scored the {len(f)} frames the run processed (source frames "
                         f"{int(f[0])}-{int(f[-1])}{step}) against those rows of the {self.gt_rows}-row ground truth")
        if self.beyond_gt:
            parts.append(f"{self.name}: {plural(self.beyond_gt, 'frame')} of the run past the {self.gt_rows}-row "
                         "ground truth left out (--overlap)")
        if self.keyframes_asked:
            parts.append(f"{self.name}: the track looked lost and its flags ask for keyframes, not for doubtful "
                         "frames: left out of the flag metrics (its p_fail still counts)")
        return "; ".join(parts) or None


def _run_name(path: Path) -> str | None:
    """The video name of a track store with one track (the run's own name for its sequence), else None."""
    try:
        store = read_store(path)
    except StoreError:
        return None  # refused with its reason when the track is read
    return store.video.name if len(store.tracks) == 1 else None


def _store_track(path: Path, name: str) -> tuple[TrackResult, int]:
    """The track of sequence ``name`` in a track store, and the frame count of the store's video."""
    try:
        store = read_store(path)
    except StoreError as exc:
        raise EvaluationError(str(exc)) from None
    ids = [t.track_id for t in store.tracks]
    if len(store.tracks) == 1:
        track = store.tracks[0]
    else:
        suffix = name.rsplit(".", 1)[-1] if "." in name else ""
        if not suffix.isdigit() or int(suffix) not in ids:
            raise EvaluationError(f"{path} holds tracks {ids}: name the sequence <Name>.<track id> (OTB multi-target "
                                  f"naming, e.g. {store.video.name}.{ids[0]}) to pick one")
        track = store.track(int(suffix))
    return track, store.video.frame_count


def load_sequence_pair(
    pred_path: str | os.PathLike,
    gt_path: str | os.PathLike,
    *,
    name: str,
    pred_origin: int = 1,
    gt_origin: int = 1,
    overlap: bool = False,
) -> SequencePair:
    """Read a result file and a ground-truth file and check they have one row per frame each.

    A track store's video must have as many frames as the ground truth has
    rows: another length means another video (or another cut of it), whose
    rows would be scored against the wrong frames. ``overlap=True`` scores the
    run's frames that the ground truth also has instead.

    Raises
    ------
    annotator.otb_format.OTBFormatError
        An unparsable row (the message names the file and line).
    EvaluationError
        The row counts differ (the message names both files).
    """
    pred_path, gt_path = Path(pred_path), Path(gt_path)
    for role, path in (("result", pred_path), ("ground-truth", gt_path)):
        if not path.is_file():
            raise MissingInputError(f"sequence {name!r}: {role} file {path} does not exist")
    gt = read_otb_boxes(gt_path, origin=gt_origin)
    if pred_path.suffix == ".npz":
        track, video_frames = _store_track(pred_path, name)
        if video_frames != len(gt) and not overlap:
            raise EvaluationError(
                f"sequence {name!r}: the run {pred_path} is of a {video_frames}-frame video but the ground truth "
                f"{gt_path} has {len(gt)} rows: evaluate against the ground truth of the same video, or give "
                "--overlap to score the frames both hold")
        keep = track.frame_indices < len(gt)
        pred, frames = track.boxes_xywh[keep], track.frame_indices[keep]
        if len(frames) == 0:
            raise EvaluationError(
                f"sequence {name!r}: {pred_path} holds no frame below {len(gt)}, the ground truth {gt_path}'s row "
                "count: evaluate against the ground truth of the same video")
        p_fail = track.signals.get("p_fail")
        asked = bool(keyframe_rows(track.reasons))
        return SequencePair(name=name, pred=np.array(pred), gt=gt[frames], pred_path=pred_path, gt_path=gt_path,
                            frames=frames, gt_rows=len(gt), p_fail=None if p_fail is None else np.array(p_fail)[keep],
                            flagged=None if asked else np.array(track.flagged)[keep], keyframes_asked=asked,
                            beyond_gt=int((~keep).sum()))
    pred = read_otb_boxes(pred_path, origin=pred_origin)
    if len(pred) != len(gt):
        raise EvaluationError(
            f"sequence {name!r}: {pred_path} has {len(pred)} rows but the ground truth {gt_path} has {len(gt)}; "
            "an OTB result file needs exactly one x,y,w,h row per ground-truth frame, the first frame included"
        )
    return SequencePair(name=name, pred=pred, gt=gt, pred_path=pred_path, gt_path=gt_path, gt_rows=len(gt))


def _select(available: Mapping[str, Path], sequences: Iterable[str] | None, root: Path) -> dict[str, Path]:
    if sequences is None:
        return dict(available)
    wanted = list(dict.fromkeys(sequences))
    unknown = [s for s in wanted if s not in available]
    if unknown:
        raise EvaluationError(
            f"{root}: no ground truth for sequence(s) {', '.join(unknown)}; "
            f"available: {', '.join(available) or 'none'}"
        )
    return {s: available[s] for s in wanted}


def load_dataset_pairs(
    gt_root: str | os.PathLike,
    results_dir: str | os.PathLike,
    *,
    sequences: Iterable[str] | None = None,
    locate: ResultLocator = default_result_candidates,
    overlap: bool = False,
    skipped: list[str] | None = None,
) -> dict[str, SequencePair]:
    """Load every sequence's ground truth and result file.

    Parameters
    ----------
    gt_root : path-like
        OTB-layout root (see :func:`discover_otb_sequences`).
    results_dir : path-like
        Folder with one result per sequence, found by ``locate``.
    sequences : iterable of str, optional
        Evaluate only these sequences, each of which must have a result.
        Default: the sequences of ``gt_root`` that have a result (a batch
        that ran part of the root); ``skipped`` receives the others.
    locate : ResultLocator
        ``(results_dir, name) -> candidate paths``; the first existing file wins.
    overlap : bool
        Score the frames a run and its ground truth both hold, when their lengths differ.
    skipped : list, optional
        Receives the sequences of ``gt_root`` left out for having no result (only without ``sequences``).

    Returns
    -------
    dict[str, SequencePair]
        In sequence-name order.

    Raises
    ------
    EvaluationError
        A missing results folder, no result for any sequence, a sequence
        named in ``sequences`` with no result file (all listed at once, each
        with the path expected), or a row-count mismatch.
    annotator.otb_format.OTBFormatError
        An unparsable row, naming the file and line.
    """
    gt_root, results_dir = Path(gt_root), Path(results_dir)
    selected = _select(discover_otb_sequences(gt_root), sequences, gt_root)
    if not results_dir.is_dir():
        raise MissingInputError(f"{results_dir}: results folder does not exist; pass the folder holding <Name>.txt "
                                "files")
    found: dict[str, Path] = {}
    missing: list[str] = []
    for name in selected:
        candidates = list(locate(results_dir, name))
        hit = next((c for c in candidates if Path(c).is_file()), None)
        if hit is None:
            missing.append(f"{name} (expected {candidates[0] if candidates else results_dir / (name + '.txt')})")
        else:
            found[name] = Path(hit)
    if missing and (sequences is not None or not found):
        raise EvaluationError(
            f"{results_dir}: no result for {len(missing)} of {len(selected)} sequence(s): {'; '.join(missing)}; "
            "add the files, or score only the sequences that have results with --sequences NAME,NAME"
        )
    if skipped is not None:
        skipped.extend(name for name in selected if name not in found)
    return {name: load_sequence_pair(found[name], selected[name], name=name, overlap=overlap) for name in found}


def evaluate_result_file(
    result: str | os.PathLike,
    ground_truth: str | os.PathLike,
    *,
    name: str | None = None,
    pairs: list[tuple[SequencePair, SequenceScore]] | None = None,
    overlap: bool = False,
    **rules,
) -> SequenceScore:
    """Score one result file (or output folder) against one ground-truth file.

    Parameters
    ----------
    result : path-like
        OTB result file, or a per-sequence output folder holding one (see
        :func:`find_result_file`).
    ground_truth : path-like
        OTB ground-truth file (1-based), e.g. ``<root>/David/groundtruth_rect.txt``.
    name : str, optional
        Sequence name; defaults to the run's video name for an output folder of one track, else to the
        ground-truth file's folder name (``Name.2`` for a second ground-truth file, which picks track 2).
    pairs : list, optional
        Receives ``(SequencePair, SequenceScore)`` (for the failure-probability metrics); the pair's
        :attr:`SequencePair.note` says when only part of the ground truth was scored.
    overlap : bool
        Score the frames a run and its ground truth both hold, when their lengths differ.
    **rules
        ``replace_first`` and ``invalid_pred``, as in :func:`~annotator.evaluation.metrics.evaluate_sequence`.

    Returns
    -------
    SequenceScore
        Success and precision curves, their AUC and precision at 20 px, per-frame IoU and centre error.

    Examples
    --------
    >>> from annotator import annotate, evaluate_result_file
    >>> _ = annotate("samples/clip.mp4", (136, 129, 48, 40), out_dir="clip_out", stop=5, formats=("otb",),
    ...              show_progress=False)
    >>> score = evaluate_result_file("clip_out", "samples/clip_groundtruth.txt", overlap=True)
    >>> score.n_frames, 0.0 <= score.auc <= 1.0
    (5, True)
    """
    ground_truth = Path(ground_truth)
    name = name or _sequence_name(ground_truth)
    result_path = find_result_file(result, name=name)
    if result_path.name == STORE_NAME and "." not in name:
        name = _run_name(result_path) or name
    pair = load_sequence_pair(result_path, ground_truth, name=name, overlap=overlap)
    score = evaluate_sequence(pair.pred, pair.gt, name=name, **rules)
    if pairs is not None:
        pairs.append((pair, score))
    return score


def evaluate_results_dir(
    gt_root: str | os.PathLike,
    results_dir: str | os.PathLike,
    *,
    tracker: str | None = None,
    sequences: Iterable[str] | None = None,
    locate: ResultLocator = default_result_candidates,
    pairs: list[tuple[SequencePair, SequenceScore]] | None = None,
    overlap: bool = False,
    skipped: list[str] | None = None,
    **rules,
) -> DatasetScore:
    """Score a folder of results against an OTB-layout root (one tracker).

    Parameters
    ----------
    gt_root : path-like
        OTB-layout root, e.g. ``../shared/otb``.
    results_dir : path-like
        One result per sequence (see :func:`load_dataset_pairs`).
    tracker : str, optional
        Name for plots and tables; defaults to the results folder's name.
    sequences : iterable of str, optional
        Score only these sequences, each of which must have a result; by default those of ``gt_root`` that have
        one (a batch that ran part of the root).
    locate : callable
        ``(results_dir, name) -> candidate paths``; the first existing file wins.
    pairs : list, optional
        Receives ``(SequencePair, SequenceScore)`` of every sequence (:attr:`SequencePair.note`: scored in part).
    overlap : bool
        Score the frames a run and its ground truth both hold, when their lengths differ.
    skipped : list, optional
        Receives the sequences of ``gt_root`` left out for having no result (only without ``sequences``).
    **rules
        ``replace_first`` and ``invalid_pred``, as in :func:`~annotator.evaluation.metrics.evaluate_sequence`.

    Returns
    -------
    DatasetScore
        Per-sequence scores and their means, the dataset's success and precision curves.
    """
    results_dir = Path(results_dir)
    loaded = load_dataset_pairs(gt_root, results_dir, sequences=sequences, locate=locate, overlap=overlap,
                                skipped=skipped)
    scores = {
        name: evaluate_sequence(pair.pred, pair.gt, name=name, **rules)
        for name, pair in loaded.items()
    }
    if pairs is not None:
        pairs.extend((loaded[name], scores[name]) for name in loaded)
    return DatasetScore.from_sequences(tracker or results_dir.resolve().name, scores)
