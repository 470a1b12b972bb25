"""Hierarchical carving: cull blocks of lattice points with a conservative test, then test exactly.

A *cell* is a block of ``size**3`` lattice points (fewer at the far faces of the lattice). A cell
survives a view when the footprint of its bounding box — the bounding rectangle of its 8 projected
corners, widened by the threshold — contains a mask pixel centre, which a summed-area table of the
mask answers in constant time; a cell reaching behind the source always survives. No lattice point
of a culled cell can be kept by the exact test, so the result equals the dense lattice's. Surviving
cells are split in eight until they reach the leaf size; the points of the leaf cells then get the
exact per-point test of :class:`~angiohull.reconstruction.engines.MaskLookup`.

The dense lattice is never held: memory follows the number of surviving cells and leaf points.

Everything is written for an array module ``xp`` (NumPy here, CuPy for ``--device cuda``, see
:mod:`.gpu`) with one ufunc per arithmetic operation, in the order of
:func:`~angiohull.reconstruction.engines.project_in_front`: IEEE-exact on both, so the CPU and GPU
keep bit-identical point sets. On the CPU with every view required, where numba is installed, the
same cells, tests and arithmetic run as one compiled kernel (:mod:`angiohull.compiled`), again with
the same points and survivor counts.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..compiled import kernels
from ..geometry import Projection
from .cube import Lattice
from .engines import (_BAND_FROM_REACH, _BAND_SLACK_PX, CHUNK_POINTS, ENGINES, CarveOutcome, MaskLookup,
                      _distance_to_mask, project_row, sparsest_first)

__all__ = ["carve_hierarchical", "carve_lookup", "carve_octree", "cell_sizes", "FootprintTest", "HIERARCHICAL_ENGINES"]

HIERARCHICAL_ENGINES = ("lookup", "octree")
_MARGIN_PX = 1e-6  # widening of footprints against rounding in the corner projections


def cell_sizes(engine: str, resolution: int) -> tuple[int, int]:
    """Root and leaf cell edges (lattice points) of a hierarchical engine at lattice resolution K."""
    if engine == "lookup":  # a sweep over 16**3 blocks, split once
        return 16, 4
    if engine == "octree":  # from cells of up to 128**3 points
        return min(128, 1 << max(2, int(np.ceil(np.log2(resolution))))), 4
    raise ValueError(f"not a hierarchical engine: {engine!r}; choose one of {list(HIERARCHICAL_ENGINES)}")


class FootprintTest:
    """Conservative "may a point of this box be kept by this view" test for many boxes at once."""

    def __init__(self, projection: Projection, mask: np.ndarray, threshold_px: float, xp: Any = np):
        self.xp = xp
        self.m = projection.matrix.tolist()
        self.rows, self.cols = mask.shape
        self.reach = float(threshold_px) + _MARGIN_PX
        table = np.zeros((self.rows + 1, self.cols + 1), dtype=np.int64 if mask.size >= 2 ** 31 else np.int32)
        table[1:, 1:] = mask
        np.cumsum(table, axis=1, out=table)  # summed-area table: table[r, c] = mask[:r, :c].sum()
        np.cumsum(table, axis=0, out=table)
        self.table = xp.asarray(table)
        self.bits = [xp.asarray(np.array([(c >> s) & 1 for c in range(8)], dtype=bool)) for s in (2, 1, 0)]

    def may_keep(self, lo, hi):
        """Bool (n,) for boxes with corners ``lo`` and ``hi`` (n, 3) in mm."""
        xp, m = self.xp, self.m
        # (n, 8) corners: corner c takes hi on axis 0 / 1 / 2 where bit 4 / 2 / 1 of c is set
        x, y, z = (xp.where(bit[None, :], hi[:, a:a + 1], lo[:, a:a + 1]) for a, bit in enumerate(self.bits))
        w = project_row(x, y, z, m, 2)
        front = w > 0
        all_front = front.all(axis=1)
        w = xp.where(front, w, 1.0)  # a box reaching behind the source is kept whatever its u, v
        u = project_row(x, y, z, m, 0) / w
        v = project_row(x, y, z, m, 1) / w
        c0 = xp.clip(xp.ceil(u.min(axis=1) - self.reach), 0, self.cols).astype(np.intp)
        c1 = xp.clip(xp.floor(u.max(axis=1) + self.reach) + 1, 0, self.cols).astype(np.intp)
        r0 = xp.clip(xp.ceil(v.min(axis=1) - self.reach), 0, self.rows).astype(np.intp)
        r1 = xp.clip(xp.floor(v.max(axis=1) + self.reach) + 1, 0, self.rows).astype(np.intp)
        t = self.table
        count = t[r1, c1] - t[r0, c1] - t[r1, c0] + t[r0, c0]
        return ~all_front | ((count > 0) & (c1 > c0) & (r1 > r0))


class _ExactTest:
    """A view's projection followed by :meth:`MaskLookup.near_uv`, on ``xp``."""

    def __init__(self, projection: Projection, mask: np.ndarray, threshold_px: float, xp: Any = np):
        self.xp = xp
        self.lookup = MaskLookup(mask, threshold_px, xp)
        self.m = projection.matrix.tolist()

    def kept(self, x, y, z):
        """Indices of the points in front of the source and closer than the threshold to the mask."""
        m = self.m
        w = project_row(x, y, z, m, 2)
        front = self.xp.flatnonzero(w > 0)
        x, y, z, w = x[front], y[front], z[front], w[front]
        return front[self.lookup.near_uv(project_row(x, y, z, m, 0) / w, project_row(x, y, z, m, 1) / w)]


def _children(xp, starts, size: int, k: int):
    half = size // 2
    offsets = xp.asarray(np.array([[a, b, c] for a in (0, half) for b in (0, half) for c in (0, half)], dtype=np.int64))
    children = (starts[:, None, :] + offsets[None]).reshape(-1, 3)
    return children[(children < k).all(axis=1)]


def _leaf_points(xp, starts, size: int, k: int, axis, chunk_points: int):
    """The lattice points of the leaf cells, chunk by chunk: ``(flat index, x, y, z)`` arrays."""
    r = xp.arange(size, dtype=np.int64)
    offsets = xp.stack(xp.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    cells_per_chunk = max(1, chunk_points // size ** 3)
    for c in range(0, len(starts), cells_per_chunk):
        ijk = (starts[c:c + cells_per_chunk, None, :] + offsets[None]).reshape(-1, 3)
        ijk = ijk[(ijk < k).all(axis=1)]
        flat = (ijk[:, 0] * k + ijk[:, 1]) * k + ijk[:, 2]
        yield flat, axis[ijk[:, 0]], axis[ijk[:, 1]], axis[ijk[:, 2]]


def carve_hierarchical(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                       threshold_px: float, root_size: int, leaf_size: int, xp: Any = np,
                       chunk_points: int = CHUNK_POINTS, min_views: int | None = None) -> CarveOutcome:
    """Cull cells from ``root_size`` down to ``leaf_size`` (powers of two), then test points exactly.

    With ``min_views = k`` below the number of views, a cell (and then a point) survives when at
    least ``k`` views may keep it (keep it); see :func:`_carve_k_of_n`. Returns NumPy arrays
    whatever ``xp`` is.
    """
    if min_views is not None and int(min_views) < len(projections):
        return _carve_k_of_n(lattice, projections, masks, threshold_px=threshold_px, root_size=root_size,
                             leaf_size=leaf_size, xp=xp, chunk_points=chunk_points, need=int(min_views))
    k = lattice.resolution
    order = sparsest_first(masks)
    if xp is np and kernels() is not None:
        outcome = _carve_compiled(lattice, [projections[i] for i in order], [masks[i] for i in order],
                                  threshold_px=threshold_px, root_size=root_size, leaf_size=leaf_size)
        if len(outcome.points_mm):
            return CarveOutcome(outcome.points_mm, outcome.survivors_per_view, order)
        # nothing kept: the NumPy path below says which view removed the last cells
    tests = [FootprintTest(projections[i], masks[i], threshold_px, xp) for i in order]
    exact = [_ExactTest(projections[i], masks[i], threshold_px, xp) for i in order]
    axis = xp.asarray(lattice.axis_mm())
    r = xp.arange(0, k, root_size, dtype=np.int64)
    starts = xp.stack(xp.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    size = root_size
    while True:
        cell_survivors = []  # lattice points (at most size**3 a cell) alive after each view
        for test in tests:
            if len(starts):
                starts = starts[test.may_keep(axis[starts], axis[xp.minimum(starts + size, k) - 1])]
            cell_survivors.append(int(len(starts)) * size ** 3)
        if size <= leaf_size or len(starts) == 0:
            break
        starts = _children(xp, starts, size, k)
        size //= 2
    if len(starts) == 0:  # culled away: say which view removed the last cells
        return CarveOutcome(np.empty((0, 3)), tuple(cell_survivors), order)
    survivors = [0] * len(order)
    kept = []
    for flat, x, y, z in _leaf_points(xp, starts, size, k, axis, chunk_points):
        for i, test in enumerate(exact):
            if len(flat):
                sel = test.kept(x, y, z)
                x, y, z, flat = x[sel], y[sel], z[sel], flat[sel]
            survivors[i] += int(len(flat))
        kept.append(flat)
    flat = xp.sort(xp.concatenate(kept))
    flat = flat.get() if hasattr(flat, "get") else flat
    return CarveOutcome(lattice.points_at(flat), tuple(survivors), order)


def _carve_compiled(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                    threshold_px: float, root_size: int, leaf_size: int) -> CarveOutcome:
    """:func:`carve_hierarchical` (every view, in the order given) by the compiled kernel: the same
    cells culled, the same exact test, the same kept points and survivor counts."""
    compiled = kernels()
    shapes = np.array([m.shape for m in masks], dtype=np.int64)
    if all(m.shape == masks[0].shape for m in masks):
        stacked = np.stack([np.asarray(m, dtype=bool) for m in masks]).view(np.uint8)
    else:  # views of different sizes: zeros beyond each view's own extent
        stacked = np.zeros((len(masks), shapes[:, 0].max(), shapes[:, 1].max()), dtype=np.uint8)
        for i, m in enumerate(masks):
            stacked[i, :m.shape[0], :m.shape[1]] = np.asarray(m, dtype=bool)
    matrices = np.stack([np.asarray(p.matrix, dtype=np.float64) for p in projections])
    reach = int(np.ceil(float(threshold_px)))
    distances = np.zeros((0, 0, 0))
    if reach >= _BAND_FROM_REACH:  # as MaskLookup: the distance transform decides first
        distances = np.full(stacked.shape, np.inf)
        for i, m in enumerate(masks):
            if m.any():
                distances[i, :m.shape[0], :m.shape[1]] = _distance_to_mask(np.asarray(m, dtype=bool))
    points, survivors = compiled.carve_lattice(lattice.axis_mm(), int(root_size), int(leaf_size), matrices, stacked,
                                               shapes, float(threshold_px), reach, float(threshold_px) + _MARGIN_PX,
                                               distances, _BAND_SLACK_PX)
    return CarveOutcome(points, tuple(int(s) for s in survivors))


def _carve_k_of_n(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                  threshold_px: float, root_size: int, leaf_size: int, xp: Any, chunk_points: int,
                  need: int) -> CarveOutcome:
    """Robust carving: keep what at least ``need`` of the views keep.

    A cell is culled when fewer than ``need`` views may keep one of its points (each view's test
    is conservative, so no point that ``need`` views keep is lost); the points of the leaf cells
    are then counted view by view with the exact test.
    """
    k = lattice.resolution
    n = len(projections)
    tests = [FootprintTest(p, m, threshold_px, xp) for p, m in zip(projections, masks)]
    exact = [_ExactTest(p, m, threshold_px, xp) for p, m in zip(projections, masks)]
    axis = xp.asarray(lattice.axis_mm())
    r = xp.arange(0, k, root_size, dtype=np.int64)
    starts = xp.stack(xp.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    size = root_size
    while len(starts):
        lo, hi = axis[starts], axis[xp.minimum(starts + size, k) - 1]
        votes = sum(test.may_keep(lo, hi).astype(np.int32) for test in tests)
        starts = starts[votes >= need]
        if size <= leaf_size or len(starts) == 0:
            break
        starts = _children(xp, starts, size, k)
        size //= 2
    survivors = [0] * n
    if len(starts) == 0:
        return CarveOutcome(np.empty((0, 3)), tuple(survivors))
    kept = []
    for flat, x, y, z in _leaf_points(xp, starts, size, k, axis, chunk_points):
        support = xp.zeros((n, len(flat)), dtype=bool)
        for i, test in enumerate(exact):
            support[i, test.kept(x, y, z)] = True
        keep = support.sum(axis=0) >= need
        for i in range(n):
            survivors[i] += int(xp.count_nonzero(support[i, keep]))
        kept.append(flat[keep])
    flat = xp.sort(xp.concatenate(kept))
    flat = flat.get() if hasattr(flat, "get") else flat
    return CarveOutcome(lattice.points_at(flat), tuple(survivors))


def carve_lookup(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 threshold_px: float, min_views: int | None = None) -> CarveOutcome:
    """The ``lookup`` engine: a sweep over blocks of 16**3 points, culled, split once into 4**3
    blocks, culled again, then exact constant-time lookups per point."""
    root, leaf = cell_sizes("lookup", lattice.resolution)
    return carve_hierarchical(lattice, projections, masks, threshold_px=threshold_px, root_size=root, leaf_size=leaf,
                              min_views=min_views)


def carve_octree(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 threshold_px: float, min_views: int | None = None) -> CarveOutcome:
    """The ``octree`` engine: culling from cells of up to 128**3 points down to 4**3, then exact
    lookups; memory follows the surviving cells, so K up to 1024 fits in a few hundred MiB."""
    root, leaf = cell_sizes("octree", lattice.resolution)
    return carve_hierarchical(lattice, projections, masks, threshold_px=threshold_px, root_size=root, leaf_size=leaf,
                              min_views=min_views)


ENGINES["lookup"] = carve_lookup
ENGINES["octree"] = carve_octree
