"""Colour conversions: reference constants, edge cases, and the compiled Lab against NumPy."""

from __future__ import annotations

import numpy as np
import pytest
from skimage.color import rgb2lab

from sptpt.color import rgb_to_hsi, rgb_to_lab, rgb_to_lab_templates


def test_lab_is_close_to_skimage_which_differs_only_in_the_white_point():
    rgb = np.random.default_rng(0).integers(0, 256, (20, 20, 3), dtype=np.uint8)
    np.testing.assert_allclose(rgb_to_lab(rgb), rgb2lab(rgb), atol=0.02)


@pytest.mark.parametrize("shape", [(3, 32, 32, 3), (1, 5, 7, 3)])
def test_compiled_lab_matches_the_numpy_reference(shape):
    rgb = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    rgb[0, 0, 0] = 0  # black: the linear branch of f(t)
    np.testing.assert_allclose(rgb_to_lab_templates(rgb), rgb_to_lab(rgb), rtol=0, atol=1e-10)


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
