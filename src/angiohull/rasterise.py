"""Turning 3D points into 2D images of a view.

Three rasterisers, each for a stated purpose:

* :func:`rasterise_points_paper` — the paper's rasteriser, used by its Dice2D protocol and by its
  synthetic data: truncate continuous projections to pixels, close with a disk of radius 2, blur
  with a Gaussian of sigma 0.5 and threshold at 0.25. It truncates (pixel ``(r, c)`` covers
  ``[c, c+1) x [r, r+1)``), unlike this project's convention of pixel centres at integers; kept
  as published so the paper's numbers can be reproduced.
* :func:`splat_points` — each point marks the pixel whose centre is nearest its projection.
* :func:`cell_silhouette` — the silhouette, at pixel resolution, of the volume the points stand
  for when each is the centre of a lattice cell (a cube of edge ``cell_mm``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage as ndi

from . import _validation as _v
from .errors import GeometryError
from .geometry import Projection

__all__ = ["rasterise_points_paper", "splat_points", "cell_silhouette", "paper_closing_footprint"]


def paper_closing_footprint(radius_px: int = 2) -> np.ndarray:
    """A disk of the given radius, ``x**2 + y**2 <= r**2``, as a bool array."""
    yy, xx = np.mgrid[-radius_px:radius_px + 1, -radius_px:radius_px + 1]
    return (xx * xx + yy * yy) <= radius_px * radius_px


def _pixels_in_front(points_mm: np.ndarray, projection: Projection) -> np.ndarray:
    h = projection.homogeneous(points_mm)
    h = h[h[:, 2] > 0]
    return h[:, :2] / h[:, 2:3]


def rasterise_points_paper(points_mm: np.ndarray, projection: Projection) -> np.ndarray:
    """The paper's rasteriser: points -> bool image of ``projection.image_shape``.

    Projections with ``0 < u < cols`` and ``0 < v < rows`` set pixel ``(floor(v), floor(u))``; the
    image is then closed with a disk of radius 2 (outside the image counts as background for the
    dilation and as foreground for the erosion), blurred with a Gaussian of sigma 0.5 px (nearest
    edge mode, truncated at 4 sigma) and thresholded at 0.25.

    Parameters
    ----------
    points_mm : (N, 3) array
        World points in mm; points behind the source are ignored.
    projection : Projection

    Returns
    -------
    (rows, cols) bool array
    """
    rows, cols = projection.image_shape
    uv = _pixels_in_front(_v.points_array(points_mm, error=GeometryError), projection)
    inside = (uv[:, 0] > 0) & (uv[:, 0] < cols) & (uv[:, 1] > 0) & (uv[:, 1] < rows)
    uv = uv[inside]
    image = np.zeros((rows, cols), dtype=bool)
    image[uv[:, 1].astype(np.intp), uv[:, 0].astype(np.intp)] = True
    disk = paper_closing_footprint(2)
    closed = ndi.binary_erosion(ndi.binary_dilation(image, disk), disk, border_value=1)
    blurred = ndi.gaussian_filter(closed.astype(np.float64), sigma=0.5, mode="nearest", truncate=4.0)
    return blurred > 0.25


def splat_points(points_mm: np.ndarray, projection: Projection) -> np.ndarray:
    """Bool image with the pixel nearest each projected point set (points outside are ignored)."""
    rows, cols = projection.image_shape
    uv = _pixels_in_front(_v.points_array(points_mm, error=GeometryError), projection)
    idx = np.rint(uv)
    inside = (idx[:, 0] >= 0) & (idx[:, 0] < cols) & (idx[:, 1] >= 0) & (idx[:, 1] < rows)
    idx = idx[inside].astype(np.intp)
    image = np.zeros((rows, cols), dtype=bool)
    image[idx[:, 1], idx[:, 0]] = True
    return image


def cell_silhouette(points_mm: np.ndarray, projection: Projection, cell_mm: float, *,
                    max_step_px: float = 0.5, chunk_points: int = 2_000_000) -> np.ndarray:
    """Silhouette of the union of cubes of edge ``cell_mm`` centred on the points.

    Each cube is sampled on a regular sub-grid fine enough that neighbouring samples project at most
    ``max_step_px`` apart; every sample marks the pixel whose centre is nearest. This is the
    reconstruction's silhouette at pixel resolution (used by the plain Dice2D).

    Parameters
    ----------
    points_mm : (N, 3) array
        Cell centres, mm.
    projection : Projection
    cell_mm : float
        Edge of each cell (the lattice spacing), mm.
    max_step_px : float, keyword-only
        Largest projected distance between neighbouring samples of a cell, px.

    Returns
    -------
    (rows, cols) bool array
    """
    points = _v.points_array(points_mm, error=GeometryError)
    cell = _v.positive_finite(cell_mm, "cell_mm", error=GeometryError)
    image = np.zeros(projection.image_shape, dtype=bool)
    if len(points) == 0:
        return image
    depth = projection.depth_mm(points)
    points = points[depth > 0]
    if len(points) == 0:
        return image
    f_max = max(projection.focal_lengths_px)
    nearest = float(projection.depth_mm(points).min())
    footprint_px = cell * f_max / max(nearest - cell, 1e-6)
    steps = max(1, math.ceil(footprint_px / max_step_px))
    offsets_1d = ((np.arange(steps) + 0.5) / steps - 0.5) * cell
    offsets = np.stack(np.meshgrid(offsets_1d, offsets_1d, offsets_1d, indexing="ij"), -1).reshape(-1, 3)
    per_chunk = max(1, chunk_points // len(offsets))
    for start in range(0, len(points), per_chunk):
        samples = (points[start:start + per_chunk, None, :] + offsets[None]).reshape(-1, 3)
        image |= splat_points(samples, projection)
    return image
