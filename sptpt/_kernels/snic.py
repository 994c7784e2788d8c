"""SNIC region growing (Achanta & Suesstrunk, CVPR 2017) as numba kernels.

Reproduces ``runSNIC`` of the official MATLAB ``snic_mex.cpp``
(``docs/design/tracker.md``, "Region growing"), with ties on distance broken
by insertion order so that the result is deterministic
(``std::priority_queue`` leaves them implementation-defined). The tests compare it label for label with a plain
``heapq`` transcription of the official loop.

Priority queue. The official queue holds duplicates: every labelled pixel
pushes each unlabelled 4-neighbour, and a pop of an already labelled pixel is
discarded. Only the smallest entry of a pixel can ever label it, so keeping
one entry per unlabelled pixel -- its smallest ``(distance, counter)`` so
far -- and lowering it when a smaller distance arrives (a later push always
has a larger counter, so it wins only on a strictly smaller distance) gives
the same sequence of labelling pops, the same labels and the same running
centroids. The counter still advances on every would-be push, so ties
compare exactly as in the duplicate queue. This halves the number of pops
and keeps the heap at the size of the growth front (~200 entries on a 32 x 32
template instead of ~700). The heap is 4-ary (half the depth of a binary
heap) and stored as two parallel arrays: the distance, and one int64
``counter << 32 | pixel``. Counters are unique, so comparing the packed keys
compares the counters, and the pixel rides along without a third array (one
load and store fewer per heap move). This bounds images to fewer than 2**28
pixels (counter < 4 N + s < 2**30); ``sptpt.superpixels`` checks it. See
``docs/design/tracker.md``, "Where the time goes", for the budget.

No validation and no defaults here; ``sptpt.superpixels`` is the public door.
"""

from __future__ import annotations

import threading

import numba
import numpy as np

from sptpt._kernels import run_in_chunks
from sptpt._kernels.color import lab_image_memo, new_lab_memo

# Heap position codes in ``pos`` besides a slot index >= 0.
_UNSEEN = -1  # not in the heap and not labelled
_LABELLED = -2
# Key of the padding slots behind the heap end: larger than any real key, so
# the 4-way child choice needs no bounds test.
_PAD_COUNTER = 1 << 62
# Low half of a packed heap key: the pixel.
_PIXEL_MASK = (1 << 32) - 1
#: Largest image (pixels) the packed keys can hold.
MAX_PIXELS = (1 << 28) - 1


@numba.njit(cache=True, inline="always")
def _u(i):  # pragma: no cover - compiled
    """An index known to be >= 0, as uint64: numba then skips the negative-index wraparound."""
    return np.uint64(i)


@numba.njit(cache=True, inline="always")
def _before(d1, c1, d2, c2):  # pragma: no cover - compiled
    """Heap order of two keys: distance first, then insertion counter.

    Non-short-circuit ``&`` / ``|`` so LLVM emits selects, not branches: the
    outcome of a heap comparison is unpredictable.
    """
    return (d1 < d2) | ((d1 == d2) & (c1 < c2))


@numba.njit(cache=True, inline="always")
def _less(heap_d, heap_c, i, j):  # pragma: no cover - compiled
    """Heap order of slots i and j."""
    return _before(heap_d[_u(i)], heap_c[_u(i)], heap_d[_u(j)], heap_c[_u(j)])


@numba.njit(cache=True, inline="always")
def _min_child(heap_d, heap_c, first):  # pragma: no cover - compiled
    """Slot of the smallest of the four children starting at ``first``."""
    m1 = first + _less(heap_d, heap_c, first + 1, first)
    m2 = first + 2 + _less(heap_d, heap_c, first + 3, first + 2)
    return m2 if _less(heap_d, heap_c, m2, m1) else m1


@numba.njit(cache=True, inline="always")
def _move(heap_d, heap_c, pos, dst, src):  # pragma: no cover - compiled
    heap_d[_u(dst)] = heap_d[_u(src)]
    key = heap_c[_u(src)]
    heap_c[_u(dst)] = key
    pos[_u(key & _PIXEL_MASK)] = dst


@numba.njit(cache=True, inline="always")
def _place(heap_d, heap_c, pos, slot, d, c):  # pragma: no cover - compiled
    heap_d[_u(slot)] = d
    heap_c[_u(slot)] = c
    pos[_u(c & _PIXEL_MASK)] = slot


@numba.njit(cache=True, inline="always")
def _sift_up(heap_d, heap_c, pos, hole, d, c, newest):  # pragma: no cover - compiled
    """Put (d, c) at ``hole`` or above.

    ``newest`` (a constant at each call site, so the compiler keeps one
    branch): c is newer than every key above, so the entry only rises above
    strictly larger distances and one comparison per level suffices.
    """
    while hole > 0:
        parent = (hole - 1) >> 2
        pd = heap_d[_u(parent)]
        rises = (d < pd) if newest else _before(d, c, pd, heap_c[_u(parent)])
        if not rises:
            break
        _move(heap_d, heap_c, pos, hole, parent)
        hole = parent
    _place(heap_d, heap_c, pos, hole, d, c)


@numba.njit(cache=True, inline="always")
def _sift_down(heap_d, heap_c, pos, size, d, c, to_leaf):  # pragma: no cover - compiled
    """Move the root's hole down along the smallest children; return where it stops.

    It stops above the first child that (d, c) comes before or, with
    ``to_leaf`` (a constant at each call site), only at a leaf. The caller
    then fills the hole.
    """
    hole = 0
    while True:
        first = 4 * hole + 1
        if first >= size:
            break
        m = _min_child(heap_d, heap_c, first)
        if not (to_leaf or _before(heap_d[_u(m)], heap_c[_u(m)], d, c)):
            break
        _move(heap_d, heap_c, pos, hole, m)
        hole = m
    return hole


@numba.njit(cache=True, inline="always")
def _replace_root_top_down(heap_d, heap_c, pos, size, d, c):  # pragma: no cover - compiled
    """Overwrite the root with (d, c) and sift it down.

    Used with the smallest new neighbour, which is often the next pixel to
    pop, so the loop usually stops after a level or two.
    """
    _place(heap_d, heap_c, pos, _sift_down(heap_d, heap_c, pos, size, d, c, to_leaf=False), d, c)


@numba.njit(cache=True, inline="always")
def _replace_root_bottom_up(heap_d, heap_c, pos, size, d, c):  # pragma: no cover - compiled
    """Overwrite the root with (d, c), Floyd's bottom-up way.

    Used with the former last entry, which almost always belongs near the
    bottom: walk the smallest children up to a leaf without comparing
    against it, then sift it up from there.
    """
    _sift_up(heap_d, heap_c, pos, _sift_down(heap_d, heap_c, pos, size, d, c, to_leaf=True), d, c, newest=False)


@numba.njit(cache=True)
def grid_tables(height, width):  # pragma: no cover - compiled
    """Template-independent tables of an ``height x width`` grid, built once per batch.

    Returns ``neighbours`` (N * 4,) int32: the 4-neighbours of each pixel in
    the official order (left, up, right, down), -1 outside the image; and
    ``xs``, ``ys`` (N,) float64: the column and row of each pixel. They spare
    the growth loop an integer division and four border tests per pixel.
    """
    n_pixels = height * width
    neighbours = np.empty(n_pixels * 4, dtype=np.int32)
    xs = np.empty(n_pixels, dtype=np.float64)
    ys = np.empty(n_pixels, dtype=np.float64)
    for y in range(height):
        for x in range(width):
            p = y * width + x
            xs[p] = x
            ys[p] = y
            neighbours[4 * p] = p - 1 if x > 0 else -1
            neighbours[4 * p + 1] = p - width if y > 0 else -1
            neighbours[4 * p + 2] = p + 1 if x < width - 1 else -1
            neighbours[4 * p + 3] = p + width if y < height - 1 else -1
    return neighbours, xs, ys


@numba.njit(cache=True, error_model="numpy")
def snic_grow(flat_lab, seeds, spatial_weight, flat_labels, neighbours, xs, ys, width,
              heap_d, heap_c, pos, owner, sums):  # pragma: no cover
    """Grow superpixels from ``seeds`` on one Lab image, writing into ``flat_labels``.

    flat_lab: (N * 3,) float64, the (H, W, 3) Lab image flattened. seeds:
    (s, 2) int64 (row, col), distinct, inside the image. spatial_weight:
    ``M**2 * s / N``. flat_labels: (N,) int32, output. neighbours, xs, ys:
    :func:`grid_tables` of the image size; width: W. Work arrays (contents
    ignored): heap_d (N + 4,) float64, heap_c (N + 4,) int64 (packed
    ``counter << 32 | pixel`` keys), pos (N,) int32, owner (N,) int32, sums
    (s * 6,) float64. N <= ``MAX_PIXELS``.
    """
    n_pixels = flat_labels.shape[0]
    n_seeds = seeds.shape[0]
    flat_labels[:] = -1
    pos[:] = _UNSEEN
    flat_sums = sums
    flat_sums[:] = 0.0

    # Seeds enter with d = 0 in raster order, so seed k is popped k-th and
    # claims its own pixel: no superpixel can be empty.
    size = 0
    counter = 0
    for k in range(n_seeds):
        p = seeds[k, 0] * width + seeds[k, 1]
        _place(heap_d, heap_c, pos, size, 0.0, (counter << 32) | p)
        owner[p] = k
        size += 1
        counter += 1
    for j in range(3):
        heap_d[size + j] = np.inf
        heap_c[size + j] = _PAD_COUNTER

    new_d = np.empty(4, dtype=np.float64)
    new_c = np.empty(4, dtype=np.int64)
    while size > 0:
        p = heap_c[0] & _PIXEL_MASK
        k = owner[p]
        flat_labels[p] = k
        pos[p] = _LABELLED
        # The root slot is dead until refilled below; -1 is below every
        # distance, so a lowered key cannot climb past it.
        heap_d[0] = -1.0

        base = 6 * k
        # Online centroid: running sums, as the official code keeps them.
        flat_sums[_u(base)] += flat_lab[3 * p]
        flat_sums[_u(base + 1)] += flat_lab[3 * p + 1]
        flat_sums[_u(base + 2)] += flat_lab[3 * p + 2]
        flat_sums[_u(base + 3)] += xs[p]
        flat_sums[_u(base + 4)] += ys[p]
        flat_sums[_u(base + 5)] += 1.0
        kl = flat_sums[_u(base)]
        ka = flat_sums[_u(base + 1)]
        kb = flat_sums[_u(base + 2)]
        kx = flat_sums[_u(base + 3)]
        ky = flat_sums[_u(base + 4)]
        ksize = flat_sums[_u(base + 5)]
        norm = ksize * ksize

        n_new = 0
        best = 0
        # Neighbour order of the official code (dx8/dy8, CONNECTIVITY = 4):
        # left, up, right, down. It fixes the counters, hence tie-breaking.
        for nb in range(4):
            q = neighbours[4 * p + nb]
            if q < 0:
                continue
            slot = pos[q]
            if slot == _LABELLED:
                continue
            # The official expression: differences of sums scaled by the
            # count, one division at the end. It equals
            # ||c - mu_c||^2 + w ||xy - mu_xy||^2 against the updated
            # centroid; keeping its rounding keeps near-ties in the official
            # order.
            ldiff = kl - flat_lab[3 * q] * ksize
            adiff = ka - flat_lab[3 * q + 1] * ksize
            bdiff = kb - flat_lab[3 * q + 2] * ksize
            xdiff = kx - xs[q] * ksize
            ydiff = ky - ys[q] * ksize
            colordist = ldiff * ldiff + adiff * adiff + bdiff * bdiff
            xydist = xdiff * xdiff + ydiff * ydiff
            d = (colordist + xydist * spatial_weight) / norm
            c = (counter << 32) | q
            counter += 1
            if slot >= 0:
                # Already queued with an older counter: a duplicate push in
                # the official queue, which matters only if strictly closer.
                if d < heap_d[_u(slot)]:
                    owner[q] = k
                    _sift_up(heap_d, heap_c, pos, slot, d, c, newest=True)
            else:
                owner[q] = k
                new_d[n_new] = d
                new_c[n_new] = c
                if n_new == 0 or d < new_d[best]:
                    best = n_new
                n_new += 1

        if n_new > 0:
            # The closest new neighbour refills the root; the rest are
            # appended. (Keys are unique, so the pop order does not depend on
            # how the heap is arranged.)
            _replace_root_top_down(heap_d, heap_c, pos, size, new_d[best], new_c[best])
            for j in range(n_new):
                if j == best:
                    continue
                size += 1
                heap_d[_u(size + 2)] = np.inf
                heap_c[_u(size + 2)] = _PAD_COUNTER
                _sift_up(heap_d, heap_c, pos, size - 1, new_d[j], new_c[j], newest=True)
        else:
            size -= 1
            if size > 0:
                last_d = heap_d[_u(size)]
                last_c = heap_c[_u(size)]
                heap_d[_u(size)] = np.inf
                heap_c[_u(size)] = _PAD_COUNTER
                _replace_root_bottom_up(heap_d, heap_c, pos, size, last_d, last_c)

    # Safety net of the official code: copy the left (else upper) label into
    # an unlabelled pixel. Flooding a connected 4-grid from >= 1 seed reaches
    # every pixel, so this never fires. Unlike the official pass it also
    # covers row 0 and column 0.
    for p in range(n_pixels):
        if flat_labels[p] < 0:
            if p % width > 0:
                flat_labels[p] = flat_labels[p - 1]
            elif p >= width:
                flat_labels[p] = flat_labels[p - width]
            else:
                flat_labels[p] = 0


@numba.njit(cache=True, nogil=True)
def _work_arrays(height, width, n_seeds):  # pragma: no cover - compiled
    """Grid tables and the heap, owner and sum buffers ``snic_grow`` reuses across the images of a range."""
    n_pixels = height * width
    neighbours, xs, ys = grid_tables(height, width)
    heap_d = np.empty(n_pixels + 4, dtype=np.float64)
    heap_c = np.empty(n_pixels + 4, dtype=np.int64)
    pos = np.empty(n_pixels, dtype=np.int32)
    owner = np.empty(n_pixels, dtype=np.int32)
    sums = np.empty(n_seeds * 6, dtype=np.float64)
    return neighbours, xs, ys, heap_d, heap_c, pos, owner, sums


@numba.njit(cache=True, nogil=True)
def _grow_range(lab, seeds, spatial_weight, labels, start, stop):  # pragma: no cover - compiled
    """Run ``snic_grow`` on images ``start:stop``, allocating work arrays once."""
    height, width = lab.shape[1], lab.shape[2]
    n_pixels = height * width
    neighbours, xs, ys, heap_d, heap_c, pos, owner, sums = _work_arrays(height, width, seeds.shape[0])
    for i in range(start, stop):
        snic_grow(lab[i].reshape(n_pixels * 3), seeds, spatial_weight, labels[i].reshape(n_pixels),
                  neighbours, xs, ys, width, heap_d, heap_c, pos, owner, sums)


@numba.njit(cache=True)
def snic_image(lab, seeds, spatial_weight):  # pragma: no cover - compiled
    """SNIC labels of one image.

    lab: (H, W, 3) float64, C-contiguous. seeds: (s, 2) int64 (row, col).
    spatial_weight: ``M**2 * s / N``. Returns (H, W) int32 labels in [0, s).
    """
    height, width = lab.shape[0], lab.shape[1]
    labels = np.empty((1, height, width), dtype=np.int32)
    _grow_range(lab.reshape(1, height, width, 3), seeds, spatial_weight, labels, 0, 1)
    return labels[0]


def snic_batch(lab, seeds, spatial_weight, n_threads):
    """SNIC labels of a batch of same-size images sharing one seed grid.

    lab: (B, H, W, 3) float64, C-contiguous. seeds: (s, 2) int64 (row, col).
    spatial_weight: ``M**2 * s / N``. n_threads: threads that grow blocks
    of images in turn (:func:`run_in_chunks`). Returns (B, H, W) int32.
    """
    n_images, height, width = lab.shape[0], lab.shape[1], lab.shape[2]
    labels = np.empty((n_images, height, width), dtype=np.int32)
    run_in_chunks(_grow_range, n_images, n_threads, lab, seeds, spatial_weight, labels)
    return labels


@numba.njit(cache=True, nogil=True)
def _grow_range_rgb(images, seeds, spatial_weight, labels, linear, rgb_to_xyz, white, memo, start,
                    stop):  # pragma: no cover
    """``_grow_range`` from uint8 RGB: each image is converted to Lab just before it grows.

    The Lab image stays in a per-thread buffer that is still in cache when
    SNIC reads it, instead of a (B, H, W, 3) float64 batch written and read
    back through memory; ``memo`` (:func:`new_lab_memo`, the calling thread's
    own) serves the whole range.
    """
    height, width = images.shape[1], images.shape[2]
    n_pixels = height * width
    neighbours, xs, ys, heap_d, heap_c, pos, owner, sums = _work_arrays(height, width, seeds.shape[0])
    flat_lab = np.empty(n_pixels * 3, dtype=np.float64)
    for i in range(start, stop):
        lab_image_memo(images[i], linear, rgb_to_xyz, white, memo, flat_lab)
        snic_grow(flat_lab, seeds, spatial_weight, labels[i].reshape(n_pixels),
                  neighbours, xs, ys, width, heap_d, heap_c, pos, owner, sums)


_THREAD = threading.local()


def _thread_lab_memo(key):
    """The calling thread's colour memo for the conversion constants ``key`` stands for, kept across batches.

    A memo entry is a pure function of the colour and the constants, so it
    stays valid from one batch (and frame) to the next; keeping it spares each
    block the 2 MiB allocation (about 20 us) and the misses of a cold memo.
    """
    if getattr(_THREAD, "lab_memo_key", None) != key:
        _THREAD.lab_memo = new_lab_memo()
        _THREAD.lab_memo_key = key
    return _THREAD.lab_memo


def snic_batch_rgb(images, seeds, spatial_weight, n_threads, linear, rgb_to_xyz, white):
    """``snic_batch`` of uint8 RGB images: Lab conversion fused into the growth.

    images: (B, H, W, 3) uint8, C-contiguous. linear, rgb_to_xyz, white: the
    constants of :func:`sptpt.color.rgb_to_lab_templates`. Same labels as
    ``snic_batch(rgb_to_lab_batch(images, ...), ...)``, bit for bit.
    """
    n_images, height, width = images.shape[0], images.shape[1], images.shape[2]
    labels = np.empty((n_images, height, width), dtype=np.int32)
    constants = (linear.tobytes(), rgb_to_xyz.tobytes(), white.tobytes())  # the key of a thread's memo

    def grow(start, stop):
        _grow_range_rgb(images, seeds, spatial_weight, labels, linear, rgb_to_xyz, white,
                        _thread_lab_memo(constants), start, stop)

    run_in_chunks(grow, n_images, n_threads)
    return labels
