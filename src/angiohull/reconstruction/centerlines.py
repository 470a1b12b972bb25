"""Centerline points from the carved cloud (docs/conventions.md, method step 4)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from ..geometry import Projection
from ..thinning import guo_hall_thin
from .engines import mask_pixel_centres

__all__ = ["skeletonise", "extract_centerlines", "TIE_PX"]

TIE_PX = 1e-9
"""Candidates whose projections lie within this many pixels of the same distance from a skeleton
pixel are equally near it; the earliest of them (in the order of the candidates) is its nearest."""


def skeletonise(mask: np.ndarray) -> np.ndarray:
    """One-pixel-wide skeleton of a bool mask by Guo–Hall thinning, as the authors thin
    (:func:`angiohull.thinning.guo_hall_thin` with ``keep_edge=True``: the pixels on the image's edge
    are never deleted)."""
    return guo_hall_thin(mask, keep_edge=True)


def _nearest(tree: cKDTree, query: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Index of the nearest point of ``tree`` to each query point, ties (within :data:`TIE_PX`)
    going to the point of lowest ``rank``."""
    distance, nearest = tree.query(query, k=2 if tree.n > 1 else 1)
    if distance.ndim == 1:
        return nearest
    tied = np.flatnonzero(distance[:, 1] <= distance[:, 0] + TIE_PX)
    nearest = nearest[:, 0]
    for i in tied:
        equally_near = np.asarray(tree.query_ball_point(query[i], distance[i, 0] + TIE_PX))
        nearest[i] = equally_near[np.argmin(rank[equally_near])]
    return nearest


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
    for projection, mask in zip(projections, masks):
        if len(index) == 0:
            break
        skeleton_uv = mask_pixel_centres(skeletonise(mask))
        if len(skeleton_uv) == 0:
            return points[:0]
        nearest = _nearest(cKDTree(projection.project(points[index])), skeleton_uv, index)
        index = index[nearest] if keep_duplicates else index[np.unique(nearest)]
    return points[index]
