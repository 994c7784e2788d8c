"""The dictionary's k-means, on its own: numpy and scikit-learn, nothing of the tracker.

Kept apart from :mod:`sptpt.coding` (which imports numba) so that a process that only clusters can import it
cheaply: the tool runs it in a short-lived child process (``annotator.kmeans_child``), which keeps scikit-learn
and the parts of scipy it loads (about 90 MiB resident) out of the tracking process. The child calls this very
function, so its centroids are the in-process ones to the bit.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: ``kmeans(features, n_clusters, n_init, seed) -> centroids``: the k-means a tracker learns its dictionary with
#: (``Tracker(kmeans=...)``). ``features`` is (M, B) float64, ``centroids`` (n_clusters, B) float64; it must equal
#: :func:`kmeans_centroids` to the bit, or the boxes change.
KMeansFunction = Callable[[np.ndarray, int, int, int], np.ndarray]


def kmeans_centroids(features: np.ndarray, n_clusters: int, n_init: int, seed: int) -> np.ndarray:
    """k-means++ seeding then batch Lloyd iterations (TPT ``fkmeans``), the best inertia of ``n_init`` kept.

    What a tracker learns each run's dictionary with, by default in its own process (``Tracker(kmeans=...)``). The
    tracker calls it with BLAS on one thread; a process that calls it for a tracker holds the same limit.

    Parameters
    ----------
    features : (M, B) ndarray of float64
        The training vectors, one per row.
    n_clusters : int
        The number of centroids, at most the number of distinct rows.
    n_init : int
        k-means++ restarts; the best inertia is kept.
    seed : int
        The k-means seed (``random_state``).

    Returns
    -------
    centroids : (n_clusters, B) float64 ndarray
        One centroid per row, not normalised.
    """
    from sklearn.cluster import KMeans  # heavy import (scikit-learn and scipy), needed once per dictionary

    kmeans = KMeans(n_clusters=n_clusters, init="k-means++", n_init=n_init, random_state=seed)
    return kmeans.fit(features).cluster_centers_.astype(np.float64, copy=False)
