"""An exact analytic tubular phantom: a few tubes made of sphere-swept segments (capsules).

This is the small phantom behind ``angiohull demo`` and the analytic oracle of the tests. Every
query on it is exact up to floating point:

* the solid is the union of closed *capsules*, one per centreline segment: all points within the
  segment's radius of the segment (a sphere swept along it);
* a segment's radius is the **mean of its two vertex radii** (a constant per segment, so the union
  of capsules is exact and simple; a taper is represented by a staircase of radii between
  consecutive segments);
* a tube given by a single vertex is one sphere (a zero-length capsule) of that vertex's radius.

Pixel convention (docs/conventions.md): pixel ``(r, c)`` of a view has its centre at ``(u, v) = (c, r)``;
its ray is the half-line from the X-ray source through that centre, towards ``w > 0``. A pixel is
vessel in :meth:`TubePhantom.silhouette` iff that ray passes within a segment's radius of the
segment.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np
from scipy.spatial import cKDTree

from .. import _validation as _v
from ..errors import AngiohullError
from ..geometry import CArmGeometry, Projection, parse_clinical_angles
from ..tree.model import arc_length_mm

__all__ = ["Tube", "TubePhantom", "demo_phantom", "demo_views"]

# Points per chunk in :meth:`TubePhantom.contains` (bounds memory at a few hundred MB at worst).
_POINT_CHUNK = 262_144
# (piece, pixel) or (piece, grid point) pairs evaluated at once.
_PAIR_CHUNK = 1_048_576
# Tolerance (mm) below which a sample counts as lying on, not strictly inside, another capsule.
_SURFACE_TOL_MM = 1e-9


@dataclass(frozen=True, eq=False)
class Tube:
    """One vessel: a centreline polyline with a radius per vertex.

    Parameters
    ----------
    centerline_mm : array_like, shape (M, 3)
        Vertices of the centreline polyline, world coordinates in mm, ``M >= 1``. Consecutive
        duplicates are allowed (they give zero-length segments, i.e. spheres).
    radius_mm : array_like, shape (M,) or scalar
        Radius (mm, > 0) at each vertex; a scalar applies to every vertex.

    Notes
    -----
    The tube's solid is the union over segments ``i`` (vertices ``i`` and ``i + 1``) of the closed
    capsule of radius ``(radius_mm[i] + radius_mm[i + 1]) / 2`` around that segment. With ``M == 1``
    it is the closed ball of radius ``radius_mm[0]`` around the single vertex. Arrays are stored as
    read-only float64 copies; equality is identity (``eq=False``), as for arrays.

    Raises
    ------
    AngiohullError
        If the shapes do not match, a value is not finite, or a radius is not > 0.
    """

    centerline_mm: np.ndarray  # (M, 3) polyline vertices, mm
    radius_mm: np.ndarray  # (M,) radius at each vertex, mm, > 0

    def __post_init__(self) -> None:
        try:
            centre = np.asarray(self.centerline_mm, dtype=np.float64)
        except (TypeError, ValueError):
            raise AngiohullError(
                f"Tube.centerline_mm must be an (M, 3) array of x, y, z in mm, got {self.centerline_mm!r}"
            ) from None
        if centre.ndim != 2 or centre.shape[1] != 3 or centre.shape[0] < 1:
            raise AngiohullError(
                f"Tube.centerline_mm must be an (M, 3) array of x, y, z in mm with M >= 1, got shape {centre.shape}"
            )
        if not np.all(np.isfinite(centre)):
            raise AngiohullError("Tube.centerline_mm contains non-finite values (nan or inf)")
        try:
            radius = np.asarray(self.radius_mm, dtype=np.float64)
        except (TypeError, ValueError):
            raise AngiohullError(f"Tube.radius_mm must be an array of M radii in mm, got {self.radius_mm!r}") from None
        if radius.ndim == 0:
            radius = np.full(centre.shape[0], float(radius))
        if radius.shape != (centre.shape[0],):
            raise AngiohullError(
                f"Tube.radius_mm must have one radius per centreline vertex, shape ({centre.shape[0]},), "
                f"got shape {radius.shape}"
            )
        if not np.all(np.isfinite(radius)) or np.any(radius <= 0):
            bad = radius[~(np.isfinite(radius) & (radius > 0))]
            raise AngiohullError(f"Tube.radius_mm must be finite and > 0 everywhere, got e.g. {bad[0]!r}")
        object.__setattr__(self, "centerline_mm", _v.readonly_copy(centre))
        object.__setattr__(self, "radius_mm", _v.readonly_copy(radius))

    @property
    def segment_count(self) -> int:
        """Number of capsules: ``M - 1``, or 1 for a single-vertex tube (a sphere)."""
        return max(1, self.centerline_mm.shape[0] - 1)

    def segments_mm(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The capsules as ``(starts (S, 3), ends (S, 3), radii (S,))`` in mm.

        Radii are the means of the two vertex radii; a single-vertex tube gives one zero-length
        segment with the vertex's radius.
        """
        c, r = self.centerline_mm, self.radius_mm
        if c.shape[0] == 1:
            return c.copy(), c.copy(), r.copy()
        return c[:-1].copy(), c[1:].copy(), 0.5 * (r[:-1] + r[1:])

    @property
    def length_mm(self) -> float:
        """Length of the centreline polyline, mm."""
        return float(np.linalg.norm(np.diff(self.centerline_mm, axis=0), axis=1).sum())


@dataclass(frozen=True, eq=False)
class TubePhantom:
    """A solid made of tubes (the union of their capsules), with exact queries.

    Parameters
    ----------
    tubes : sequence of Tube
        At least one tube. Stored as a tuple.
    name : str
        A label for reports and file names.

    Raises
    ------
    AngiohullError
        If ``tubes`` is empty or holds something other than :class:`Tube`, or ``name`` is not a str.
    """

    tubes: tuple[Tube, ...]  # the vessels; the solid is the union of all their capsules
    name: str  # label for reports
    # Capsules of all tubes, concatenated: starts (S, 3), ends (S, 3), radii (S,).
    _segments: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False, repr=False)
    # The same capsules cut into short pieces (union unchanged) for spatial pruning.
    _pieces: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False, repr=False)
    # Index of the next / previous capsule of the same tube (-1 at a tube's ends).
    _next: np.ndarray = field(init=False, repr=False)
    _previous: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if isinstance(self.tubes, Tube):
            raise AngiohullError("TubePhantom.tubes must be a sequence of Tube, got a single Tube; wrap it: (tube,)")
        try:
            tubes = tuple(self.tubes)
        except TypeError:
            raise AngiohullError(f"TubePhantom.tubes must be a sequence of Tube, got {self.tubes!r}") from None
        if not tubes:
            raise AngiohullError("TubePhantom.tubes must hold at least one Tube, got none")
        for i, tube in enumerate(tubes):
            if not isinstance(tube, Tube):
                raise AngiohullError(f"TubePhantom.tubes[{i}] must be a Tube, got {type(tube).__name__}")
        if not isinstance(self.name, str):
            raise AngiohullError(f"TubePhantom.name must be a str, got {self.name!r}")
        parts = [t.segments_mm() for t in tubes]
        starts = np.concatenate([p[0] for p in parts])
        ends = np.concatenate([p[1] for p in parts])
        radii = np.concatenate([p[2] for p in parts])
        object.__setattr__(self, "tubes", tubes)
        object.__setattr__(self, "_segments", (_v.readonly_copy(starts), _v.readonly_copy(ends), _v.readonly_copy(radii)))
        object.__setattr__(self, "_pieces", tuple(_v.readonly_copy(x) for x in _cut_into_pieces(starts, ends, radii)))
        counts = np.array([p[2].size for p in parts])
        first = np.cumsum(counts) - counts
        index = np.arange(radii.size)
        nxt = np.where(np.isin(index + 1, first) | (index + 1 == radii.size), -1, index + 1)
        prev = np.where(np.isin(index, first), -1, index - 1)
        object.__setattr__(self, "_next", _v.readonly_copy(nxt, np.int64))
        object.__setattr__(self, "_previous", _v.readonly_copy(prev, np.int64))

    # -- plain accessors ----------------------------------------------------------------------
    def segments_mm(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All capsules ``(starts (S, 3), ends (S, 3), radii (S,))`` in mm, tube after tube."""
        return tuple(x.copy() for x in self._segments)  # type: ignore[return-value]

    def bounding_box_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds ``(lower (3,), upper (3,))`` of the solid, mm (exact)."""
        a, b, r = self._segments
        return (np.minimum(a, b) - r[:, None]).min(axis=0), (np.maximum(a, b) + r[:, None]).max(axis=0)

    # -- point queries ------------------------------------------------------------------------
    def contains(self, points_mm: np.ndarray) -> np.ndarray:
        """Whether each point lies in the closed solid.

        Parameters
        ----------
        points_mm : array_like, shape (N, 3)
            World points in mm.

        Returns
        -------
        inside : ndarray of bool, shape (N,)
            True where the distance to some segment is <= that segment's radius.
        """
        points = _v.points_array(points_mm, "points_mm")
        return self._within(points, shrink_mm=0.0)

    def _within(self, points: np.ndarray, *, shrink_mm: float) -> np.ndarray:
        """True where some piece has ``distance <= radius - shrink_mm`` (chunked, kd-tree pruned)."""
        out = np.zeros(points.shape[0], dtype=bool)
        if points.shape[0] == 0:
            return out
        lower, upper = self.bounding_box_mm()
        candidates = np.flatnonzero(np.all((points >= lower) & (points <= upper), axis=1))
        a, b, r = self._pieces
        centres = 0.5 * (a + b)
        reach = 0.5 * np.linalg.norm(b - a, axis=1) + r
        # Slightly enlarged query radii: the exact test below decides.
        reach = reach * (1.0 + 1e-9) + 1e-9
        for start in range(0, candidates.size, _POINT_CHUNK):
            index = candidates[start:start + _POINT_CHUNK]
            chunk = points[index]
            tree = cKDTree(chunk)
            lists = tree.query_ball_point(centres, reach)
            counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
            if counts.sum() == 0:
                continue
            point_idx = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists if len(x)])
            piece_idx = np.repeat(np.arange(len(lists)), counts)
            for lo in range(0, point_idx.size, _PAIR_CHUNK):
                pi = point_idx[lo:lo + _PAIR_CHUNK]
                si = piece_idx[lo:lo + _PAIR_CHUNK]
                hit = _point_within_segment(chunk[pi], a[si], b[si], r[si] - shrink_mm)
                out[index[pi[hit]]] = True
        return out

    # -- projections --------------------------------------------------------------------------
    def silhouette(self, projection: Projection | CArmGeometry) -> np.ndarray:
        """Exact binary projection of the solid.

        Parameters
        ----------
        projection : Projection or CArmGeometry
            The view; its ``image_shape`` gives the output shape.

        Returns
        -------
        mask : ndarray of bool, shape (rows, cols)
            ``mask[r, c]`` is True iff the half-line from the source through the pixel centre
            ``(u, v) = (c, r)`` passes within a segment's radius of that segment (closed test).

        Notes
        -----
        Each (short piece of a) capsule's bounding box is projected to a pixel box (its 8
        corners, enlarged by one pixel; the whole image when the box reaches behind the source);
        only those pixels are tested, with the closed-form ray-segment distance.
        """
        proj = _as_projection(projection)
        rows, cols = proj.image_shape
        mask = np.zeros((rows, cols), dtype=bool)
        matrix = proj.matrix
        left_inv = np.linalg.inv(matrix[:, :3])
        source = proj.camera_centre_mm
        a, b, r = self._pieces

        # Pixel boxes of the pieces' axis-aligned bounding boxes.
        lo = np.minimum(a, b) - r[:, None]
        hi = np.maximum(a, b) + r[:, None]
        corner_sel = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=bool)
        corners = np.where(corner_sel[None, :, :], hi[:, None, :], lo[:, None, :])  # (K, 8, 3)
        h = corners @ matrix[:, :3].T + matrix[:, 3]
        w = h[..., 2]
        behind = np.any(w <= 0, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = h[..., 0] / w
            v = h[..., 1] / w
        u = np.where(behind[:, None], 0.0, u)
        v = np.where(behind[:, None], 0.0, v)
        c0 = np.where(behind, 0, np.floor(u.min(axis=1)) - 1)
        c1 = np.where(behind, cols - 1, np.ceil(u.max(axis=1)) + 1)
        r0 = np.where(behind, 0, np.floor(v.min(axis=1)) - 1)
        r1 = np.where(behind, rows - 1, np.ceil(v.max(axis=1)) + 1)
        c0 = np.clip(c0, 0, cols).astype(np.int64)
        c1 = np.clip(c1, -1, cols - 1).astype(np.int64)
        r0 = np.clip(r0, 0, rows).astype(np.int64)
        r1 = np.clip(r1, -1, rows - 1).astype(np.int64)
        widths = np.maximum(c1 - c0 + 1, 0)
        heights = np.maximum(r1 - r0 + 1, 0)
        counts = widths * heights

        # Per-piece constants of the ray-segment distance.
        edge = b - a
        edge_sq = np.einsum("ij,ij->i", edge, edge)
        w0 = source - a  # source relative to the segment start
        w0_sq = np.einsum("ij,ij->i", w0, w0)
        w1 = source - b
        w1_sq = np.einsum("ij,ij->i", w1, w1)
        e_dot_w0 = np.einsum("ij,ij->i", edge, w0)
        moment = np.cross(edge, w0)  # (D . moment) = w0 . (D x E)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_src = np.where(edge_sq > 0, np.clip(e_dot_w0 / edge_sq, 0.0, 1.0), 0.0)
        near = w0 - t_src[:, None] * edge
        source_sq = np.einsum("ij,ij->i", near, near)  # distance^2 source-segment (s = 0)
        r_sq = r * r

        for piece, local in _pair_chunks(counts):
            width = widths[piece]
            rr = r0[piece] + local // width
            cc = c0[piece] + local % width
            dirs = (cc[:, None] * left_inv[:, 0] + rr[:, None] * left_inv[:, 1]) + left_inv[:, 2]
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            dist_sq = _ray_segment_distance_sq(
                dirs, edge[piece], edge_sq[piece], w0[piece], w0_sq[piece], w1_sq[piece],
                e_dot_w0[piece], moment[piece], source_sq[piece],
            )
            hit = dist_sq <= r_sq[piece]
            mask[rr[hit], cc[hit]] = True
        return mask

    # -- point samplings ----------------------------------------------------------------------
    def surface_points_mm(self, spacing_mm: float = 0.5, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """Points on the outer surface of the solid, about ``spacing_mm`` apart.

        Each capsule's surface (cylinder rings plus two hemispherical caps, or a whole sphere for
        a zero-length segment) is sampled on rings of latitude / along the axis; samples strictly
        inside another capsule (by more than 1e-9 mm) are dropped, so every point returned lies on
        the boundary of the union.

        Parameters
        ----------
        spacing_mm : float
            Target distance between neighbouring samples, mm (> 0).
        rng : numpy.random.Generator or int, optional
            If given, each ring gets a random azimuthal phase (points stay exactly on the
            surface). Default: no randomness, the same points every call.

        Returns
        -------
        points : ndarray, shape (N, 3)
            mm.
        """
        spacing = _v.positive_finite(spacing_mm, "spacing_mm")
        generator = None if rng is None else np.random.default_rng(rng)
        a, b, r = self._segments
        points, owner, side = _capsule_surfaces(a, b, r, spacing, generator)
        # Cap samples strictly inside the adjacent capsule of the same tube (most of every joint's
        # caps) are dropped by a direct test first; the general test below finds the rest.
        neighbour = np.where(side > 0, self._next[owner], np.where(side < 0, self._previous[owner], -1))
        check = neighbour >= 0
        index = np.flatnonzero(check)
        inside_neighbour = _point_within_segment(points[index], a[neighbour[index]], b[neighbour[index]],
                                                 r[neighbour[index]] - _SURFACE_TOL_MM)
        points = np.delete(points, index[inside_neighbour], axis=0)
        inside = self._within(points, shrink_mm=_SURFACE_TOL_MM)
        return points[~inside]

    def lumen_points_mm(self, spacing_mm: float = 0.5) -> np.ndarray:
        """Nodes of the regular grid ``spacing_mm * (i, j, k)`` (integers) inside the closed solid.

        Parameters
        ----------
        spacing_mm : float
            Grid step, mm (> 0). The grid is aligned to the world origin.

        Returns
        -------
        points : ndarray, shape (N, 3)
            mm, sorted lexicographically by grid index, without duplicates.
        """
        h = _v.positive_finite(spacing_mm, "spacing_mm")
        a, b, r = self._pieces
        lo = np.ceil((np.minimum(a, b) - r[:, None]) / h).astype(np.int64)
        hi = np.floor((np.maximum(a, b) + r[:, None]) / h).astype(np.int64)
        ext = np.maximum(hi - lo + 1, 0)
        counts = ext.prod(axis=1)
        gmin = lo.min(axis=0)
        gext = hi.max(axis=0) - gmin + 1
        keys: list[np.ndarray] = []
        for piece, local in _pair_chunks(counts):
            ny, nz = ext[piece, 1], ext[piece, 2]
            idx = np.stack([local // (ny * nz), (local // nz) % ny, local % nz], axis=1) + lo[piece]
            hit = _point_within_segment(idx * h, a[piece], b[piece], r[piece])
            idx = idx[hit] - gmin
            keys.append((idx[:, 0] * gext[1] + idx[:, 1]) * gext[2] + idx[:, 2])
        if not keys:
            return np.empty((0, 3))
        key = np.unique(np.concatenate(keys))
        idx = np.stack([key // (gext[1] * gext[2]), (key // gext[2]) % gext[1], key % gext[2]], axis=1) + gmin
        return idx * h

    def __repr__(self) -> str:
        return f"TubePhantom(name={self.name!r}, tubes={len(self.tubes)}, segments={self._segments[2].size})"


# -- geometry kernels -------------------------------------------------------------------------
def _as_projection(projection: Projection | CArmGeometry) -> Projection:
    if isinstance(projection, CArmGeometry):
        return projection.projection()
    if not isinstance(projection, Projection):
        raise AngiohullError(
            f"projection must be an angiohull.geometry.Projection or CArmGeometry, got {type(projection).__name__}"
        )
    return projection


def _pair_chunks(counts: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Enumerate the pairs ``(item, k)``, ``0 <= k < counts[item]``, at most ``_PAIR_CHUNK`` at a time.

    Yields ``(item index, k)`` arrays; memory stays bounded however large one item's count is.
    """
    cum = np.cumsum(counts)
    total = int(cum[-1]) if cum.size else 0
    for first in range(0, total, _PAIR_CHUNK):
        ids = np.arange(first, min(first + _PAIR_CHUNK, total), dtype=np.int64)
        item = np.searchsorted(cum, ids, side="right")
        yield item, ids - (cum[item] - counts[item])


def _cut_into_pieces(a: np.ndarray, b: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split each segment into pieces no longer than ``max(2 r, length / 1000)`` (same union)."""
    length = np.linalg.norm(b - a, axis=1)
    n = np.maximum(1, np.ceil(length / np.maximum(2.0 * r, length / 1000.0))).astype(np.int64)
    n = np.where(length > 0, n, 1)
    seg = np.repeat(np.arange(r.size), n)
    k = np.arange(seg.size) - np.repeat(np.cumsum(n) - n, n)
    t0 = (k / n[seg])[:, None]
    t1 = np.where(k + 1 == n[seg], 1.0, (k + 1) / n[seg])[:, None]
    edge = (b - a)[seg]
    return a[seg] + t0 * edge, np.where(t1 == 1.0, b[seg], a[seg] + t1 * edge), r[seg]


def _point_within_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Row-wise ``distance(p, segment ab) <= radius`` (False where radius < 0)."""
    edge = b - a
    rel = p - a
    edge_sq = np.einsum("ij,ij->i", edge, edge)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(edge_sq > 0, np.clip(np.einsum("ij,ij->i", rel, edge) / edge_sq, 0.0, 1.0), 0.0)
    diff = rel - t[:, None] * edge
    return (np.einsum("ij,ij->i", diff, diff) <= radius * radius) & (radius >= 0)


def _ray_segment_distance_sq(dirs, edge, edge_sq, w0, w0_sq, w1_sq, e_dot_w0, moment, source_sq):
    """Squared distance between half-lines ``S + s D`` (s >= 0, |D| = 1) and segments ``A + t E``.

    The squared distance is a convex quadratic in ``(s, t)`` on ``s >= 0, 0 <= t <= 1``: its
    minimum is the unconstrained one when feasible, else on an edge of the domain. So it is the
    least of: the source to the segment (``s = 0``), each endpoint to the half-line
    (``t = 0``, ``t = 1``) and, when feasible, the line-line distance.
    ``w0 = S - A``, ``w1 = S - B``, ``moment = E x w0``.
    """
    b = np.einsum("ij,ij->i", dirs, edge)  # D . E
    d = np.einsum("ij,ij->i", dirs, w0)  # D . w0
    # Endpoint A to the half-line: foot at s = -d when d < 0.
    cand_a = np.where(d < 0, w0_sq - d * d, w0_sq)
    d1 = d - b  # D . w1
    cand_b = np.where(d1 < 0, w1_sq - d1 * d1, w1_sq)
    best = np.minimum(np.minimum(cand_a, cand_b), source_sq)
    den = edge_sq - b * b  # |D x E|^2
    ok = den > 1e-12 * edge_sq
    if np.any(ok):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (b * e_dot_w0 - edge_sq * d) / den
            t = (e_dot_w0 - b * d) / den
            m = np.einsum("ij,ij->i", dirs, moment)
            cand_i = m * m / den
        feasible = ok & (s >= 0) & (t >= 0) & (t <= 1)
        best = np.where(feasible, np.minimum(best, cand_i), best)
    return np.maximum(best, 0.0)


def _orthonormal_frames(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing each unit axis (rows) to an orthonormal frame."""
    helper = np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(axes, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(axes, e1)


def _capsule_surfaces(a: np.ndarray, b: np.ndarray, r: np.ndarray, spacing: float,
                      generator: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples on the surface of every capsule, about ``spacing`` apart, as rings of points.

    Each capsule gives rings along its cylinder (both end rings included) and rings of latitude on
    its two hemispherical caps; a zero-length capsule gives a whole sphere (about the z axis).
    Returns ``(points (N, 3), owning capsule (N,), side (N,))`` with side +1 / -1 for samples on
    the cap at ``b`` / ``a`` and 0 on the cylinder.
    """
    edge = b - a
    length = np.linalg.norm(edge, axis=1)
    axes = np.where(length[:, None] > 0, edge / np.where(length > 0, length, 1.0)[:, None], [[0.0, 0.0, 1.0]])
    e1, e2 = _orthonormal_frames(axes)
    seg = np.arange(r.size)
    # Cylinder rings: t = k / n for k = 0..n (one ring, the equator, for a sphere).
    n_ax = np.where(length > 0, np.maximum(1, np.ceil(length / spacing)), 0).astype(np.int64)
    cyl_seg = np.repeat(seg, n_ax + 1)
    k = np.arange(cyl_seg.size) - np.repeat(np.cumsum(n_ax + 1) - (n_ax + 1), n_ax + 1)
    t = np.where(n_ax[cyl_seg] > 0, k / np.maximum(n_ax[cyl_seg], 1), 0.0)
    centres = [a[cyl_seg] + t[:, None] * edge[cyl_seg]]
    radii = [r[cyl_seg]]
    owner = [cyl_seg]
    side = [np.zeros(cyl_seg.size, dtype=np.int64)]
    # Cap rings: latitudes phi = (pi / 2) k / n_lat, k = 0..n_lat - 1 (the equator is a cylinder ring).
    n_lat = np.maximum(1, np.ceil(0.5 * np.pi * r / spacing)).astype(np.int64)
    cap_seg = np.repeat(seg, n_lat)
    k = np.arange(cap_seg.size) - np.repeat(np.cumsum(n_lat) - n_lat, n_lat)
    phi = 0.5 * np.pi * k / n_lat[cap_seg]
    height = r[cap_seg] * np.cos(phi)
    for sign, base in ((1, b), (-1, a)):
        centres.append(base[cap_seg] + sign * height[:, None] * axes[cap_seg])
        radii.append(r[cap_seg] * np.sin(phi))
        owner.append(cap_seg)
        side.append(np.full(cap_seg.size, sign, dtype=np.int64))
    centres_all = np.concatenate(centres)
    ring_r = np.concatenate(radii)
    ring_owner = np.concatenate(owner)
    ring_side = np.concatenate(side)
    count = np.where(ring_r > 0, np.maximum(1, np.ceil(2.0 * np.pi * ring_r / spacing)), 1).astype(np.int64)
    phase = np.zeros(count.size) if generator is None else generator.uniform(0.0, 2.0 * np.pi, size=count.size)
    ring = np.repeat(np.arange(count.size), count)
    j = np.arange(ring.size) - np.repeat(np.cumsum(count) - count, count)
    angle = phase[ring] + 2.0 * np.pi * j / count[ring]
    o = ring_owner[ring]
    points = centres_all[ring] + ring_r[ring][:, None] * (np.cos(angle)[:, None] * e1[o] + np.sin(angle)[:, None] * e2[o])
    return points, o, ring_side[ring]


# -- the demo ---------------------------------------------------------------------------------
def _sample_curve(curve: Callable[[np.ndarray], np.ndarray], step_mm: float = 1.0) -> np.ndarray:
    """Points of ``curve(t)``, t in [0, 1], equally spaced in arc length (about ``step_mm``)."""
    t_dense = np.linspace(0.0, 1.0, 4001)
    dense = curve(t_dense)
    arc = arc_length_mm(dense)
    n = max(2, int(round(arc[-1] / step_mm)) + 1)
    return curve(np.interp(np.linspace(0.0, arc[-1], n), arc, t_dense))


def _taper(points: np.ndarray, r_start: float, r_end: float) -> np.ndarray:
    """Radii varying linearly with arc length from ``r_start`` to ``r_end``."""
    arc = arc_length_mm(points)
    return r_start + (r_end - r_start) * arc / arc[-1]


def _main_vessel(t: np.ndarray) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64)
    return np.stack([
        -31.0 + 62.0 * t + 6.0 * np.sin(2.0 * np.pi * t),
        22.0 * np.sin(np.pi * t) - 11.0,
        29.0 - 58.0 * t + 9.0 * np.sin(3.0 * np.pi * t),
    ], axis=-1)


def _bezier(p0, p1, p2) -> Callable[[np.ndarray], np.ndarray]:
    p0, p1, p2 = (np.asarray(p, dtype=np.float64) for p in (p0, p1, p2))

    def curve(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[..., None]
        return (1 - t) ** 2 * p0 + 2 * (1 - t) * t * p1 + t * t * p2

    return curve


def demo_phantom() -> TubePhantom:
    """The small vessel tree of ``angiohull demo``: one main vessel and three branches.

    The main vessel (about 110 mm, radius 2.0 -> 1.2 mm) is an analytic space curve; the branches
    (radius 1.4/1.3/1.2 -> 1.0 mm, 32-40 mm long) are quadratic Bézier curves starting on it.
    Curves are sampled about every 1 mm of arc length. Everything lies within about 45 mm of the
    isocentre, inside the field of view of :func:`demo_views`. No randomness.
    """
    main = _sample_curve(_main_vessel)
    tubes = [Tube(main, _taper(main, 2.0, 1.2))]
    branches = [
        # (start parameter on the main vessel, control offset, end offset, radii)
        (0.22, (6.0, -10.0, -10.0), (20.0, -16.0, -30.0), (1.4, 1.0)),
        (0.45, (4.0, 14.0, 4.0), (0.0, 28.0, -12.0), (1.3, 1.0)),
        (0.68, (12.0, -6.0, 10.0), (28.0, -4.0, 14.0), (1.2, 1.0)),
    ]
    for t_start, control, end, (r0, r1) in branches:
        start = _main_vessel(np.array(t_start))
        points = _sample_curve(_bezier(start, start + np.array(control), start + np.array(end)))
        tubes.append(Tube(points, _taper(points, r0, r1)))
    return TubePhantom(tuple(tubes), "demo-tree")


DEMO_VIEW_NAMES: tuple[str, ...] = ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30")


def demo_views() -> list[tuple[str, CArmGeometry]]:
    """The three views of ``angiohull demo``: ``(clinical name, geometry)``.

    RAO 30 CRA 30, LAO 60 CRA 30 and RAO 30 CAU 30; SID 1200 mm, SOD 800 mm, 512 x 512 pixels of
    0.35 mm (a half field of about 59.7 mm at the isocentre).
    """
    views = []
    for name in DEMO_VIEW_NAMES:
        primary, secondary = parse_clinical_angles(name)
        views.append((name, CArmGeometry(primary_deg=primary, secondary_deg=secondary, sid_mm=1200.0,
                                         sod_mm=800.0, pixel_spacing_mm=(0.35, 0.35), image_shape=(512, 512))))
    return views
