"""DSST's correlation filter (``sptpt.correlation``): exact answers on circularly shifted samples, the running
average, and the errors of its public door."""

from __future__ import annotations

import numpy as np
import pytest

from sptpt.correlation import CorrelationFilter


def gaussian_label(shape: tuple[int, ...], sigma: float = 1.5) -> np.ndarray:
    """A Gaussian peaking at index 0 along every axis, wrapping around (as DSST's labels do)."""
    grids = np.meshgrid(*[(np.arange(n) + n // 2) % n - n // 2 for n in shape], indexing="ij")
    return np.exp(-0.5 * sum(g.astype(float) ** 2 for g in grids) / sigma**2)


def flat_filter(shape: tuple[int, ...], learning_rate: float = 0.025) -> CorrelationFilter:
    """A filter with a window of ones, so that a circular shift of a sample is a phase change of its spectrum."""
    return CorrelationFilter(gaussian_label(shape), np.ones(shape), learning_rate=learning_rate, regularisation=0.01)


@pytest.mark.parametrize("shape, shift", [((33,), (5,)), ((33,), (-7,)), ((16, 16), (3, -2)), ((12, 20), (0, 6))])
def test_the_response_peaks_where_the_sample_has_moved(shape, shift):
    rng = np.random.default_rng(0)
    features = rng.standard_normal((4, *shape))
    filt = flat_filter(shape)
    filt.learn(filt.spectrum(features))
    assert np.unravel_index(np.argmax(filt.response(filt.spectrum(features))), shape) == (0,) * len(shape)
    moved = np.roll(features, shift, axis=tuple(range(1, 1 + len(shape))))
    peak = np.unravel_index(np.argmax(filt.response(filt.spectrum(moved))), shape)
    assert peak == tuple(s % n for s, n in zip(shift, shape))


def test_the_response_to_the_training_sample_is_nearly_the_label():
    # y = IFFT(G |F|^2 / (|F|^2 + lambda)): the label where the sample has energy far above lambda.
    shape = (8, 8)
    features = np.random.default_rng(1).standard_normal((3, *shape)) * 100
    filt = flat_filter(shape)
    filt.learn(filt.spectrum(features))
    np.testing.assert_allclose(filt.response(filt.spectrum(features)), gaussian_label(shape), atol=1e-4)


def test_blend_is_a_running_average_of_the_samples_filters():
    shape = (10,)
    rng = np.random.default_rng(2)
    first, second, probe = (rng.standard_normal((2, *shape)) for _ in range(3))
    blended = flat_filter(shape, learning_rate=0.25)
    blended.learn(blended.spectrum(first))
    blended.blend(blended.spectrum(second))
    # The same running average by hand: A and B of each sample alone, weighted 3/4 and 1/4.
    label = np.fft.fft(gaussian_label(shape))
    spectra = [np.fft.fft(x, axis=-1) for x in (first, second)]
    numerator = sum(w * np.conj(label)[None] * f for w, f in zip((0.75, 0.25), spectra))
    denominator = sum(w * (np.abs(f) ** 2).sum(axis=0) for w, f in zip((0.75, 0.25), spectra))
    z = np.fft.fft(probe, axis=-1)
    expected = np.fft.ifft((np.conj(numerator) * z).sum(axis=0) / (denominator + 0.01)).real
    np.testing.assert_allclose(blended.response(blended.spectrum(probe)), expected, rtol=1e-12, atol=1e-12)


def test_blend_at_rate_one_forgets_the_past():
    shape = (6, 6)
    rng = np.random.default_rng(3)
    old, new, probe = (rng.standard_normal((2, *shape)) for _ in range(3))
    forgetful, fresh = flat_filter(shape, learning_rate=1.0), flat_filter(shape, learning_rate=1.0)
    forgetful.learn(forgetful.spectrum(old))
    forgetful.blend(forgetful.spectrum(new))
    fresh.learn(fresh.spectrum(new))
    assert np.array_equal(forgetful.response(forgetful.spectrum(probe)), fresh.response(fresh.spectrum(probe)))


def test_the_window_weighs_every_channel_before_the_transform():
    shape = (9,)
    window = np.hanning(9)
    filt = CorrelationFilter(gaussian_label(shape), window, learning_rate=0.1, regularisation=0.01)
    features = np.arange(18.0).reshape(2, 9)
    np.testing.assert_allclose(filt.spectrum(features), np.fft.fft(features * window[None], axis=1))


def test_responding_or_blending_before_learning_is_an_error():
    filt = flat_filter((5,))
    assert not filt.learned
    spectrum = filt.spectrum(np.ones((1, 5)))
    with pytest.raises(RuntimeError, match=r"response\(\) before learn\(\)"):
        filt.response(spectrum)
    with pytest.raises(RuntimeError, match=r"blend\(\) before learn\(\)"):
        filt.blend(spectrum)
    filt.learn(spectrum)
    assert filt.learned


@pytest.mark.parametrize("label, window, rate, regularisation, match", [
    (np.ones(5), np.ones(6), 0.1, 0.01, "same 1-D or 2-D shape"),
    (np.ones((2, 2, 2)), np.ones((2, 2, 2)), 0.1, 0.01, "same 1-D or 2-D shape"),
    (np.ones(5), np.ones(5), 0.0, 0.01, r"learning_rate must lie in \(0, 1\], got 0.0"),
    (np.ones(5), np.ones(5), 1.5, 0.01, "learning_rate"),
    (np.ones(5), np.ones(5), 0.1, 0.0, "regularisation must be finite and > 0, got 0.0"),
    (np.ones(5), np.ones(5), 0.1, np.inf, "regularisation must be finite and > 0, got inf"),
])
def test_bad_arguments_are_named(label, window, rate, regularisation, match):
    with pytest.raises(ValueError, match=match):
        CorrelationFilter(label, window, learning_rate=rate, regularisation=regularisation)


def test_samples_of_other_axes_or_channels_are_refused_not_broadcast():
    filt = flat_filter((5,))
    with pytest.raises(ValueError, match=r"features must have shape \(d, 5\), got \(3, 1\)"):
        filt.spectrum(np.ones((3, 1)))
    with pytest.raises(ValueError, match=r"spectrum must have shape \(d, 5\), got \(5,\)"):
        filt.learn(np.ones(5, dtype=complex))
    filt.learn(filt.spectrum(np.ones((3, 5))))
    with pytest.raises(ValueError, match=r"spectrum must have shape \(3, 5\), got \(1, 5\)"):
        filt.response(filt.spectrum(np.ones((1, 5))))
    with pytest.raises(ValueError, match=r"spectrum must have shape \(3, 5\), got \(2, 5\)"):
        filt.blend(filt.spectrum(np.ones((2, 5))))
    with pytest.raises(ValueError, match=r"spectrum must have shape \(3, 5\), got \(3, 4\)"):
        filt.response([[1, 2, 3, 4]] * 3)  # a list is read as an array, then refused by its shape
    square = flat_filter((8, 8))
    with pytest.raises(ValueError, match=r"features must have shape \(d, 8, 8\), got \(2, 8, 4\)"):
        square.spectrum(np.ones((2, 8, 4)))
    with pytest.raises(ValueError, match=r"spectrum must have shape \(d, 8, 8\), got \(8, 8\)"):
        square.learn(np.ones((8, 8), dtype=complex))


def test_learning_again_forgets_the_channel_count_too():
    filt = flat_filter((5,))
    filt.learn(filt.spectrum(np.ones((3, 5))))
    filt.learn(filt.spectrum(np.arange(10.0).reshape(2, 5)))  # learn() forgets the earlier filter, whatever its d
    assert filt.numerator.shape == (2, 5)
    assert filt.response(filt.spectrum(np.ones((2, 5)))).shape == (5,)


def test_the_window_is_the_filters_own_copy():
    window = np.hanning(7)
    filt = CorrelationFilter(gaussian_label((7,)), window, learning_rate=0.1, regularisation=0.01)
    before = filt.spectrum(np.ones((1, 7)))
    window[:] = 0.0
    assert np.array_equal(filt.spectrum(np.ones((1, 7))), before)
