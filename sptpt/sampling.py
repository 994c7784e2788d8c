"""Particle proposals around the current estimate: candidates and negatives.

Randomness is injected: every function takes a ``numpy.random.Generator``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["draw_candidates", "draw_negatives"]


def draw_candidates(
    state: np.ndarray, n: int, sigma: np.ndarray, rng: np.random.Generator, *, min_scale: float
) -> np.ndarray:
    """Gaussian random walk around ``state`` (paper eqs. 8-10; TPT ``DrawSample``).

    Parameters
    ----------
    state : (6,) ndarray
        Current affine state.
    n : int
        Number of candidates.
    sigma : (6,) ndarray
        Standard deviation per state parameter.
    rng : numpy.random.Generator
    min_scale : float
        Lower bound on scale and aspect, so that no candidate collapses to an
        empty box (not in TPT; a safety clamp that never binds in practice).

    Returns
    -------
    states : (n, 6) float64 ndarray
        No resampling and no carried weights, as in TPT.
    """
    states = state[None, :] + sigma[None, :] * rng.standard_normal((n, 6))
    states[:, 2] = np.maximum(states[:, 2], min_scale)
    states[:, 4] = np.maximum(states[:, 4], min_scale)
    return states


def draw_negatives(state: np.ndarray, n: int, template_size: int, rng: np.random.Generator) -> np.ndarray:
    """Negative samples around the estimate (TPT ``DrawNegative``).

    See ``docs/design/tracker.md``, "Candidates and negative samples".

    Centres are drawn with a standard deviation of the target's width and
    height, then pushed out to at least a quarter of the width in x *and* a
    quarter of the height in y, so that every negative overlaps the estimate
    by an IoU of at most about 0.39. All other parameters equal the estimate's.

    Returns
    -------
    states : (n, 6) float64 ndarray
    """
    cx, cy = state[0], state[1]
    sigma_x = round(template_size * state[2])
    sigma_y = round(template_size * state[2] * state[4])
    states = np.repeat(state[None, :], n, axis=0)
    states[:, 0] = _push_out(cx + sigma_x * rng.standard_normal(n), cx, round(sigma_x / 4))
    states[:, 1] = _push_out(cy + sigma_y * rng.standard_normal(n), cy, round(sigma_y / 4))
    return states


def _push_out(values: np.ndarray, centre: float, margin: float) -> np.ndarray:
    values = values.copy()
    values[(values >= centre) & (values <= centre + margin)] = centre + margin
    values[(values >= centre - margin) & (values < centre)] = centre - margin
    return values
