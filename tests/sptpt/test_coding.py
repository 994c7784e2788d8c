"""Dictionary and exact non-negative LASSO.

See ``docs/design/tracker.md``, "Dictionary", "Non-negative sparse codes" and "Checks the tests hold".
"""

from __future__ import annotations

import warnings

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import solve_triangular
from scipy.optimize import nnls
from sklearn.linear_model import Lasso

from sptpt.coding import encode_nonnegative, encode_tensors, kkt_residual, learn_dictionary

LAM = 0.01


def histogram_features(n: int, rng: np.random.Generator, *, n_bins: int = 8, n_cues: int = 8) -> np.ndarray:
    """Features shaped like the real ones: 8 sparse cue histograms, each summing to 1, L2-normalised."""
    weights = rng.gamma(0.3, size=(n, n_cues, n_bins)) * (rng.random((n, n_cues, n_bins)) < 0.5)
    weights[..., 0] += 1e-3  # no empty histogram
    hist = weights / weights.sum(axis=-1, keepdims=True)
    features = hist.reshape(n, n_cues * n_bins)
    return features / np.linalg.norm(features, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def problem() -> tuple[np.ndarray, np.ndarray]:
    """Real-size problem: B = 64, z = 50 k-means atoms of 225 training features."""
    rng = np.random.default_rng(2024)
    prototypes = histogram_features(30, rng)
    def around(count: int) -> np.ndarray:
        # Signals near a few prototypes, as candidates are near the target.
        mixed = prototypes[rng.integers(0, 30, count)] + 0.3 * histogram_features(count, rng)
        return mixed / np.linalg.norm(mixed, axis=1, keepdims=True)
    dictionary = learn_dictionary(around(225), 50, rng=rng)
    return around(2000), dictionary


def objective(signals: np.ndarray, dictionary: np.ndarray, codes: np.ndarray, lam: float) -> np.ndarray:
    residual = signals - codes @ dictionary.T
    return 0.5 * (residual**2).sum(axis=1) + lam * np.abs(codes).sum(axis=1)


def reference_nnls(signals: np.ndarray, dictionary: np.ndarray, lam: float) -> np.ndarray:
    """The exact NNLS reformulation: G = R^T R, c = D^T a - lam, h = nnls(R, R^{-T} c).

    0.5 ||R h - R^{-T} c||^2 = 0.5 h^T G h - c^T h + const, so both have the
    same minimiser over h >= 0 (requires D of full column rank).
    """
    gram = dictionary.T @ dictionary
    upper = np.linalg.cholesky(gram).T
    codes = np.empty((signals.shape[0], dictionary.shape[1]))
    for m, signal in enumerate(signals):
        target = solve_triangular(upper, dictionary.T @ signal - lam, trans="T")
        codes[m] = nnls(upper, target, maxiter=10_000)[0]
    return codes


def reference_sklearn(signals: np.ndarray, dictionary: np.ndarray, lam: float) -> np.ndarray:
    """sklearn's coordinate-descent Lasso, the solver of sparse_encode's lasso_cd, with alpha = lam / B as
    sparse_encode passes it, so its objective is ours.

    Run to a duality gap of 1e-12 instead of sparse_encode's own stop, which scikit-learn changed: 1.3 to 1.7
    stop where Lasso's default tol of 1e-4 does (codes up to 5e-3 off on the problem below), 1.9 far tighter
    (3e-7). With the gap given, 1.3 and 1.9 give the same codes to 1e-10.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ConvergenceWarning chatter
        lasso = Lasso(alpha=lam / dictionary.shape[0], fit_intercept=False, positive=True, tol=1e-12,
                      max_iter=100_000)
        return lasso.fit(dictionary, signals.T).coef_


# ---------------------------------------------------------------------------
# agreement with references


def test_codes_match_nnls_reference(problem) -> None:
    signals, dictionary = problem
    codes = encode_nonnegative(signals[:300], dictionary, lam=LAM)
    want = reference_nnls(signals[:300], dictionary, LAM)
    np.testing.assert_allclose(codes, want, rtol=0, atol=1e-6)


def test_codes_match_sklearn_lasso(problem) -> None:
    """sklearn's Lasso run to a duality gap of 1e-12 (relative) is within about 1e-10 of
    the optimum, hence 1e-7 here; its objective is never lower than ours beyond rounding."""
    signals, dictionary = problem
    codes = encode_nonnegative(signals[:40], dictionary, lam=LAM)
    want = reference_sklearn(signals[:40], dictionary, LAM)
    np.testing.assert_allclose(codes, want, rtol=0, atol=1e-7)
    ours = objective(signals[:40], dictionary, codes, LAM)
    assert np.all(ours <= objective(signals[:40], dictionary, want, LAM) + 1e-14)


@pytest.mark.parametrize("lam", [0.0, 0.001, 0.01, 0.1])
def test_kkt_on_real_size_problem(problem, lam: float) -> None:
    signals, dictionary = problem
    codes = encode_nonnegative(signals, dictionary, lam=lam)
    assert codes.shape == (2000, dictionary.shape[1])
    assert np.all(codes >= 0.0)
    assert kkt_residual(signals, dictionary, codes, lam=lam).max() <= 1e-6


def test_lam_zero_is_nnls(problem) -> None:
    signals, dictionary = problem
    codes = encode_nonnegative(signals[:50], dictionary, lam=0.0)
    want = np.array([nnls(dictionary, s, maxiter=10_000)[0] for s in signals[:50]])
    np.testing.assert_allclose(codes, want, rtol=0, atol=1e-6)


def test_deterministic_and_thread_count_independent(problem) -> None:
    signals, dictionary = problem
    first = encode_nonnegative(signals, dictionary)
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        single = encode_nonnegative(signals, dictionary)
    finally:
        numba.set_num_threads(previous)
    assert np.array_equal(first, encode_nonnegative(signals, dictionary))
    assert np.array_equal(first, single)


@pytest.mark.parametrize("threads", [1, 2])
def test_code_tensors_are_the_codes_of_each_template_as_columns(problem, threads: int) -> None:
    """Tensor pooling is arrangement: tensor n's column j is superpixel j's code, to the bit."""
    signals, dictionary = problem
    n, s = 7, 25
    features = signals[: n * s].reshape(n, s, -1)
    want = encode_nonnegative(signals[: n * s], dictionary).reshape(n, s, -1).transpose(0, 2, 1)
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        tensors = encode_tensors(features, dictionary)
    finally:
        numba.set_num_threads(previous)
    assert tensors.shape == (n, dictionary.shape[1], s) and tensors.flags.c_contiguous
    assert np.array_equal(tensors, want)


@pytest.mark.parametrize("start", ["own", "neighbour", "wrong", "empty", "all"])
def test_a_warm_start_reaches_the_same_optimum(problem, start: str) -> None:
    """Started from any support, the active set ends at the optimum the cold start finds (the problem is strictly
    convex), to the tolerance and KKT-certified; from the optimum's own support it often ends in one solve."""
    signals, dictionary = problem
    n, s = 12, 25
    features = signals[: n * s].reshape(n, s, -1)
    cold = encode_tensors(features, dictionary)
    rng = np.random.default_rng(3)
    starts = {"own": cold[0], "neighbour": encode_tensors(signals[n * s : n * s + s][None], dictionary)[0],
              "wrong": (cold[1] == 0) * rng.random(cold[1].shape),  # every atom the optimum leaves out, none it uses
              "empty": np.zeros_like(cold[0]), "all": np.ones_like(cold[0])}
    warm = encode_tensors(features, dictionary, start=starts[start])
    np.testing.assert_allclose(warm, cold, rtol=0, atol=1e-10)
    assert (warm >= 0).all()
    codes = warm.transpose(0, 2, 1).reshape(n * s, -1)
    assert kkt_residual(signals[: n * s], dictionary, codes, lam=LAM).max() <= 1e-8
    if start == "empty":  # no support: the cold start itself, to the bit
        assert np.array_equal(warm, cold)


def test_a_warm_start_must_be_one_code_tensor(problem) -> None:
    signals, dictionary = problem
    features = signals[:50].reshape(2, 25, -1)
    with pytest.raises(ValueError, match=r"start must be a \(z, s\) = \(50, 25\) code tensor"):
        encode_tensors(features, dictionary, start=np.ones((25, 50)))


def reference_capped(signal: np.ndarray, dictionary: np.ndarray, lam: float, start: np.ndarray,
                     max_solves: int) -> np.ndarray:
    """Lawson-Hanson by dense solves, as the kernel steps it: the start's atoms pruned until all are positive, then
    at most ``max_solves`` solves, each after the atom of largest positive gradient enters (or after a step back
    to the boundary when a passive code would turn negative)."""
    gram = dictionary.T @ dictionary
    c = dictionary.T @ signal
    tol = 1e-10 * max(np.abs(c).max(), lam)
    c = c - lam
    ridge = 1e-12 * np.diagonal(gram).max()

    def solve(passive: list[int]) -> np.ndarray:
        return np.linalg.solve(gram[np.ix_(passive, passive)] + ridge * np.eye(len(passive)), c[passive])

    passive = list(np.flatnonzero(start > 0))
    h = np.zeros(len(c))
    while passive:
        sol = solve(passive)
        if (sol > 0).all():
            h[passive] = sol
            break
        passive = [q for q, v in zip(passive, sol) if v > 0]
    solves, blocked = 0, set()
    while solves < max_solves:
        gradient = c - gram @ h
        free = [i for i in range(len(c)) if i not in passive and i not in blocked and gradient[i] > tol]
        if not free:
            break
        entering = max(free, key=lambda i: (gradient[i], -i))
        passive.append(entering)
        first = True
        while solves < max_solves:
            solves += 1
            sol = solve(passive)
            if (sol > 0).all():
                h[passive] = sol
                blocked = set()
                break
            if first and sol[-1] <= 0:
                passive.pop()
                blocked.add(entering)
                break
            first = False
            ratios = [(h[q] / (h[q] - v) if h[q] - v > 0 else 0.0, k)
                      for k, (q, v) in enumerate(zip(passive, sol)) if v <= 0]
            alpha, leaving = min(ratios)
            h[passive] += alpha * (sol - h[passive])
            h[passive[leaving]] = 0.0
            h[[q for q in passive if h[q] <= 0]] = 0.0
            passive = [q for q in passive if h[q] > 0]
    return h


@pytest.mark.parametrize("max_solves", [0, 1, 2, 3])
def test_capped_codes_match_the_reference(problem, max_solves: int) -> None:
    """Codes capped at a few solves after a start (the shortlist's first look) are the active set's iterate after
    those solves, as a slow reference steps it."""
    signals, dictionary = problem
    n, s = 6, 25
    features = signals[: n * s].reshape(n, s, -1)
    start = encode_tensors(signals[n * s : n * s + s][None], dictionary)[0]  # a neighbour's codes
    capped = encode_tensors(features, dictionary, start=start, max_solves=max_solves)
    want = np.stack([np.stack([reference_capped(features[t, j], dictionary, LAM, start[:, j], max_solves)
                               for j in range(s)], axis=1) for t in range(n)])
    np.testing.assert_allclose(capped, want, rtol=0, atol=1e-9)
    assert (capped >= 0).all()


def test_capped_codes_approach_the_optimum(problem) -> None:
    """Each solve lowers the objective or keeps it; the start's own solve is already below the start; a cap the
    solves never reach gives the optimum to the bit, as an uncapped warm start does."""
    signals, dictionary = problem
    n, s = 8, 25
    features = signals[: n * s].reshape(n, s, -1)
    start = encode_tensors(signals[n * s : n * s + s][None], dictionary)[0]
    flat = features.reshape(n * s, -1)

    def objectives(tensors: np.ndarray) -> np.ndarray:
        return objective(flat, dictionary, tensors.transpose(0, 2, 1).reshape(n * s, -1), LAM)

    levels = [objectives(encode_tensors(features, dictionary, start=start, max_solves=k)) for k in range(6)]
    for before, after in zip(levels, levels[1:]):
        assert np.all(after <= before + 1e-12)
    assert np.all(levels[0] <= objectives(np.broadcast_to(start, (n, *start.shape))) + 1e-12)
    optimum = encode_tensors(features, dictionary, start=start)
    assert np.array_equal(encode_tensors(features, dictionary, start=start, max_solves=10_000), optimum)
    assert np.all(levels[2] >= objectives(optimum) - 1e-12)
    assert levels[2].sum() > objectives(optimum).sum()  # two solves are not yet the optimum here


@pytest.mark.parametrize("max_solves, start, match", [
    (2, None, "max_solves needs a start"),
    (-1, "codes", "max_solves must be an integer >= 0, got -1"),
    (1.5, "codes", "max_solves must be an integer >= 0, got 1.5"),
    (True, "codes", "max_solves must be an integer >= 0, got True"),
])
def test_capped_codes_refuse_bad_caps(problem, max_solves, start, match) -> None:
    signals, dictionary = problem
    features = signals[:50].reshape(2, 25, -1)
    start = None if start is None else encode_tensors(features[:1], dictionary)[0]
    with pytest.raises(ValueError, match=match):
        encode_tensors(features, dictionary, start=start, max_solves=max_solves)


def test_code_tensors_need_three_axes(problem) -> None:
    signals, dictionary = problem
    with pytest.raises(ValueError, match=r"features must be an \(n, s, B\) array"):
        encode_tensors(signals[:10], dictionary)
    assert encode_tensors(np.zeros((0, 25, 64)), dictionary).shape == (0, dictionary.shape[1], 25)
    assert encode_tensors(np.zeros((3, 0, 64)), dictionary).shape == (3, dictionary.shape[1], 0)


# ---------------------------------------------------------------------------
# degenerate problems with exact answers


def test_zero_signal_gives_zero_code(problem) -> None:
    _, dictionary = problem
    codes = encode_nonnegative(np.zeros((3, 64)), dictionary)
    assert np.array_equal(codes, np.zeros((3, dictionary.shape[1])))


def test_signal_equal_to_atom(problem) -> None:
    """a = d_k: h = (1 - lam) e_k, since g_j = lam (d_j^T d_k - 1) <= 0 off k and 0 at k."""
    _, dictionary = problem
    codes = encode_nonnegative(dictionary.T, dictionary)
    np.testing.assert_allclose(codes, (1.0 - LAM) * np.eye(dictionary.shape[1]), rtol=0, atol=1e-9)


def test_large_lam_gives_zero_codes(problem) -> None:
    signals, dictionary = problem
    lam = float((signals[:20] @ dictionary).max()) + 1e-9
    assert np.array_equal(encode_nonnegative(signals[:20], dictionary, lam=lam), np.zeros((20, 50)))


def test_duplicate_atoms(problem) -> None:
    """G singular: codes not unique, but the optimum value and D h are."""
    signals, dictionary = problem
    doubled = np.concatenate([dictionary[:, :25], dictionary[:, :25]], axis=1)
    codes = encode_nonnegative(signals[:200], doubled)
    assert np.all(codes >= 0.0)
    assert kkt_residual(signals[:200], doubled, codes).max() <= 1e-6
    want = reference_nnls(signals[:200], dictionary[:, :25], LAM)
    np.testing.assert_allclose(codes @ doubled.T, want @ dictionary[:, :25].T, rtol=0, atol=1e-6)
    np.testing.assert_allclose(
        objective(signals[:200], doubled, codes, LAM),
        objective(signals[:200], dictionary[:, :25], want, LAM),
        rtol=0,
        atol=1e-12,
    )


def test_dependent_atom_cheaper_in_l1(problem) -> None:
    """d_new = (d_0 + d_1) / ||d_0 + d_1|| spans nothing new but costs less L1 than d_0 + d_1:
    the active set has to swap it in along the null direction of G."""
    _, dictionary = problem
    combined = dictionary[:, 0] + dictionary[:, 1]
    extended = np.column_stack([dictionary[:, :10], combined / np.linalg.norm(combined)])
    signals = np.stack(
        [combined, 0.7 * dictionary[:, 0] + 0.3 * dictionary[:, 1], dictionary[:, 2] + combined]
    )
    signals /= np.linalg.norm(signals, axis=1, keepdims=True)
    codes = encode_nonnegative(signals, extended)
    assert np.all(codes >= 0.0)
    assert kkt_residual(signals, extended, codes).max() <= 1e-6
    assert codes[0, 10] > 0.9 and codes[0, 0] == 0.0 and codes[0, 1] == 0.0


def test_overcomplete_dictionary() -> None:
    """z > B: G is singular everywhere; KKT still certifies the codes."""
    rng = np.random.default_rng(11)
    dictionary = rng.random((10, 40))
    dictionary /= np.linalg.norm(dictionary, axis=0)
    signals = rng.random((300, 10))
    signals /= np.linalg.norm(signals, axis=1, keepdims=True)
    codes = encode_nonnegative(signals, dictionary)
    assert np.all(codes >= 0.0)
    assert kkt_residual(signals, dictionary, codes).max() <= 1e-6
    want = reference_sklearn(signals[:20], dictionary, LAM)
    ours = objective(signals[:20], dictionary, codes[:20], LAM)
    assert np.all(ours <= objective(signals[:20], dictionary, want, LAM) + 1e-12)


def test_zero_atom_is_never_used() -> None:
    rng = np.random.default_rng(4)
    dictionary = np.abs(rng.standard_normal((8, 5)))
    dictionary[:, 2] = 0.0
    signals = np.abs(rng.standard_normal((20, 8)))
    for lam in (0.0, LAM):
        codes = encode_nonnegative(signals, dictionary, lam=lam)
        assert np.all(codes[:, 2] == 0.0)
        assert kkt_residual(signals, dictionary, codes, lam=lam).max() <= 1e-6


@settings(max_examples=60, deadline=None)
@given(
    data=st.data(),
    n_features=st.integers(1, 8),
    n_atoms=st.integers(1, 8),
    n_signals=st.integers(1, 4),
    lam=st.sampled_from([0.0, 0.01, 0.1, 0.5]),
)
def test_kkt_property(data: st.DataObject, n_features: int, n_atoms: int, n_signals: int, lam: float) -> None:
    """Any sign, duplicates, zero columns: values on a grid of 1/4 make degeneracy common."""
    grid = st.integers(-4, 4).map(lambda v: v / 4)
    dictionary = np.array(
        data.draw(st.lists(grid, min_size=n_features * n_atoms, max_size=n_features * n_atoms))
    ).reshape(n_features, n_atoms)
    signals = np.array(
        data.draw(st.lists(grid, min_size=n_features * n_signals, max_size=n_features * n_signals))
    ).reshape(n_signals, n_features)
    codes = encode_nonnegative(signals, dictionary, lam=lam)
    assert np.all(codes >= 0.0)
    assert kkt_residual(signals, dictionary, codes, lam=lam).max() <= 1e-6


# ---------------------------------------------------------------------------
# kkt_residual itself


def test_kkt_residual_by_hand() -> None:
    dictionary = np.eye(2)
    signals = np.array([[0.5, 0.2]])
    # Optimum: h = a - lam = (0.49, 0.19).
    assert kkt_residual(signals, dictionary, np.array([[0.49, 0.19]]))[0] == pytest.approx(0.0, abs=1e-15)
    # h = 0: the gradient is a - lam = (0.49, 0.19), positive where h is zero.
    assert kkt_residual(signals, dictionary, np.zeros((1, 2)))[0] == pytest.approx(0.49)
    # h_0 too large by 0.1: |g_0| = 0.1 on the support.
    assert kkt_residual(signals, dictionary, np.array([[0.59, 0.19]]))[0] == pytest.approx(0.1)
    # A negative entry is a violation of h >= 0 (here 0.3 > |g|).
    assert kkt_residual(signals, dictionary, np.array([[0.49, -0.3]]), lam=0.01)[0] == pytest.approx(0.49)
    assert kkt_residual(np.array([[0.0, 0.0]]), dictionary, np.array([[0.0, -0.3]]))[0] == pytest.approx(0.3)


# ---------------------------------------------------------------------------
# dictionary


def test_dictionary_shape_norm_and_determinism(problem) -> None:
    signals, _ = problem
    first = learn_dictionary(signals[:225], 50, rng=np.random.default_rng(9))
    again = learn_dictionary(signals[:225], 50, rng=np.random.default_rng(9))
    assert first.shape == (64, 50)
    assert first.flags.c_contiguous
    np.testing.assert_allclose(np.linalg.norm(first, axis=0), 1.0, rtol=0, atol=1e-14)
    assert np.array_equal(first, again)
    # Centroids of non-negative features; sklearn centres the data internally,
    # so exact zeros come back as rounding noise of order 1e-17.
    assert np.all(first >= -1e-15)


def test_dictionary_advances_the_generator(problem) -> None:
    signals, _ = problem
    rng = np.random.default_rng(1)
    learn_dictionary(signals[:100], 10, rng=rng)
    reference = np.random.default_rng(1)
    reference.integers(0, 2**31 - 1)
    assert rng.integers(0, 1_000_000) == reference.integers(0, 1_000_000)


@pytest.mark.parametrize(
    ("n_distinct", "n_atoms", "expected"), [(7, 50, 7), (60, 50, 50), (50, 50, 50), (1, 3, 1)]
)
def test_dictionary_size_is_min_of_atoms_and_distinct_rows(
    n_distinct: int, n_atoms: int, expected: int
) -> None:
    rng = np.random.default_rng(n_distinct)
    rows = histogram_features(n_distinct, rng)
    features = rows[rng.permutation(np.arange(225) % n_distinct)]
    dictionary = learn_dictionary(features, n_atoms, rng=rng)
    assert dictionary.shape == (64, expected)
    if expected == n_distinct:
        # One centroid per distinct row: the atoms are exactly those rows (unit norm already).
        order = np.lexsort(dictionary[::-1])
        np.testing.assert_allclose(dictionary[:, order], rows[np.lexsort(rows.T[::-1])].T, atol=1e-12)


# ---------------------------------------------------------------------------
# errors


D_OK = np.eye(4)[:, :3]
A_OK = np.ones((2, 4))
RNG = np.random.default_rng


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: encode_nonnegative(np.ones(4), D_OK), ValueError, "signals must be a 2-D array"),
        (lambda: encode_nonnegative(A_OK, np.ones((4, 3, 1))), ValueError, "dictionary must be a 2-D array"),
        (lambda: encode_nonnegative(np.ones((2, 5)), D_OK), ValueError, "signals has 5 features per row"),
        (lambda: encode_nonnegative(A_OK * np.nan, D_OK), ValueError, "signals contains NaN"),
        (lambda: encode_nonnegative(A_OK, np.full((4, 3), np.inf)), ValueError, "dictionary contains NaN"),
        (lambda: encode_nonnegative(A_OK, D_OK, lam=-0.1), ValueError, "lam must be a finite number >= 0"),
        (lambda: encode_nonnegative(A_OK, D_OK, lam=np.nan), ValueError, "lam must be a finite"),
        (lambda: encode_nonnegative(A_OK, D_OK, lam="0.1"), ValueError, "lam must be a real number"),
        (lambda: encode_nonnegative(A_OK.astype(complex), D_OK), ValueError, "signals must hold real"),
        (lambda: kkt_residual(A_OK, D_OK, np.zeros((2, 4))), ValueError, r"codes must have shape .*2, 3"),
        (lambda: kkt_residual(A_OK, D_OK, np.zeros((2, 3)), lam=-1.0), ValueError, "lam"),
        (lambda: learn_dictionary(A_OK, 2, rng=0), TypeError, "rng must be a numpy.random.Generator"),
        (lambda: learn_dictionary(A_OK, 2, rng=np.random.RandomState(0)), TypeError, "rng must be"),
        (lambda: learn_dictionary(A_OK, 0, rng=RNG()), ValueError, "n_atoms must be a positive integer"),
        (lambda: learn_dictionary(A_OK, 2.5, rng=RNG()), TypeError, "n_atoms"),
        (lambda: learn_dictionary(np.ones(4), 2, rng=RNG()), ValueError, "features must be a 2-D"),
        (lambda: learn_dictionary(np.ones((0, 4)), 2, rng=RNG()), ValueError, "non-empty"),
        (lambda: learn_dictionary(A_OK * np.nan, 2, rng=RNG()), ValueError, "features contains NaN"),
    ],
)
def test_bad_inputs(call, error, match) -> None:
    with pytest.raises(error, match=match):
        call()


def test_empty_inputs() -> None:
    assert encode_nonnegative(np.zeros((0, 4)), D_OK).shape == (0, 3)
    assert encode_nonnegative(A_OK, np.zeros((4, 0))).shape == (2, 0)
    assert kkt_residual(A_OK, np.zeros((4, 0)), np.zeros((2, 0))).shape == (2,)


# ---------------------------------------------------------------------------
# the kernel's fallback path


@pytest.mark.parametrize("max_iter", [0, 1, 3])
def test_coordinate_descent_fallback_reaches_the_optimum(max_iter: int) -> None:
    """max_iter = 0 is pure projected coordinate descent; 1 and 3 interrupt the
    active set midway and let coordinate descent finish from its iterate."""
    from sptpt._kernels.lasso import nonnegative_lasso

    rng = np.random.default_rng(8)
    dictionary = histogram_features(8, rng).T.copy()
    signals = histogram_features(50, rng)
    gram = dictionary.T @ dictionary
    codes = nonnegative_lasso(gram, dictionary, signals, LAM, 1e-12, 1e-12, max_iter, 100_000, 2)[:, :, 0]
    np.testing.assert_allclose(codes, reference_nnls(signals, dictionary, LAM), rtol=0, atol=1e-8)


def test_fallback_sweep_cap_terminates_feasible() -> None:
    from sptpt._kernels.lasso import nonnegative_lasso

    rng = np.random.default_rng(8)
    dictionary = histogram_features(30, rng).T.copy()
    signals = histogram_features(20, rng)
    gram = dictionary.T @ dictionary
    codes = nonnegative_lasso(gram, dictionary, signals, LAM, 0.0, 1e-12, 0, 1, 2)[:, :, 0]
    assert np.all(codes >= 0.0) and np.all(np.isfinite(codes))
