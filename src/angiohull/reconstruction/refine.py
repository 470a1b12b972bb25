"""The ``refined`` preset: sharper hulls from what is known about vessels (beyond the paper).

The visual hull of three views is thicker than the vessel (a tube seen from three directions
carves to a polygon around its circular section, widened by the pixel threshold) and carries
phantom volume where the cones of different branches meet. :func:`refine_hull` removes both with
steps that stay interpretable:

1. **Masks** (:func:`clean_mask`): vessel pixels with fewer than 2 vessel neighbours (of 8) are
   dropped and background pixels with at least 5 are filled, before carving: isolated false
   positives go, pinholes close, and a vessel that lost pixels at random keeps the rest.
2. **Connectivity**: the tree is one structure; connected parts of the hull (26-neighbourhood on
   the lattice) holding less than ``component_fraction`` of its points are dropped.
3. **Radius consistency**: *axis points* are the hull points whose projection lies on the 2D
   centreline (Guo–Hall thinning of the mask) in every view, within the projection of a lattice
   cell: they stand for the vessels' 3D centrelines. Each gets a radius: in every view, the
   half-width of the mask at the 2D centreline pixel nearest to its projection, converted to mm at
   its depth; the smallest over the views (a vessel overlapping another in one view only looks
   wider there). A hull point is kept when its distance to the nearest axis point is at most that
   point's radius plus ``slack_cells`` lattice spacings. This trims the polygonal excess of the hull
   and the threshold's widening back to a tube. (A 3D skeleton of the hull would be the obvious
   axis, but scikit-image's 3D thinning can delete structures of even thickness entirely,
   scikit-image issue #3757.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.spatial import cKDTree
from skimage.morphology import thin

from ..geometry import Projection
from .cube import Lattice

__all__ = ["RefineSettings", "REFINED", "clean_mask", "refine_hull"]


@dataclass(frozen=True)
class RefineSettings:
    """Parameters of the ``refined`` preset."""

    resolution: int = 256  # lattice points per axis (finer than the paper's 100: less thickening)
    min_neighbours: int = 2  # clean_mask: a vessel pixel needs this many vessel neighbours (of 8)
    fill_neighbours: int = 5  # clean_mask: a background pixel with this many vessel neighbours is filled
    component_fraction: float = 0.05  # drop connected parts of the hull smaller than this fraction
    slack_cells: float = 0.5  # tolerance of the radius check, in lattice spacings


REFINED = RefineSettings()
"""The settings of ``preset="refined"`` (the same for every case; measured in docs/beyond-the-paper.md)."""


def clean_mask(mask: np.ndarray, min_neighbours: int = 2, fill_neighbours: int = 5) -> np.ndarray:
    """Remove isolated specks and fill pinholes of a bool mask.

    A vessel pixel stays when at least ``min_neighbours`` of its 8 neighbours are vessel; a
    background pixel becomes vessel when at least ``fill_neighbours`` of them are. Unlike a median
    filter, a vessel that has lost half of its pixels at random is kept (its pixels still have about
    half of their neighbours), while a lone false positive goes.
    """
    mask = np.asarray(mask, dtype=bool)
    kernel = np.ones((3, 3), dtype=np.int32)
    kernel[1, 1] = 0
    neighbours = ndi.convolve(mask.astype(np.int32), kernel, mode="constant")
    return (mask & (neighbours >= min_neighbours)) | (~mask & (neighbours >= fill_neighbours))


def refine_hull(points_mm: np.ndarray, lattice: Lattice, projections: Sequence[Projection],
                masks: Sequence[np.ndarray], settings: RefineSettings = REFINED) -> tuple[np.ndarray, dict]:
    """Connectivity and radius consistency applied to carved lattice points (see the module notes).

    Parameters
    ----------
    points_mm : (N, 3) array
        Kept lattice points of ``lattice``.
    lattice : Lattice
    projections, masks : sequences
        The views the points were carved with (masks as carved, i.e. already cleaned).
    settings : RefineSettings

    Returns
    -------
    points : (M, 3) array
        The refined points, a subset of ``points_mm`` in the same order.
    info : dict
        Counts removed by each step.
    """
    if len(points_mm) == 0:
        return points_mm, {"components_removed": 0, "radius_removed": 0}
    h = lattice.spacing_mm
    ijk = np.round((points_mm + lattice.half_edge_mm) / h).astype(np.int64)
    low = ijk.min(axis=0) - 2
    local = ijk - low
    volume = np.zeros(tuple(local.max(axis=0) + 3), dtype=bool)
    volume[tuple(local.T)] = True
    # 2. connectivity
    labels, _ = ndi.label(volume, structure=np.ones((3, 3, 3)))
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    big = sizes[labels[tuple(local.T)]] >= settings.component_fraction * len(points_mm)
    # 3. radius consistency. Axis points: hull points whose projection lies on (within a lattice
    # cell of) the 2D centreline in every view; each gets the smallest radius the views show there.
    candidates = points_mm[big]
    near_axis = np.ones(len(candidates), dtype=bool)
    radius = np.full(len(candidates), np.inf)
    for projection, mask in zip(projections, masks):
        mask = np.asarray(mask, dtype=bool)
        inside = ndi.distance_transform_edt(mask)
        centreline = thin(mask)
        off_centre, nearest = ndi.distance_transform_edt(~centreline, return_indices=True)
        uv = projection.project(candidates)
        px_per_mm = max(projection.focal_lengths_px) / projection.depth_mm(candidates)
        cols = np.clip(np.floor(uv[:, 0] + 0.5).astype(np.int64), 0, mask.shape[1] - 1)
        rows = np.clip(np.floor(uv[:, 1] + 0.5).astype(np.int64), 0, mask.shape[0] - 1)
        reach_px = 0.5 * np.sqrt(3.0) * h * px_per_mm + 0.5
        near_axis &= off_centre[rows, cols] <= reach_px
        # half-width at the nearest centreline pixel; the distance to the nearest background pixel
        # centre overshoots the edge (half-way between pixel centres) by 0.5 px
        half_width = inside[nearest[0, rows, cols], nearest[1, rows, cols]] - 0.5
        radius = np.minimum(radius, half_width / px_per_mm)
    if not near_axis.any():
        return points_mm[big], {"components_removed": int((~big).sum()), "radius_removed": 0}
    axis_points = candidates[near_axis]
    distance, owner = cKDTree(axis_points).query(candidates)
    within = distance <= radius[near_axis][owner] + settings.slack_cells * h
    keep = np.zeros(len(points_mm), dtype=bool)
    keep[np.flatnonzero(big)[within]] = True
    return points_mm[keep], {"components_removed": int((~big).sum()), "radius_removed": int((~within).sum())}
