"""Sub-pixel view shifts from 2D centrelines: triangulate the other views, fit this one.

The support score of :mod:`.calibration` compares a view's mask with the visual hull of the other
views. That hull carries phantom volume where the cones of different branches meet, and the mask
is wide: the score is flat over a pixel or two and leans towards the phantom volume. Vessels are
tubes, and a tube's axis projects onto the centreline of its silhouette in every view. This module
uses that:

1. **Centrelines.** Each mask is thinned (Guo–Hall, ``skimage.morphology.thin``). Thinning keeps
   one of the two middle pixels of an even-width vessel, a half-pixel bias whose direction depends
   on the vessel's and so differs between views; each centreline pixel is therefore moved along its
   normal to the midpoint of the mask's two edges.
2. **Epipolar matching.** For two views ``i`` and ``j`` with camera centres ``C_i`` and ``C_j``,
   every back-projected ray lies in one plane of the pencil around the baseline ``C_i C_j``;
   a 3D point projects into both views on rays of the *same* plane. Each centreline pixel gets the
   angle of its plane in that pencil; pixels of ``i`` and ``j`` whose angles agree within
   ``match_tolerance_px`` (converted to an angle with the median angular size of a pixel) are
   candidate matches, triangulated to the midpoint of the closest points of their two rays.
   A pixel of ``i`` has at most one true match, so a pair's weight is one over the larger of the
   two pixels' candidate counts (a vessel running along the epipolar lines does not outvote the
   rest).
3. **Fit.** Projected into view ``v``, the triangulated points of the true vessels lie on ``v``'s
   centreline when ``v``'s shift is right, while wrong matches land anywhere. The cost of a shift
   ``s`` is the weighted mean of ``min(d, cutoff_px)**2`` with ``d`` the distance from a shifted
   projection to the nearest centreline pixel of ``v``: a truncated quadratic, so wrong matches
   add a constant. It is minimised over integer shifts within ``reach`` of the start, then on
   halving grids down to 0.05 px. The distances are exact but mostly not asked of a k-d tree
   (:meth:`Centreline.distances`): about two thirds of the candidate matches land farther than
   the cutoff from any centreline, which a per-pixel lower bound shows at once, and for the rest
   each pixel lists the few centreline points that can be nearest.
4. **Sweeps.** Each view in turn is fitted to the points triangulated from the others (the
   others with their current shifts), until no view moves by more than 0.05 px.

A common 3D translation of the object shifts all views consistently and leaves the cost unchanged
to first order (only the magnification changes, about 0.1 % per mm at a source distance of
800 mm): the sweeps do not fix it, and :mod:`.calibration` chooses it afterwards (its gauge step).
"""

from __future__ import annotations

from itertools import combinations
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from ..compiled import kernels
from ..geometry import Projection
from ..thinning import guo_hall_thin as thin
from .epipolar import EpipolarPencil, ray_directions

__all__ = ["Centreline", "centreline_rays", "match_pair", "fit_view_shift", "fit_view_scale", "polish_shifts",
           "consistency_cost", "fit_jointly", "fit_scales_jointly", "PAIRS_PER_VIEW"]

RADIUS_TOLERANCE = 0.3
"""Two matched centreline pixels must show the same vessel radius (mm, at the triangulated point)
within this fraction plus one pixel: silhouettes of different vessels rarely do."""

NORMAL_RADIUS_PX = 3
"""A centreline pixel's normal is fitted to the centreline pixels within this radius."""

MAX_CENTRING_PX = 1.0
"""The largest move of a centreline pixel to the midpoint of its vessel's edges (thinning is off by
at most half a pixel on a clean mask; more means the profile ran into a junction)."""

PAIRS_PER_VIEW = 3
"""With more than three views, a view is fitted to the points of this many pairs of other views
(the best-conditioned ones), so that the work grows linearly with the number of views."""


class Centreline:
    """The Guo–Hall centreline of one mask: pixel coordinates ``(u, v)`` and a k-d tree of them."""

    def __init__(self, mask: np.ndarray):
        mask = np.asarray(mask, dtype=bool)
        skeleton = thin(mask)
        rows, cols = np.nonzero(skeleton)
        pixels = np.column_stack([cols, rows]).astype(float)
        # half-width of the vessel at each centreline pixel: the distance to the nearest background
        # pixel centre overshoots the edge (half-way between pixel centres) by 0.5 px
        self.half_width_px = ndi.distance_transform_edt(mask)[rows, cols] - 0.5
        self.uv_px = pixels + _centring_offsets(mask, skeleton, pixels, self.half_width_px)
        self.tree = cKDTree(self.uv_px) if len(self.uv_px) else None
        self.distance_floor_px, self._candidate_row, self._candidates = _distance_floor(self.tree, mask.shape)
        if self._candidates is not None:
            # the candidates' coordinates, padded with inf: the first _NARROW of each pixel, and all of
            # them for the few pixels that have more (most have about five)
            padded_u, padded_v = np.append(self.uv_px[:, 0], np.inf), np.append(self.uv_px[:, 1], np.inf)
            self._wide_u, self._wide_v = padded_u[self._candidates], padded_v[self._candidates]
            self._narrow_u = np.ascontiguousarray(self._wide_u[:, :_NARROW])
            self._narrow_v = np.ascontiguousarray(self._wide_v[:, :_NARROW])
            self._overflows = np.isfinite(self._wide_u[:, _NARROW:]).any(axis=1)

    def distances(self, uv_px: np.ndarray, cutoff_px: float) -> np.ndarray:
        """Distance from each point to the nearest centreline point, ``cutoff_px`` where it is
        farther. Exact, and quicker than asking the k-d tree: a point whose nearest pixel's distance
        floor exceeds the cutoff is farther (most candidate matches of :func:`match_pair` land far
        from any centreline); for the others only that pixel's candidates are measured. Points off
        the image go to the k-d tree; points that are not finite (no projection) count as farther."""
        distance = np.full(len(uv_px), float(cutoff_px))
        if self.tree is None or len(uv_px) == 0:
            return distance
        compiled = kernels()
        if compiled is not None and self._candidates is not None:
            points = np.asarray(uv_px, dtype=np.float64)
            # the floor is compared as NumPy compares it with this cutoff (a Python float: in single precision)
            limit = float(np.asarray(cutoff_px, dtype=np.result_type(self.distance_floor_px, cutoff_px)))
            distance, ask = compiled.centreline_distances(
                np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1]), float(cutoff_px), limit,
                cutoff_px < _FLOOR_REACH_PX - np.sqrt(0.5), self.distance_floor_px, self._candidate_row,
                self._wide_u, self._wide_v)
            if ask.any():
                found, _ = self.tree.query(points[ask], distance_upper_bound=cutoff_px)
                distance[ask] = np.minimum(found, cutoff_px)  # misses come back as inf
            return distance
        finite = np.all(np.isfinite(uv_px), axis=1)
        rows, cols = self.distance_floor_px.shape
        iu = np.floor(uv_px[:, 0] + 0.5)
        iv = np.floor(uv_px[:, 1] + 0.5)
        on_image = (iu >= 0) & (iu < cols) & (iv >= 0) & (iv < rows)
        ask = finite & ~on_image
        if cutoff_px >= _FLOOR_REACH_PX - np.sqrt(0.5):  # the floor does not tell: ask about every point
            ask, on_image = finite, np.zeros(len(uv_px), dtype=bool)
        on = np.flatnonzero(on_image)
        on_rows, on_cols = iv[on].astype(np.int64), iu[on].astype(np.int64)
        near = self.distance_floor_px[on_rows, on_cols] <= cutoff_px
        if near.any():
            index = on[near]
            rows = self._candidate_row[on_rows[near], on_cols[near]]
            u, v = uv_px[index, 0][:, None], uv_px[index, 1][:, None]
            # the square root of the least square: the same as the least root (rounding keeps order)
            du, dv = u - self._narrow_u[rows], v - self._narrow_v[rows]
            nearest = (du * du + dv * dv).min(axis=1)
            wide = np.flatnonzero(self._overflows[rows])
            if len(wide):  # the same minimum over all of these pixels' candidates
                du, dv = u[wide] - self._wide_u[rows[wide]], v[wide] - self._wide_v[rows[wide]]
                nearest[wide] = (du * du + dv * dv).min(axis=1)
            distance[index] = np.minimum(np.sqrt(nearest), cutoff_px)
        if ask.any():
            found, _ = self.tree.query(uv_px[ask], distance_upper_bound=cutoff_px)
            distance[ask] = np.minimum(found, cutoff_px)  # misses come back as inf
        return distance


_NARROW = 6  # Centreline.distances reads this many candidates of a pixel first (the rest where it has more)
_FLOOR_REACH_PX = 4.0  # Centreline.distance_floor_px is measured out to this distance from the centreline
_ROUNDING_PX = 1e-9  # the floor is lowered and the candidates' radius raised by this: exact despite rounding


def _distance_floor(tree: cKDTree | None, shape: tuple[int, int]):
    """Per pixel, for the points whose nearest pixel it is (within half a pixel diagonal of its
    centre): a lower bound of their distance to the nearest point of ``tree`` (the pixel centre's,
    less half a diagonal; inf beyond _FLOOR_REACH_PX), and the points of ``tree`` that can be the
    nearest (those within the pixel centre's distance plus a whole diagonal).

    Returns ``(floor (rows, cols), candidate row (rows, cols), candidates (n, C))``: the
    candidates of a pixel are row ``candidate row[pixel]`` of ``candidates``, indices into the
    tree's points padded with ``len(points)``; None where ``tree`` is None."""
    if tree is None:
        return None, None, None
    floor = np.full(shape, np.inf, dtype=np.float32)  # single precision, rounded down below: still a floor
    low = np.maximum(np.floor(tree.mins - _FLOOR_REACH_PX).astype(np.int64), 0)  # (u, v)
    high = np.minimum(np.ceil(tree.maxes + _FLOOR_REACH_PX).astype(np.int64) + 1, (shape[1], shape[0]))
    # only the pixels within the reach of a point's nearest pixel (plus half a diagonal) are asked
    box = np.zeros((high[1] - low[1], high[0] - low[0]), dtype=bool)
    nearest = np.clip(np.floor(tree.data + 0.5).astype(np.int64) - low, 0, np.array(box.shape[::-1]) - 1)
    box[nearest[:, 1], nearest[:, 0]] = True
    r = int(np.ceil(_FLOOR_REACH_PX + np.sqrt(0.5)))
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    near = np.zeros_like(box)
    for oy, ox in zip(dy[dx * dx + dy * dy <= r * r], dx[dx * dx + dy * dy <= r * r]):
        near[max(oy, 0):box.shape[0] + min(oy, 0), max(ox, 0):box.shape[1] + min(ox, 0)] |= \
            box[max(-oy, 0):box.shape[0] + min(-oy, 0), max(-ox, 0):box.shape[1] + min(-ox, 0)]
    v, u = np.nonzero(near)
    v, u = v + low[1], u + low[0]
    centres = np.column_stack([u, v]).astype(float)
    found, _ = tree.query(centres, distance_upper_bound=_FLOOR_REACH_PX)
    band = np.isfinite(found)
    below = (found[band] - np.sqrt(0.5) - _ROUNDING_PX).astype(np.float32)
    floor[v[band], u[band]] = np.nextafter(below, np.float32(-np.inf))
    lists = tree.query_ball_point(centres[band], found[band] + np.sqrt(2.0) + _ROUNDING_PX)
    counts = np.fromiter((len(c) for c in lists), dtype=np.int64, count=len(lists))
    candidates = np.full((len(lists), int(counts.max(initial=1))), tree.n, dtype=np.int32)
    candidates[np.arange(len(lists)).repeat(counts), _ranks(counts)] = np.concatenate(
        [np.asarray(c, dtype=np.int32) for c in lists]) if len(lists) else np.zeros(0, np.int32)
    candidate_row = np.zeros(shape, dtype=np.int32)
    candidate_row[v[band], u[band]] = np.arange(len(lists))
    return floor, candidate_row, candidates


def _ranks(counts: np.ndarray) -> np.ndarray:
    """0, 1, ..., counts[0]-1, 0, 1, ..., counts[1]-1, ..."""
    return np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def _skeleton_normals(skeleton: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Unit normal of the centreline at each pixel (zero where it has too few neighbours): the
    minor axis of the scatter of skeleton pixels within NORMAL_RADIUS_PX."""
    r = NORMAL_RADIUS_PX
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1].astype(float)
    inside = dx ** 2 + dy ** 2 <= r * r
    rows, cols = pixels[:, 1].astype(int), pixels[:, 0].astype(int)
    # the skeleton's moments in the disc around each of its pixels (whole numbers: exact in any order)
    padded = np.pad(skeleton.astype(bool), r)
    moments = {key: np.zeros(len(pixels)) for key in ("n", "x", "y", "xx", "xy", "yy")}
    for ox, oy in zip(dx[inside], dy[inside]):
        hit = padded[rows + r + int(oy), cols + r + int(ox)]
        moments["n"] += hit
        moments["x"] += hit * ox
        moments["y"] += hit * oy
        moments["xx"] += hit * (ox * ox)
        moments["xy"] += hit * (ox * oy)
        moments["yy"] += hit * (oy * oy)
    n = moments["n"]
    cxx = moments["xx"] / n - (moments["x"] / n) ** 2
    cyy = moments["yy"] / n - (moments["y"] / n) ** 2
    cxy = moments["xy"] / n - moments["x"] * moments["y"] / n ** 2
    along = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # direction of the major axis
    normals = np.column_stack([-np.sin(along), np.cos(along)])
    normals[n < 3] = 0.0
    return normals


def _centring_offsets(mask: np.ndarray, skeleton: np.ndarray, pixels: np.ndarray,
                      half_width_px: np.ndarray) -> np.ndarray:
    """Per centreline pixel, the move along its normal to the midpoint of the mask's two edges.

    Thinning keeps one of the two middle pixels of an even-width vessel, a half-pixel bias that
    depends on the vessel's direction (and so differs between views). The mask is sampled along
    the normal (nearest pixel, steps of 0.2 px) and the run of vessel pixels through the
    centreline pixel gives the two edges; the move is limited to MAX_CENTRING_PX.
    """
    if len(pixels) == 0:
        return np.zeros((0, 2))
    normals = _skeleton_normals(skeleton, pixels)
    reach = float(np.ceil(np.max(half_width_px))) + 2.0
    step = 0.2  # no sample falls on a pixel edge (half-integer offsets) of a row or column
    t = np.arange(-reach, reach + step / 2, step)
    centre = len(t) // 2
    samples = pixels[:, None, :] + t[None, :, None] * normals[:, None, :]
    iu = np.floor(samples[..., 0] + 0.5).astype(np.int64)
    iv = np.floor(samples[..., 1] + 0.5).astype(np.int64)
    rows, cols = mask.shape
    valid = (iu >= 0) & (iu < cols) & (iv >= 0) & (iv < rows)
    inside = np.zeros(iu.shape, dtype=bool)
    inside[valid] = mask[iv[valid], iu[valid]]
    # first sample outside the vessel on either side (the run through the centre; none: the reach)
    outside_right = ~inside[:, centre:]
    outside_left = ~inside[:, centre::-1]
    right = np.where(outside_right.any(axis=1), np.argmax(outside_right, axis=1), outside_right.shape[1])
    left = np.where(outside_left.any(axis=1), np.argmax(outside_left, axis=1), outside_left.shape[1])
    # the edge lies half a step before the first outside sample on each side
    move = 0.5 * ((right - 0.5) - (left - 0.5)) * step
    move = np.clip(move, -MAX_CENTRING_PX, MAX_CENTRING_PX)
    return move[:, None] * normals


def centreline_rays(projection: Projection, centre_line: Centreline) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit ray directions through a view's centreline points, and through the same points moved
    by one pixel in u and in v: what :func:`match_pair` needs of one view (any pair it is in)."""
    uv = centre_line.uv_px
    return tuple(ray_directions(projection, uv + step) for step in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)))


def match_pair(projection_i: Projection, projection_j: Projection, centre_line_i: Centreline,
               centre_line_j: Centreline, match_tolerance_px: float = 0.75, *,
               rays_i: tuple | None = None, rays_j: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangulated candidate matches of two views' centreline pixels, and their weights.

    ``rays_i``, ``rays_j``: :func:`centreline_rays` of the two views, when already at hand.
    Returns ``(points_mm (M, 3), weights (M,))``; see the module notes.
    """
    if len(centre_line_i.uv_px) == 0 or len(centre_line_j.uv_px) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    c_i, c_j = projection_i.camera_centre_mm, projection_j.camera_centre_mm
    rays_i = centreline_rays(projection_i, centre_line_i) if rays_i is None else rays_i
    rays_j = centreline_rays(projection_j, centre_line_j) if rays_j is None else rays_j
    d_i, d_j = rays_i[0], rays_j[0]
    pencil = EpipolarPencil(c_i, c_j)
    unwrapped_i = pencil.unwrapped_angle(d_i)
    phi_i = pencil.wrapped(unwrapped_i)
    pencil.offset = float(np.angle(np.mean(np.exp(1j * phi_i))))  # keep the angles away from +-pi
    phi_i = pencil.wrapped(unwrapped_i)
    phi_j = pencil.angle(d_j)
    # angular size of one pixel, from unit steps in u and v
    pixel_angle = []
    for rays, phi in ((rays_i, phi_i), (rays_j, phi_j)):
        steps = [np.angle(np.exp(1j * (pencil.angle(stepped) - phi))) for stepped in rays[1:]]
        pixel_angle.append(float(np.median(np.hypot(*steps))))
    tolerance = match_tolerance_px * max(pixel_angle)
    order = np.argsort(phi_j)
    sorted_phi = phi_j[order]
    low = np.searchsorted(sorted_phi, phi_i - tolerance)
    high = np.searchsorted(sorted_phi, phi_i + tolerance)
    counts_i = high - low
    total = int(counts_i.sum())
    if total == 0:
        return np.zeros((0, 3)), np.zeros(0)
    ii = np.repeat(np.arange(len(phi_i)), counts_i)
    first = np.repeat(low - (np.cumsum(counts_i) - counts_i), counts_i)
    jj = order[np.arange(total) + first]
    # midpoint of the closest points of the two rays
    a, b = d_i[ii], d_j[jj]
    w0 = c_i - c_j
    ab = np.einsum("ij,ij->i", a, b)
    aw, bw = a @ w0, b @ w0
    denominator = np.maximum(1.0 - ab ** 2, 1e-12)
    s = (ab * bw - aw) / denominator
    t = (bw - ab * aw) / denominator
    # a true match joins two silhouettes of the same vessel: the same radius in mm at the point
    focal_i, focal_j = max(projection_i.focal_lengths_px), max(projection_j.focal_lengths_px)
    radius_i = centre_line_i.half_width_px[ii] * s / focal_i
    radius_j = centre_line_j.half_width_px[jj] * t / focal_j
    pixel_mm = np.maximum(s / focal_i, t / focal_j)
    same = np.abs(radius_i - radius_j) <= RADIUS_TOLERANCE * np.maximum(radius_i, radius_j) + pixel_mm
    keep = np.flatnonzero(same & (s > 0) & (t > 0))
    ii, jj, s, t = ii[keep], jj[keep], s[keep], t[keep]
    points = 0.5 * ((c_i + s[:, None] * a[keep]) + (c_j + t[:, None] * b[keep]))  # of the matches kept only
    counts_i = np.bincount(ii, minlength=len(phi_i))
    counts_j = np.bincount(jj, minlength=len(phi_j))
    weights = 1.0 / np.maximum(counts_i[ii], counts_j[jj])
    return points, weights


def _cost(centre_line: Centreline, uv_px: np.ndarray, weights: np.ndarray, shift_px, cutoff_px: float) -> float:
    distance = centre_line.distances(uv_px + np.asarray(shift_px), cutoff_px)
    return float(np.sum(weights * distance ** 2) / np.sum(weights))


def fit_view_shift(centre_line: Centreline, uv_px: np.ndarray, weights: np.ndarray, start_px, *,
                   reach_px: int = 3, cutoff_px: float = 2.0,
                   steps_px: Sequence[float] = (0.5, 0.25, 0.1, 0.05)) -> tuple[np.ndarray, float]:
    """The shift near ``start_px`` that brings projected points ``uv_px`` onto the centreline.

    Minimises the fit cost over integer shifts within ``reach_px`` of the start, then on 3 x 3
    grids of step ``steps_px`` (0.5, 0.25, 0.1 and 0.05 px) around the best. Returns ``(shift (2,),
    cost)``.
    """
    start = np.asarray(start_px, dtype=float)
    if centre_line.tree is None or len(uv_px) == 0 or np.sum(weights) <= 0:
        return start, float(cutoff_px ** 2)

    offsets = np.arange(-reach_px, reach_px + 1, dtype=float)
    grid = [start + (du, dv) for du in offsets for dv in offsets]
    cost = _ShiftCost(centre_line, uv_px, weights, cutoff_px)
    known: dict[bytes, float] = {}  # every grid but the first repeats its centre
    for step in (*steps_px, None):
        new = [g for g in grid if g.tobytes() not in known]
        known.update(zip([g.tobytes() for g in new], cost(new)))
        costs = [known[g.tobytes()] for g in grid]
        best = grid[int(np.argmin(costs))]
        if step is None:
            return best, min(costs)
        grid = [best + (du * step, dv * step) for du in (-1, 0, 1) for dv in (-1, 0, 1)]


class _ShiftCost:
    """:func:`_cost` at the shifts of one grid in one call of :meth:`Centreline.distances`; the
    same values to the last bit."""

    def __init__(self, centre_line: Centreline, uv_px: np.ndarray, weights: np.ndarray, cutoff_px: float):
        self.centre_line, self.uv_px, self.weights, self.cutoff_px = centre_line, uv_px, weights, cutoff_px
        self.total = np.sum(weights)

    def __call__(self, shifts_px: Sequence[np.ndarray]) -> list[float]:
        costs: list[float] = []
        chunk = max(1, _SHIFT_BATCH_POINTS // max(1, len(self.uv_px)))  # a larger batch leaves the cache
        for first in range(0, len(shifts_px), chunk):
            some = shifts_px[first:first + chunk]
            moved = np.concatenate([self.uv_px + np.asarray(shift, dtype=float) for shift in some])
            found = self.centre_line.distances(moved, self.cutoff_px).reshape(len(some), len(self.uv_px))
            costs += [float(np.sum(self.weights * distance ** 2) / self.total) for distance in found]
        return costs


_SHIFT_BATCH_POINTS = 100_000  # _ShiftCost measures about this many shifted points per call (measured best)


def _view_direction(projection: Projection) -> np.ndarray:
    """Unit direction from the source through the principal point."""
    return ray_directions(projection, np.array([projection.principal_point_px]))[0]


def _pairs_for(view: int, projections: Sequence[Projection]) -> list[tuple[int, int]]:
    """Pairs of other views to triangulate for ``view``: all of them up to three other views, else
    the PAIRS_PER_VIEW pairs whose smallest angle (between the pair's directions and to ``view``'s)
    is largest."""
    others = [i for i in range(len(projections)) if i != view]
    pairs = list(combinations(others, 2))
    if len(others) <= 3:
        return pairs
    directions = [_view_direction(p) for p in projections]

    def angle(a, b):
        return float(np.arccos(np.clip(abs(directions[a] @ directions[b]), 0.0, 1.0)))

    pairs.sort(key=lambda ij: -min(angle(*ij), angle(ij[0], view), angle(ij[1], view)))
    return pairs[:PAIRS_PER_VIEW]


def _triangulated_for(pairs: Sequence[tuple[int, int]], projections: Sequence[Projection],
                      centre_lines: Sequence[Centreline], shifts_px: np.ndarray,
                      matched: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The points triangulated from ``pairs`` of views (those that fit a view: :func:`_pairs_for`;
    weights: every pair counts the same). ``matched`` caches :func:`match_pair` and the views' rays,
    by the views' matrices and shifts: a search that moves some views reuses the pairs of the others."""
    matched = {} if matched is None else matched
    if len(matched) > _MATCHED_ENTRIES:
        matched.clear()
    parts = []
    for i, j in pairs:
        keys = {k: (k, projections[k].matrix.tobytes(), np.asarray(shifts_px[k], dtype=float).tobytes()) for k in (i, j)}
        pair_key = (keys[i], keys[j])
        if pair_key not in matched:
            views = {}
            for k in (i, j):  # a view's rays serve every pair it is in
                if keys[k] not in matched:
                    shifted = projections[k].shifted(*shifts_px[k])
                    matched[keys[k]] = (shifted, centreline_rays(shifted, centre_lines[k]))
                views[k] = matched[keys[k]]
            matched[pair_key] = match_pair(views[i][0], views[j][0], centre_lines[i], centre_lines[j],
                                           rays_i=views[i][1], rays_j=views[j][1])
        parts.append(matched[pair_key])
    parts = [(x, w / w.sum()) for x, w in parts if len(x)]
    if not parts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.concatenate([x for x, _ in parts]), np.concatenate([w for _, w in parts])


def polish_shifts(projections: Sequence[Projection], centre_lines: Sequence[Centreline], shifts_px, *,
                  reach_px: int = 3, cutoff_px: float = 2.0, max_sweeps: int = 6,
                  tolerance_px: float = 0.05) -> np.ndarray:
    """Refine every view's shift against the others' triangulated centrelines (see the module notes).

    Needs at least three views. Returns the shifts, (N, 2).
    """
    shifts = np.array(shifts_px, dtype=float)
    if len(projections) < 3:
        raise ValueError("centreline fitting needs at least three views")
    pair_lists = [_pairs_for(v, projections) for v in range(len(projections))]
    matched: dict = {}  # pairs (and rays) of views that have not moved since are reused
    for sweep in range(max_sweeps):
        moved = 0.0
        for v, projection in enumerate(projections):
            points, weights = _triangulated_for(pair_lists[v], projections, centre_lines, shifts, matched)
            new, _ = fit_view_shift(centre_lines[v], projection.project(points) if len(points) else points[:, :2],
                                    weights, shifts[v], reach_px=reach_px if sweep == 0 else 1, cutoff_px=cutoff_px)
            moved = max(moved, float(np.max(np.abs(new - shifts[v]))))
            shifts[v] = new
        if moved <= tolerance_px:
            break
    return shifts


def consistency_cost(projections: Sequence[Projection], centre_lines: Sequence[Centreline], shifts_px, *,
                     cutoff_px: float = 2.0) -> float:
    """How badly the shifted views disagree: the sum over views of the fit cost of each view's
    shift against the points triangulated from the others (pixels squared; 0 when every
    triangulated point lands on a centreline)."""
    pair_lists = [_pairs_for(v, projections) for v in range(len(projections))]
    return _summed_cost(projections, centre_lines, np.asarray(shifts_px, dtype=float), pair_lists, cutoff_px)


_MATCHED_ENTRIES = 96  # a cache of _triangulated_for beyond this many entries starts afresh


def _summed_cost(projections, centre_lines, shifts: np.ndarray, pair_lists, cutoff_px: float,
                 matched: dict | None = None) -> float:
    total = 0.0
    matched = {} if matched is None else matched  # a pair of views serves several views' fits
    for v, projection in enumerate(projections):
        points, weights = _triangulated_for(pair_lists[v], projections, centre_lines, shifts, matched)
        if len(points) == 0 or centre_lines[v].tree is None:
            total += cutoff_px ** 2
            continue
        total += _cost(centre_lines[v], projection.project(points), weights, shifts[v], cutoff_px)
    return total


def _pattern_search(cost, x: np.ndarray, directions: np.ndarray, steps: Sequence[float],
                    max_passes: int) -> tuple[np.ndarray, float]:
    """Minimise ``cost`` from ``x`` along ``directions`` (rows), both signs, for each step size in
    turn; a step size is repeated until a pass over the directions no longer lowers the cost."""
    best = cost(x)
    for step in steps:
        for _ in range(max_passes):
            improved = False
            for direction in directions:
                for trial in (x + step * direction, x - step * direction):
                    value = cost(trial)
                    if value < best - 1e-12:
                        x, best, improved = trial, value, True
                        break
            if not improved:
                break
    return x, best


def _off_gauge_basis(gauge_directions: np.ndarray, size: int) -> np.ndarray:
    """Rows: an orthonormal basis of the shift changes (length ``size``) that the columns of
    ``gauge_directions`` -- those a common 3D translation produces -- do not explain."""
    gauge = np.asarray(gauge_directions, dtype=float).reshape(size, -1)
    u, singular, _ = np.linalg.svd(gauge, full_matrices=True)
    rank = int(np.count_nonzero(singular > 1e-9 * max(1.0, float(singular.max(initial=0.0)))))
    return u[:, rank:].T


def fit_jointly(projections: Sequence[Projection], centre_lines: Sequence[Centreline], shifts_px,
                gauge_directions: np.ndarray, *, cutoff_px: float = 2.0,
                steps_px: Sequence[float] = (1.0, 0.5, 0.25, 0.1, 0.05), max_passes: int = 20,
                views: Sequence[int] | None = None, reach_px: int = 0) -> tuple[np.ndarray, float]:
    """Minimise :func:`consistency_cost` over all views' shifts together (a pattern search).

    :func:`polish_shifts` moves one view at a time against the others, which is not a descent on
    the summed cost: along a direction the cost barely sees (two views that share an image axis)
    its sweeps wander. Here every trial step changes the summed cost's argument directly. The search
    runs along an orthonormal basis of the shift changes that ``gauge_directions`` (2N, k) -- the
    columns the common 3D translation produces -- do not explain; each step size is repeated until
    a pass over the basis (both signs) no longer lowers the cost.

    ``views``: only these views' shifts change (default: all); the others are held, and the
    basis is that of their shift changes which no translation leaving the held views in place
    explains. ``reach_px``: each changing view first takes the best integer offset within this
    reach of its start (the summed cost, the other views as they stand), one view after another,
    before the pattern search (default 0: none).

    Returns ``(shifts (N, 2), cost)``.
    """
    shifts = np.asarray(shifts_px, dtype=float).ravel()
    n = len(projections)
    free = list(range(n)) if views is None else sorted(set(int(v) for v in views))
    columns = np.array([2 * v + k for v in free for k in (0, 1)], dtype=int)
    gauge = np.asarray(gauge_directions, dtype=float).reshape(2 * n, -1)
    held = np.setdiff1d(np.arange(2 * n), columns)
    if len(held):  # translations that leave the held views in place: the null space of their rows
        gauge = gauge @ _off_gauge_basis(gauge[held].T, gauge.shape[1]).T
    local = _off_gauge_basis(gauge[columns], len(columns))
    basis = np.zeros((len(local), 2 * n))
    basis[:, columns] = local
    pair_lists = [_pairs_for(v, projections) for v in range(n)]
    matched: dict = {}  # a trial step moves some views only: the pairs of the others are reused

    def cost(x: np.ndarray) -> float:
        return _summed_cost(projections, centre_lines, x.reshape(-1, 2), pair_lists, cutoff_px, matched)

    offsets = [(du, dv) for du in range(-reach_px, reach_px + 1) for dv in range(-reach_px, reach_px + 1)]
    for v in free if reach_px > 0 else ():  # the best integer offset, one view after another
        trials = []
        for offset in offsets:
            trial = shifts.copy()
            trial[2 * v:2 * v + 2] += offset
            trials.append((cost(trial), trial))
        shifts = min(trials, key=lambda t: t[0])[1]
    shifts, best = _pattern_search(cost, shifts, basis, steps_px, max_passes)
    return shifts.reshape(-1, 2), best


def fit_scales_jointly(projections: Sequence[Projection], centre_lines: Sequence[Centreline], scales, shifts_px,
                       views: Sequence[int], gauge_directions: np.ndarray, *, cutoff_px: float = 2.0,
                       steps_px: Sequence[float] = (2.0, 1.0, 0.5, 0.25, 0.1, 0.05),
                       max_passes: int = 20) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`fit_jointly` with the image scales of ``views`` as further coordinates.

    ``projections`` are the header's views; view ``v`` is taken as
    ``projections[v].magnified(scales[v]).shifted(*shifts[v])``. A scale about the principal point
    and a shift trade against each other when a view's vessels lie off the principal point (a view
    too large by 10 % is explained almost as well by 7 % and a 3 px shift). The search therefore
    moves a view's scale about the centroid of its centreline pixels, with its shift adjusted so
    that the centroid stays put, in steps measured in pixels at the centreline pixels' RMS distance
    from that centroid. ``gauge_directions``: as for :func:`fit_jointly`, at the starting scales.

    Returns ``(scales (N,), shifts (N, 2), cost)``.
    """
    n = len(projections)
    scales = np.asarray(scales, dtype=float)
    start = np.asarray(shifts_px, dtype=float).ravel()
    pair_lists = [_pairs_for(v, projections) for v in range(n)]
    matched: dict = {}  # as in fit_jointly
    pivots = []  # (view, centroid (2,) - principal point (2,), RMS radius px)
    for v in views:
        uv = centre_lines[v].uv_px
        centroid = uv.mean(axis=0) if len(uv) else np.asarray(projections[v].principal_point_px, dtype=float)
        radius = float(np.sqrt(np.mean(np.sum((uv - centroid) ** 2, axis=1)))) if len(uv) > 1 else 1.0
        pivots.append((v, centroid - np.asarray(projections[v].principal_point_px, dtype=float), max(radius, 1.0)))

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out_scales, out_shifts = scales.copy(), x[:2 * n].reshape(-1, 2).copy()
        for k, (v, offset, radius) in enumerate(pivots):
            change = x[2 * n + k] / radius
            out_scales[v] = scales[v] * (1.0 + change)
            out_shifts[v] = (1.0 + change) * out_shifts[v] - change * offset
        return out_scales, out_shifts

    def cost(x: np.ndarray) -> float:
        trial_scales, trial_shifts = unpack(x)
        return _summed_cost([p.magnified(f) for p, f in zip(projections, trial_scales)], centre_lines, trial_shifts,
                            pair_lists, cutoff_px, matched)

    basis = _off_gauge_basis(gauge_directions, 2 * n)
    directions = np.zeros((len(basis) + len(pivots), 2 * n + len(pivots)))
    directions[:len(basis), :2 * n] = basis
    directions[len(basis):, 2 * n:] = np.eye(len(pivots))
    x, best = _pattern_search(cost, np.concatenate([start, np.zeros(len(pivots))]), directions, steps_px, max_passes)
    out_scales, out_shifts = unpack(x)
    return out_scales, out_shifts, best


def fit_view_scale(projections: Sequence[Projection], centre_lines: Sequence[Centreline], shifts_px, view: int,
                   factors: Sequence[float], *, cutoff_px: float = 2.0) -> tuple[float, np.ndarray, float, float]:
    """The image scale of one view (about its principal point, :meth:`Projection.magnified`) that
    brings the points triangulated from the other views onto its centreline.

    ``projections`` are the views as they stand (any scale already applied), ``shifts_px`` their
    shifts. For every factor in ``factors`` (relative to the view as it stands) the view's shift is
    refitted (:func:`fit_view_shift`, from the shift that keeps the projected points' weighted
    centroid in place, within 1 px of it). Returns ``(factor, shift (2,), cost, cost at factor 1)``;
    ``(1, shift, cost, cost)`` when nothing is triangulated.
    """
    shifts = np.asarray(shifts_px, dtype=float)
    points, weights = _triangulated_for(_pairs_for(view, projections), projections, centre_lines, shifts)
    here = projections[view].shifted(*shifts[view])
    if len(points) == 0 or centre_lines[view].tree is None:
        return 1.0, shifts[view].copy(), float(cutoff_px ** 2), float(cutoff_px ** 2)
    uv_here = here.project(points)
    centroid = np.average(uv_here, axis=0, weights=weights)
    _, cost_here = fit_view_shift(centre_lines[view], uv_here, weights, (0.0, 0.0), reach_px=1, cutoff_px=cutoff_px)
    # every factor's shift to a quarter pixel, then the best few on to 0.05 px (the same grids as one fit)
    coarse = []
    for factor in factors:
        uv = projections[view].magnified(float(factor)).shifted(*shifts[view]).project(points)
        start = centroid - np.average(uv, axis=0, weights=weights)
        shift, cost = fit_view_shift(centre_lines[view], uv, weights, start, reach_px=1, cutoff_px=cutoff_px,
                                     steps_px=(0.5, 0.25))
        coarse.append((cost, float(factor), uv, shift))
    best = (cost_here, 1.0, shifts[view].copy())
    for _, factor, uv, shift in sorted(coarse, key=lambda c: c[0])[:_REFINED_FACTORS]:
        shift, cost = fit_view_shift(centre_lines[view], uv, weights, shift, reach_px=0, cutoff_px=cutoff_px,
                                     steps_px=(0.1, 0.05))
        if cost < best[0]:
            best = (cost, factor, shifts[view] + shift)
    return best[1], best[2], best[0], cost_here


_REFINED_FACTORS = 3  # fit_view_scale carries this many of the best factors on from a quarter pixel to 0.05 px
