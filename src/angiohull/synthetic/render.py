"""Binary vessel masks of a tube solid in a view: exact silhouette, or the paper's rasteriser."""

from __future__ import annotations

import numpy as np

from ..errors import AngiohullError
from ..geometry import Projection
from ..rasterise import rasterise_points_paper
from .. import options
from .phantom import TubePhantom

__all__ = ["RASTERISERS", "PAPER_SURFACE_SPACING_MM", "render_mask"]

RASTERISERS = options.RASTERISERS

PAPER_SURFACE_SPACING_MM = 0.2
"""Spacing of the surface points the paper's rasteriser splats, mm (below a pixel at the isocentre,
0.23 mm for the paper's geometry, so the closing only has to bridge sub-pixel gaps)."""


def render_mask(phantom: TubePhantom, projection: Projection, rasteriser: str = "exact", *,
                surface_points_mm: np.ndarray | None = None) -> np.ndarray:
    """A (rows, cols) bool mask of ``phantom`` seen through ``projection``.

    Parameters
    ----------
    phantom : TubePhantom
    projection : Projection
    rasteriser : {"exact", "paper"}
        See :data:`RASTERISERS`.
    surface_points_mm : (N, 3) array, optional
        For ``paper``: the surface points to splat (computed once per tree and reused over the
        views); default ``phantom.surface_points_mm(PAPER_SURFACE_SPACING_MM)``.
    """
    if rasteriser == "exact":
        return phantom.silhouette(projection)
    if rasteriser == "paper":
        points = phantom.surface_points_mm(PAPER_SURFACE_SPACING_MM) if surface_points_mm is None else surface_points_mm
        return rasterise_points_paper(points, projection)
    raise AngiohullError(f"rasteriser must be one of {', '.join(RASTERISERS)}, got {rasteriser!r}")
