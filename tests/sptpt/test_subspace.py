"""Incremental SVD and tensor reconstruction errors against batch and explicit computations."""

from __future__ import annotations

import numpy as np
import pytest

from sptpt.subspace import IncrementalSVD, TensorSubspace, reconstruction_error


def test_incremental_svd_with_forgetting_one_equals_batch_svd():
    rng = np.random.default_rng(0)
    data = rng.standard_normal((30, 8)) @ rng.standard_normal((8, 40)) + rng.normal(0, 0.01, (30, 40))
    model = IncrementalSVD.fit(data[:, :10], max_rank=30)
    for start in range(10, 40, 5):
        model = model.update(data[:, start : start + 5], max_rank=30, forgetting=1.0)
    centred = data - data.mean(axis=1, keepdims=True)
    _, sigma, _ = np.linalg.svd(centred, full_matrices=False)
    k = model.singular_values.shape[0]
    np.testing.assert_allclose(model.singular_values, sigma[:k], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(model.mean, data.mean(axis=1), atol=1e-12)
    assert model.count == 40
    np.testing.assert_allclose(model.basis.T @ model.basis, np.eye(k), atol=1e-10)


def test_forgetting_weights_the_mean_toward_new_columns():
    old = np.zeros((3, 4))
    new = np.ones((3, 4))
    model = IncrementalSVD.fit(old + np.arange(4) * 1e-3, max_rank=3).update(new, max_rank=3, forgetting=0.5)
    # mean = (ff n0 mu0 + q muB) / (q + ff n0) = 4 / 6 for the unit entries
    np.testing.assert_allclose(model.mean, np.full(3, 4 / 6), atol=1e-3)
    assert model.count == 4 + 0.5 * 4


def test_truncation_keeps_at_most_max_rank():
    rng = np.random.default_rng(1)
    model = IncrementalSVD.fit(rng.standard_normal((20, 30)), max_rank=5)
    assert model.basis.shape == (20, 5)
    model = model.update(rng.standard_normal((20, 7)), max_rank=5, forgetting=0.9)
    assert model.basis.shape == (20, 5)


def explicit_errors(model: TensorSubspace, codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u1, u2, v = model.codeword.basis, model.superpixel.basis, model.sample.basis
    re1, re2 = [], []
    for j in codes:
        e = j - model.mean_tensor
        re1.append(np.linalg.norm(e - u1 @ u1.T @ e @ u2 @ u2.T) ** 2)
        vec = e.reshape(-1)
        re2.append(np.linalg.norm(vec - v @ (v.T @ vec)) ** 2)
    return np.array(re1), np.array(re2)


@pytest.mark.parametrize("ranks", [(4, 3, 5), (10, 5, 40)])
def test_closed_form_reconstruction_error_equals_explicit(ranks):
    rng = np.random.default_rng(2)
    stack = np.abs(rng.standard_normal((12, 10, 6)))
    model = TensorSubspace.fit(stack, ranks).update(np.abs(rng.standard_normal((5, 10, 6))), ranks, 0.9)
    codes = np.abs(rng.standard_normal((7, 10, 6)))
    re1, re2 = model.errors(codes)
    ref1, ref2 = explicit_errors(model, codes)
    np.testing.assert_allclose(re1, ref1, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(re2, ref2, rtol=1e-9, atol=1e-12)


def test_reconstruction_error_modes():
    rng = np.random.default_rng(3)
    model = TensorSubspace.fit(np.abs(rng.standard_normal((8, 6, 5))), (3, 2, 4))
    codes = np.abs(rng.standard_normal((4, 6, 5)))
    re1, re2 = model.errors(codes)
    np.testing.assert_allclose(reconstruction_error(model, codes, gamma=0.5, mode="paper"), 0.5 * re1 + 0.5 * re2)
    np.testing.assert_allclose(reconstruction_error(model, codes, gamma=0.5, mode="paper_literal"), re1 + 0.5 * re2)
    np.testing.assert_allclose(
        reconstruction_error(model, codes, gamma=0.5, mode="tpt_code"), 0.5 * np.sqrt(re1) + np.sqrt(re2)
    )
    with pytest.raises(ValueError, match="re_mode"):
        reconstruction_error(model, codes, gamma=0.5, mode="nope")


def test_training_samples_reconstruct_better_than_others():
    rng = np.random.default_rng(4)
    basis = np.abs(rng.standard_normal((3, 8, 5)))
    stack = np.einsum("qk,kzs->qzs", np.abs(rng.standard_normal((20, 3))), basis)
    model = TensorSubspace.fit(stack, (8, 5, 10))
    inside = np.einsum("qk,kzs->qzs", np.abs(rng.standard_normal((5, 3))), basis)
    outside = np.abs(rng.standard_normal((5, 8, 5))) * stack.std()

    def err(c):
        return reconstruction_error(model, c, gamma=0.5, mode="paper")

    assert err(inside).max() < err(outside).min()


@pytest.mark.parametrize("shape", [(50, 300), (300, 40), (20, 20)])
def test_batch_fit_matches_a_thin_svd(shape):
    rng = np.random.default_rng(5)
    data = np.abs(rng.standard_normal(shape)) * (rng.random(shape) < 0.2)
    model = IncrementalSVD.fit(data, max_rank=15)
    centred = data - data.mean(axis=1, keepdims=True)
    u, sigma, _ = np.linalg.svd(centred, full_matrices=False)
    k = model.singular_values.shape[0]
    np.testing.assert_allclose(model.singular_values, sigma[:k], rtol=1e-9)
    # Same subspace: the projectors agree (singular vectors are defined up to sign).
    np.testing.assert_allclose(model.basis @ model.basis.T, u[:, :k] @ u[:, :k].T, atol=1e-8)


@pytest.mark.parametrize("ranks", [(3, 2, 4), (40, 1, 2), (1, 5, 40)])
def test_truncated_model_equals_a_fit_with_those_ranks_and_the_explicit_projection(ranks):
    rng = np.random.default_rng(4)
    stack = np.abs(rng.standard_normal((30, 10, 6)))
    full = TensorSubspace.fit(stack, (10, 6, 30))
    small = full.truncated(ranks)
    assert small.ranks == tuple(min(r, k) for r, k in zip(ranks, full.ranks))
    codes = np.abs(rng.standard_normal((7, 10, 6)))
    re1, re2 = small.errors(codes)
    ref1, ref2 = explicit_errors(small, codes)
    np.testing.assert_allclose(re1, ref1, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(re2, ref2, rtol=1e-9, atol=1e-12)
    # Leading singular vectors are the rank-limited fit (projections do not depend on their signs).
    fitted1, fitted2 = TensorSubspace.fit(stack, ranks).errors(codes)
    np.testing.assert_allclose(re1, fitted1, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(re2, fitted2, rtol=1e-8, atol=1e-10)
    assert full.truncated(full.ranks) is full
