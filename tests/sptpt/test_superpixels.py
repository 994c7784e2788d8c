"""SNIC superpixels: seeding, kernel == reference, invariants, errors.

See ``docs/design/tracker.md``, "SNIC superpixels".
"""

from __future__ import annotations

import heapq

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from sptpt._kernels.color import MEMO_BITS
from sptpt._kernels.snic import snic_batch, snic_batch_rgb, snic_image
from sptpt.color import RGB_TO_XYZ, SRGB_TO_LINEAR, WHITE, rgb_to_lab, rgb_to_lab_templates
from sptpt.superpixels import seed_grid, snic, snic_lab

# ---------------------------------------------------------------------------
# Reference: a slow, obviously-correct transcription of runSNIC
# ---------------------------------------------------------------------------


def reference_snic(lab: np.ndarray, seeds: np.ndarray, compactness: float) -> np.ndarray:
    """Official runSNIC with heapq and (d, counter) keys; same arithmetic as the kernel."""
    height, width = lab.shape[:2]
    n_pixels = height * width
    n_seeds = len(seeds)
    spatial_weight = (compactness * compactness * n_seeds) / n_pixels
    pixels = [tuple(float(v) for v in lab[y, x]) for y in range(height) for x in range(width)]
    labels = [-1] * n_pixels
    sums = [[0.0] * 6 for _ in range(n_seeds)]  # L, a, b, x, y, count
    queue: list[tuple[float, int, int, int]] = []
    counter = 0
    for k, (row, col) in enumerate(seeds):
        heapq.heappush(queue, (0.0, counter, int(row) * width + int(col), k))
        counter += 1
    while queue:
        _, _, p, k = heapq.heappop(queue)
        if labels[p] >= 0:
            continue
        labels[p] = k
        y, x = divmod(p, width)
        acc = sums[k]
        acc[0] += pixels[p][0]
        acc[1] += pixels[p][1]
        acc[2] += pixels[p][2]
        acc[3] += x
        acc[4] += y
        acc[5] += 1.0
        for dx, dy in ((-1, 0), (0, -1), (1, 0), (0, 1)):  # left, up, right, down
            xx, yy = x + dx, y + dy
            if not (0 <= xx < width and 0 <= yy < height):
                continue
            q = yy * width + xx
            if labels[q] >= 0:
                continue
            n = acc[5]
            ldiff = acc[0] - pixels[q][0] * n
            adiff = acc[1] - pixels[q][1] * n
            bdiff = acc[2] - pixels[q][2] * n
            xdiff = acc[3] - xx * n
            ydiff = acc[4] - yy * n
            colordist = ldiff * ldiff + adiff * adiff + bdiff * bdiff
            xydist = xdiff * xdiff + ydiff * ydiff
            d = (colordist + xydist * spatial_weight) / (n * n)
            heapq.heappush(queue, (d, counter, q, k))
            counter += 1
    assert min(labels) >= 0  # the official fill pass is never needed
    return np.array(labels, dtype=np.int32).reshape(height, width)


# ---------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------


def smooth_noisy(rng: np.random.Generator, height: int, width: int, noise: float = 12.0) -> np.ndarray:
    """A template-like image: a few colour blobs plus noise, uint8 RGB."""
    yy, xx = np.mgrid[0:height, 0:width]
    image = np.zeros((height, width, 3))
    for _ in range(4):
        cy, cx = rng.uniform(0, height), rng.uniform(0, width)
        radius = rng.uniform(1.5, max(3.0, height / 2, width / 2))
        blob = np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * radius**2))
        image += blob[..., None] * rng.uniform(0, 255, 3)
    image = image / max(image.max(), 1e-9) * 230 + rng.normal(0, noise, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def quadrants(height: int, width: int) -> np.ndarray:
    colours = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0]], dtype=np.uint8)
    image = np.empty((height, width, 3), dtype=np.uint8)
    h2, w2 = height // 2, width // 2
    image[:h2, :w2], image[:h2, w2:], image[h2:, :w2], image[h2:, w2:] = colours
    return image


def structured(kind: str, height: int, width: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:height, 0:width]
    if kind == "flat":  # every colour distance 0: ties everywhere
        return np.full((height, width, 3), 128, dtype=np.uint8)
    if kind == "checker":  # two colours, many exact ties
        mask = ((yy + xx) % 2).astype(bool)
        return np.where(mask[..., None], np.uint8([200, 60, 30]), np.uint8([30, 90, 200])).astype(np.uint8)
    if kind == "stripes":
        return np.stack([(xx // 3 % 2) * 255, (yy * 7) % 256, np.full_like(xx, 90)], -1).astype(np.uint8)
    if kind == "gradient":
        return np.stack([xx * 255 // max(width - 1, 1), yy * 255 // max(height - 1, 1), (xx + yy) % 256], -1).astype(
            np.uint8
        )
    if kind == "noise":
        return rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    if kind == "smooth":
        return smooth_noisy(rng, height, width)
    raise AssertionError(kind)


KINDS = ["flat", "checker", "stripes", "gradient", "noise", "smooth"]


def check_invariants(labels: np.ndarray, seeds: np.ndarray) -> None:
    """Every label 0..s-1 present, sizes sum to N, each superpixel 4-connected, seed k owns label k."""
    n_seeds = len(seeds)
    assert labels.dtype == np.int32
    counts = np.bincount(labels.ravel(), minlength=n_seeds)
    assert counts.size == n_seeds and labels.min() == 0
    assert np.all(counts >= 1)
    assert counts.sum() == labels.size
    np.testing.assert_array_equal(labels[seeds[:, 0], seeds[:, 1]], np.arange(n_seeds))
    for k in range(n_seeds):
        _, n_components = ndimage.label(labels == k)  # default structure: 4-connectivity
        assert n_components == 1, f"superpixel {k} has {n_components} pieces"


# ---------------------------------------------------------------------------
# Seeding
# ---------------------------------------------------------------------------


def test_official_seeds_32x32_k30_are_a_5x5_grid_from_3_to_27() -> None:
    seeds = seed_grid(32, 32, 30)
    grid = np.array([3, 9, 15, 21, 27])
    expected = np.stack(np.meshgrid(grid, grid, indexing="ij"), -1).reshape(-1, 2)
    assert seeds.dtype == np.int64
    np.testing.assert_array_equal(seeds, expected)


def test_exact_seeds_32x32_k30_are_5_rows_by_6_cols() -> None:
    seeds = seed_grid(32, 32, 30, seeding="exact")
    assert seeds.shape == (30, 2) and seeds.dtype == np.int64
    rows = np.array([(2 * i + 1) * 32 // 10 for i in range(5)])  # floor((i + 0.5) * 32 / 5)
    cols = np.array([(2 * j + 1) * 32 // 12 for j in range(6)])  # floor((j + 0.5) * 32 / 6)
    np.testing.assert_array_equal(np.unique(seeds[:, 0]), rows)
    np.testing.assert_array_equal(np.unique(seeds[:, 1]), cols)
    np.testing.assert_array_equal(seeds[:6, 0], 3)  # raster order, rows outer


@pytest.mark.parametrize(
    ("height", "width", "k", "shape"),
    [
        (32, 32, 30, (5, 6)),
        (64, 32, 30, (6, 5)),  # tall image: more rows
        (32, 64, 8, (2, 4)),  # 2:1 image, 2 x 4 is exact
        (32, 32, 4, (2, 2)),
        (32, 32, 7, (1, 7)),  # prime: the only fitting factorisation
    ],
)
def test_exact_grid_shape_follows_the_image_aspect(height: int, width: int, k: int, shape: tuple[int, int]) -> None:
    seeds = seed_grid(height, width, k, seeding="exact")
    assert (np.unique(seeds[:, 0]).size, np.unique(seeds[:, 1]).size) == shape


def test_official_seeding_takes_half_step_before_the_step_decrement() -> None:
    # 32 x 32, K = 13: g = 9 gives 9 seeds (error 4), g = 8 gives 16 (error 3),
    # so g becomes 8 while half stays floor(9 / 2) = 4.
    seeds = seed_grid(32, 32, 13)
    grid = np.array([4, 12, 20, 28])
    np.testing.assert_array_equal(seeds, np.stack(np.meshgrid(grid, grid, indexing="ij"), -1).reshape(-1, 2))


def test_official_seeding_returns_only_placed_seeds() -> None:
    # 27 x 4, K = 8: g = 3 allows 1 x 9 seeds but only rows 2..23 pass
    # y <= H - half; snic_mex would pad the 9th seed at (0, 0).
    seeds = seed_grid(27, 4, 8)
    np.testing.assert_array_equal(seeds, np.stack([np.arange(2, 24, 3), np.full(8, 2)], -1))


@settings(max_examples=60, deadline=None)
@given(
    height=st.integers(1, 48),
    width=st.integers(1, 48),
    k=st.integers(1, 80),
    seeding=st.sampled_from(["official", "exact"]),
)
def test_seeds_are_distinct_inside_and_in_raster_order(height: int, width: int, k: int, seeding: str) -> None:
    try:
        seeds = seed_grid(height, width, k, seeding=seeding)
    except ValueError as error:
        # Too many segments, no fitting factorisation, or an official grid
        # step longer than a side.
        assert k > height * width or seeding == "exact" or "places no seed" in str(error)
        return
    assert seeds.ndim == 2 and seeds.shape[1] == 2 and len(seeds) >= 1
    assert np.all(seeds >= 0) and np.all(seeds[:, 0] < height) and np.all(seeds[:, 1] < width)
    flat = seeds[:, 0] * width + seeds[:, 1]
    assert np.all(np.diff(flat) > 0)
    if seeding == "exact":
        assert len(seeds) == k


# ---------------------------------------------------------------------------
# Kernel == reference
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(
    ("height", "width", "k", "seeding"),
    [
        (32, 32, 30, "official"),
        (32, 32, 30, "exact"),
        (17, 23, 12, "official"),
        (24, 40, 15, "exact"),
        (29, 29, 30, "official"),  # staggered official grid
        (9, 5, 45, "official"),  # one seed per pixel
    ],
)
def test_kernel_equals_reference(kind: str, height: int, width: int, k: int, seeding: str) -> None:
    image = structured(kind, height, width)
    seeds = seed_grid(height, width, k, seeding=seeding)
    # snic() converts with the compiled Lab; feed the reference the same values so
    # that exact ties are broken on identical numbers.
    lab = rgb_to_lab_templates(image[None])[0]
    expected = reference_snic(lab, seeds, 20.0)
    spatial_weight = (20.0 * 20.0 * len(seeds)) / (height * width)
    np.testing.assert_array_equal(snic_image(lab, seeds, spatial_weight), expected)
    np.testing.assert_array_equal(snic(image, n_segments=k, seeding=seeding), expected)
    check_invariants(expected, seeds)


@settings(max_examples=40, deadline=None)
@given(
    height=st.integers(1, 20),
    width=st.integers(1, 20),
    k=st.integers(1, 30),
    compactness=st.sampled_from([0.0, 1.0, 10.0, 20.0, 40.0]),
    seeding=st.sampled_from(["official", "exact"]),
    seed=st.integers(0, 2**32 - 1),
    smooth=st.booleans(),
)
def test_kernel_equals_reference_random(
    height: int, width: int, k: int, compactness: float, seeding: str, seed: int, smooth: bool
) -> None:
    rng = np.random.default_rng(seed)
    if smooth:
        image = smooth_noisy(rng, height, width)
    else:  # few distinct colours: exact distance ties are common
        image = rng.choice(np.array([0, 128, 255], dtype=np.uint8), size=(height, width, 3))
    try:
        seeds = seed_grid(height, width, k, seeding=seeding)
    except ValueError:
        return
    labels = snic(image, n_segments=k, compactness=compactness, seeding=seeding)
    expected = reference_snic(rgb_to_lab_templates(image[None])[0], seeds, compactness)
    np.testing.assert_array_equal(labels, expected)
    check_invariants(labels, seeds)


# ---------------------------------------------------------------------------
# Exact answers and properties
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("height", "width", "seeding"),
    [(32, 32, "official"), (48, 48, "official"), (32, 32, "exact"), (32, 48, "exact"), (24, 40, "exact")],
)
def test_four_quadrants_give_four_quadrant_labels(seeding: str, height: int, width: int) -> None:
    labels = snic(quadrants(height, width), n_segments=4, seeding=seeding)
    expected = np.zeros((height, width), dtype=np.int32)
    expected[: height // 2, width // 2 :] = 1
    expected[height // 2 :, : width // 2] = 2
    expected[height // 2 :, width // 2 :] = 3
    np.testing.assert_array_equal(labels, expected)


def test_official_32x32_template_gives_25_connected_superpixels() -> None:
    image = smooth_noisy(np.random.default_rng(3), 32, 32)
    labels = snic(image)  # paper defaults: K = 30, M = 20, official seeding
    assert labels.shape == (32, 32) and labels.dtype == np.int32
    check_invariants(labels, seed_grid(32, 32, 30))
    assert labels.max() == 24


def test_deterministic_and_batch_equals_per_image() -> None:
    rng = np.random.default_rng(11)
    batch = np.stack([smooth_noisy(rng, 32, 32) for _ in range(9)] + [structured("checker", 32, 32)])
    first = snic(batch)
    assert first.shape == (10, 32, 32) and first.dtype == np.int32
    np.testing.assert_array_equal(snic(batch), first)
    np.testing.assert_array_equal(np.stack([snic(image) for image in batch]), first)


def test_thread_count_does_not_change_labels() -> None:
    rng = np.random.default_rng(5)
    batch = np.stack([smooth_noisy(rng, 32, 32) for _ in range(7)])
    lab = rgb_to_lab(batch)
    seeds = seed_grid(32, 32, 30)
    weight = (20.0 * 20.0 * len(seeds)) / 1024
    # n_chunks splits the batch into the ranges the threads run.
    results = [snic_batch(lab, seeds, weight, n_chunks) for n_chunks in (1, 2, 3, 7, 50)]
    for labels in results[1:]:
        np.testing.assert_array_equal(labels, results[0])
    previous = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        np.testing.assert_array_equal(snic(batch), results[0])
    finally:
        numba.set_num_threads(previous)
    np.testing.assert_array_equal(snic(batch), results[0])


@pytest.mark.parametrize("n_chunks", [1, 2, 3])
def test_fused_rgb_kernel_equals_lab_kernel_bit_for_bit(n_chunks: int) -> None:
    # More distinct colours than memo slots, so that slots are overwritten and
    # colours come back after eviction; plus smooth templates that repeat
    # colours, as the tracker's do.
    rng = np.random.default_rng(17)
    n_noisy = 2 * (1 << MEMO_BITS) // (32 * 32) + 1
    noisy = rng.integers(0, 256, (n_noisy, 32, 32, 3), dtype=np.uint8)
    smooth = np.stack([smooth_noisy(rng, 32, 32) for _ in range(20)])
    batch = np.concatenate([smooth[:10], noisy, smooth[10:], smooth[:5]])
    seeds = seed_grid(32, 32, 30)
    weight = (20.0 * 20.0 * len(seeds)) / 1024
    expected = snic_batch(rgb_to_lab_templates(batch), seeds, weight, n_chunks)
    labels = snic_batch_rgb(batch, seeds, weight, n_chunks, SRGB_TO_LINEAR, RGB_TO_XYZ, WHITE)
    np.testing.assert_array_equal(labels, expected)


def test_snic_lab_matches_snic_and_accepts_a_single_image() -> None:
    image = smooth_noisy(np.random.default_rng(2), 20, 30)
    seeds = seed_grid(20, 30, 12, seeding="exact")
    labels = snic_lab(rgb_to_lab(image), seeds, compactness=10.0)
    np.testing.assert_array_equal(labels, snic(image, n_segments=12, compactness=10.0, seeding="exact"))
    assert snic_lab(rgb_to_lab(image[None]), seeds).shape == (1, 20, 30)


def test_fill_pass_labels_pixels_no_seed_reached() -> None:
    # Unreachable with real seeds (the 4-grid is connected); without seeds
    # every pixel goes through the official fill pass.
    labels = snic_image(np.zeros((4, 5, 3)), np.zeros((0, 2), dtype=np.int64), 0.0)
    np.testing.assert_array_equal(labels, np.zeros((4, 5), dtype=np.int32))


def test_empty_batch() -> None:
    assert snic(np.zeros((0, 32, 32, 3), dtype=np.uint8)).shape == (0, 32, 32)


# ---------------------------------------------------------------------------
# Errors name the argument
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("images", "error", "match"),
    [
        ([[[0, 0, 0]]], TypeError, "images"),
        (np.zeros((32, 32, 3), dtype=np.float64), TypeError, "images.*uint8"),
        (np.zeros((32, 32), dtype=np.uint8), ValueError, "images.*grayscale"),
        (np.zeros((32, 32, 4), dtype=np.uint8), ValueError, "images"),
        (np.zeros((2, 2, 32, 32, 3), dtype=np.uint8), ValueError, "images"),
        (np.zeros((0, 32, 3), dtype=np.uint8), ValueError, "images"),
    ],
)
def test_bad_images(images: object, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        snic(images)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"n_segments": 0}, ValueError, "n_segments"),
        ({"n_segments": 2.5}, TypeError, "n_segments"),
        ({"n_segments": True}, TypeError, "n_segments"),
        ({"n_segments": 1025}, ValueError, "n_segments.*pixels"),
        ({"compactness": -1.0}, ValueError, "compactness"),
        ({"compactness": float("nan")}, ValueError, "compactness"),
        ({"compactness": "20"}, TypeError, "compactness"),
        ({"seeding": "grid"}, ValueError, "seeding"),
        ({"n_segments": 37, "seeding": "exact"}, ValueError, "n_segments=37"),
    ],
)
def test_bad_parameters(kwargs: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        snic(np.zeros((32, 32, 3), dtype=np.uint8), **kwargs)


@pytest.mark.parametrize(
    ("seeds", "match"),
    [
        (np.array([[3, 3], [3, 3]]), "distinct"),
        (np.array([[3, 40]]), "inside"),
        (np.array([[-1, 0]]), "inside"),
        (np.zeros((0, 2), dtype=np.int64), "seeds"),
        (np.array([[1.0, 2.0]]), "seeds"),
    ],
)
def test_snic_lab_rejects_bad_seeds(seeds: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        snic_lab(np.zeros((32, 32, 3)), seeds)


def test_images_beyond_the_packed_key_range_are_rejected() -> None:
    # A broadcast view: 2**14 x 2**14 pixels without the memory.
    huge = np.broadcast_to(np.zeros((1, 1, 3), dtype=np.uint8), (1 << 14, 1 << 14, 3))
    with pytest.raises(ValueError, match="at most"):
        snic(huge)
    with pytest.raises(ValueError, match="at most"):
        snic_lab(np.broadcast_to(np.zeros((1, 1, 3)), (1 << 14, 1 << 14, 3)), np.array([[0, 0]]))


def test_seed_grid_rejects_bad_sizes() -> None:
    with pytest.raises(ValueError, match="height"):
        seed_grid(0, 32, 4)
    with pytest.raises(TypeError, match="width"):
        seed_grid(32, 32.0, 4)  # type: ignore[arg-type]


def test_kernel_pool_survives_fork() -> None:
    """A child forked after the kernel threads started still runs batches in parallel."""
    import multiprocessing as mp

    images = np.random.default_rng(0).integers(0, 256, size=(6, 12, 12, 3), dtype=np.uint8)
    want = snic(images, n_segments=9)
    with mp.get_context("fork").Pool(1) as pool:
        got = pool.apply_async(_snic_two_threads, (images,)).get(timeout=120)
    np.testing.assert_array_equal(got, want)


def _snic_two_threads(images: np.ndarray) -> np.ndarray:
    from sptpt._kernels import run_in_chunks  # noqa: F401 - the pool lives there
    from sptpt._kernels.snic import snic_batch_rgb
    from sptpt.color import RGB_TO_XYZ, SRGB_TO_LINEAR, WHITE
    from sptpt.superpixels import _spatial_weight, seed_grid

    seeds = seed_grid(12, 12, 9)
    return snic_batch_rgb(images, seeds, _spatial_weight(20.0, len(seeds), 12, 12), 2,
                          SRGB_TO_LINEAR, RGB_TO_XYZ, WHITE)
