"""Carving engines: which lattice points survive every view.

An engine is a function ``(lattice, projections, masks, *, threshold_px) -> CarveOutcome``. All
engines implement the same rule (DESIGN.md, method step 3): a point is kept by a view when it lies
in front of the source (``w > 0``) and the Euclidean distance from its projection to the nearest
mask pixel centre is strictly below ``threshold_px``; views are applied in the given order, each to
the survivors of the previous ones.

``kdtree`` is the reference: the paper's own procedure, one :class:`scipy.spatial.cKDTree` per
view built on the mask's pixel centres and queried by every surviving point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from ..geometry import Projection
from .cube import Lattice

__all__ = ["CarveOutcome", "ENGINES", "carve_kdtree", "mask_pixel_centres"]

CHUNK_POINTS = 1 << 21
"""Points projected at once by the dense engines (bounds temporary memory)."""


@dataclass(frozen=True)
class CarveOutcome:
    """What an engine returns."""

    points_mm: np.ndarray  # (N, 3) kept lattice points, mm, in lattice order
    survivors_per_view: tuple[int, ...]  # points alive after each view, in the order applied


def mask_pixel_centres(mask: np.ndarray) -> np.ndarray:
    """Pixel centres ``(u, v) = (column, row)`` of the nonzero pixels, shape (M, 2) float64."""
    rows, cols = np.nonzero(mask)
    return np.stack([cols, rows], axis=1).astype(np.float64)


def _kept_by_view(points: np.ndarray, projection: Projection, tree: cKDTree, threshold_px: float) -> np.ndarray:
    h = points @ projection.matrix[:, :3].T + projection.matrix[:, 3]
    front = h[:, 2] > 0
    keep = np.zeros(len(points), dtype=bool)
    uv = h[front, :2] / h[front, 2:3]
    distance, _ = tree.query(uv, k=1, distance_upper_bound=threshold_px)
    keep[front] = distance < threshold_px
    return keep


def carve_kdtree(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 threshold_px: float) -> CarveOutcome:
    """The reference engine: sequential filtering with one cKDTree per view (the paper's method)."""
    trees = [cKDTree(mask_pixel_centres(m)) for m in masks]
    survivors = [0] * len(projections)
    kept_chunks = []
    for start in range(0, lattice.n_points, CHUNK_POINTS):
        points = lattice.points(start, start + CHUNK_POINTS)
        for i, (projection, tree) in enumerate(zip(projections, trees)):
            if len(points):
                points = points[_kept_by_view(points, projection, tree, threshold_px)]
            survivors[i] += len(points)
        kept_chunks.append(points)
    return CarveOutcome(np.concatenate(kept_chunks, axis=0), tuple(survivors))


Engine = Callable[..., CarveOutcome]

ENGINES: dict[str, Engine] = {"kdtree": carve_kdtree}
"""Engines by name."""
