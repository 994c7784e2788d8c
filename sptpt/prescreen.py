"""A cheap first look at every candidate, so that SPTPT's full evaluation is spent on the likely few.

Why: most of a frame's time goes to the superpixels, features and sparse codes of candidates that
have no chance of winning. A run's candidates are nearly pure shifts of its last estimate (``robust``
moves the scale by 1% and never rotates), and a template's plain grey levels already say whether it
sits on the object: over 5,124 rounds of ``robust`` on eight ``../shared/otb`` sequences, the
candidate SPTPT scored best was among the third of the candidates most like the object's recent look
in 81% of the rounds (a random third: 33%), and where it was not, the best of that third scored within
0.09 standard deviations of it (a screen on stored rounds, grey as the mean of the channels; the
prescreen uses BT.601 luma; ``benchmarks/HISTORY.md``, "Speed, memory and throughput").
``TrackerParams.prescreen_share``. No preset uses it: with ``robust`` it kept the accuracy on
``../shared/otb``, where it was designed, and lost 0.06 of success AUC on the unseen ``../shared/otb_extra``
(``benchmarks/RESULTS.md``, "The default's speed").

The cue is normalised cross-correlation (NCC) of grey templates: the warped ``T x T`` candidate
against a running mean of the templates of the run's accepted estimates. NCC ignores a change of
brightness or contrast across the whole template, and the running mean (rate :data:`LEARNING_RATE`)
follows a slowly changing object as the positive model does. The templates are those SPTPT warps
anyway, so the prescreen adds two small matrix products a round.
"""

from __future__ import annotations

import math

import numpy as np

from sptpt.gradients import GREY

__all__ = ["AppearanceReference", "LEARNING_RATE", "grey_ncc"]

LEARNING_RATE = 0.1  # weight of each accepted estimate's template in the running mean (screened: HISTORY.md)


_GREY32 = GREY.astype(np.float32)


def _grey_rows(templates: np.ndarray) -> np.ndarray:
    """``(N, T, T, 3)`` uint8 RGB templates -> ``(N, T*T)`` float32 luma rows (float32: half the memory traffic
    of float64, and the prescreen only ranks)."""
    templates = np.asarray(templates)
    return (templates.reshape(-1, 3) @ _GREY32).reshape(len(templates), -1)


def _grey_image(template: np.ndarray) -> np.ndarray:
    """One ``(T, T, 3)`` uint8 template -> its ``(T, T)`` float64 luma (the running mean is kept in float64)."""
    template = np.asarray(template)
    return _grey_rows(template[None])[0].reshape(template.shape[:2]).astype(np.float64)


def grey_ncc(templates: np.ndarray, reference_grey: np.ndarray) -> np.ndarray:
    """NCC in [-1, 1] of each ``(N, T, T, 3)`` uint8 template's luma with a ``(T, T)`` grey reference.

    0 where the template or the reference is flat (no variation to correlate). One matrix product: the
    standardised reference sums to 0, so each template's own mean drops out of the numerator.
    """
    rows = _grey_rows(templates)
    reference = np.asarray(reference_grey, dtype=np.float32).ravel()
    reference = reference - reference.mean()
    reference_norm = np.linalg.norm(reference)
    if reference_norm == 0:
        return np.zeros(len(rows))
    numerator = (rows @ (reference / reference_norm)).astype(np.float64)
    rows64 = rows.astype(np.float64)
    spread = np.sqrt(np.maximum((rows64 * rows64).sum(axis=1) - rows64.sum(axis=1) ** 2 / rows.shape[1], 0.0))
    return np.divide(numerator, spread, out=np.zeros(len(rows)), where=spread > 1e-6 * np.sqrt(rows.shape[1]))


class AppearanceReference:
    """The object's recent look for the prescreen: ``AppearanceReference(first_template)``, then ``most_alike``
    each round and ``learn`` on each accepted estimate's template."""

    def __init__(self, template: np.ndarray) -> None:
        self.grey = _grey_image(template)

    def learn(self, template: np.ndarray) -> None:
        """Blend an accepted estimate's ``(T, T, 3)`` uint8 template into the running mean."""
        self.grey = (1.0 - LEARNING_RATE) * self.grey + LEARNING_RATE * _grey_image(template)

    def most_alike(self, templates: np.ndarray, share: float) -> np.ndarray:
        """Indices, ascending, of the ``ceil(share * N)`` templates most like the reference (exact ties: the
        earlier)."""
        # rounded first: a third of 150 is 50.000000000000007 in floating point, and must keep 50
        keep = min(len(templates), max(1, math.ceil(round(share * len(templates), 9))))
        order = np.argsort(-grey_ncc(templates, self.grey), kind="stable")
        return np.sort(order[:keep])
