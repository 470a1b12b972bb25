"""Centerline points from the carved cloud (docs/conventions.md, method step 4)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..geometry import Projection
from ..thinning import guo_hall_skeleton_pixels, guo_hall_thin
from .nearest import nearest_with_ties

__all__ = ["skeletonise", "extract_centerlines", "TIE_PX"]

TIE_PX = 1e-9
"""Candidates whose projections lie within this many pixels of the same distance from a skeleton
pixel are equally near it; the earliest of them (in the order of the candidates) is its nearest."""


def skeletonise(mask: np.ndarray) -> np.ndarray:
    """One-pixel-wide skeleton of a bool mask by Guo–Hall thinning, as the authors thin
    (:func:`angiohull.thinning.guo_hall_thin` with ``keep_edge=True``: the pixels on the image's edge
    are never deleted)."""
    return guo_hall_thin(mask, keep_edge=True)


def extract_centerlines(points_mm: np.ndarray, projections: Sequence[Projection],
                        masks: Sequence[np.ndarray], *, keep_duplicates: bool = False) -> np.ndarray:
    """Select the carved points that lie on every view's skeleton.

    Starting from ``points_mm`` as candidates, for each view in turn: project the candidates, build
    a cKDTree on the projections, query it with every skeleton pixel centre, and keep the nearest
    candidate of each skeleton pixel. Ties: of the candidates equally near a skeleton pixel (to
    :data:`TIE_PX`), the one earliest in ``points_mm`` is kept, so the result does not depend on
    how the tree was built nor on the last bits of the projection arithmetic.

    Parameters
    ----------
    points_mm : (N, 3) array
        The carved vessel points, mm.
    projections, masks : sequences of equal length
        The views, as given to the reconstruction.
    keep_duplicates : bool, keyword-only
        False (default): each kept candidate once, in candidate order. True: as the authors' code
        returns it, one row per skeleton pixel of each view (a candidate nearest to several
        skeleton pixels repeats), the last view's rows in the order of its skeleton pixels (row
        by row); for comparisons with their output.

    Returns
    -------
    (M, 3) array
        Centerline points, mm (M = 0 when there are no candidates).
    """
    points = np.asarray(points_mm, dtype=np.float64)
    index = np.arange(len(points))  # the candidates, as indices into points
    # every view's skeleton at once (as skeletonise thins each): one thinning pass over them all
    skeletons_uv = guo_hall_skeleton_pixels(masks, keep_edge=True) if len(index) else []
    for projection, skeleton_uv in zip(projections, skeletons_uv):
        if len(index) == 0:
            break
        if len(skeleton_uv) == 0:
            return points[:0]
        _, nearest = nearest_with_ties(projection.project(points[index]), skeleton_uv, TIE_PX, index)
        index = index[nearest] if keep_duplicates else index[np.unique(nearest)]
    return points[index]
