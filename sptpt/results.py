"""What the tracker returns for one frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FrameResult", "checked_box", "checked_particles", "confidence_from_log_likelihood"]


def confidence_from_log_likelihood(log_likelihood: float, *, scale: float) -> float:
    """Map the log-likelihood ``RE- - RE+`` to a confidence in [0, 1].

    A logistic squashing centred on the paper's acceptance threshold (0):
    a frame the model would refuse to learn from gets confidence <= 0.5.
    ``scale`` is the log-likelihood difference that moves the confidence
    from 0.5 to about 0.73; it sets how quickly confidence saturates.
    """
    if not np.isfinite(log_likelihood):
        return 0.0
    return float(1.0 / (1.0 + np.exp(-log_likelihood / scale)))


def checked_box(box_xywh, owner: str = "") -> np.ndarray:
    """One box ``(x, y, w, h)`` as a (4,) float64 array.

    Parameters
    ----------
    box_xywh : array-like
        Four numbers.
    owner : str
        What the box belongs to, the start of the error message (``"OverlayItem: "``).

    Returns
    -------
    numpy.ndarray
        The box, (4,) float64.

    Raises
    ------
    ValueError
        ``box_xywh`` is not four numbers.
    """
    box = np.asarray(box_xywh, dtype=np.float64)
    if box.shape != (4,):
        raise ValueError(f"{owner}box_xywh must have shape (4,), got {box.shape}")
    return box


def checked_particles(particles_xywh, particle_scores, owner: str = "") -> tuple[np.ndarray | None, np.ndarray | None]:
    """Candidate boxes ``(N, 4)`` and their scores ``(N,)`` as float64 arrays, or both None.

    Parameters
    ----------
    particles_xywh : array-like or None
        ``(N, 4)`` boxes.
    particle_scores : array-like or None
        ``(N,)`` scores, one per box.
    owner : str
        What they belong to, the start of the error message (``"OverlayItem: "``).

    Returns
    -------
    tuple of numpy.ndarray or None
        ``(boxes, scores)`` as float64 arrays, or ``(None, None)``.

    Raises
    ------
    ValueError
        Only one is given, or their shapes do not pair up.
    """
    if (particles_xywh is None) != (particle_scores is None):
        raise ValueError(f"{owner}particles_xywh and particle_scores come together or not at all")
    if particles_xywh is None:
        return None, None
    particles = np.asarray(particles_xywh, dtype=np.float64)
    scores = np.asarray(particle_scores, dtype=np.float64)
    if particles.ndim != 2 or particles.shape[1] != 4 or scores.shape != (particles.shape[0],):
        raise ValueError(f"{owner}particles_xywh must be (N, 4) and particle_scores (N,), "
                         f"got {particles.shape} and {scores.shape}")
    return particles, scores


@dataclass(frozen=True)
class FrameResult:
    """The tracker's estimate for one frame.

    Attributes
    ----------
    box_xywh : (4,) float64 ndarray
        Estimated box, 0-based pixels, ``x, y, w, h`` (top-left corner and size).
    log_likelihood : float
        ``RE- - RE+`` of the winning candidate (paper eq. 11); during the first
        frames, before both subspace models exist, the bootstrap intersection
        score with the first-frame code tensor (see ``scoring``).
    confidence : float
        In [0, 1], a monotone function of ``log_likelihood``; 0.5 is the
        acceptance threshold.
    accepted : bool
        Whether the frame's winning tensor joined the positive model
        (``log_likelihood > Phi``).
    scoring : str
        ``"init"`` for the first frame, ``"bootstrap"`` before both subspace
        models exist, ``"subspace"`` afterwards.
    particles_xywh : (N, 4) float64 ndarray or None
        Boxes of all candidates scored in full (with a shortlist, only its candidates), 0-based ``xywh``; only
        when asked for.
    particle_scores : (N,) float64 ndarray or None
        Log-likelihood of each candidate; only when asked for.
    superpixel_labels : (h, w) int32 ndarray or None
        The winning candidate's superpixel labels mapped back to the frame,
        covering the frame window whose top-left pixel is
        ``superpixel_origin_xy``; -1 where the window is outside the candidate.
        Only when asked for.
    superpixel_origin_xy : (2,) int64 ndarray or None
        0-based frame column and row of ``superpixel_labels[0, 0]``.
    run_boxes_xywh : (R, 4) float64 ndarray or None
        With ``independent_runs`` R > 1: every run's box this frame, in run
        order (``box_xywh`` is one of them, or with ``run_choice="consensus"``
        the mean of those that agree, with ``filter_vote`` perhaps with the
        correlation-filter tracker's box, which is not listed here). Where the
        runs disagree, one has likely lost the target. None for a single run.
    guide_box_xywh : (4,) float64 ndarray or None
        With a ``guide`` (a learned tracker, :class:`sptpt.tracker.Guide`): its own box this frame, all NaN where it
        has none. None without a guide.
    guide_score : float
        The guide's own score of its box (NaN without a guide).
    """

    box_xywh: np.ndarray
    log_likelihood: float
    confidence: float
    accepted: bool
    scoring: str
    particles_xywh: np.ndarray | None = None
    particle_scores: np.ndarray | None = None
    superpixel_labels: np.ndarray | None = None
    superpixel_origin_xy: np.ndarray | None = None
    run_boxes_xywh: np.ndarray | None = None
    guide_box_xywh: np.ndarray | None = None
    guide_score: float = float("nan")

    def __post_init__(self) -> None:
        object.__setattr__(self, "box_xywh", checked_box(self.box_xywh))
        if not 0.0 <= self.confidence <= 1.0:
            raise ValueError(f"confidence must lie in [0, 1], got {self.confidence}")
        if self.scoring not in ("init", "bootstrap", "subspace"):
            raise ValueError(f"scoring must be 'init', 'bootstrap' or 'subspace', got {self.scoring!r}")
        particles, scores = checked_particles(self.particles_xywh, self.particle_scores)
        object.__setattr__(self, "particles_xywh", particles)
        object.__setattr__(self, "particle_scores", scores)
        if (self.superpixel_labels is None) != (self.superpixel_origin_xy is None):
            raise ValueError("superpixel_labels and superpixel_origin_xy come together or not at all")
        if self.run_boxes_xywh is not None:
            runs = np.asarray(self.run_boxes_xywh, dtype=np.float64)
            if runs.ndim != 2 or runs.shape[1] != 4 or len(runs) < 2:
                raise ValueError(f"run_boxes_xywh must be (R, 4) with R >= 2, got {runs.shape}")
            object.__setattr__(self, "run_boxes_xywh", runs)
        if self.guide_box_xywh is not None:
            object.__setattr__(self, "guide_box_xywh", checked_box(self.guide_box_xywh, "guide_"))
