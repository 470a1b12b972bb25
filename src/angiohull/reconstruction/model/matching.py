"""Correspondences of centerline pixels across views: epipolar candidates from the other view's
mask, then an exact min-sum choice of one candidate (or none) per pixel over the pixel graph.

Notation: view A's skeleton pixels are matched into view B; ``p`` is a pixel of A.

1. **Candidates.** Every 3D point seen at ``p`` lies on ``p``'s ray, which projects into B as the
   epipolar line of ``p``. B's mask *core* is sampled along that line (bilinear, every
   ``line_step_px``, within ``depth_range_mm`` of the isocentre's depth along the ray); each run of
   vessel pixels is a candidate at its middle. The core (:func:`mask_core`) is the mask's pixels at
   least ``core_fraction`` of the local half-width deep (the half-width of the widest skeleton disc
   that covers them), and those within a pixel of the skeleton: a line that only grazes a vessel's
   rim, or a bump or halo on a segmented mask's edge, gives no run there, and a run's middle sits
   nearer the axis. (Since 2026-12-03; the whole mask before. 200 generated trees in two clinical
   views, paired: Dice3D +0.40 ± 0.33 points with exact masks, +0.52 ± 0.44 with segmented ones,
   radius error unchanged within 0.007 mm. The local half-width read at the nearest skeleton pixel
   instead gained +0.37 / +0.92 there but put the XCAT vessel's centerline 0.29 mm farther from its
   truth: where a wide vessel's skeleton forks into prongs near its ends, a spur's small half-width
   let the flank beside it into the core.) The half-widths (below) and the skeleton are the whole
   mask's. A run many vessel widths long (a vessel of B running along the line) is split into pieces
   a width long (at most ``max_pieces``), each a candidate: there the line does not fix the depth,
   and the neighbours decide. Where an even number of pieces leaves out the run's middle and that
   middle lies within ``middle_skeleton_px`` of B's skeleton, the middle is one more candidate: a
   line that crosses a vessel at a slant runs through it for its width / sin(angle), and the middle
   of that run is on the axis. (Until 2026-12-02 it was no candidate: a straight vessel crossing the
   lines at 28 degrees came out 1.0-1.45 mm off its axis all along.) Mask runs, not B's skeleton, so
   that a vessel foreshortened into a blob in B, or two vessels overlapping there, still give one.
   Each candidate is triangulated (midpoint of the shortest segment between the two rays) and tagged
   with B's skeleton pixel nearest to it (its chain and direction in B).
2. **Unary cost**: the disagreement of the radius the two views show at that depth (half-width
   times depth / focal length; ``((rA - rB) / sigma)**2`` with ``sigma = radius_sigma_px`` pixels
   at the larger scale plus ``radius_sigma_rel`` of the radius, capped at ``radius_cap``). B's
   half-width is taken at the candidate and at B's nearest skeleton pixel, and the one that agrees
   better counts (the first is off the axis for a piece of a long run, the second widened by an
   overlap or a junction nearby). ``p`` lies on A's skeleton, so its partner should lie on B's:
   the candidate's distance ``d`` to B's skeleton costs ``(d / partner_skeleton_px)**2`` (capped
   at ``cap``; since 2026-12-02: a piece of a slanted run, or a run's middle between two vessels,
   lies off it). With three or more views, for every other view: the candidate
   is dropped when its projection lies farther than ``mask_px`` from that view's mask (outside the
   visual hull), and costs ``(d / other_skeleton_px)**2`` (capped at ``cap``) for its distance
   ``d`` to that view's skeleton. With ``claims`` (B's own matching into A, from an earlier
   round), a candidate whose B pixel that matching put elsewhere along A (farther than
   ``claim_px`` plus the half-width from ``p``) costs ``claim_cost`` more.
3. **Pairwise cost** between the candidates of neighbouring pixels: a 3D step longer than
   ``max_stretch`` times the pixel step at that depth (a vessel can run out of A's image plane,
   not jump) costs ``jump_weight`` per unit of excess stretch; going over from one chain of B to
   another costs ``switch_cost`` plus ``turn_weight * (1 - |cos|)`` of the angle between the two
   chains' directions in B: straight on through a crossing in B is free, turning onto the vessel
   that crosses there (the phantom the epipolar line alone cannot rule out) bends. Where A's
   pixel is a junction, only ``switch_cost`` applies (a side branch leaves at an angle).
4. **No match**: a pixel may stay unmatched at ``gap_cost`` (its vessel hidden or foreshortened in
   B, or a false skeleton piece); entering or leaving that state costs ``gap_switch_cost``.
5. **Solve**: the costs are minimised exactly over a breadth-first spanning forest of A's pixel
   graph (cycles where vessels cross in A are cut): min-sum messages from the leaves to the
   roots, level by level for all pixels of a level at once, then the choices back down.
6. **Anchored again** (:func:`anchored_match`): once a reconstruction stands, the pixels of A that
   nothing in it explains are matched again with the others pinned to it, their partner's
   distance to B's skeleton free and B showing the vessel wider than A free (an overlap in B only
   widens it); a match is kept where matched neighbours join it to a pinned pixel.
7. **Width bias** (two views, :func:`with_width_bias`): a segmentation may draw one view's edges
   farther out than the other's (a threshold, a blur), and every half-width of that view is then
   larger by about the same number of pixels. The radius term (2.) compares the views' radii, so a
   bias of 2 px makes every true pair cost about 1 (instead of 0.2-0.3), and a narrower wrong
   vessel the cheaper partner. Before the first round, each view is matched into the other; of
   the pairs whose pixels both lie inside a chain away from its ends and junctions (and the
   partner within a pixel of B's skeleton), the median half-width difference (A's brought to B's
   scale) is the bias; half of it is taken off the wider view's half-widths and added to the
   other's, and the matchings and the median again, until it moves less than 0.05 px (2-4 rounds
   for a bias of 1-2 px: the radius term at first draws the pairs to agreeing widths; one round
   where none; it stops after the first where that measures under a quarter of
   ``width_bias_min_px``). It is taken off wherever the radii compare (here and in 6.); the radius
   of a pair, the views' mean, stays what they show. Less than ``width_bias_min_px`` is not taken
   off, and the first round's matchings, which are then the first round of 2. (no claims), are
   not computed again.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ...compiled import kernels
from ...geometry import Projection
from ..epipolar import ray_directions
from .graph2d import CenterlineGraph2D

__all__ = ["Avoid", "MatchSettings", "MATCH_SETTINGS", "ViewData", "anchored_match", "mask_core", "match_pixels",
           "measured_width_bias", "triangulate_midpoint", "with_width_bias"]


@dataclass(frozen=True)
class MatchSettings:
    """Parameters of the correspondence (module notes); the same for every case."""

    depth_range_mm: float = 150.0  # candidates within this of the isocentre's depth along each ray
    line_step_px: float = 0.5  # the mask is sampled along each epipolar line at this step
    max_pieces: int = 8  # a run along the line is split in at most this many candidates
    middle_skeleton_px: float = 1.0  # ... and its middle is one more where it lies this near B's skeleton
    max_candidates: int = 12  # kept per pixel, cheapest first
    radius_cap: float = 2.0
    radius_sigma_px: float = 0.7
    radius_sigma_rel: float = 0.15
    mask_px: float = 1.5  # a candidate farther than this from another view's mask is outside the hull
    other_skeleton_px: float = 2.0  # scale of the cost of a candidate's distance to another view's skeleton
    partner_skeleton_px: float = 3.0  # ... and to the partner view's own skeleton
    cap: float = 4.0  # each unary term at most this
    max_stretch: float = 3.0  # 3D step over the projected step in A beyond which a jump costs
    jump_weight: float = 1.0
    switch_cost: float = 0.5
    turn_weight: float = 4.0
    gap_cost: float = 2.0
    gap_switch_cost: float = 2.0
    claim_px: float = 2.0  # B's own match of q lies farther than this plus the half-width from p in A ...
    claim_cost: float = 1.5  # ... costs this
    core_fraction: float = 0.5  # the epipolar lines read B's mask pixels this share of the half-width deep (1.)
    # two views: how much wider one view shows the vessels than the other (a per-view segmentation bias), measured
    # on the views' matchings, is taken off where the radii compare (7.) ...
    width_bias: bool = True
    width_bias_min_px: float = 0.5  # ... where it is this much or more


MATCH_SETTINGS = MatchSettings()


@dataclass(frozen=True)
class ViewData:
    """One view, prepared for matching."""

    projection: Projection
    mask: np.ndarray  # (rows, cols) bool
    graph: CenterlineGraph2D
    image: np.ndarray  # (rows, cols) float32: what the epipolar lines read (1 vessel, 0 background)
    box_uv: tuple[np.ndarray, np.ndarray]  # (u, v) corners of the mask's bounding box, 2 px wider
    inside_px: np.ndarray  # (rows, cols) distance of each pixel to the nearest background pixel
    nearest_skeleton: np.ndarray  # (rows, cols) index of the nearest skeleton pixel (-1: none)
    outside_px: np.ndarray  # (rows, cols) distance of each pixel to the nearest mask pixel
    skeleton_px: np.ndarray  # (rows, cols) distance of each pixel to the nearest skeleton pixel
    focal_px: float
    width_bias_px: float = 0.0  # what this view's mask adds to every half-width (px), taken off where radii compare


def triangulate_midpoint(centre_a: np.ndarray, dir_a: np.ndarray, centre_b: np.ndarray,
                         dir_b: np.ndarray) -> np.ndarray:
    """Midpoints of the shortest segments between rays ``centre_a + s dir_a`` and ``centre_b + t dir_b``
    (unit directions (N, 3)); (N, 3) mm."""
    w0 = centre_a - centre_b
    b = np.einsum("ij,ij->i", dir_a, dir_b)
    d = dir_a @ w0
    e = dir_b @ w0
    denom = np.maximum(1.0 - b * b, 1e-12)
    s = (b * e - d) / denom
    t = (e - b * d) / denom
    return 0.5 * ((centre_a + s[:, None] * dir_a) + (centre_b + t[:, None] * dir_b))


def mask_core(mask: np.ndarray, graph: CenterlineGraph2D, inside_px: np.ndarray, skeleton_px: np.ndarray,
              nearest_skeleton: np.ndarray, fraction: float) -> np.ndarray:
    """The mask's pixels at least ``fraction`` of the local half-width deep, and every mask pixel
    within one pixel of the skeleton (so that the core of a thin vessel stays a 4-connected band).

    A pixel's depth is its distance to the background less half a pixel (``inside_px - 0.5``); its
    local half-width is that of the widest skeleton disc covering it (a skeleton pixel's disc: its
    own distance to the background in levels half a pixel apart, a pixel apart from 8 px, less
    half a pixel), not that of the nearest skeleton pixel, which is a side spur's where the
    skeleton forks into prongs near a wide vessel's end; a pixel no disc covers takes its nearest
    skeleton pixel's. ``fraction`` 0 gives the mask; 0.5 the middle half of each vessel's width."""
    if fraction <= 0 or graph.n_pixels == 0:
        return mask.copy()
    rows, cols = np.nonzero(mask)
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))  # the skeleton lies inside
    uv = graph.uv_px.astype(np.int64) - np.array([box[1].start, box[0].start])
    inside = inside_px[box]
    radius = inside[uv[:, 1], uv[:, 0]]
    radius = np.where(radius < 8.0, np.floor(2.0 * radius) / 2.0, np.floor(radius))  # levels 0.5 px apart, 1 px from 8
    covering = np.zeros(inside.shape)
    for level in np.unique(radius):  # ascending: a wider disc overwrites a narrower one
        chosen = uv[radius >= level]
        # the discs lie within their centres' box grown by the level: the distance there is exact
        reach = int(np.ceil(level)) + 1
        low = np.maximum(chosen.min(axis=0) - reach, 0)
        high = np.minimum(chosen.max(axis=0) + reach + 1, [inside.shape[1], inside.shape[0]])
        seeds = np.ones((high[1] - low[1], high[0] - low[0]), dtype=bool)
        seeds[chosen[:, 1] - low[1], chosen[:, 0] - low[0]] = False
        part = covering[low[1]:high[1], low[0]:high[0]]
        part[ndi.distance_transform_edt(seeds) <= level] = level
    half = np.where(covering > 0, covering - 0.5, graph.half_width_px[np.maximum(nearest_skeleton[box], 0)])
    core = np.zeros_like(mask)
    core[box] = mask[box] & ((inside - 0.5 >= fraction * half) | (skeleton_px[box] <= 1.0))
    return core


def _sample(image: np.ndarray, uv: np.ndarray, outside: float) -> np.ndarray:
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    ok = (u >= 0) & (v >= 0) & (u < image.shape[1]) & (v < image.shape[0])
    out = np.full(len(uv), outside)
    out[ok] = image[v[ok], u[ok]]
    return out


@dataclass
class _Candidates:
    sample: np.ndarray  # (C,) index of the A sample
    q: np.ndarray  # (C,) B skeleton pixel nearest the candidate's place in B
    point: np.ndarray  # (C, 3)
    radius: np.ndarray  # (C,) mm
    unary: np.ndarray  # (C,)
    scale_a: np.ndarray  # (C,) mm per px of A at the point


def _line_runs(b: ViewData, start_uv: np.ndarray, end_uv: np.ndarray, step_px: float) -> tuple[np.ndarray, ...]:
    """The runs of B's mask along each segment ``start -> end`` (one per A sample):
    ``(sample, t_in, t_out)`` in px from ``start`` (sub-pixel edges of the bilinear mask)."""
    rows, cols = b.mask.shape
    box_lo, box_hi = b.box_uv
    direction = end_uv - start_uv
    length = np.linalg.norm(direction, axis=1)
    direction = direction / np.maximum(length, 1e-12)[:, None]
    # clip each segment to the box around the mask (slab method)
    t0, t1 = np.zeros(len(start_uv)), length.copy()
    for axis in range(2):
        d = direction[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (box_lo[axis] - start_uv[:, axis]) / d
            c = (box_hi[axis] - start_uv[:, axis]) / d
        lo, hi = np.minimum(a, c), np.maximum(a, c)
        flat = np.abs(d) < 1e-12
        inside = (start_uv[:, axis] >= box_lo[axis]) & (start_uv[:, axis] <= box_hi[axis])
        lo = np.where(flat, np.where(inside, -np.inf, np.inf), lo)
        hi = np.where(flat, np.where(inside, np.inf, -np.inf), hi)
        t0, t1 = np.maximum(t0, lo), np.minimum(t1, hi)
    samples, t_in, t_out = [], [], []
    span = np.maximum(t1 - t0, 0.0)
    count = np.ceil(span / step_px).astype(np.int64) + 1
    order = np.argsort(count)
    chunk = max(1, 2_000_000 // max(1, int(count.max())))
    for lo_i in range(0, len(order), chunk):
        idx = order[lo_i:lo_i + chunk]
        idx = idx[span[idx] > 0]
        if len(idx) == 0:
            continue
        n = int(count[idx].max())
        t = t0[idx, None] + step_px * np.arange(n)[None, :]
        valid = t <= t1[idx, None] + 1e-9
        u = start_uv[idx, 0, None] + t * direction[idx, 0, None]
        v = start_uv[idx, 1, None] + t * direction[idx, 1, None]
        value = ndi.map_coordinates(b.image, [v.ravel(), u.ravel()], order=1, mode="constant", cval=0.0).reshape(t.shape)
        value = np.where(valid, value, 0.0)
        inside = np.pad(value >= 0.5, ((0, 0), (1, 1)))
        change = np.diff(inside.astype(np.int8), axis=1)
        r_in, c_in = np.nonzero(change == 1)  # first inside sample of a run is c_in
        r_out, c_out = np.nonzero(change == -1)  # last inside sample is c_out - 1
        padded = np.pad(value, ((0, 0), (1, 1)))
        # sub-pixel edges: where the bilinear value crosses 0.5 between the samples
        before, first = padded[r_in, c_in], padded[r_in, c_in + 1]
        enter = (c_in - 1) + (0.5 - before) / np.maximum(first - before, 1e-9)
        last, after = padded[r_out, c_out], padded[r_out, c_out + 1]
        leave = (c_out - 1) + (last - 0.5) / np.maximum(last - after, 1e-9)
        tt = t[:, :1]
        samples.append(idx[r_in])
        t_in.append(tt[r_in, 0] + step_px * enter)
        t_out.append(tt[r_out, 0] + step_px * leave)
    if not samples:
        empty = np.zeros(0)
        return empty.astype(np.int64), empty, empty, direction
    return np.concatenate(samples), np.concatenate(t_in), np.concatenate(t_out), direction


def _candidates(a: ViewData, b: ViewData, others: Sequence[ViewData], samples: np.ndarray,
                settings: MatchSettings, keep_all: bool = False) -> _Candidates:
    """The candidates of the ``samples`` (module notes, steps 1-2): at most ``max_candidates`` per
    sample, cheapest first, or with ``keep_all`` every one."""
    ga, gb = a.graph, b.graph
    dirs_a = ray_directions(a.projection, ga.uv_px[samples])
    centre_a = a.projection.camera_centre_mm
    reach = np.linalg.norm(centre_a)
    near = centre_a + (reach - settings.depth_range_mm) * dirs_a
    far = centre_a + (reach + settings.depth_range_mm) * dirs_a
    start_uv, end_uv = b.projection.project(near), b.projection.project(far)
    sample_of, t_in, t_out, direction = _line_runs(b, start_uv, end_uv, settings.line_step_px)
    run_px = t_out - t_in
    middle = 0.5 * (t_in + t_out)
    q_uv = start_uv[sample_of] + middle[:, None] * direction[sample_of]
    half_b = np.maximum(_bilinear(b.inside_px, q_uv) - 0.5, 0.5)
    # a run much longer than the vessel is wide runs along the line: split it in pieces a width
    # long; where the pieces leave out the run's middle (an even number of them) and that middle
    # lies on B's skeleton, the middle is a candidate too: a line crossing a vessel at a slant runs
    # through it for width / sin(angle), and the middle of such a run is on the vessel's axis
    pieces = np.clip(np.rint(run_px / (2.0 * half_b + 1.0)), 1, settings.max_pieces).astype(np.int64)
    count = pieces + ((pieces % 2 == 0) & (_bilinear(b.skeleton_px, q_uv) <= settings.middle_skeleton_px))
    owner = np.repeat(np.arange(len(run_px)), count)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    k = np.arange(len(owner)) - first[owner]
    t_mid = t_in[owner] + np.where(k < pieces[owner], (k + 0.5) / pieces[owner], 0.5) * run_px[owner]
    sample_of = sample_of[owner]
    q_uv = start_uv[sample_of] + t_mid[:, None] * direction[sample_of]
    q = _sample(b.nearest_skeleton, q_uv, -1).astype(np.int64)
    # the vessel's half-width where the candidate lies: at B's nearest skeleton pixel (the run's
    # middle, or a piece of a long run, need not lie on the vessel's axis)
    # B's half-width there, two ways: at the candidate (the run's middle, or a piece of a long run,
    # need not lie on the vessel's axis) and at B's nearest skeleton pixel (an overlap or a junction
    # nearby widens it); the radius cost takes the one that agrees better with A's
    half_run = np.maximum(_bilinear(b.inside_px, q_uv) - 0.5 - b.width_bias_px, 0.5)
    half_skeleton = np.maximum(np.where(q >= 0, gb.half_width_px[np.maximum(q, 0)], 0.5) - b.width_bias_px, 0.5)
    dirs_b = ray_directions(b.projection, q_uv)
    point = triangulate_midpoint(centre_a, dirs_a[sample_of], b.projection.camera_centre_mm, dirs_b)
    scale_a = a.projection.depth_mm(point) / a.focal_px
    scale_b = b.projection.depth_mm(point) / b.focal_px
    ra = np.maximum(ga.half_width_px[samples[sample_of]] - a.width_bias_px, 0.5) * scale_a
    unary = np.full(len(point), np.inf)
    rb = np.zeros(len(point))
    for half_b in (half_run, half_skeleton):
        r = half_b * scale_b
        sigma = settings.radius_sigma_px * np.maximum(scale_a, scale_b) + settings.radius_sigma_rel * np.maximum(ra, r)
        # rays that do not cross (two views along one line) triangulate to no point: whether the
        # arithmetic gives nan or a huge number there depends on the last bit of the rays (it
        # differs between CPUs), and a nan cost is kept by no comparison below, so it is not warned of
        with np.errstate(invalid="ignore", divide="ignore"):
            cost = np.minimum(((ra - r) / sigma) ** 2, settings.radius_cap)
        better = cost < unary
        unary[better], rb[better] = cost[better], r[better]
    # p lies on A's skeleton, so its partner should lie on B's: a candidate off B's skeleton (a
    # piece of a run that crosses a vessel at a slant, or a run between two vessels) costs for it
    off_skeleton_b = _bilinear(b.skeleton_px, q_uv)
    unary += np.minimum((off_skeleton_b / settings.partner_skeleton_px) ** 2, settings.cap)
    valid = a.projection.in_front(point) & b.projection.in_front(point)
    for other in others:
        uv = other.projection.project(point)
        valid &= _sample(other.outside_px, uv, np.inf) <= settings.mask_px
        off_skeleton = _sample(other.skeleton_px, uv, np.inf)
        unary += np.minimum((off_skeleton / settings.other_skeleton_px) ** 2, settings.cap)
    valid &= q >= 0
    radius = 0.5 * (ra + rb)
    cands = _Candidates(sample_of[valid], q[valid], point[valid], radius[valid], unary[valid], scale_a[valid])
    return cands if keep_all else _cheapest(cands, settings.max_candidates)


def _cheapest(cands: _Candidates, count: int) -> _Candidates:
    """At most ``count`` candidates per sample, by sample, cheapest first."""
    order = np.lexsort((cands.unary, cands.sample))
    rank = np.arange(len(order)) - np.searchsorted(cands.sample[order], cands.sample[order], side="left")
    keep = order[rank < count]
    return _Candidates(*(getattr(cands, f)[keep] for f in ("sample", "q", "point", "radius", "unary", "scale_a")))


@dataclass(frozen=True)
class Avoid:
    """A region of 3D space a matching avoids: a candidate whose point lies within ``reach_mm``
    (per point) of one of ``points_mm`` costs ``cost`` more (the hypothesis that a branch there is a
    wrong pairing; module notes of :mod:`angiohull.reconstruction.model`)."""

    points_mm: np.ndarray  # (M, 3)
    reach_mm: np.ndarray  # (M,)
    cost: float


def _avoiding(cands: _Candidates, avoid: Avoid | None) -> _Candidates:
    """``cands`` with ``avoid.cost`` added to the unary cost of those within its region."""
    if avoid is None or len(avoid.points_mm) == 0 or len(cands.point) == 0:
        return cands
    gap, nearest = cKDTree(avoid.points_mm).query(cands.point)
    inside = gap <= avoid.reach_mm[nearest]
    return replace(cands, unary=cands.unary + avoid.cost * inside)


def _claimed(a: ViewData, samples: np.ndarray, cands: _Candidates, claims: np.ndarray,
             settings: MatchSettings) -> np.ndarray:
    """(C,) bool: B's own matching put the 3D point of the candidate's B pixel elsewhere along A
    (farther than ``claim_px`` plus the half-width from the candidate's pixel in A)."""
    claimed = claims[cands.q]
    has = np.isfinite(claimed[:, 0])
    out = np.zeros(len(cands.q), dtype=bool)
    where = a.projection.project(claimed[has])
    pixel = samples[cands.sample[has]]
    out[has] = np.linalg.norm(where - a.graph.uv_px[pixel], axis=1) > settings.claim_px + a.graph.half_width_px[pixel]
    return out


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    return ndi.map_coordinates(image, [uv[:, 1], uv[:, 0]], order=1, mode="nearest")


def _forest_states(unary: np.ndarray, every: np.ndarray, offset: np.ndarray, levels: Sequence[np.ndarray],
                   parent: np.ndarray) -> np.ndarray:
    """Each pixel's state (column of ``unary``, (P, S) costs) that minimises the unary costs plus
    the transition costs ``every`` ((E, child state, parent state), the rows of level ``d``'s
    pixels from ``offset[d - 1]``) over the forest of ``levels`` (roots first) and ``parent``:
    min-sum messages from the leaves to the roots, level by level (each pixel's cost plus its
    subtree's, added to its parent's in the level's order), then the choices back down (the first
    of equal costs). The compiled kernel does the same per pixel, without the level's arrays."""
    compiled = kernels()
    if compiled is not None:
        sizes = np.array([len(level) for level in levels], dtype=np.int64)
        return compiled.forest_states(np.ascontiguousarray(unary, dtype=np.float64),
                                      np.ascontiguousarray(every, dtype=np.float64), np.asarray(offset, np.int64),
                                      np.concatenate(levels).astype(np.int64), np.concatenate([[0], np.cumsum(sizes)]),
                                      np.asarray(parent, np.int64))
    total = unary.copy()  # each pixel's cost plus its subtree's messages
    best_child = np.zeros(unary.shape, dtype=np.int64)
    for depth in range(len(levels) - 1, 0, -1):
        level = levels[depth]
        up = parent[level]
        joint = total[level][:, :, None] + every[offset[depth - 1]:offset[depth]]  # (n, child, parent)
        choice = np.argmin(joint, axis=1)
        best_child[level] = choice
        np.add.at(total, up, joint.min(axis=1))  # the values at ``choice``
    state = np.zeros(len(unary), dtype=np.int64)
    roots = levels[0]
    state[roots] = np.argmin(total[roots], axis=1)
    for level in levels[1:]:
        state[level] = best_child[level, state[parent[level]]]
    return state


def match_pixels(a: ViewData, b: ViewData, others: Sequence[ViewData] = (), settings: MatchSettings = MATCH_SETTINGS,
                 claims: np.ndarray | None = None, cache: dict | None = None, avoid: Avoid | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match every skeleton pixel of view ``a`` into view ``b`` at once: the costs of the module
    notes, minimised exactly over a spanning forest of A's pixel graph (min-sum messages from the
    leaves to the roots, then the choices back down), so that the choices along one vessel, through
    A's junctions, hang together. With ``avoid``, the candidates in its region cost more (before
    each pixel's cheapest ``max_candidates`` are kept). ``cache`` (a dict, the same views and
    settings each call): the candidates and transitions are computed once, and the matching without
    claims or ``avoid`` is returned again (the same arrays: not to be changed); with ``avoid``, the
    avoided candidates and their transitions are kept there too for the next call with the same
    ``avoid`` (the same object: the rounds of one hypothesis's matchings), the last one's only.

    Returns
    -------
    points : (P, 3) array
        The matched 3D point of each pixel of A (nan where left unmatched).
    radii : (P,) array
        The radius the two views show there, mm (nan where unmatched).
    parent : (P,) array
        Each pixel's neighbour towards its root in the forest (-1 at a root).
    """
    g = a.graph
    n_p, n_c = g.n_pixels, settings.max_candidates
    points = np.full((n_p, 3), np.nan)
    radii = np.full(n_p, np.nan)
    if n_p == 0 or b.graph.n_pixels == 0:
        return points, radii, np.full(n_p, -1, dtype=np.int64)
    if cache is not None and claims is None and avoid is None and "unclaimed" in cache:
        return cache["unclaimed"]
    if cache is not None and "candidates" in cache and (avoid is None or "every" in cache):
        cands, parent, levels, every = cache["candidates"], cache["parent"], cache["levels"], cache.get("every")
    else:
        every = _candidates(a, b, others, np.arange(n_p), settings, keep_all=True)
        cands = _cheapest(every, settings.max_candidates)
        parent, levels = g.spanning_forest()
        if cache is not None:
            cache.update(candidates=cands, parent=parent, levels=levels, every=every)
    if avoid is not None:  # other candidates than the cached ones, so their transitions too
        avoided = cache.get("avoided") if cache is not None else None
        if avoided is None or avoided["avoid"] is not avoid:  # kept for the next round of this avoid
            avoided = {"avoid": avoid, "candidates": _cheapest(_avoiding(every, avoid), settings.max_candidates)}
            if cache is not None:
                cache["avoided"] = avoided
        cands, cache = avoided["candidates"], avoided
    cost_of = cands.unary
    if claims is not None:
        cost_of = cost_of + settings.claim_cost * _claimed(a, np.arange(n_p), cands, claims, settings)
    slot = np.arange(len(cands.sample)) - np.searchsorted(cands.sample, cands.sample, side="left")
    gap = n_c
    unary = np.full((n_p, n_c + 1), np.inf)
    unary[:, gap] = settings.gap_cost
    unary[cands.sample, slot] = cost_of
    point = np.zeros((n_p, n_c, 3))
    point[cands.sample, slot] = cands.point
    radius = np.full((n_p, n_c), np.nan)
    radius[cands.sample, slot] = cands.radius
    chain_b = np.full((n_p, n_c), -1, dtype=np.int64)
    chain_b[cands.sample, slot] = b.graph.chain_of[cands.q]
    tangent_b = np.zeros((n_p, n_c, 2))
    tangent_b[cands.sample, slot] = b.graph.tangent[cands.q]
    scale = np.ones((n_p, n_c))
    scale[cands.sample, slot] = cands.scale_a
    s = settings

    def transition(child: np.ndarray, up: np.ndarray) -> np.ndarray:
        """(n, C+1, C+1) cost of (child state, parent state)."""
        # the norms coordinate by coordinate: np.linalg.norm's squares added in the same order,
        # without its strided reduction over the last axis
        du, dv = (g.uv_px[child, k] - g.uv_px[up, k] for k in range(2))
        step_px = np.sqrt(du * du + dv * dv)
        at_child, at_up = point[child], point[up]
        dx, dy, dz = (at_child[:, :, None, k] - at_up[:, None, :, k] for k in range(3))
        jump = np.sqrt((dx * dx + dy * dy) + dz * dz)
        ds = np.maximum(step_px[:, None, None] * scale[up][:, None, :], 1e-6)
        cost = s.jump_weight * np.maximum(jump / ds - s.max_stretch, 0.0)
        switch = chain_b[child][:, :, None] != chain_b[up][:, None, :]
        cos = np.abs(np.einsum("nai,nbi->nab", tangent_b[child], tangent_b[up]))
        turn = np.where(switch, s.switch_cost + s.turn_weight * (1.0 - cos), 0.0)
        # a side branch leaves A's junction: its partner in B may leave B's junction at an angle
        turn = np.where((g.degree[up] > 2)[:, None, None], np.where(switch, s.switch_cost, 0.0), turn)
        full = np.empty((len(child), n_c + 1, n_c + 1))
        full[:, :n_c, :n_c] = cost + turn
        full[:, :n_c, gap] = s.gap_switch_cost
        full[:, gap, :n_c] = s.gap_switch_cost
        full[:, gap, gap] = 0.0
        return full

    if cache is not None and "transitions" in cache:
        transitions = cache["transitions"]
    else:  # every level's at once (one batch of small arrays, not one per level), sliced per level below
        below = levels[1:]
        children = np.concatenate(below) if below else np.zeros(0, dtype=np.int64)
        transitions = (transition(children, parent[children]),
                       np.concatenate([[0], np.cumsum([len(level) for level in below])]).astype(np.int64))
        if cache is not None:
            cache["transitions"] = transitions
    state = _forest_states(unary, *transitions, levels, parent)
    matched = state < gap
    idx = np.flatnonzero(matched)
    points[idx] = point[idx, state[idx]]
    radii[idx] = radius[idx, state[idx]]
    if cache is not None and claims is None and avoid is None:
        cache["unclaimed"] = (points, radii, parent)
    return points, radii, parent


def anchored_match(a: ViewData, b: ViewData, anchor_mm: np.ndarray, anchor_radius_mm: np.ndarray,
                   settings: MatchSettings = MATCH_SETTINGS, max_segment_mm: float = 2.0, avoid: Avoid | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Match the *free* skeleton pixels of view ``a`` (those whose ``anchor_mm`` row is nan) into view
    ``b`` again, the others pinned to their anchors (a reconstruction's 3D points that explain
    them): the min-sum matching of :func:`match_pixels` over A's pixel graph, where a pinned pixel
    has one candidate, its anchor moved onto its ray, at no cost, and a free pixel the candidates of
    its epipolar line with two terms eased: its partner's distance to B's skeleton does not count
    (where A shows a vessel nothing explains, B may show it merged with another vessel, off any
    skeleton of its own), and B showing the vessel wider than A costs nothing (an overlap there
    only widens it; the radius is then A's), narrower as before. A free pixel's match is kept only
    where a path of matched neighbours (at most ``max_segment_mm`` apart in 3D) joins it to a pinned
    pixel: what continues the reconstruction, not a vessel placed anew. ``avoid``: as for
    :func:`match_pixels`, on the free pixels' candidates.

    Returns
    -------
    points : (P, 3) array
        The matched 3D point of each pixel of A (pinned ones at their anchors on their rays; nan
        where unmatched or not joined).
    radii : (P,) array
        mm, nan likewise.
    parent : (P,) array
        Each pixel's neighbour towards its root in A's spanning forest (-1 at a root).
    new : (P,) bool
        The free pixels matched and joined.
    """
    g = a.graph
    n_p = g.n_pixels
    anchor_mm = np.asarray(anchor_mm, dtype=float).reshape(n_p, 3)
    anchor_radius_mm = np.asarray(anchor_radius_mm, dtype=float).reshape(n_p)
    points, radii = np.full((n_p, 3), np.nan), np.full(n_p, np.nan)
    parent, levels = g.spanning_forest() if n_p else (np.zeros(0, dtype=np.int64), [])
    free = np.isnan(anchor_mm[:, 0])
    if n_p == 0 or b.graph.n_pixels == 0 or not free.any() or free.all():
        return points, radii, parent, np.zeros(n_p, dtype=bool)
    # the free pixels' candidates, without the partner's skeleton term, the radius term one-sided
    samples = np.flatnonzero(free)
    eased = replace(settings, radius_cap=0.0, partner_skeleton_px=np.inf)
    c = _candidates(a, b, [], samples, eased, keep_all=avoid is not None)
    if avoid is not None:
        c = _cheapest(_avoiding(c, avoid), settings.max_candidates)
    pixel = samples[c.sample]
    ra = np.maximum(g.half_width_px[pixel] - a.width_bias_px, 0.5) * c.scale_a
    rb = 2.0 * c.radius - ra  # B's radius (the candidates hold the two views' mean)
    sigma = settings.radius_sigma_px * c.scale_a + settings.radius_sigma_rel * np.maximum(ra, rb)
    unary_free = c.unary + np.where(rb < ra, np.minimum(((ra - rb) / sigma) ** 2, settings.radius_cap), 0.0)
    radius_free = np.where(rb > ra, ra, c.radius)
    # the pinned pixels: their anchors moved onto their rays
    pinned = np.flatnonzero(~free)
    rays = ray_directions(a.projection, g.uv_px[pinned])
    centre = a.projection.camera_centre_mm
    on_ray = centre + np.einsum("ij,ij->i", anchor_mm[pinned] - centre, rays)[:, None] * rays
    uv_b = np.rint(b.projection.project(on_ray)).astype(np.int64)
    rows, cols = b.mask.shape
    q_pinned = b.nearest_skeleton[np.clip(uv_b[:, 1], 0, rows - 1), np.clip(uv_b[:, 0], 0, cols - 1)]
    sample = np.concatenate([pixel, pinned])
    fields = (np.concatenate([c.q, np.maximum(q_pinned, 0)]), np.vstack([c.point, on_ray]),
              np.concatenate([radius_free, anchor_radius_mm[pinned]]),
              np.concatenate([unary_free, np.zeros(len(pinned))]),
              np.concatenate([c.scale_a, a.projection.depth_mm(on_ray) / a.focal_px]))
    order = np.lexsort((fields[3], sample))
    sample = sample[order]
    rank = np.arange(len(sample)) - np.searchsorted(sample, sample, side="left")
    keep = rank < settings.max_candidates  # by pixel, cheapest first
    cands = _Candidates(sample[keep], *(f[order][keep] for f in fields))
    got, got_radii, parent = match_pixels(a, b, [], settings, None,
                                          {"candidates": cands, "parent": parent, "levels": levels})
    matched = np.isfinite(got_radii)
    # joined to a pinned pixel through matched neighbours
    child = np.flatnonzero((parent >= 0) & matched)
    child = child[matched[parent[child]]]
    child = child[np.linalg.norm(got[child] - got[parent[child]], axis=1) <= max_segment_mm]
    links = coo_matrix((np.ones(len(child)), (child, parent[child])), shape=(n_p, n_p))
    _, component = connected_components(links, directed=False)
    joined = np.isin(component, component[~free & matched])
    keep_pixel = matched & (~free | joined)
    points[keep_pixel], radii[keep_pixel] = got[keep_pixel], got_radii[keep_pixel]
    return points, radii, parent, free & keep_pixel


def _clear_pixels(view: ViewData) -> np.ndarray:
    """(P,) bool: the skeleton pixels inside a chain (two neighbours) farther than twice their
    half-width plus 2 px from any end or junction pixel, where the half-width is the vessel's own
    (not widened by a junction, a branch leaving or an overlap)."""
    g = view.graph
    uv = g.uv_px.astype(np.int64)
    nodes = uv[g.degree != 2]
    if len(nodes) == 0:
        return g.degree == 2
    seeds = np.ones(view.mask.shape, dtype=bool)
    seeds[nodes[:, 1], nodes[:, 0]] = False
    apart = ndi.distance_transform_edt(seeds)[uv[:, 1], uv[:, 0]]
    return (g.degree == 2) & (apart > 2.0 * g.half_width_px + 2.0)


def _width_differences(views: Sequence[ViewData], settings: MatchSettings, clear: Sequence[np.ndarray],
                       caches: dict | None = None) -> np.ndarray:
    """View 1's half-width less view 0's (px, the matched pixel's brought to its partner's scale at
    the matched point; the views' own half-widths, whatever their ``width_bias_px``) over the pairs
    of each view's matching into the other (as the views' biases stand) whose two pixels lie inside
    a chain away from its ends and junctions, the partner within a pixel of the other view's
    skeleton. ``caches``: :func:`match_pixels`'s cache per pair (a, b) of these views.
    ``clear``: :func:`_clear_pixels` of each view (its graph's, whatever the bias)."""
    differences = []
    for a, b, sign in ((0, 1, 1.0), (1, 0, -1.0)):
        va, vb = views[a], views[b]
        points, radii, _ = match_pixels(va, vb, (), settings, cache=None if caches is None else caches[(a, b)])
        pixel = np.flatnonzero(np.isfinite(radii))
        point = points[pixel]
        uv = np.rint(vb.projection.project(point)).astype(np.int64)
        rows, cols = vb.mask.shape
        inside = (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < cols) & (uv[:, 1] < rows)
        pixel, point, uv = pixel[inside], point[inside], uv[inside]
        q = vb.nearest_skeleton[uv[:, 1], uv[:, 0]]
        keep = (q >= 0) & (vb.skeleton_px[uv[:, 1], uv[:, 0]] <= 1.0)
        keep[keep] &= clear[a][pixel[keep]] & clear[b][q[keep]]
        depth = point[keep]
        ratio = (va.projection.depth_mm(depth) / va.focal_px) / (vb.projection.depth_mm(depth) / vb.focal_px)
        differences.append(sign * (vb.graph.half_width_px[q[keep]] - va.graph.half_width_px[pixel[keep]] * ratio))
    return np.concatenate(differences)


def measured_width_bias(views: Sequence[ViewData], settings: MatchSettings = MATCH_SETTINGS,
                        caches: dict | None = None, settled_below: float = 0.0) -> float:
    """How much wider (px, half-width) view 1 shows the vessels than view 0 (two views; module
    notes, 7.): the median of :func:`_width_differences` over the first round's matchings (no
    claims), again with that bias split between the views, until it moves less than 0.05 px
    (``_WIDTH_BIAS_ROUNDS`` at most), or at once where the first round's is less than
    ``settled_below`` in size. 0 where fewer than ``_WIDTH_BIAS_MIN_PAIRS`` pairs count.
    ``caches`` (:func:`match_pixels`'s cache per pair (0, 1), (1, 0)): the first round's matchings
    (the views with no bias) fill them. (The matching without the radius term measured it in one
    go, but paired the wrong vessels where only the radii tell them apart: 1.1 px on exact masks of
    one tree.)"""
    bias = 0.0
    clear = [_clear_pixels(v) for v in views]  # (the graphs' own: the same every round)
    for round_ in range(_WIDTH_BIAS_ROUNDS):
        split = [replace(views[0], width_bias_px=-0.5 * bias), replace(views[1], width_bias_px=0.5 * bias)]
        differences = _width_differences(split, settings, clear, caches if round_ == 0 else None)
        if len(differences) < _WIDTH_BIAS_MIN_PAIRS:
            return 0.0
        measured = float(np.median(differences))
        moved, bias = abs(measured - bias), measured
        if moved < 0.05 or (round_ == 0 and abs(measured) < settled_below):
            break
    return bias


_WIDTH_BIAS_ROUNDS = 8
_WIDTH_BIAS_MIN_PAIRS = 50  # fewer clear pairs measure no bias


def with_width_bias(views: Sequence[ViewData], settings: MatchSettings = MATCH_SETTINGS, caches: dict | None = None
                    ) -> tuple[list[ViewData], float]:
    """The two views with the bias of :func:`measured_width_bias` split between them (half taken off view
    1's half-widths, half added to view 0's, so the radius of a pair, the two views' mean, stays
    what they show), and the bias measured; views unchanged where it is less than
    ``width_bias_min_px``, and unchanged (and 0) without ``width_bias`` or with other than two
    views. ``caches`` (:func:`match_pixels`'s cache per pair (0, 1), (1, 0), empty): filled by
    the measurement's first round for the views returned, so that their first round of matchings
    (no claims) costs nothing again; emptied again where the bias is taken (other views).

    The measurement stops after its first round where that measures less than a quarter of
    ``width_bias_min_px``: the later rounds move it away from 0, towards the bias, but on no case
    measured from there to ``width_bias_min_px``. One view dilated or eroded by 1 px (generated
    left and rca trees 1-8): 0.52-1.04 px in the first round, 0.70-1.13 in the last; by 2 px (trees
    1-8; eroded, left and rca 1-4) or dilated by 3: 0.26-2.7 in the first (left tree 2 eroded by
    2 px the least, -0.26, then -1.76); with none, at most 0.22 (0.23 in the last); the
    benchmark's, at most 0.49 px in the last, are left alone either way.
    """
    views = list(views)
    if len(views) != 2 or not settings.width_bias:
        return views, 0.0
    bias = measured_width_bias(views, settings, caches, settled_below=0.25 * settings.width_bias_min_px)
    taken = bias if abs(bias) >= settings.width_bias_min_px else 0.0
    if taken and caches is not None:
        for cache in caches.values():
            cache.clear()
    return [replace(views[0], width_bias_px=-0.5 * taken), replace(views[1], width_bias_px=0.5 * taken)], bias
