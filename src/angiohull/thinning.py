"""Guo–Hall thinning of binary images, vectorised over the pixels that can change.

Guo & Hall, "Parallel thinning with two-subiteration algorithms", Comm. ACM 32(3), 1989, algorithm
A1. Notation (the paper's figure 1, with row index growing downward)::

    p9 p2 p3
    p8 p1 p4
    p7 p6 p5

A foreground pixel p1 is deleted in a subiteration when all of these hold:

- C(p1) = 1, with C = [~p2 & (p3 | p4)] + [~p4 & (p5 | p6)] + [~p6 & (p7 | p8)] + [~p8 & (p9 | p2)];
- 2 <= N(p1) <= 3, with N = min(N1, N2), N1 = (p9|p2) + (p3|p4) + (p5|p6) + (p7|p8),
  N2 = (p2|p3) + (p4|p5) + (p6|p7) + (p8|p9);
- m(p1) = 0, with m = p4 & (p2 | p3 | ~p5) in the first subiteration of each pass and
  m = p8 & (p6 | p7 | ~p9) in the second.

Every pixel of a subiteration is decided on the image as it was when the subiteration began
(parallel thinning); passes repeat until one deletes nothing. This subiteration order is the one of
the ``guo_hall`` of the cv-algorithms package, which the paper's authors thin with: on their 48
synthetic studies this gives their skeletons pixel for pixel (``tests/test_thinning.py``).
OpenCV's ``ximgproc.thinning(THINNING_GUOHALL)`` runs the two subiterations in the other order
(its skeletons of those masks share about 60 % of their pixels with the authors'), and
``skimage.morphology.thin`` uses a different rule table (3 of the 48 studies differ by 10-17
pixels).

The image outside the array is background (pixels on the array's edge are thinned like any other).

Speed: only pixels with a background 4-neighbour can be deleted (C = 1 needs one), and a pixel's
decision changes only when its 3x3 neighbourhood or the subiteration changes, so each subiteration
looks at the pixels it may delete (those whose neighbourhood changed in the last two subiterations)
through a 256-entry table of the rule (benchmarks/pipeline.py measures it against
``skimage.morphology.thin``).
"""

from __future__ import annotations

import numpy as np

from .compiled import kernels

__all__ = ["guo_hall_thin", "guo_hall_thin_many", "guo_hall_skeleton_pixels", "GUO_HALL_TABLES", "pixel_box"]


def _rule_tables() -> np.ndarray:
    """(2, 256) bool: whether p1 is deleted in subiteration 0 / 1, indexed by the neighbourhood code
    sum(p_k << (k - 2)) for k = 2..9."""
    code = np.arange(256)
    p2, p3, p4, p5, p6, p7, p8, p9 = (((code >> bit) & 1).astype(bool) for bit in range(8))
    c = ((~p2 & (p3 | p4)).astype(int) + (~p4 & (p5 | p6)) + (~p6 & (p7 | p8)) + (~p8 & (p9 | p2)))
    n1 = (p9 | p2).astype(int) + (p3 | p4) + (p5 | p6) + (p7 | p8)
    n2 = (p2 | p3).astype(int) + (p4 | p5) + (p6 | p7) + (p8 | p9)
    n = np.minimum(n1, n2)
    common = (c == 1) & (n >= 2) & (n <= 3)
    m_first = p4 & (p2 | p3 | ~p5)
    m_second = p8 & (p6 | p7 | ~p9)
    return np.stack([common & ~m_first, common & ~m_second])


GUO_HALL_TABLES = _rule_tables()
"""(2, 256) bool: the deletion rule of each subiteration by neighbourhood code (see the module notes)."""


def pixel_box(image: np.ndarray, margin: int = 0) -> tuple[int, int, int, int] | None:
    """``(row start, row stop, column start, column stop)`` of the box that holds the nonzero
    pixels of a 2D image, grown by ``margin`` pixels (within the image); None when there are none.
    Thinning, mask cleaning and the maps that only matter near the vessel work on it."""
    rows = np.flatnonzero(np.any(image, axis=1))
    if len(rows) == 0:
        return None
    cols = np.flatnonzero(np.any(image, axis=0))
    return (max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, image.shape[0]),
            max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, image.shape[1]))


def guo_hall_thin(mask: np.ndarray, *, keep_edge: bool = False) -> np.ndarray:
    """One-pixel-wide skeleton of a binary image by Guo–Hall thinning (see the module notes).

    Parameters
    ----------
    mask : (rows, cols) array
        Nonzero = foreground.
    keep_edge : bool, keyword-only
        Never delete the pixels on the array's edge (first and last row and column), as the
        authors' thinning does (cv-algorithms' ``guo_hall`` only visits the interior pixels); a
        vessel that leaves the image then keeps its cross-section on the edge. Default False:
        edge pixels are thinned like the others, the outside counting as background.

    Returns
    -------
    (rows, cols) bool array
        The skeleton, a subset of the foreground.

    Examples
    --------
    >>> import numpy as np
    >>> bar = np.zeros((5, 9), dtype=bool); bar[1:4, 1:8] = True
    >>> guo_hall_thin(bar).astype(int)
    array([[0, 0, 0, 0, 0, 0, 0, 0, 0],
           [0, 0, 0, 0, 0, 0, 0, 0, 0],
           [0, 0, 1, 1, 1, 1, 1, 0, 0],
           [0, 0, 0, 0, 0, 0, 0, 0, 0],
           [0, 0, 0, 0, 0, 0, 0, 0, 0]])
    """
    return guo_hall_thin_many([mask], keep_edge=keep_edge)[0]


def guo_hall_thin_many(masks, *, keep_edge: bool = False) -> list[np.ndarray]:
    """:func:`guo_hall_thin` of several images at once: their bounding boxes are stacked into one
    image, each with a background margin, and thinned together (the same skeletons, pixel for
    pixel: a pixel's decision reads only its 3 x 3 neighbourhood, and an image whose pass deletes
    nothing stays as it is while the others go on); the per-subiteration overhead is paid once for
    all of them (the centerline step thins every view's mask)."""
    masks = [np.asarray(m) for m in masks]
    outs = [np.zeros(m.shape, dtype=bool) for m in masks]
    for (i, r0, r1, c0, c1), top, skeleton in _thinned_boxes(masks, keep_edge):
        outs[i][r0:r1, c0:c1] = skeleton[top + 1:top + 1 + r1 - r0, 1:1 + c1 - c0]
    return outs


def guo_hall_skeleton_pixels(masks, *, keep_edge: bool = False) -> list[np.ndarray]:
    """The pixel centres ``(u, v) = (column, row)`` of each image's :func:`guo_hall_thin` skeleton,
    (M, 2) float64 in row-major order (as ``np.nonzero`` lists them), without building the skeleton
    images."""
    masks = [np.asarray(m) for m in masks]
    outs = [np.empty((0, 2)) for _ in masks]
    thinned = _thinned_boxes(masks, keep_edge)
    if not thinned:
        return outs
    stacked = thinned[0][2]
    rows, cols = np.nonzero(stacked)  # every box's pixels at once, box after box
    for (i, r0, r1, c0, c1), top, _ in thinned:
        lo, hi = np.searchsorted(rows, [top + 1, top + 1 + r1 - r0])
        outs[i] = np.stack([cols[lo:hi] - 1 + c0, rows[lo:hi] - top - 1 + r0], axis=1).astype(np.float64)
    return outs


def _thinned_boxes(masks: list[np.ndarray], keep_edge: bool) -> list[tuple[tuple[int, ...], int, np.ndarray]]:
    """Thin the masks' bounding boxes stacked into one image: ``((mask index, r0, r1, c0, c1), top,
    stacked skeleton)`` per non-empty mask, the box at rows ``top + 1 ..`` and columns ``1 ..`` of
    the stacked image (the same array for all)."""
    for m in masks:
        if m.ndim != 2:
            raise ValueError(f"guo_hall_thin expects a 2D image, got shape {m.shape}")
    boxes = []
    for i, m in enumerate(masks):
        foreground = m != 0
        box = pixel_box(foreground)
        if box is not None:
            boxes.append((i, foreground, *box))
    if not boxes:
        return []
    # the bounding boxes one under the other, each with a background margin of one pixel, flattened
    width = max(c1 - c0 for *_, c0, c1 in boxes) + 2
    image = np.zeros((sum(r1 - r0 + 2 for _, _, r0, r1, _, _ in boxes), width), dtype=np.uint8)
    frozen = None  # with keep_edge: the images' edge pixels, never deleted
    tops = []
    top = 0
    for i, foreground, r0, r1, c0, c1 in boxes:
        image[top + 1:top + 1 + r1 - r0, 1:1 + c1 - c0] = foreground[r0:r1, c0:c1]
        rows, cols = foreground.shape
        if keep_edge and (r0 == 0 or c0 == 0 or r1 == rows or c1 == cols):
            if frozen is None:
                frozen = np.zeros(image.shape, dtype=bool)
            edge = np.zeros((rows, cols), dtype=bool)
            edge[[0, -1], :] = True
            edge[:, [0, -1]] = True
            frozen[top + 1:top + 1 + r1 - r0, 1:1 + c1 - c0] = edge[r0:r1, c0:c1]
        tops.append(top)
        top += r1 - r0 + 2
    compiled = kernels()
    if compiled is not None:
        never = np.zeros(image.size, dtype=bool) if frozen is None else frozen.ravel()
        compiled.guo_hall_thin_flat(image.ravel(), never, width, GUO_HALL_TABLES)
    else:
        _thin_stacked_numpy(image, frozen)
    skeleton = image.view(bool)
    return [((i, int(r0), int(r1), int(c0), int(c1)), t, skeleton) for (i, _, r0, r1, c0, c1), t in zip(boxes, tops)]


def _thin_stacked_numpy(image: np.ndarray, frozen: np.ndarray | None) -> None:
    """Thin ``image`` (uint8 0/1, a background margin of one pixel all round) in place; ``frozen``
    (bool, same shape, or None) pixels are never deleted. The reference of the compiled kernel."""
    width = image.shape[1]
    flat = image.ravel()
    # offsets of p2..p9 and their bit in the code
    offsets = np.array([-width, -width + 1, 1, width + 1, width, width - 1, -1, -width - 1], dtype=np.int64)
    # pixels that may be deleted: foreground with a background 4-neighbour
    inner = image[1:-1, 1:-1] != 0
    border = image != 0
    border[1:-1, 1:-1] &= ~(inner & (image[:-2, 1:-1] != 0) & (image[2:, 1:-1] != 0)
                            & (image[1:-1, :-2] != 0) & (image[1:-1, 2:] != 0))
    if frozen is not None:
        border &= ~frozen
        frozen = frozen.ravel()
    candidates = np.flatnonzero(border)
    recent: list[np.ndarray] = [candidates, candidates]  # pixels to look at, from the last two subiterations
    stamp = np.empty(len(flat), dtype=np.int64)  # scratch: removes repeated indices without sorting
    # every foreground pixel's neighbourhood code, kept up to date as pixels are deleted
    pixels = np.flatnonzero(flat)
    code = np.zeros(len(flat), dtype=np.uint8)
    for bit, offset in enumerate(offsets):
        code[pixels] |= flat[pixels + offset] << np.uint8(bit)
    # deleting a pixel clears, in its neighbour at offsets[k], the bit pointing back (k + 4 mod 8)
    clear = [np.uint8(~(1 << ((bit + 4) % 8)) & 0xFF) for bit in range(8)]
    changed_in_pass = 0
    subiteration = 0
    while True:
        look = np.concatenate(recent)
        stamp[look] = np.arange(len(look))
        look = look[stamp[look] == np.arange(len(look))]  # each pixel once (its last occurrence)
        look = look[flat[look] != 0] if frozen is None else look[(flat[look] != 0) & ~frozen[look]]
        deleted = look[GUO_HALL_TABLES[subiteration][code[look]]]
        flat[deleted] = 0
        for bit, offset in enumerate(offsets):
            code[deleted + offset] &= clear[bit]
        changed_in_pass += len(deleted)
        touched = (deleted[:, None] + offsets[None, :]).ravel()
        recent = [recent[1], touched[flat[touched] != 0]]
        if subiteration == 1:
            if changed_in_pass == 0:
                break
            changed_in_pass = 0
        subiteration = 1 - subiteration
