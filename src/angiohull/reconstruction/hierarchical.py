"""Hierarchical carving: cull blocks of lattice points with a conservative test, then test exactly.

A *cell* is a block of ``size**3`` lattice points (fewer at the far faces of the lattice). A cell
survives a view when the footprint of its bounding box — the bounding rectangle of its 8 projected
corners, widened by the threshold — contains a mask pixel centre, which a summed-area table of the
mask answers in constant time; a cell reaching behind the source always survives. No lattice point
of a culled cell can be kept by the exact test, so the result equals the dense lattice's. Surviving
cells are split in eight until they reach the leaf size; the points of the leaf cells then get the
exact per-point test of :class:`~angiohull.reconstruction.engines.MaskLookup`.

The dense lattice is never held: memory follows the number of surviving cells and leaf points.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..geometry import Projection
from .cube import Lattice
from .engines import CHUNK_POINTS, ENGINES, CarveOutcome, MaskLookup, project_in_front, sparsest_first

__all__ = ["carve_hierarchical", "carve_lookup", "carve_octree", "FootprintTest"]

_MARGIN_PX = 1e-6  # widening of footprints against rounding in the corner projections


class FootprintTest:
    """Conservative "may a point of this box be kept by this view" test for many boxes at once."""

    def __init__(self, projection: Projection, mask: np.ndarray, threshold_px: float):
        self.matrix = projection.matrix
        self.rows, self.cols = mask.shape
        self.reach = float(threshold_px) + _MARGIN_PX
        table = np.zeros((self.rows + 1, self.cols + 1), dtype=np.int64 if mask.size >= 2 ** 31 else np.int32)
        table[1:, 1:] = mask
        np.cumsum(table, axis=1, out=table)  # summed-area table: table[r, c] = mask[:r, :c].sum()
        np.cumsum(table, axis=0, out=table)
        self.table = table

    def may_keep(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Bool (n,) for boxes with corners ``lo`` and ``hi`` (n, 3) in mm."""
        n = len(lo)
        corners = np.empty((n, 8, 3))
        for c in range(8):
            corners[:, c, 0] = hi[:, 0] if c & 4 else lo[:, 0]
            corners[:, c, 1] = hi[:, 1] if c & 2 else lo[:, 1]
            corners[:, c, 2] = hi[:, 2] if c & 1 else lo[:, 2]
        uv, front = project_in_front(corners.reshape(-1, 3), self.matrix)
        all_front = front.reshape(n, 8).all(axis=1)
        keep = ~all_front  # a box reaching behind the source has no bounded footprint: keep it
        rows_front = np.repeat(all_front, 8)[front]
        uv = uv[rows_front].reshape(-1, 8, 2)
        if len(uv) == 0:
            return keep
        c0 = np.clip(np.ceil(uv[..., 0].min(axis=1) - self.reach), 0, self.cols).astype(np.intp)
        c1 = np.clip(np.floor(uv[..., 0].max(axis=1) + self.reach) + 1, 0, self.cols).astype(np.intp)
        r0 = np.clip(np.ceil(uv[..., 1].min(axis=1) - self.reach), 0, self.rows).astype(np.intp)
        r1 = np.clip(np.floor(uv[..., 1].max(axis=1) + self.reach) + 1, 0, self.rows).astype(np.intp)
        t = self.table
        count = t[r1, c1] - t[r0, c1] - t[r1, c0] + t[r0, c0]
        keep[all_front] = (count > 0) & (c1 > c0) & (r1 > r0)
        return keep


def _cell_boxes(lattice: Lattice, starts: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    axis = lattice.axis_mm()
    last = np.minimum(starts + size, lattice.resolution) - 1
    return axis[starts], axis[last]


def _split(starts: np.ndarray, size: int, k: int) -> np.ndarray:
    half = size // 2
    offsets = np.array([[a, b, c] for a in (0, half) for b in (0, half) for c in (0, half)], dtype=np.int64)
    children = (starts[:, None, :] + offsets[None]).reshape(-1, 3)
    return children[np.all(children < k, axis=1)]


def _leaf_indices(starts: np.ndarray, size: int, k: int) -> np.ndarray:
    """Flat lattice indices of the points of leaf cells (n_cells * size**3 at most), unsorted."""
    r = np.arange(size, dtype=np.int64)
    offsets = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    ijk = (starts[:, None, :] + offsets[None]).reshape(-1, 3)
    ijk = ijk[np.all(ijk < k, axis=1)]
    return (ijk[:, 0] * k + ijk[:, 1]) * k + ijk[:, 2]


def carve_hierarchical(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                       threshold_px: float, root_size: int, leaf_size: int) -> CarveOutcome:
    """Cull cells from ``root_size`` down to ``leaf_size`` (powers of two), then test points exactly."""
    k = lattice.resolution
    order = sparsest_first(masks)
    tests = [FootprintTest(projections[i], masks[i], threshold_px) for i in order]
    lookups = [(projections[i].matrix, MaskLookup(masks[i], threshold_px)) for i in order]
    r = np.arange(0, k, root_size, dtype=np.int64)
    starts = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    size = root_size
    while True:
        cell_survivors = []  # lattice points (at most size**3 a cell) alive after each view
        for test in tests:
            if len(starts):
                lo, hi = _cell_boxes(lattice, starts, size)
                starts = starts[test.may_keep(lo, hi)]
            cell_survivors.append(len(starts) * size ** 3)
        if size <= leaf_size or len(starts) == 0:
            break
        starts = _split(starts, size, k)
        size //= 2
    if len(starts) == 0:  # culled away: say which view removed the last cells
        return CarveOutcome(np.empty((0, 3)), tuple(cell_survivors), order)
    survivors = [0] * len(order)
    kept = []
    cells_per_chunk = max(1, CHUNK_POINTS // size ** 3)
    for c in range(0, len(starts), cells_per_chunk):
        flat = _leaf_indices(starts[c:c + cells_per_chunk], size, k)
        points = lattice.points_at(flat)
        for i, (matrix, lookup) in enumerate(lookups):
            if len(points):
                uv, front = project_in_front(points, matrix)
                front[front] = lookup.near(uv)
                points, flat = points[front], flat[front]
            survivors[i] += len(points)
        kept.append(flat)
    flat = np.sort(np.concatenate(kept))
    return CarveOutcome(lattice.points_at(flat), tuple(survivors), order)


def carve_lookup(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 threshold_px: float) -> CarveOutcome:
    """The ``lookup`` engine: a sweep over blocks of 16**3 points, culled, split once into 4**3
    blocks, culled again, then exact constant-time lookups per point."""
    return carve_hierarchical(lattice, projections, masks, threshold_px=threshold_px, root_size=16, leaf_size=4)


def carve_octree(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 threshold_px: float) -> CarveOutcome:
    """The ``octree`` engine: culling from cells of up to 128**3 points down to 4**3, then exact
    lookups; memory follows the surviving cells, so K up to 1024 fits in a few hundred MiB."""
    root = min(128, 1 << max(2, int(np.ceil(np.log2(lattice.resolution)))))
    return carve_hierarchical(lattice, projections, masks, threshold_px=threshold_px, root_size=root, leaf_size=4)


ENGINES["lookup"] = carve_lookup
ENGINES["octree"] = carve_octree
