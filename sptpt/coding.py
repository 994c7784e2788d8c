"""Dictionary learning and exact non-negative sparse coding.

The dictionary is the set of k-means++ centroids of the first frame's
superpixel features, L2-normalised (TPT ``fkmeans``). Every superpixel
feature ``a`` is then coded by

    h* = argmin_{h >= 0}  0.5 ||a - D h||_2^2 + lam ||h||_1,

SPAMS ``mexLasso`` with ``mode = 2``, ``pos = true`` (TPT ``l1_opt``), which
is also the converged ``sklearn.decomposition.sparse_encode(A, D.T,
algorithm='lasso_cd', alpha=lam, positive=True)`` (sklearn divides alpha by
B, so the objectives agree). Not ``algorithm='lasso_lars'``: sklearn
documents that positive LARS may stop before the solution for small alpha,
and on histogram features it leaves KKT residuals of about 1e-2 on half of
the signals. The solver here is exact (active set), because the
subspace scores are differences of small reconstruction errors and are
sensitive to code noise; :func:`kkt_residual` certifies it. See
``docs/design/tracker.md``, "Dictionary" and "Non-negative sparse codes".
"""

from __future__ import annotations

import numbers

import numba
import numpy as np

from sptpt._kernels.lasso import nonnegative_lasso
from sptpt._kmeans import KMeansFunction, kmeans_centroids
from sptpt._validation import positive_int as _positive_int

__all__ = ["learn_dictionary", "encode_nonnegative", "encode_tensors", "kkt_residual"]

# Stopping tolerance of the active set on the gradient D^T (a - D h) - lam,
# relative to the signal's largest |D^T a| (or lam): far below the 1e-6 KKT residual
# the tests ask for, yet above the rounding of the gradient itself.
_REL_TOL = 1e-10
# Ridge added to every passive-set factorisation, relative to the largest
# squared atom norm. It keeps the Cholesky factor finite when atoms are
# duplicated or linearly dependent and perturbs the gradient by ridge * h,
# about 1e-12 for unit atoms.
_REL_RIDGE = 1e-12
# Active-set solves per signal before falling back to coordinate descent.
# Lawson-Hanson needs about one solve per support element plus one per
# removal; this cap is only a guard against rounding-induced cycling.
_ITER_PER_ATOM = 4
_ITER_EXTRA = 20
# Coordinate-descent sweeps of the fallback (each O(z^2)); reached only on
# pathological inputs, and what it leaves is visible through kkt_residual.
_MAX_SWEEPS = 1000


def learn_dictionary(
    features: np.ndarray,
    n_atoms: int,
    *,
    rng: np.random.Generator,
    n_init: int = 1,
    kmeans: KMeansFunction = kmeans_centroids,
) -> np.ndarray:
    """Learn the codebook: k-means++ centroids of ``features``, L2-normalised.

    TPT's ``fkmeans`` with ``careful = 1`` is k-means++ seeding followed by
    batch Lloyd iterations, which is ``sklearn.cluster.KMeans(init="k-means++")``
    (``docs/design/tracker.md``, "Dictionary").

    Parameters
    ----------
    features : (M, B) array_like of float
        Training vectors, one per row (the 9 * s superpixel features of the
        nine one-pixel-shifted first-frame templates in the tracker).
    n_atoms : int
        Requested number of atoms ``z`` (50 in the paper setting). Fewer
        are returned when ``features`` has fewer distinct rows:
        ``z = min(n_atoms, number of distinct rows)``.
    rng : numpy.random.Generator
        Source of randomness; one integer is drawn from it as the k-means
        seed, so the result is a deterministic function of the generator's
        state.
    n_init : int, optional
        k-means restarts, the best inertia kept. 1 matches TPT's single
        ``fkmeans`` run.
    kmeans : callable, optional
        What runs the k-means: ``kmeans(features, n_clusters, n_init, seed)``
        returns the centroids. In this process by default; the tool runs
        the same function in a child process (``annotator.kmeans_child``).

    Returns
    -------
    dictionary : (B, z) float64 ndarray
        Atoms as columns, each of unit L2 norm. A centroid that is exactly
        zero (only possible if a cluster holds only zero rows) stays zero.

    Raises
    ------
    TypeError
        If ``rng`` is not a ``numpy.random.Generator`` or ``n_atoms`` /
        ``n_init`` is not an integer.
    ValueError
        If ``features`` is not a non-empty finite 2-D array or ``n_atoms`` /
        ``n_init`` is not positive.
    """
    features = _as_matrix(features, "features")
    if features.shape[0] == 0 or features.shape[1] == 0:
        raise ValueError(f"features must be a non-empty (M, B) array, got shape {features.shape}")
    n_atoms = _positive_int(n_atoms, "n_atoms")
    n_init = _positive_int(n_init, "n_init")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator, got {type(rng).__name__}; "
            "create one with np.random.default_rng(seed)"
        )
    n_distinct = np.unique(features, axis=0).shape[0]
    n_clusters = min(n_atoms, n_distinct)
    seed = int(rng.integers(0, 2**31 - 1))
    centroids = np.asarray(kmeans(features, n_clusters, n_init, seed), dtype=np.float64)
    norms = np.linalg.norm(centroids, axis=1, keepdims=True)
    atoms = np.divide(centroids, norms, out=np.zeros_like(centroids), where=norms > 0.0)
    return np.ascontiguousarray(atoms.T)


def encode_nonnegative(
    signals: np.ndarray,
    dictionary: np.ndarray,
    *,
    lam: float = 0.01,
) -> np.ndarray:
    """Exact non-negative LASSO codes of many signals against one dictionary.

    Solves, for every row ``a`` of ``signals``,
    ``argmin_{h >= 0} 0.5 ||a - D h||^2 + lam ||h||_1`` (SPAMS ``mexLasso``
    mode 2 with ``pos = true``; ``docs/design/tracker.md``, "Non-negative sparse codes").

    Parameters
    ----------
    signals : (M, B) array_like of float
        One signal per row (L2-normalised superpixel features in the tracker).
    dictionary : (B, z) array_like of float
        Atoms as columns (see :func:`learn_dictionary`).
    lam : float, optional
        L1 weight ``lambda`` >= 0 (0.01, TPT).

    Returns
    -------
    codes : (M, z) float64 ndarray
        Non-negative codes whose KKT residual (:func:`kkt_residual`) is at
        most about ``1e-10 * max_j |d_j^T a|``.

    Raises
    ------
    ValueError
        If the arrays are not finite 2-D float arrays with
        ``signals.shape[1] == dictionary.shape[0]``, or ``lam`` is negative
        or not finite.

    Notes
    -----
    With ``G = D^T D`` (once) and ``c = D^T a - lam`` (per signal, in the
    kernel, over the nonzero entries of ``a``) each row is the QP ``min_{h >= 0} 0.5 h^T G h - c^T h``, solved
    in parallel over signals by a Lawson-Hanson active set: the coordinate
    with the largest positive gradient ``(c - G h)_j`` enters, the passive
    system is solved with a Cholesky factor grown by one row per entry
    (O(p^2)), and when a passive coordinate would turn negative the iterate
    steps back to the boundary and that coordinate leaves (factor rebuilt).
    It stops when ``(c - G h)_j <= tol`` off the support and
    ``|c - G h|_j <= tol`` on it, with ``tol = 1e-10 * max(max_j |d_j^T a|,
    lam)`` per signal, so that one large signal does not loosen the others.

    Degenerate dictionaries: a ridge of ``1e-12 * max_j ||d_j||^2`` on the
    passive system, with pivots clamped to it, keeps the factor finite when
    atoms are duplicated or dependent (a duplicate of a support atom never
    enters, since its gradient equals that atom's, zero). Termination is
    guaranteed: after ``4 z + 20`` passive solves, or if the final KKT check
    fails, the code is finished by at most 1000 sweeps of projected
    coordinate descent from the current feasible iterate.
    """
    codes = _encode(signals, dictionary, lam, group=1)
    return codes.reshape(codes.shape[:2])


def encode_tensors(
    features: np.ndarray,
    dictionary: np.ndarray,
    *,
    lam: float = 0.01,
    start: np.ndarray | None = None,
    max_solves: int | None = None,
) -> np.ndarray:
    """Code tensors: the non-negative LASSO code of every superpixel, pooled per template.

    Tensor pooling is arrangement (``docs/design/tracker.md``, "Tensor pooling"): the codes of a template's
    ``s`` superpixels are the columns of its ``z x s`` tensor. Same codes, to the
    bit, as :func:`encode_nonnegative` of the ``(n s, B)`` features
    transposed per template, written in place by the kernel.

    Parameters
    ----------
    features : (n, s, B) array_like of float
        The superpixel features of ``n`` templates.
    dictionary : (B, z) array_like of float
    lam : float, optional
        L1 weight ``lambda`` >= 0.
    start : (z, s) array_like of float, optional
        A code tensor whose supports the solves start from, superpixel by superpixel (each column of every
        template from that column's positive atoms): the same optimum, reached in fewer steps when the codes are
        close to these, but equal to the default's only up to the solver's tolerance, not to the bit.
    max_solves : int, optional
        With ``start``: stop each code after this many active-set solves beyond the start (0: the start's own
        solve, its atoms pruned until every one is positive). A first look, not the optimum: the codes are
        non-negative and their objective never above the start's, but no KKT residual is promised. None (the
        default) solves to the optimum.

    Returns
    -------
    tensors : (n, z, s) float64 ndarray

    Raises
    ------
    ValueError
        As :func:`encode_nonnegative`, or if ``features`` is not 3-D.
    """
    features = np.asarray(features)
    if features.ndim != 3:
        raise ValueError(f"features must be an (n, s, B) array, got shape {features.shape}")
    n, s, b = features.shape
    if s == 0:  # no superpixels: n empty tensors (the signals alone cannot tell n)
        return np.zeros((n, np.shape(dictionary)[-1], 0), dtype=np.float64)
    if start is not None:
        start = np.ascontiguousarray(start, dtype=np.float64)
        if start.shape != (np.shape(dictionary)[-1], s):
            raise ValueError(f"start must be a (z, s) = ({np.shape(dictionary)[-1]}, {s}) code tensor, got shape "
                             f"{start.shape}")
    if max_solves is not None:
        if start is None:
            raise ValueError("max_solves needs a start: it caps the solves that follow the start's support")
        max_solves = _nonnegative_int(max_solves, "max_solves")
    return _encode(features.reshape(n * s, b), dictionary, lam, group=s, start=start, max_solves=max_solves)


def _encode(signals: np.ndarray, dictionary: np.ndarray, lam: float, *, group: int,
            start: np.ndarray | None = None, max_solves: int | None = None) -> np.ndarray:
    """Validated arguments into the kernel; (M / group, z, group) codes."""
    signals, dictionary, lam = _lasso_arguments(signals, dictionary, lam)
    n_atoms = dictionary.shape[1]
    if signals.shape[0] == 0 or n_atoms == 0:
        return np.zeros((signals.shape[0] // group, n_atoms, group), dtype=np.float64)
    gram = dictionary.T @ dictionary
    # Exact symmetry: the kernel reads G by rows where the maths uses columns.
    gram = np.ascontiguousarray(0.5 * (gram + gram.T))
    ridge = _REL_RIDGE * float(np.diagonal(gram).max())
    if not ridge > 0.0:
        ridge = np.finfo(np.float64).tiny
    if max_solves is None:
        max_iter, max_sweeps = _ITER_PER_ATOM * n_atoms + _ITER_EXTRA, _MAX_SWEEPS
    else:  # a first look: no polish by coordinate descent either
        max_iter, max_sweeps = max_solves, 0
    return nonnegative_lasso(gram, dictionary, signals, lam, _REL_TOL, ridge, max_iter, max_sweeps,
                             numba.get_num_threads(), group, start)


def kkt_residual(
    signals: np.ndarray,
    dictionary: np.ndarray,
    codes: np.ndarray,
    *,
    lam: float = 0.01,
) -> np.ndarray:
    """Largest violation of the KKT conditions of the non-negative LASSO, per signal.

    With ``g = D^T (a - D h) - lam``, the optimality conditions of
    ``min_{h >= 0} 0.5 ||a - D h||^2 + lam ||h||_1`` are ``g_j = 0`` where
    ``h_j > 0``, ``g_j <= 0`` where ``h_j = 0``, and ``h >= 0``.

    Parameters
    ----------
    signals : (M, B) array_like of float
    dictionary : (B, z) array_like of float
    codes : (M, z) array_like of float
    lam : float, optional
        L1 weight >= 0 used for the codes.

    Returns
    -------
    residual : (M,) float64 ndarray
        ``max_j`` of ``|g_j|`` where ``h_j > 0``, ``max(g_j, 0)`` where
        ``h_j == 0``, and ``max(-h_j, 0)``; 0 for an exact solution.

    Raises
    ------
    ValueError
        On non-finite or mismatched arrays, or a negative ``lam``.
    """
    signals, dictionary, lam = _lasso_arguments(signals, dictionary, lam)
    codes = _as_matrix(codes, "codes")
    expected = (signals.shape[0], dictionary.shape[1])
    if codes.shape != expected:
        raise ValueError(f"codes must have shape (M, z) = {expected}, got {codes.shape}")
    if codes.shape[1] == 0:
        return np.zeros(codes.shape[0], dtype=np.float64)
    gradient = (signals - codes @ dictionary.T) @ dictionary - lam
    violation = np.where(codes > 0.0, np.abs(gradient), np.maximum(gradient, 0.0))
    violation = np.maximum(violation, np.maximum(-codes, 0.0))
    return violation.max(axis=1)


def _lasso_arguments(signals: object, dictionary: object, lam: object) -> tuple[np.ndarray, np.ndarray, float]:
    """The ``(M, B)`` signals and ``(B, z)`` dictionary as :func:`_as_matrix` makes them and ``lam`` as a float >= 0,
    or an error naming the argument at fault."""
    signals = _as_matrix(signals, "signals")
    dictionary = _as_matrix(dictionary, "dictionary")
    lam = _nonnegative_float(lam, "lam")
    if signals.shape[1] != dictionary.shape[0]:
        raise ValueError(
            f"signals has {signals.shape[1]} features per row but dictionary has "
            f"{dictionary.shape[0]} rows; dictionary must be (B, z) with atoms as columns"
        )
    return signals, dictionary, lam


def _as_matrix(value: object, name: str) -> np.ndarray:
    """``value`` as a finite, C-contiguous float64 2-D array, or an error naming it."""
    array = np.asarray(value)
    if array.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got shape {array.shape}")
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    array = np.ascontiguousarray(array, dtype=np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return array


def _nonnegative_int(value: object, name: str) -> int:
    """``value`` as an int >= 0, or an error naming it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 0:
        raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
    return int(value)


def _nonnegative_float(value: object, name: str) -> float:
    """``value`` as a finite float >= 0, or an error naming it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number >= 0, got {value!r}")
    value = float(value)
    if not (np.isfinite(value) and value >= 0.0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value}")
    return value

