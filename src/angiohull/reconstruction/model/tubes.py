"""Lattice points inside a union of tubes (capsules with a radius at each end)."""

from __future__ import annotations

import numpy as np

from ..cube import Lattice

__all__ = ["lattice_points_in_tubes"]

_CHUNK = 4_000_000  # candidate (ball, offset) pairs per block


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
    """The points of ``lattice`` within ``margin_mm`` of the union of the tubes (each a segment
    swept by a ball whose radius goes linearly from one end's to the other's); (N, 3) mm, in
    lattice (C) order. The tubes are covered by balls at most half a lattice step apart along
    each segment: the union of the balls falls short of the swept tube by at most
    ``(h / 4)**2 / (2 r)`` (0.016 mm for a 0.5 mm lattice step and a 0.5 mm radius)."""
    h = lattice.spacing_mm
    half = lattice.half_edge_mm
    k = lattice.resolution
    if len(starts_mm) == 0:
        return np.zeros((0, 3))
    centres, radii = _densified(np.asarray(starts_mm, float), np.asarray(ends_mm, float),
                                np.asarray(start_radius_mm, float), np.asarray(end_radius_mm, float), 0.5 * h)
    reach = radii + margin_mm
    base = np.rint((centres + half) / h).astype(np.int64)
    cells = np.ceil(reach / h).astype(np.int64) + 1
    found = []
    for n in np.unique(cells):
        group = np.flatnonzero(cells == n)
        grid = np.arange(-n, n + 1)
        offsets = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), axis=-1).reshape(-1, 3)
        offsets = offsets[np.linalg.norm(offsets, axis=1) <= n + 1]
        per_block = max(1, _CHUNK // len(offsets))
        for lo in range(0, len(group), per_block):
            g = group[lo:lo + per_block]
            index = base[g, None, :] + offsets[None, :, :]  # (G, O, 3)
            position = index * h - half
            inside = np.linalg.norm(position - centres[g, None, :], axis=2) <= reach[g, None]
            inside &= np.all((index >= 0) & (index < k), axis=2)
            hit = index[inside]
            found.append((hit[:, 0] * k + hit[:, 1]) * k + hit[:, 2])
    return lattice.points_at(np.unique(np.concatenate(found)))
