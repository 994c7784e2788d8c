"""Colour conversions: reference constants, edge cases, and the compiled Lab against NumPy."""

from __future__ import annotations

import numpy as np
import pytest
from skimage.color import rgb2lab

from sptpt._kernels.color import MEMO_BITS, lab_image_memo, new_lab_memo
from sptpt.color import RGB_TO_XYZ, SRGB_TO_LINEAR, WHITE, rgb_to_hsi, rgb_to_lab, rgb_to_lab_templates


def test_lab_is_close_to_skimage_which_differs_only_in_the_white_point():
    rgb = np.random.default_rng(0).integers(0, 256, (20, 20, 3), dtype=np.uint8)
    np.testing.assert_allclose(rgb_to_lab(rgb), rgb2lab(rgb), atol=0.02)


@pytest.mark.parametrize("shape", [(3, 32, 32, 3), (1, 5, 7, 3)])
def test_compiled_lab_matches_the_numpy_reference(shape):
    rgb = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    rgb[0, 0, 0] = 0  # black: the linear branch of f(t)
    np.testing.assert_allclose(rgb_to_lab_templates(rgb), rgb_to_lab(rgb), rtol=0, atol=1e-10)


def test_memoised_lab_is_bit_identical_to_the_batch_kernel():
    # Enough colours to overwrite memo slots, then the same images again
    # (hits, and colours that were evicted), then a smooth image.
    rng = np.random.default_rng(4)
    side = 256
    assert side * side > (1 << MEMO_BITS) // 2
    images = [rng.integers(0, 256, (side, side, 3), dtype=np.uint8) for _ in range(2)]
    images += images[::-1] + [np.repeat(np.arange(256, dtype=np.uint8)[:, None, None], 3, axis=2)]
    memo = new_lab_memo()
    for image in images:
        out = np.empty(image.size, dtype=np.float64)
        lab_image_memo(image, SRGB_TO_LINEAR, RGB_TO_XYZ, WHITE, memo, out)
        expected = rgb_to_lab_templates(image[None])[0]
        np.testing.assert_array_equal(out.reshape(image.shape), expected)


def test_hsi_of_special_colours_follows_spt():
    hsi = rgb_to_hsi(np.array([[0, 0, 0], [128, 128, 128], [255, 0, 0], [0, 0, 255], [0, 255, 0]], np.uint8))
    np.testing.assert_allclose(hsi[0], [0.25, 1.0, 0.0])  # black: eps denominators, as SPT
    np.testing.assert_allclose(hsi[1], [0.0, 0.0, 128 / 255])  # gray: S = 0 -> H = 0
    np.testing.assert_allclose(hsi[2], [0.0, 1.0, 1 / 3], atol=1e-7)
    np.testing.assert_allclose(hsi[3], [2 / 3, 1.0, 1 / 3], atol=1e-7)
    np.testing.assert_allclose(hsi[4], [1 / 3, 1.0, 1 / 3], atol=1e-7)


def test_conversions_reject_non_uint8():
    with pytest.raises(TypeError, match="uint8"):
        rgb_to_lab(np.zeros((2, 2, 3)))
    with pytest.raises(TypeError, match="uint8"):
        rgb_to_hsi(np.zeros((2, 2, 3), np.int16))
