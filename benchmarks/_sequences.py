"""The OTB sequences a benchmark runs on (every one under a root, or the ones named by ``--sequences``), and their
ground truth.

One rule for every benchmark: a name that is not a sequence of the root is
refused (a typo must not shrink a benchmark silently to the sequences that
happen to match).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["SequenceError", "ground_truth_file", "select_sequences"]


class SequenceError(ValueError):
    """``--sequences`` or the OTB root cannot be used; the message says why and what to give instead."""


def select_sequences(root: str | Path, names: str | None) -> list[Path]:
    """The sequence folders (those holding ``groundtruth_rect.txt``) of ``root``.

    ``names`` is a comma-separated list (kept in its order, duplicates dropped),
    or ``None``, ``""`` or ``"all"`` for every sequence in name order. Raises
    :class:`SequenceError` when the root holds no sequence or a name is not one.
    """
    root = Path(root)
    found = {p.name: p for p in sorted(root.iterdir()) if (p / "groundtruth_rect.txt").is_file()} \
        if root.is_dir() else {}
    if not found:
        raise SequenceError(f"--otb {root}: no sequence folders (with groundtruth_rect.txt) there; "
                            "give the folder that holds the OTB sequences, such as ../shared/otb")
    if not names or names == "all":
        return list(found.values())
    wanted = list(dict.fromkeys(n.strip() for n in names.split(",") if n.strip()))
    if not wanted:
        raise SequenceError(f"--sequences {names!r} names no sequence: give comma-separated names such as "
                            f"{','.join(list(found)[:2])}, or 'all'")
    unknown = [n for n in wanted if n not in found]
    if unknown:
        raise SequenceError(f"--sequences: {', '.join(unknown)} {'is' if len(unknown) == 1 else 'are'} not in "
                            f"{root}; choose from {', '.join(found)}")
    return [found[n] for n in wanted]


def ground_truth_file(roots: list[Path], sequence: str) -> Path:
    """The sequence's ``groundtruth_rect.txt`` in the first of ``roots`` that holds it."""
    for root in roots:
        if (root / sequence / "groundtruth_rect.txt").is_file():
            return root / sequence / "groundtruth_rect.txt"
    raise SystemExit(f"no ground truth for {sequence} under {', '.join(map(str, roots))}: give its OTB root with --otb")
