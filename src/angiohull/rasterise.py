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

import itertools
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi

from . import _validation as _v
from .errors import GeometryError
from .geometry import Projection

__all__ = ["boundary_cells", "rasterise_points_paper", "splat_points", "cell_silhouette", "paper_closing_footprint",
           "dilated_square"]


def paper_closing_footprint(radius_px: int = 2) -> np.ndarray:
    """A disk of the given radius, ``x**2 + y**2 <= r**2``, as a bool array."""
    yy, xx = np.mgrid[-radius_px:radius_px + 1, -radius_px:radius_px + 1]
    return (xx * xx + yy * yy) <= radius_px * radius_px


def dilated_square(image: np.ndarray, side_px: int) -> np.ndarray:
    """``ndi.binary_dilation(image, np.ones((side_px, side_px)))``, the same pixels: a square is the
    product of two lines, so the dilation is a running maximum along the rows, then along the
    columns (O(1) a pixel whatever the side; 4-7x faster at side 9 on 512 x 512). For an even side
    scipy's dilation reaches one pixel further back than forward, which the filters' origin -1 gives."""
    side = int(side_px)
    if side < 1:
        raise ValueError(f"the square's side must be at least 1 pixel, got {side_px}")
    origin = 0 if side % 2 else -1
    out = ndi.maximum_filter1d(np.asarray(image, dtype=bool).view(np.uint8), side, axis=0, mode="constant",
                               cval=0, origin=origin)
    return ndi.maximum_filter1d(out, side, axis=1, mode="constant", cval=0, origin=origin).view(bool)


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


def _interior_cells(points: np.ndarray, cell_mm: float) -> np.ndarray:
    """(N,) bool: the point's six face neighbours at ``cell_mm`` are among the points too. All False
    unless the points lie on a grid of that spacing (to 1e-6 of a cell)."""
    interior = np.zeros(len(points), dtype=bool)
    index_float = (points - points.min(axis=0)) / cell_mm
    index = np.rint(index_float).astype(np.int64)
    if np.abs(index_float - index).max(initial=0.0) > 1e-6:
        return interior
    size = index.max(axis=0) + 3  # a margin of one cell, so that neighbours never wrap
    stride = np.array([size[1] * size[2], size[2], 1], dtype=np.int64)
    key = (index + 1) @ stride
    ordered = np.sort(key)
    interior[:] = True
    for step in (*stride, *-stride):
        neighbour = key + step
        at = np.minimum(np.searchsorted(ordered, neighbour), len(ordered) - 1)
        interior &= ordered[at] == neighbour
    return interior


def boundary_cells(points_mm: np.ndarray, cell_mm: float, sources_mm: Sequence[np.ndarray] = ()) -> np.ndarray:
    """The points of a grid of spacing ``cell_mm`` that miss one of their six face neighbours: the
    cells whose union has the same silhouette from any source outside it. All the points when they
    do not lie on such a grid, or when one of ``sources_mm`` (camera centres) lies in their box."""
    points = _v.points_array(points_mm, error=GeometryError)
    half = _v.positive_finite(cell_mm, "cell_mm", error=GeometryError) / 2.0
    if len(points) == 0:
        return points
    low, high = points.min(axis=0) - half, points.max(axis=0) + half
    if any(np.all((low <= source) & (source <= high)) for source in sources_mm):
        return points  # the argument needs every source outside
    return points[~_interior_cells(points, 2.0 * half)]


def cell_silhouette(points_mm: np.ndarray, projection: Projection, cell_mm: float, *,
                    chunk_pairs: int = 4_000_000, skip_interior: bool = True) -> np.ndarray:
    """Silhouette of the union of axis-aligned cubes of edge ``cell_mm`` centred on the points.

    Pixel ``(r, c)`` is set when the ray from the source through its centre ``(u, v) = (c, r)``
    meets one of the cubes (slab test, exact up to rounding). This is the reconstruction's
    silhouette at pixel resolution, used by the plain Dice2D: each kept lattice point stands for
    the lattice cell around it.

    When the points lie on a grid of spacing ``cell_mm`` (a lattice's kept points), the cells whose
    six face neighbours are all there are skipped: a ray from outside the union meets it first
    through the face of a cell with a missing neighbour, so they add no pixel (at K = 1024 most
    cells of a vessel are inside).

    Parameters
    ----------
    points_mm : (N, 3) array
        Cell centres, mm.
    projection : Projection
    cell_mm : float
        Edge of each cell (the lattice spacing), mm.
    chunk_pairs : int, keyword-only
        Upper bound on the (cell, candidate pixel) pairs tested at once (bounds memory).
    skip_interior : bool, keyword-only
        Skip the interior cells (default); False when the caller passes boundary cells already
        (:func:`boundary_cells`, e.g. once for several views).

    Returns
    -------
    (rows, cols) bool array
    """
    points = _v.points_array(points_mm, error=GeometryError)
    half = _v.positive_finite(cell_mm, "cell_mm", error=GeometryError) / 2.0
    rows, cols = projection.image_shape
    image = np.zeros((rows, cols), dtype=bool)
    if skip_interior:
        points = boundary_cells(points, 2.0 * half, [projection.camera_centre_mm])
    corners = np.array(list(itertools.product((-half, half), repeat=3)))
    centre = projection.camera_centre_mm
    # cells containing or behind the source have no bounded footprint; they are left out
    lo, hi = points - half, points + half
    in_front = np.all(projection.homogeneous((points[:, None, :] + corners).reshape(-1, 3))[:, 2].reshape(-1, 8) > 0, axis=1)
    contains_source = np.all((lo <= centre) & (centre <= hi), axis=1)
    points, lo, hi = points[in_front & ~contains_source], lo[in_front & ~contains_source], hi[in_front & ~contains_source]
    if len(points) == 0:
        return image
    uv = projection.project((points[:, None, :] + corners).reshape(-1, 3)).reshape(-1, 8, 2)
    u0 = np.clip(np.ceil(uv[..., 0].min(1)), 0, cols).astype(np.int64)
    u1 = np.clip(np.floor(uv[..., 0].max(1)), -1, cols - 1).astype(np.int64)
    v0 = np.clip(np.ceil(uv[..., 1].min(1)), 0, rows).astype(np.int64)
    v1 = np.clip(np.floor(uv[..., 1].max(1)), -1, rows - 1).astype(np.int64)
    nu, nv = np.maximum(u1 - u0 + 1, 0), np.maximum(v1 - v0 + 1, 0)
    pairs = nu * nv
    inverse = np.linalg.inv(projection.matrix[:, :3])
    bounds = np.concatenate([[0], np.cumsum(pairs)])
    start = 0
    while start < len(points):
        stop = int(np.searchsorted(bounds, bounds[start] + chunk_pairs, side="right")) - 1
        stop = max(stop, start + 1)
        cell = np.repeat(np.arange(start, stop), pairs[start:stop])
        local = np.arange(len(cell)) - np.repeat(bounds[start:stop] - bounds[start], pairs[start:stop])
        u = u0[cell] + local % np.maximum(nu[cell], 1)
        v = v0[cell] + local // np.maximum(nu[cell], 1)
        # C + t * inv(M) @ [u, v, 1] projects to (u, v) with w = t: t > 0 is in front of the source
        direction = np.stack([u, v, np.ones_like(u)], axis=1).astype(np.float64) @ inverse.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t_lo = (lo[cell] - centre) / direction
            t_hi = (hi[cell] - centre) / direction
        t_near = np.where(np.isnan(t_lo), -np.inf, np.minimum(t_lo, t_hi)).max(axis=1)
        t_far = np.where(np.isnan(t_hi), np.inf, np.maximum(t_lo, t_hi)).min(axis=1)
        hit = (t_near <= t_far) & (t_far > 0)
        image[v[hit], u[hit]] = True
        start = stop
    return image
