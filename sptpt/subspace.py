"""Tensor subspace models of code tensors and their reconstruction error.

The positive model is learned incrementally (IRTSA: one sequential
Karhunen-Loeve update with mean update and forgetting factor per mode, as
IVT's ``sklm``); the negative model is refitted from scratch from a stack of
negative samples by the same first-batch routine (a HOSVD). See
``docs/design/tracker.md``, "Tensor subspace models" and "Reconstruction error and likelihood".
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from sptpt._kernels import map_on_threads

__all__ = ["IncrementalSVD", "TensorSubspace", "reconstruction_error", "RE_MODES"]

RE_MODES = ("paper", "paper_literal", "tpt_code")

# sklm drops singular values whose energy is below this share of the total.
_ENERGY_CUTOFF = 1e-6


@dataclass(frozen=True)
class IncrementalSVD:
    """Rank-limited SVD of a growing, mean-centred column set (Ross et al. 2008, ``sklm``).

    Attributes
    ----------
    basis : (d, k) ndarray
        Orthonormal left singular vectors.
    singular_values : (k,) ndarray
    mean : (d,) ndarray
        Running (forgetting-weighted) mean of the columns.
    count : float
        Effective number of columns seen, ``q + ff * n0`` per update.
    """

    basis: np.ndarray
    singular_values: np.ndarray
    mean: np.ndarray
    count: float

    @classmethod
    def fit(cls, columns: np.ndarray, max_rank: int) -> "IncrementalSVD":
        """First batch: centre the columns and keep the leading ``max_rank`` singular vectors.

        Parameters
        ----------
        columns : (d, q) ndarray
        max_rank : int
        """
        mean = columns.mean(axis=1)
        u, sigma = _left_singular(columns - mean[:, None], max_rank)
        u, sigma = _truncate(u, sigma, max_rank)
        return cls(u, sigma, mean, float(columns.shape[1]))

    def update(self, columns: np.ndarray, max_rank: int, forgetting: float) -> "IncrementalSVD":
        """Sequential KL update with a new batch of columns (``sklm`` with mean update).

        Parameters
        ----------
        columns : (d, q) ndarray
        max_rank : int
        forgetting : float
            Forgetting factor in (0, 1]; 1 reproduces the batch SVD of all columns.
        """
        q = columns.shape[1]
        n0 = self.count
        batch_mean = columns.mean(axis=1)
        # The mean-shift column makes the centred SVD of the union exact (sklm);
        # its weight uses n0 without the forgetting factor, as sklm does.
        shift = np.sqrt(q * n0 / (q + n0)) * (self.mean - batch_mean)
        augmented = np.concatenate([columns - batch_mean[:, None], shift[:, None]], axis=1)
        mean = (forgetting * n0 * self.mean + q * batch_mean) / (q + forgetting * n0)
        u0, sigma0 = self.basis, self.singular_values
        projection = u0.T @ augmented
        residual = augmented - u0 @ projection
        qbasis, _ = np.linalg.qr(residual)
        # Re-orthogonalise once: the residual can be tiny and lose orthogonality to u0.
        qbasis -= u0 @ (u0.T @ qbasis)
        qbasis, _ = np.linalg.qr(qbasis)
        k0 = sigma0.shape[0]
        r = np.zeros((k0 + qbasis.shape[1], k0 + augmented.shape[1]))
        r[:k0, :k0] = forgetting * np.diag(sigma0)
        r[:k0, k0:] = projection
        r[k0:, k0:] = qbasis.T @ residual
        ut, st, _ = np.linalg.svd(r, full_matrices=False)
        u, sigma = _truncate(np.concatenate([u0, qbasis], axis=1) @ ut, st, max_rank)
        return IncrementalSVD(u, sigma, mean, q + forgetting * n0)


def _left_singular(x: np.ndarray, max_rank: int) -> tuple[np.ndarray, np.ndarray]:
    """Leading left singular vectors and all singular values of ``x``, through the eigen-decomposition
    of its smaller Gram matrix.

    The negative model refits unfoldings such as 50 x 5000 and 1250 x 200 on
    every accepted frame; the Gram route is several times faster than a thin
    SVD there. Squaring the spectrum costs accuracy only for singular values
    far below the ``_ENERGY_CUTOFF`` that truncation drops anyway. Only the
    first ``max_rank`` vectors are returned (all singular values are, for the
    energy cutoff): :func:`_truncate` keeps no more, and for 1250 x 200 forming
    the other 160 as ``X v / sigma`` took a third of the refit.
    """
    d, q = x.shape
    if d <= q:
        energy, u = np.linalg.eigh(x @ x.T)
        order = np.argsort(energy)[::-1]
        return u[:, order[:max_rank]], np.sqrt(np.maximum(energy[order], 0.0))
    energy, v = np.linalg.eigh(x.T @ x)
    order = np.argsort(energy)[::-1]
    energy, v = np.maximum(energy[order], 0.0), v[:, order]
    # Columns for (numerically) zero singular values cannot be recovered as X v / sigma; drop them.
    keep = energy > energy[0] * 1e-14 if energy.size and energy[0] > 0 else np.zeros(energy.shape, bool)
    sigma = np.sqrt(energy[keep])
    return (x @ v[:, keep][:, :max_rank]) / sigma[:max_rank], sigma


def _truncate(u: np.ndarray, sigma: np.ndarray, max_rank: int) -> tuple[np.ndarray, np.ndarray]:
    energy = sigma**2
    total = energy.sum()
    keep = int(np.count_nonzero(energy >= _ENERGY_CUTOFF * total)) if total > 0 else 0
    keep = max(1, min(keep, max_rank, sigma.shape[0]))
    return u[:, :keep], sigma[:keep]


def _truncated(svd: IncrementalSVD, rank: int) -> IncrementalSVD:
    if svd.basis.shape[1] <= rank:
        return svd
    return IncrementalSVD(svd.basis[:, :rank], svd.singular_values[:rank], svd.mean, svd.count)


def _unfold_codeword(stack: np.ndarray) -> np.ndarray:
    """(q, z, s) stack -> mode-1 unfolding (z, s q): every superpixel's code vector."""
    return stack.transpose(1, 0, 2).reshape(stack.shape[1], -1)


def _unfold_superpixel(stack: np.ndarray) -> np.ndarray:
    """(q, z, s) stack -> mode-2 unfolding (s, z q): every codeword's profile over superpixels."""
    return stack.transpose(2, 0, 1).reshape(stack.shape[2], -1)


def _unfold_sample(stack: np.ndarray) -> np.ndarray:
    """(q, z, s) stack -> (z s, q): one vectorised tensor per column (C order)."""
    return stack.reshape(stack.shape[0], -1).T


_UNFOLDINGS = (_unfold_codeword, _unfold_superpixel, _unfold_sample)
# The sample mode first: its fit (a 200 x 200 Gram matrix from 1250-long columns, for the negatives) takes
# about as long as the other two together, so it is taken first and the other thread fits those two meanwhile.
_MODE_ORDER = (2, 0, 1)


def _per_mode(solve) -> list:
    """``[solve(0), solve(1), solve(2)]``, the modes' independent fits run on the kernel threads.

    Each mode's result is computed exactly as alone; only the single-threaded BLAS work of two
    modes overlaps.
    """
    by_mode = dict(zip(_MODE_ORDER, map_on_threads(solve, _MODE_ORDER, numba.get_num_threads())))
    return [by_mode[mode] for mode in range(len(_MODE_ORDER))]


@dataclass(frozen=True)
class TensorSubspace:
    """A third-order tensor subspace: mode bases for codewords and superpixels, and a sample-mode basis.

    Attributes
    ----------
    codeword : IncrementalSVD
        Mode-1 basis ``U1 (z, R1)``.
    superpixel : IncrementalSVD
        Mode-2 basis ``U2 (s, R2)``.
    sample : IncrementalSVD
        Sample-mode basis ``V (z s, R3)``; its mean is the mean tensor ``M``.
    """

    codeword: IncrementalSVD
    superpixel: IncrementalSVD
    sample: IncrementalSVD

    @classmethod
    def fit(cls, stack: np.ndarray, ranks: tuple[int, int, int]) -> "TensorSubspace":
        """Batch fit (HOSVD with mean tensor) of a ``(q, z, s)`` stack of code tensors."""
        return cls(*_per_mode(lambda mode: IncrementalSVD.fit(_UNFOLDINGS[mode](stack), ranks[mode])))

    def update(self, stack: np.ndarray, ranks: tuple[int, int, int], forgetting: float) -> "TensorSubspace":
        """Incremental update of every mode with a new ``(q, z, s)`` stack (IRTSA)."""
        models = (self.codeword, self.superpixel, self.sample)
        return TensorSubspace(*_per_mode(
            lambda mode: models[mode].update(_UNFOLDINGS[mode](stack), ranks[mode], forgetting)))

    @property
    def ranks(self) -> tuple[int, int, int]:
        """Current ranks of the codeword, superpixel and sample-mode bases."""
        return (self.codeword.basis.shape[1], self.superpixel.basis.shape[1], self.sample.basis.shape[1])

    def truncated(self, ranks: tuple[int, int, int]) -> "TensorSubspace":
        """The same model keeping at most ``ranks`` leading basis vectors per mode (no refit).

        The bases are ordered by singular value, so the leading columns are the best
        rank-limited subspace of the data the model was fitted on.
        """
        if all(r >= k for r, k in zip(ranks, self.ranks)):
            return self
        return TensorSubspace(*(_truncated(svd, r)
                                for svd, r in zip((self.codeword, self.superpixel, self.sample), ranks)))

    @property
    def mean_tensor(self) -> np.ndarray:
        """(z, s) mean code tensor ``M``."""
        z = self.codeword.basis.shape[0]
        return self.sample.mean.reshape(z, -1)

    def errors(self, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Squared reconstruction errors of code tensors in modes 1-2 and in the sample mode.

        Parameters
        ----------
        codes : (N, z, s) ndarray

        Returns
        -------
        re_modes : (N,) ndarray
            ``||E - U1 U1^T E U2 U2^T||_F^2 = ||E||^2 - ||U1^T E U2||^2``, ``E = J - M``.
        re_sample : (N,) ndarray
            ``||e - V V^T e||^2 = ||e||^2 - ||V^T e||^2``, ``e = vec(E)``.
        """
        centred = codes - self.mean_tensor[None]
        energy = np.einsum("nij,nij->n", centred, centred)
        # U1^T (E U2) as two matrix products: E U2 for all tensors at once is one
        # (N z, s) x (s, R2) product; einsum's contraction took twice as long.
        n, z, s = codes.shape
        right = (centred.reshape(n * z, s) @ self.superpixel.basis).reshape(n, z, -1)
        core = np.matmul(self.codeword.basis.T, right)
        projected = centred.reshape(n, -1) @ self.sample.basis
        # Clip tiny negatives from cancellation: an error is a squared norm.
        re_modes = np.maximum(energy - np.einsum("nab,nab->n", core, core), 0.0)
        re_sample = np.maximum(energy - np.einsum("nk,nk->n", projected, projected), 0.0)
        return re_modes, re_sample


def reconstruction_error(model: TensorSubspace, codes: np.ndarray, *, gamma: float, mode: str) -> np.ndarray:
    """Reconstruction error of code tensors against a model (paper eqs. 5-7).

    Parameters
    ----------
    model : TensorSubspace
    codes : (N, z, s) ndarray
    gamma : float
        Weight of the modes-1-2 term.
    mode : {'paper', 'paper_literal', 'tpt_code'}
        ``paper``: ``gamma RE1 + (1 - gamma) RE2`` with squared norms;
        ``paper_literal``: RE1 counted twice, as eq. 5's sum over the two
        unfoldings literally reads; ``tpt_code``: ``0.5 sqrt(RE1) + sqrt(RE2)``
        as TPT's ``Evaluate.m`` (``docs/design/tracker.md``, "Reconstruction error and likelihood").

    Returns
    -------
    errors : (N,) ndarray
    """
    re_modes, re_sample = model.errors(codes)
    if mode == "paper":
        return gamma * re_modes + (1.0 - gamma) * re_sample
    if mode == "paper_literal":
        return gamma * 2.0 * re_modes + (1.0 - gamma) * re_sample
    if mode == "tpt_code":
        return 0.5 * np.sqrt(re_modes) + np.sqrt(re_sample)
    raise ValueError(f"re_mode must be one of {RE_MODES}, got {mode!r}")
