"""Centerline points from the carved cloud (docs/conventions.md, method step 4)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree
from skimage.morphology import thin

from ..geometry import Projection
from .engines import mask_pixel_centres

__all__ = ["skeletonise", "extract_centerlines"]


def skeletonise(mask: np.ndarray) -> np.ndarray:
    """One-pixel-wide skeleton of a bool mask by Guo–Hall thinning (``skimage.morphology.thin``).

    Thinning only looks at 3x3 neighbourhoods and treats the outside as background, so it runs on
    the mask's bounding box with a one-pixel background margin: the same skeleton, less work.
    """
    mask = np.asarray(mask, dtype=bool)
    skeleton = np.zeros_like(mask)
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if len(rows) == 0:
        return skeleton
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    crop = np.zeros((r1 - r0 + 2, c1 - c0 + 2), dtype=bool)
    crop[1:-1, 1:-1] = mask[r0:r1, c0:c1]
    skeleton[r0:r1, c0:c1] = thin(crop)[1:-1, 1:-1]
    return skeleton


def extract_centerlines(points_mm: np.ndarray, projections: Sequence[Projection],
                        masks: Sequence[np.ndarray]) -> np.ndarray:
    """Select the carved points that lie on every view's skeleton.

    Starting from ``points_mm`` as candidates, for each view in turn: project the candidates, build
    a cKDTree on the projections, query it with every skeleton pixel centre, and keep the nearest
    candidate of each skeleton pixel (each kept once, in candidate order).

    Parameters
    ----------
    points_mm : (N, 3) array
        The carved vessel points, mm.
    projections, masks : sequences of equal length
        The views, as given to the reconstruction.

    Returns
    -------
    (M, 3) array
        Centerline points, mm (M = 0 when there are no candidates).
    """
    candidates = np.asarray(points_mm, dtype=np.float64)
    for projection, mask in zip(projections, masks):
        if len(candidates) == 0:
            break
        skeleton_uv = mask_pixel_centres(skeletonise(mask))
        if len(skeleton_uv) == 0:
            return candidates[:0]
        tree = cKDTree(projection.project(candidates))
        _, nearest = tree.query(skeleton_uv, k=1)
        candidates = candidates[np.unique(nearest)]
    return candidates
