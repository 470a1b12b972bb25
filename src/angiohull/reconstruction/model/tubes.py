"""Lattice points inside a union of tubes (segments swept by a ball whose radius goes linearly from
one end's to the other's)."""

from __future__ import annotations

import numpy as np

from ...compiled import kernels
from ...tree.voxels import coordinates
from ..cube import Lattice

__all__ = ["lattice_points_in_tubes"]

_CHUNK = 2_000_000  # (ball, column) pairs per block


def _densified(a: np.ndarray, b: np.ndarray, ra: np.ndarray, rb: np.ndarray,
               step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Balls along each segment, at most ``step_mm`` apart: (centres (M, 3), radii (M,))."""
    length = np.linalg.norm(b - a, axis=1)
    count = np.maximum(1, np.ceil(length / step_mm).astype(np.int64))
    owner = np.repeat(np.arange(len(a)), count + 1)
    first = np.concatenate([[0], np.cumsum(count + 1)[:-1]])
    t = (np.arange(len(owner)) - first[owner]) / count[owner]
    centres = a[owner] + t[:, None] * (b[owner] - a[owner])
    radii = ra[owner] + t * (rb[owner] - ra[owner])
    return centres, radii


def lattice_points_in_tubes(starts_mm: np.ndarray, ends_mm: np.ndarray, start_radius_mm: np.ndarray,
                            end_radius_mm: np.ndarray, lattice: Lattice, *, margin_mm: float = 0.0) -> np.ndarray:
    """The points of ``lattice`` within ``margin_mm`` of the union of the tubes; (N, 3) mm, in
    lattice (C) order.

    The tubes are covered by balls at most half a lattice step apart along each segment (the union
    of the balls falls short of the swept tube by at most ``(h / 4)**2 / (2 r)``: 0.016 mm for a
    0.5 mm step and a 0.5 mm radius). A lattice point is kept when it lies within a ball's radius
    (plus the margin) of its centre, decided exactly column by column: each ball covers, in each
    lattice column (x, y) of its disk, one run of z indices, marked in a difference array over the
    tubes' bounding box and summed along z.
    """
    h = lattice.spacing_mm
    half = lattice.half_edge_mm
    k = lattice.resolution
    if len(starts_mm) == 0:
        return np.zeros((0, 3))
    centres, radii = _densified(np.asarray(starts_mm, float), np.asarray(ends_mm, float),
                                np.asarray(start_radius_mm, float), np.asarray(end_radius_mm, float), 0.5 * h)
    axis = lattice.axis_mm()
    c = (centres + half) / h  # fractional lattice indices
    reach = (radii + margin_mm) / h  # in lattice steps
    lo = np.clip(np.floor(c - reach[:, None]).astype(np.int64), 0, k - 1).min(axis=0)
    hi = np.clip(np.ceil(c + reach[:, None]).astype(np.int64), 0, k - 1).max(axis=0)
    shape = hi - lo + 1
    compiled = kernels()
    if compiled is not None:
        inside = compiled.balls_on_lattice(centres, radii, float(margin_mm), axis, float(half), float(h), lo,
                                           shape.astype(np.int64))
        ijk = coordinates(inside) + lo
        return lattice.points_at((ijk[:, 0] * k + ijk[:, 1]) * k + ijk[:, 2])
    size = int(np.prod(shape[:2])) * int(shape[2] + 1)  # one spare z per column for the run ends
    marks = np.zeros(size, dtype=np.int64)
    base = np.floor(c[:, :2]).astype(np.int64)
    cells = np.ceil(reach).astype(np.int64) + 1
    for n in np.unique(cells):
        group = np.flatnonzero(cells == n)
        grid = np.arange(-n, n + 2)
        di, dj = (x.ravel() for x in np.meshgrid(grid, grid, indexing="ij"))
        per_block = max(1, _CHUNK // len(di))
        for first in range(0, len(group), per_block):
            g = group[first:first + per_block]
            i = base[g, 0, None] + di[None, :]
            j = base[g, 1, None] + dj[None, :]
            ok = (i >= 0) & (i < k) & (j >= 0) & (j < k)
            ic, jc = np.clip(i, 0, k - 1), np.clip(j, 0, k - 1)
            # squared distance across the column, in mm, from the lattice's own coordinates
            dx = axis[ic] - centres[g, 0, None]
            dy = axis[jc] - centres[g, 1, None]
            rem = (radii[g, None] + margin_mm) ** 2 - dx * dx - dy * dy
            ok &= rem >= 0
            span = np.sqrt(np.maximum(rem, 0.0))
            z = centres[g, 2, None]
            k_lo = np.ceil((z - span + half) / h - 1e-9).astype(np.int64)
            k_hi = np.floor((z + span + half) / h + 1e-9).astype(np.int64)
            # the lattice's own coordinates decide at the run's ends (the same test as a distance check)
            k_lo = np.clip(k_lo, 0, k - 1)
            k_hi = np.clip(k_hi, 0, k - 1)
            for _ in range(2):
                k_lo = np.where((k_lo > 0) & ((axis[np.maximum(k_lo - 1, 0)] - z) ** 2 <= rem), k_lo - 1, k_lo)
                # (a run beyond the lattice's last or first point moves past it: read there, and empty)
                k_lo = np.where((axis[np.minimum(k_lo, k - 1)] - z) ** 2 > rem, k_lo + 1, k_lo)
                k_hi = np.where((k_hi < k - 1) & ((axis[np.minimum(k_hi + 1, k - 1)] - z) ** 2 <= rem), k_hi + 1, k_hi)
                k_hi = np.where((axis[np.maximum(k_hi, 0)] - z) ** 2 > rem, k_hi - 1, k_hi)
            ok &= k_lo <= k_hi
            column = ((ic - lo[0]) * shape[1] + (jc - lo[1]))[ok] * (shape[2] + 1)
            marks += np.bincount(column + (k_lo[ok] - lo[2]), minlength=size)
            marks -= np.bincount(column + (k_hi[ok] + 1 - lo[2]), minlength=size)
    inside = np.cumsum(marks.reshape(shape[0], shape[1], shape[2] + 1), axis=2)[:, :, :-1] > 0
    ijk = np.argwhere(inside) + lo
    return lattice.points_at((ijk[:, 0] * k + ijk[:, 1]) * k + ijk[:, 2])
