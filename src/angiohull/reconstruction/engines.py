"""Carving engines: which lattice points survive every view.

An engine is a function ``(lattice, projections, masks, *, threshold_px, min_views=None) ->
CarveOutcome``. All engines implement the same rule (docs/conventions.md, method step 3): a point is kept by a
view when it lies in front of the source (``w > 0``) and the Euclidean distance from its projection
to the nearest mask pixel centre is strictly below ``threshold_px``; views are applied in the given
order, each to the survivors of the previous ones. With ``min_views = k`` (robust carving, beyond
the paper) a point survives when at least ``k`` views keep it; ``None`` means all of them.

``kdtree`` is the reference: the paper's own procedure, one :class:`scipy.spatial.cKDTree` per
view built on the mask's pixel centres and queried by every surviving point.

:class:`MaskLookup` gives the same answer as the tree with constant-time work per point: the only
pixel centres that can lie closer than ``t`` to ``(u, v)`` are those with ``|c - u| < t`` and
``|r - v| < t``, a ``2 ceil(t) x 2 ceil(t)`` window (2 x 2 for ``t <= 1``); it reads those mask
pixels and tests their exact distances. :func:`carve_dense_lookup` applies it to every lattice
point (views sparsest mask first, each to the survivors of the previous ones); the ``lookup`` and
``octree`` engines of :mod:`.hierarchical` add conservative block culling in front of it.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from ..geometry import Projection
from .cube import Lattice

__all__ = ["CarveOutcome", "ENGINES", "carve_kdtree", "carve_dense_lookup", "mask_pixel_centres", "project_in_front",
           "MaskLookup", "sparsest_first", "project_row"]

CHUNK_POINTS = 1 << 21
"""Points projected at once by the dense engines (bounds temporary memory)."""


@dataclass(frozen=True)
class CarveOutcome:
    """What an engine returns."""

    points_mm: np.ndarray  # (N, 3) kept lattice points, mm, in lattice order
    survivors_per_view: tuple[int, ...]  # points alive after each view, in the order applied
    order: tuple[int, ...] | None = None  # indices of the views in the order applied (None: as given)


def mask_pixel_centres(mask: np.ndarray) -> np.ndarray:
    """Pixel centres ``(u, v) = (column, row)`` of the nonzero pixels, shape (M, 2) float64."""
    rows, cols = np.nonzero(mask)
    return np.stack([cols, rows], axis=1).astype(np.float64)


def project_row(x, y, z, m: list[list[float]], r: int):
    """``x*m[r][0] + y*m[r][1] + z*m[r][2] + m[r][3]``, left to right, one ufunc per operation.

    The single place where engines compute projections: element by element (no BLAS, no fused
    multiply-add), so every engine, batch size and array module (NumPy, CuPy) gives bit-identical
    coordinates for the same point and decides ties the same way.
    """
    return x * m[r][0] + y * m[r][1] + z * m[r][2] + m[r][3]


def project_in_front(points: np.ndarray, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates of the points in front of the source, and which points those are.

    Returns
    -------
    uv : (M, 2) array
        ``(u, v)`` of the points with ``w > 0``.
    front : (N,) bool array
    """
    m = np.asarray(matrix).tolist()
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    w = project_row(x, y, z, m, 2)
    front = w > 0
    x, y, z, w = x[front], y[front], z[front], w[front]
    return np.stack([project_row(x, y, z, m, 0) / w, project_row(x, y, z, m, 1) / w], axis=1), front


def _kept_by_view(points: np.ndarray, projection: Projection, tree: cKDTree, threshold_px: float) -> np.ndarray:
    uv, front = project_in_front(points, projection.matrix)
    keep = np.zeros(len(points), dtype=bool)
    distance, _ = tree.query(uv, k=1, distance_upper_bound=threshold_px)
    keep[front] = distance < threshold_px
    return keep


def carve_kdtree(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 threshold_px: float, min_views: int | None = None) -> CarveOutcome:
    """The reference engine: sequential filtering with one cKDTree per view (the paper's method).

    With ``min_views = k < N`` a point is kept when at least ``k`` of the ``N`` views keep it
    (each view's test as above); ``survivors_per_view`` then counts, per view, the kept points it
    supports.
    """
    trees = [cKDTree(mask_pixel_centres(m)) for m in masks]
    n = len(projections)
    need = n if min_views is None else int(min_views)
    survivors = [0] * n
    kept_chunks = []
    for start in range(0, lattice.n_points, CHUNK_POINTS):
        points = lattice.points(start, start + CHUNK_POINTS)
        if need == n:
            for i, (projection, tree) in enumerate(zip(projections, trees)):
                if len(points):
                    points = points[_kept_by_view(points, projection, tree, threshold_px)]
                survivors[i] += len(points)
        else:
            support = np.stack([_kept_by_view(points, p, t, threshold_px) for p, t in zip(projections, trees)])
            keep = support.sum(axis=0) >= need
            points = points[keep]
            for i in range(n):
                survivors[i] += int(np.count_nonzero(support[i, keep]))
        kept_chunks.append(points)
    return CarveOutcome(np.concatenate(kept_chunks, axis=0), tuple(survivors))


_BAND_FROM_REACH = 3  # MaskLookup decides by a distance transform first from this window reach on
_BAND_SLACK_PX = 1e-9  # ... leaving the points within this of the threshold to the exact window test


_DISTANCES: dict[tuple, np.ndarray] = {}


def _distance_to_mask(mask: np.ndarray) -> np.ndarray:
    """Distance from every pixel centre to the nearest mask pixel centre (read-only), remembered for
    the last few masks by content: calibration carves the same masks dozens of times."""
    key = (mask.shape, hashlib.blake2b(np.packbits(mask).tobytes(), digest_size=16).digest())
    if key not in _DISTANCES:
        if len(_DISTANCES) >= 16:
            _DISTANCES.pop(next(iter(_DISTANCES)))
        distance = ndi.distance_transform_edt(~mask)
        distance.flags.writeable = False
        _DISTANCES[key] = distance
    return _DISTANCES[key]


class MaskLookup:
    """Exact "closer than ``threshold_px`` to a mask pixel centre" test by direct pixel reads.

    Parameters
    ----------
    mask : (rows, cols) bool array
    threshold_px : float
        Strict distance threshold, px.
    xp : module, optional
        Array module the test runs on (NumPy, or CuPy for the GPU path).
    """

    def __init__(self, mask: np.ndarray, threshold_px: float, xp: Any = np):
        self.xp = xp
        self.threshold_px = float(threshold_px)
        self.reach = int(np.ceil(self.threshold_px))  # window: floor(u) + (1 - reach .. reach)
        rows, cols = mask.shape
        self.pad = 2 * self.reach + 1
        padded = np.zeros((rows + 2 * self.pad, cols + 2 * self.pad), dtype=bool)
        padded[self.pad:self.pad + rows, self.pad:self.pad + cols] = mask
        self.flat = xp.asarray(padded.ravel())
        self.stride = padded.shape[1]
        self.shape = (rows, cols)
        self.offsets = [(a, b) for b in range(1 - self.reach, self.reach + 1) for a in range(1 - self.reach, self.reach + 1)]
        # With a wide window, most points are decided by the distance from their nearest pixel centre
        # to the mask (a distance transform), which is within half a pixel diagonal of theirs; only
        # the points near the threshold go through the window (NumPy only).
        self.distance = None
        if xp is np and self.reach >= _BAND_FROM_REACH and mask.any():
            self.distance = _distance_to_mask(np.asarray(mask, dtype=bool))

    def near_uv(self, u, v):
        """Bool (M,) for coordinate arrays ``u``, ``v``: a mask pixel centre is strictly closer than
        the threshold (computed as cKDTree does: the square root of the summed squares)."""
        if self.distance is None or len(u) == 0:
            return self._near_window(u, v)
        rows, cols = self.shape
        ru, rv = np.floor(u + 0.5), np.floor(v + 0.5)
        inside = (ru >= 0) & (ru < cols) & (rv >= 0) & (rv < rows)  # False for nan
        to_centre = np.sqrt((u - ru) ** 2 + (v - rv) ** 2)
        nearest = np.full(len(u), np.nan)
        nearest[inside] = self.distance[rv[inside].astype(np.intp), ru[inside].astype(np.intp)]
        # |distance to the mask - distance from the nearest pixel centre| <= distance to that centre
        keep = inside & (nearest + to_centre < self.threshold_px - _BAND_SLACK_PX)
        unsure = np.flatnonzero(~keep & ~(inside & (nearest - to_centre >= self.threshold_px + _BAND_SLACK_PX)))
        if len(unsure):
            keep[unsure] = self._near_window(u[unsure], v[unsure])
        return keep

    def _near_window(self, u, v):
        """:meth:`near_uv` by reading every pixel of the window around each point."""
        xp, rows, cols = self.xp, *self.shape
        # points far outside the image map into the zero padding; non-finite ones too
        fu = xp.floor(xp.clip(xp.where(xp.isnan(u), -1e9, u), -self.reach - 1, cols + self.reach))
        fv = xp.floor(xp.clip(xp.where(xp.isnan(v), -1e9, v), -self.reach - 1, rows + self.reach))
        base = (fv.astype(np.intp) + self.pad) * self.stride + (fu.astype(np.intp) + self.pad)
        keep = xp.zeros(len(u), dtype=bool)
        for a, b in self.offsets:  # every window pixel for every point: no data-dependent compaction
            du = u - (fu + a)
            dv = v - (fv + b)
            keep |= self.flat[base + (b * self.stride + a)] & (xp.sqrt(du * du + dv * dv) < self.threshold_px)
        return keep

    def near(self, uv):
        """:meth:`near_uv` for an (M, 2) array of ``(u, v)``."""
        return self.near_uv(uv[:, 0], uv[:, 1])


def sparsest_first(masks: Sequence[np.ndarray]) -> tuple[int, ...]:
    """View order with the smallest fraction of vessel pixels first (cuts the most points early)."""
    fractions = [np.count_nonzero(m) / m.size for m in masks]
    return tuple(int(i) for i in np.argsort(fractions, kind="stable"))


def carve_dense_lookup(lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                       threshold_px: float) -> CarveOutcome:
    """Every lattice point, exact constant-time lookups; the same kept set as ``kdtree``.

    Not a registered engine (the block-culled ``lookup`` gives the same result faster); the tests
    use it as the dense oracle of the hierarchical engines."""
    order = sparsest_first(masks)
    lookups = [(projections[i].matrix, MaskLookup(masks[i], threshold_px)) for i in order]
    survivors = [0] * len(order)
    kept_chunks = []
    for start in range(0, lattice.n_points, CHUNK_POINTS):
        points = lattice.points(start, start + CHUNK_POINTS)
        for i, (matrix, lookup) in enumerate(lookups):
            if len(points):
                uv, front = project_in_front(points, matrix)
                front[front] = lookup.near(uv)
                points = points[front]
            survivors[i] += len(points)
        kept_chunks.append(points)
    return CarveOutcome(np.concatenate(kept_chunks, axis=0), tuple(survivors), order)


Engine = Callable[..., CarveOutcome]

ENGINES: dict[str, Engine] = {"kdtree": carve_kdtree}
"""Engines by name (``lookup`` and ``octree`` register from :mod:`.hierarchical`)."""
