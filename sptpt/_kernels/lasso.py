"""Exact non-negative LASSO on a Gram matrix: Lawson-Hanson active set per signal.

For every row ``c`` of ``linear`` the kernel solves the quadratic program

    min_{h >= 0}  0.5 h^T G h - c^T h,

which is ``min_{h >= 0} 0.5 ||a - D h||^2 + lam ||h||_1`` with ``G = D^T D``
and ``c = D^T a - lam`` (SPAMS ``mexLasso`` mode 2, ``pos = true``;
``docs/design/tracker.md``, "Non-negative sparse codes"). The gradient of
the negated objective is ``w = c - G h``; the optimum satisfies
``w_j <= 0`` where ``h_j = 0`` and ``w_j = 0`` where ``h_j > 0`` (KKT).

Compiled with ``error_model="numpy"``: numba's default guards every division
with a test for a zero divisor. No divisor here can be zero (Cholesky pivots
are clamped to ``ridge > 0``; the step ratio and the coordinate step test
``gap > 0`` and ``G_jj > 0`` first), so the codes are bit-identical; the
guards cost about a tenth of the coding time.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sptpt._kernels import run_in_chunks


@numba.njit(cache=True, inline="always", error_model="numpy")
def _cholesky_append(chol, forward, gram, c, passive, p, j, ridge):  # pragma: no cover
    """Append coordinate ``j`` as row/column ``p`` of the Cholesky factor.

    ``chol[:p, :p]`` is the lower factor of ``G[P, P] + ridge I``; this adds
    the row ``l = L^{-1} G[P, j]`` and the pivot ``sqrt(G_jj + ridge - l.l)``,
    O(p^2). ``forward[:p] = L^{-1} c[P]`` is extended the same way, so each
    later solve needs only the back substitution. A pivot that rounding or a
    linearly dependent atom (duplicate columns of D) drives below ``ridge``
    is clamped to ``ridge``: the factor stays finite, and the step-back of
    the active set then moves along the near-null direction until a
    coordinate leaves.
    """
    for i in range(p):
        acc = gram[passive[i], j]
        for k in range(i):
            acc -= chol[i, k] * chol[p, k]
        chol[p, i] = acc / chol[i, i]
    pivot = gram[j, j] + ridge
    for k in range(p):
        pivot -= chol[p, k] * chol[p, k]
    if not pivot >= ridge:
        pivot = ridge
    chol[p, p] = math.sqrt(pivot)
    acc = c[j]
    for k in range(p):
        acc -= chol[p, k] * forward[k]
    forward[p] = acc / chol[p, p]


@numba.njit(cache=True, inline="always", error_model="numpy")
def _back_solve(chol, forward, p, out, work):  # pragma: no cover
    """``out[:p] = L^{-T} forward[:p]``, row-oriented so that L is read by rows."""
    for i in range(p):
        work[i] = forward[i]
    for i in range(p - 1, -1, -1):
        value = work[i] / chol[i, i]
        out[i] = value
        for k in range(i):
            work[k] -= value * chol[i, k]


@numba.njit(cache=True, inline="always", error_model="numpy")
def _gradient(gram, c, h, passive, p, w):  # pragma: no cover
    """``w = c - G h`` using only the passive coordinates (h is zero elsewhere)."""
    z = c.shape[0]
    for i in range(z):
        w[i] = c[i]
    for k in range(p):
        q = passive[k]
        value = h[q]
        for i in range(z):
            w[i] -= value * gram[q, i]


@numba.njit(cache=True, inline="always", error_model="numpy")
def _violation(h, w):  # pragma: no cover
    """Largest KKT violation of a feasible ``h`` given ``w = c - G h``."""
    worst = 0.0
    for i in range(h.shape[0]):
        if h[i] > 0.0:
            v = abs(w[i])
        else:
            v = w[i]
        if v > worst:
            worst = v
    return worst


@numba.njit(cache=True, error_model="numpy")
def _coordinate_descent(gram, c, h, w, tol, max_sweeps):  # pragma: no cover
    """Projected coordinate descent sweeps from a feasible ``h`` (fallback/polish).

    Exact minimisation along one coordinate at a time, ``w`` kept equal to
    ``c - G h``; stops when the KKT violation is at most ``tol`` or after
    ``max_sweeps`` sweeps, so it always terminates. Atoms with ``G_jj = 0``
    (zero atoms) are left at their current value: the objective does not
    depend on them beyond the linear term, which is ``lam >= 0``.
    """
    z = c.shape[0]
    # Rebuild w from scratch: h may come from an interrupted active set.
    for i in range(z):
        w[i] = c[i]
    for q in range(z):
        value = h[q]
        if value != 0.0:
            for i in range(z):
                w[i] -= value * gram[q, i]
    for _ in range(max_sweeps):
        if _violation(h, w) <= tol:
            return
        for j in range(z):
            diagonal = gram[j, j]
            if diagonal <= 0.0:
                continue
            new = h[j] + w[j] / diagonal
            if new < 0.0:
                new = 0.0
            delta = new - h[j]
            if delta != 0.0:
                h[j] = new
                for i in range(z):
                    w[i] -= delta * gram[j, i]


@numba.njit(cache=True, inline="always", error_model="numpy")
def _warm_start(gram, c, h, w, passive, in_passive, chol, forward, sol, work, start, ridge):  # pragma: no cover
    """Start from the coordinates where ``start`` is positive: the unconstrained optimum on them, with those whose
    value is not positive dropped until every one is; sets ``h``, ``w`` and the factor, returns the passive count.

    Lawson-Hanson converges to the same optimum from any such point; a support close to the optimum's skips most
    of its one-coordinate-at-a-time additions.
    """
    z = c.shape[0]
    p = 0
    for j in range(z):
        if start[j] > 0.0:
            passive[p] = j
            p += 1
    while p > 0:
        for k in range(p):
            _cholesky_append(chol, forward, gram, c, passive, k, passive[k], ridge)
        _back_solve(chol, forward, p, sol, work)
        kept = 0
        for k in range(p):
            if sol[k] > 0.0:
                passive[kept] = passive[k]
                sol[kept] = sol[k]
                kept += 1
        if kept == p:
            break
        p = kept
    for k in range(p):
        h[passive[k]] = sol[k]
        in_passive[passive[k]] = True
    _gradient(gram, c, h, passive, p, w)
    return p


@numba.njit(cache=True, error_model="numpy")
def _solve_one(gram, c, h, w, passive, in_passive, blocked, chol, forward, sol, work,
               tol, ridge, max_iter, max_sweeps, start):  # pragma: no cover
    """Lawson-Hanson active set for one signal; ``h`` (zeroed here) receives the code. ``start``: a ``(z,)`` code
    whose support to start from (:func:`_warm_start`), or an empty array to start from nothing."""
    z = c.shape[0]
    for i in range(z):
        h[i] = 0.0
        w[i] = c[i]
        in_passive[i] = False
        blocked[i] = False
    p = 0
    if start.shape[0] > 0:
        p = _warm_start(gram, c, h, w, passive, in_passive, chol, forward, sol, work, start, ridge)
    n_iter = 0
    converged = False
    while n_iter < max_iter:
        # Entering coordinate: the largest positive gradient outside P.
        j = -1
        best = tol
        # The gradient test first: it is almost always false (at most a few
        # coordinates off P have a positive gradient), so the scan seldom
        # reaches the two mask tests, whose outcome is unpredictable.
        for i in range(z):
            if w[i] > best and not in_passive[i] and not blocked[i]:
                best = w[i]
                j = i
        if j < 0:
            converged = True
            break
        _cholesky_append(chol, forward, gram, c, passive, p, j, ridge)
        passive[p] = j
        in_passive[j] = True
        p += 1
        first = True
        stepped = False
        while n_iter < max_iter:
            n_iter += 1
            _back_solve(chol, forward, p, sol, work)
            alpha = 1.0
            leaving = -1
            for k in range(p):
                if sol[k] <= 0.0:
                    q = passive[k]
                    gap = h[q] - sol[k]
                    ratio = h[q] / gap if gap > 0.0 else 0.0
                    if leaving < 0 or ratio < alpha:
                        alpha = ratio
                        leaving = k
            if leaving < 0:
                for k in range(p):
                    h[passive[k]] = sol[k]
                stepped = True
                break
            if first and sol[p - 1] <= 0.0:
                # In exact arithmetic the entering coordinate is positive in
                # the new solution (its Schur complement is positive and its
                # gradient was > tol); if rounding says otherwise, undo the
                # addition and block it until h changes, instead of cycling.
                p -= 1
                in_passive[j] = False
                blocked[j] = True
                break
            first = False
            # Step back to the boundary of h >= 0 along the segment h -> sol.
            for k in range(p):
                q = passive[k]
                h[q] += alpha * (sol[k] - h[q])
            h[passive[leaving]] = 0.0
            kept = 0
            for k in range(p):
                q = passive[k]
                if h[q] > 0.0:
                    passive[kept] = q
                    kept += 1
                else:
                    h[q] = 0.0
                    in_passive[q] = False
            p = kept
            # Removing rows from a Cholesky factor is done by rebuilding it:
            # p is small and removals are rare next to additions.
            for k in range(p):
                _cholesky_append(chol, forward, gram, c, passive, k, passive[k], ridge)
        if stepped:
            _gradient(gram, c, h, passive, p, w)
            for i in range(z):
                blocked[i] = False
    # At convergence the free coordinates are at a zero gradient up to the
    # ridge and rounding, and the others at most tol, except a coordinate
    # still blocked by the rounding guard; polish with coordinate descent
    # only if the KKT conditions do not hold to tol.
    if converged and _violation(h, w) <= tol:
        return
    _coordinate_descent(gram, c, h, w, tol, max_sweeps)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _linear_term(dictionary, signal, lam, rel_tol, c):  # pragma: no cover
    """``c = D^T a - lam`` and the signal's tolerance ``rel_tol * max(max_j |d_j^T a|, lam)``.

    Superpixel features are sparse (about 20 of 64 entries are nonzero), so
    the product runs over the nonzero entries of ``a``, adding rows of D in
    order of ``b``: the same sum as a dense sequential dot product, since a
    skipped term is an exact zero.
    """
    z = c.shape[0]
    for i in range(z):
        c[i] = 0.0
    for b in range(signal.shape[0]):
        value = signal[b]
        if value != 0.0:
            for i in range(z):
                c[i] += value * dictionary[b, i]
    scale = lam
    for i in range(z):
        if abs(c[i]) > scale:
            scale = abs(c[i])
        c[i] -= lam
    return rel_tol * scale


def nonnegative_lasso(gram, dictionary, signals, lam, rel_tol, ridge, max_iter, max_sweeps, n_threads, group=1,
                      start=None):
    """Non-negative LASSO codes of every row of ``signals``.

    gram: (z, z) float64, ``D^T D``, exactly symmetric, C-contiguous.
    dictionary: (B, z) float64, C-contiguous. signals: (M, B) float64,
    C-contiguous. lam: L1 weight >= 0. rel_tol: KKT tolerance on
    ``w = c - G h`` relative to ``max(max_j |d_j^T a|, lam)`` per signal.
    ridge: added to the diagonal of every passive-set factorisation (> 0).
    max_iter: active-set solves per signal before handing over to at most
    max_sweeps coordinate-descent sweeps. n_threads: threads that solve blocks
    of signals in turn. group: signals per code tensor, a divisor of M. Returns
    (M / group, z, group) float64 codes, all >= 0: signal ``m``'s code is
    column ``m % group`` of tensor ``m // group`` (with ``group = 1``, reshape
    to (M, z) for free). Signals are independent, so the result does not
    depend on ``n_threads`` or the blocks.

    ``D^T a`` is formed per signal inside the parallel ranges rather than as
    one BLAS product beforehand: that product ran on one thread (BLAS is
    limited to one in the tracker) and took a sixth of the coding time. The
    codes are written straight into their tensors: transposing (M, z) codes
    afterwards was a single-threaded copy of about 1.5 ms a frame.

    start: None, or a (z, group) float64 tensor, C-contiguous: every signal's solve then starts from the support
    of the column of ``start`` it would fill (:func:`_warm_start`). The codes are the same optimum to the
    tolerance, not to the bit.
    """
    codes = np.empty((signals.shape[0] // group, gram.shape[0], group), dtype=np.float64)
    start = np.empty((0, group), dtype=np.float64) if start is None else start
    run_in_chunks(_lasso_range, signals.shape[0], n_threads, gram, dictionary, signals, lam, rel_tol, ridge,
                  max_iter, max_sweeps, codes, start)
    return codes


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lasso_range(gram, dictionary, signals, lam, rel_tol, ridge, max_iter, max_sweeps, codes, starts,
                 start, stop):  # pragma: no cover - compiled
    """Signals ``start:stop`` of :func:`nonnegative_lasso` into their columns of ``codes`` (``starts``: the warm
    start tensor, or one with no rows)."""
    z = gram.shape[0]
    group = codes.shape[2]
    # Unsigned, so that indexing with an entry skips numba's negative-index wraparound.
    passive = np.empty(z, dtype=np.uint64)
    in_passive = np.empty(z, dtype=np.bool_)
    blocked = np.empty(z, dtype=np.bool_)
    chol = np.zeros((z, z), dtype=np.float64)
    forward = np.empty(z, dtype=np.float64)
    sol = np.empty(z, dtype=np.float64)
    work = np.empty(z, dtype=np.float64)
    w = np.empty(z, dtype=np.float64)
    c = np.empty(z, dtype=np.float64)
    h = np.empty(z, dtype=np.float64)
    cold = np.empty(0, dtype=np.float64)
    warm = np.empty(z, dtype=np.float64)
    for m in range(start, stop):
        tol = _linear_term(dictionary, signals[m], lam, rel_tol, c)
        column = m % group
        from_code = cold
        if starts.shape[0] > 0:
            for i in range(z):
                warm[i] = starts[i, column]
            from_code = warm
        _solve_one(gram, c, h, w, passive, in_passive, blocked, chol,
                   forward, sol, work, tol, ridge, max_iter, max_sweeps, from_code)
        tensor = codes[m // group]
        for i in range(z):
            tensor[i, column] = h[i]
