"""Scores of a reconstructed vessel tree against a true one: centerline distances, overlap, clDice,
radius error, branch detection and bifurcations (docs/conventions.md, "Metrics").

Notation
--------
``R`` is the reconstructed tree and ``T`` the true tree, two :class:`~angiohull.tree.VesselTree`
in the same frame, in mm. The *centerline* of a tree is the union of its branch polylines
(``Branch.points_mm``); the connector from a parent point to a child's first point belongs to the
solid (:mod:`angiohull.tree.solid`) but not to the centerline. ``L(X)`` is the total centerline
length of tree ``X`` (the sum of its branch lengths) and ``L_b`` the length of branch ``b``.

Sampling
--------
With ``h = sample_step_mm``, branch ``b`` is sampled at ``n_b + 1`` points evenly spaced in arc
length, ``s_k = k L_b / n_b`` for ``k = 0 .. n_b`` and ``n_b = max(1, ceil(L_b / h))`` (``L_b / h``
within 1e-9 of an integer counts as that integer): the spacing
``h_b = L_b / n_b`` is at most ``h`` and both ends are samples. Positions and radii are
interpolated linearly along the polyline. A sample's weight is the arc length it stands for, the
trapezoidal rule: ``h_b`` inside a branch, ``h_b / 2`` at its two ends; the weights of a tree sum
to ``L(X)``.

Along the centerline, a quantity ``q`` known at the samples (a distance, a radius, a margin) is
extended to every point of a branch by linear interpolation in arc length between consecutive
samples; ``q~`` is that interpolant. Two operations on it are used below, both over arc length:

* the *mean* of ``q`` over ``X`` is ``(integral of q~ ds) / L(X)``, i.e. the weighted sum
  ``sum_i w_i q_i / L(X)``;
* the *length where* ``m <= 0`` for a margin ``m`` is the measure (mm) of the arc length where
  ``m~ <= 0``; on each sample interval the margin is linear, so this is exact per interval.

Both are exact whenever ``q`` is linear in arc length between samples (e.g. the distance of a
straight line to a parallel or collinear one) and converge to their continuous values as ``h``
shrinks (O(h²) for a smooth ``q``).

Distances
---------
``d_XY(x)`` is the exact Euclidean distance of a point ``x`` to the centerline of ``Y``: the minimum
over every segment of ``Y``'s polylines of the point-to-segment distance (computed exactly, to
rounding). ``c_Y(x)`` is the closest point and ``r_Y(c)`` the radius of ``Y`` there, interpolated
linearly along that segment between its end radii; of equally near points (bit for bit), the
first in tree order (lowest branch, then lowest segment) is taken. For the samples of ``T``,
``d_TR`` is their distance to ``R``'s centerline; for those of ``R``, ``d_RT`` their distance to
``T``'s. These are centerline-to-centerline distances: radii play no part in them.

Scores
------
Centerline distances (mm; symmetric):

* ``centerline_mean_true_to_rec_mm``: the mean of ``d_TR`` over ``T``;
  ``centerline_mean_rec_to_true_mm``: the mean of ``d_RT`` over ``R``;
  ``centerline_mean_mm``: the average of the two;
* ``centerline_p95_mm``: the larger of the two directed length-weighted 95th percentiles, the
  percentile of ``d_XY`` over ``X`` being the smallest ``v`` such that the length of ``X`` where
  ``d~_XY <= v`` is at least ``0.95 L(X)``;
* ``centerline_hausdorff_mm``: the largest sample distance either way, ``max(max d_TR, max d_RT)``
  (the maximum of ``d~``; the continuous Hausdorff distance lies within ``h / 2`` of it).

Overlap, for each ``d`` of ``overlap_mm`` (shares in [0, 1]; the key writes ``d`` in mm without its
decimal point: 0.5 -> ``ot05mm``, 1.0 -> ``ot1mm``, 1.5 -> ``ot15mm``):

* ``ot<d>mm``: the length of ``T`` where ``d~_TR <= d``, divided by ``L(T)``;
* ``ot<d>mm_reverse``: the length of ``R`` where ``d~_RT <= d``, divided by ``L(R)``.

clDice, the continuous form of Shit et al. (2021), with ``sd_X`` the signed distance to the solid
of ``X``: the minimum over its capsules (:meth:`VesselTree.capsules
<angiohull.tree.VesselTree.capsules>`, connectors included) of the distance to the capsule's
segment less its radius, as :func:`~angiohull.tree.solid.signed_distance_mm` (``<= 0`` inside,
as :func:`~angiohull.tree.solid.contains`; computed exactly here):

* ``cldice_sensitivity``: the length of ``T`` where ``sd~_R <= 0`` (``T``'s centerline inside
  ``R``'s solid), divided by ``L(T)``;
* ``cldice_precision``: the length of ``R`` where ``sd~_T <= 0``, divided by ``L(R)``;
* ``cldice``: their harmonic mean ``2 S P / (S + P)``, 0 when both are 0.

Radius along matched points (mm): the *matched* part ``M`` of ``T`` is where ``d~_TR <= r~_T``
(the true sample lies within its own radius of ``R``'s centerline). The error at a true sample is
``e = r_R(c_R(x)) - r_T(x)`` (positive: R too wide), interpolated like every other quantity. With ``|M|`` the length of
``M``: ``radius_bias_mm = (integral over M of e~) / |M|``, ``radius_mae_mm = (integral over M of
|e~|) / |M|``, ``radius_rmse_mm = sqrt((integral over M of e~²) / |M|)`` (integrals of the
piecewise-linear ``e~``, exact per interval) and ``radius_matched_share = |M| / L(T)``. The three
errors are nan when ``|M| = 0``.

Branches (counts are ints; a ratio is nan when nothing is counted):

* a true branch is *counted* when ``L_b >= min_branch_mm`` and *found* when the length of the
  branch where ``d~_TR <= r~_T`` is more than ``L_b / 2``; ``branch_recall = branches_found /
  branches_true`` (``branches_true`` = counted);
* a reconstructed branch is counted when ``L_b >= min_branch_mm`` and *true* when the length of
  the branch where ``d~_RT <= r~_T(c_T)`` (the true radius at the closest point of ``T``'s
  centerline) is more than ``L_b / 2``; ``branch_precision`` = true / ``branches_reconstructed``
  (counted).

Bifurcations: the points :attr:`VesselTree.bifurcation_points_mm
<angiohull.tree.VesselTree.bifurcation_points_mm>` of each tree (``bifurcations_true``,
``bifurcations_reconstructed``) are matched one to one (scipy's ``linear_sum_assignment``): the
matching has the largest number of pairs at most ``bifurcation_match_mm`` apart and, among those,
the smallest sum of their distances; farther pairs are not matched. ``bifurcations_matched`` counts
the pairs and ``bifurcation_error_mm`` is their mean distance (nan when none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Sequence

import numpy as np
from scipy.spatial import cKDTree

from .. import _validation as _v
from ..errors import TreeError
from ..tree.model import VesselTree

__all__ = ["TreeScores", "tree_scores", "undefined_scores", "centerline_samples", "distance_to_centerline",
           "overlap_key", "match_bifurcations", "MAX_SAMPLES"]

MAX_SAMPLES = 20_000_000
"""Most centerline samples one tree may get (a larger count asks for a larger step)."""

_PERCENTILE = 0.95
_BISECTIONS = 64  # halvings of the distance range when solving for the percentile (below rounding)
_FIRST_K = 8  # nearest index entries looked at first per point
_PAIR_BUDGET = 2_000_000  # point-segment pairs evaluated at once


# -- argument checks --------------------------------------------------------------------------------

def _check_tree(tree: Any, name: str) -> VesselTree:
    if not isinstance(tree, VesselTree):
        raise TreeError(f"{name} must be a VesselTree, got {type(tree).__name__}")
    return tree


def overlap_key(d_mm: float) -> str:
    """Name of the overlap score at ``d_mm``: ``"ot" + d without its decimal point + "mm"``
    (0.5 -> ``"ot05mm"``, 1.0 -> ``"ot1mm"``, 1.5 -> ``"ot15mm"``)."""
    text = np.format_float_positional(float(d_mm), trim="-")
    return f"ot{text.replace('.', '')}mm"


def _thresholds(overlap_mm: Any) -> tuple[float, ...]:
    if isinstance(overlap_mm, np.ndarray):
        overlap_mm = overlap_mm.ravel().tolist()
    if isinstance(overlap_mm, (int, float, np.integer, np.floating)) and not isinstance(overlap_mm, (bool, np.bool_)):
        items: tuple[Any, ...] = (overlap_mm,)
    elif isinstance(overlap_mm, (str, bytes)):
        raise TreeError(f"overlap_mm must be a sequence of distances in mm, got {overlap_mm!r}")
    else:
        try:
            items = tuple(overlap_mm)
        except TypeError:
            raise TreeError(f"overlap_mm must be a sequence of distances in mm, got {type(overlap_mm).__name__}") from None
    if not items:
        raise TreeError("overlap_mm must hold at least one distance in mm, got an empty sequence")
    values = tuple(_v.positive_finite(x, f"overlap_mm[{i}]", error=TreeError) for i, x in enumerate(items))
    keys = [overlap_key(x) for x in values]
    if len(set(keys)) != len(keys):
        raise TreeError(f"overlap_mm gives clashing score names {keys} for {list(values)}; give each distance once "
                        f"(1.5 and 15 both read 'ot15mm')")
    return values


def _non_negative(value: Any, name: str) -> float:
    number = _v.finite(value, name, error=TreeError)
    if number < 0:
        raise TreeError(f"{name} must be >= 0 mm, got {value!r}")
    return number


# -- sampling ---------------------------------------------------------------------------------------

class _Samples(NamedTuple):
    points: np.ndarray  # (N, 3) mm
    weights: np.ndarray  # (N,) mm of arc length each stands for
    radius: np.ndarray  # (N,) mm
    branch: np.ndarray  # (N,) int64
    start: np.ndarray  # (I,) index of each interval's first sample (the second is start + 1)
    step: np.ndarray  # (I,) arc length of each interval, mm
    lengths: np.ndarray  # (B,) branch lengths, mm


def _sample(tree: VesselTree, step_mm: float) -> _Samples:
    branches = tree.branches
    lengths = np.array([b.length_mm for b in branches])
    counts = np.array([b.n_points for b in branches])
    n = np.maximum(1, np.ceil(lengths / step_mm - 1e-9)).astype(np.int64)
    total = int((n + 1).sum())
    if total > MAX_SAMPLES:
        raise TreeError(f"sample_step_mm = {step_mm!r} gives {total:,} samples for a {lengths.sum():.1f} mm tree "
                        f"(at most {MAX_SAMPLES:,}); use a larger step")
    vertices = np.concatenate([b.points_mm for b in branches])
    radii = np.concatenate([b.radius_mm for b in branches])
    first_vertex = np.concatenate([[0], np.cumsum(counts)[:-1]])
    last_vertex = first_vertex + counts - 1
    seg = np.sqrt(np.einsum("ij,ij->i", np.diff(vertices, axis=0), np.diff(vertices, axis=0)))
    seg[last_vertex[:-1]] = 0.0  # the step from one branch's last point to the next branch's first
    cum = np.concatenate([[0.0], np.cumsum(seg)])  # global arc at each vertex (flat across branch joins)

    branch = np.repeat(np.arange(len(branches), dtype=np.int64), n + 1)
    first_sample = np.concatenate([[0], np.cumsum(n + 1)[:-1]])
    k = np.arange(total) - first_sample[branch]
    s = lengths[branch] * k / n[branch]  # arc length of each sample in its branch
    base = cum[first_vertex][branch]
    v = np.searchsorted(cum, base + s, side="right") - 1
    v = np.clip(v, first_vertex[branch], last_vertex[branch] - 1)
    t = np.clip((s - (cum[v] - base)) / seg[v], 0.0, 1.0)  # in-branch segments have length > 0
    t[k == 0] = 0.0
    t[k == n[branch]] = 1.0
    v[k == 0] = first_vertex[branch[k == 0]]
    v[k == n[branch]] = last_vertex[branch[k == n[branch]]] - 1
    points = (1.0 - t)[:, None] * vertices[v] + t[:, None] * vertices[v + 1]
    radius = (1.0 - t) * radii[v] + t * radii[v + 1]

    h = lengths / n
    inner = np.ones(total, dtype=bool)
    inner[first_sample + n] = False  # a branch's last sample starts no interval
    start = np.flatnonzero(inner)
    step = h[branch[start]]
    weights = np.zeros(total)
    weights[start] += 0.5 * step
    weights[start + 1] += 0.5 * step
    return _Samples(points, weights, radius, branch, start, step, lengths)


def centerline_samples(tree: VesselTree, step_mm: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tree's centerline sampled evenly in arc length (module notes, "Sampling").

    Parameters
    ----------
    tree : VesselTree
    step_mm : float
        Largest spacing of the samples along a branch, mm (> 0); each branch gets
        ``ceil(L_b / step_mm)`` equal intervals, both its ends included.

    Returns
    -------
    points_mm : (N, 3) array
        Sample positions, mm, branch after branch, each from its proximal end.
    weights_mm : (N,) array
        Arc length each sample stands for (trapezoidal rule), mm; they sum to ``tree.length_mm``.
    radius_mm : (N,) array
        Radius at each sample (interpolated linearly along the polyline), mm.
    branch : (N,) int64 array
        Index of the branch each sample lies on.

    Raises
    ------
    TreeError
        If ``tree`` is not a VesselTree, ``step_mm`` is not a positive finite number, or the step
        would give more than :data:`MAX_SAMPLES` samples.
    """
    _check_tree(tree, "tree")
    step = _v.positive_finite(step_mm, "step_mm", error=TreeError)
    samples = _sample(tree, step)
    return samples.points, samples.weights, samples.radius, samples.branch


# -- exact distance to a centerline ----------------------------------------------------------------

class _SegmentIndex:
    """Segments ``[a_i, b_i]`` with end radii, cut into pieces of bounded length and indexed by
    their midpoints, for the exact minimum over segments of ``|x - c_i(x)| - offset_i``
    (``c_i(x)`` the point of segment ``i`` nearest to ``x``; offset 0: the distance to the
    polylines; offset the capsule radius: the signed distance to a union of capsules).

    A point's value on a piece is at least its distance to the piece's midpoint less half the
    longest piece and the largest offset; once the k-th nearest midpoint is that far beyond the
    best exact value among the k nearest pieces, no other piece can do better, and the answer is
    exact.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, ra: np.ndarray, rb: np.ndarray, owner: np.ndarray,
                 offset: np.ndarray | None = None):
        length = np.sqrt(np.einsum("ij,ij->i", b - a, b - a))
        # pieces of at most twice the median segment (and few enough in all): tight midpoint bounds
        cap = max(2.0 * float(np.median(length)), float(length.sum()) / 100_000)
        pieces = np.maximum(1, np.ceil(length / cap - 1e-9)).astype(np.int64)
        seg = np.repeat(np.arange(len(a)), pieces)
        j = np.arange(len(seg)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        t0 = (j / pieces[seg])[:, None]
        t1 = ((j + 1) / pieces[seg])[:, None]
        self.a = (1.0 - t0) * a[seg] + t0 * b[seg]
        end = (1.0 - t1) * a[seg] + t1 * b[seg]
        self.ab = end - self.a
        self.length_sq = np.einsum("ij,ij->i", self.ab, self.ab)
        self.ra = (1.0 - t0[:, 0]) * ra[seg] + t0[:, 0] * rb[seg]
        self.dr = (1.0 - t1[:, 0]) * ra[seg] + t1[:, 0] * rb[seg] - self.ra
        self.owner = owner[seg]
        self.offset = None if offset is None else offset[seg]
        self.slack = 0.5 * float(np.sqrt(self.length_sq.max())) + (0.0 if offset is None else float(offset.max()))
        self.index = cKDTree(self.a + 0.5 * self.ab)
        self.size = len(seg)

    @classmethod
    def centerline(cls, tree: VesselTree) -> "_SegmentIndex":
        """Every segment of the tree's branch polylines (connectors not included)."""
        branches = tree.branches
        return cls(np.concatenate([b.points_mm[:-1] for b in branches]),
                   np.concatenate([b.points_mm[1:] for b in branches]),
                   np.concatenate([b.radius_mm[:-1] for b in branches]),
                   np.concatenate([b.radius_mm[1:] for b in branches]),
                   np.concatenate([np.full(b.n_points - 1, i, dtype=np.int64) for i, b in enumerate(branches)]))

    @classmethod
    def solid(cls, tree: VesselTree) -> "_SegmentIndex":
        """The tree's capsules (:meth:`VesselTree.capsules`): values are signed distances to the solid."""
        a, b, radius, owner = tree.capsules()
        return cls(a, b, radius, radius, owner, offset=radius)

    def _exact(self, x: np.ndarray, nearest: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Best of the candidate pieces ``nearest`` (m, k) for points ``x`` (m, 3): value, piece, t."""
        a = self.a[nearest]
        ab = self.ab[nearest]
        t = np.einsum("mkj,mkj->mk", x[:, None, :] - a, ab) / self.length_sq[nearest]
        np.clip(t, 0.0, 1.0, out=t)
        gap = x[:, None, :] - a - t[..., None] * ab
        value = np.sqrt(np.einsum("mkj,mkj->mk", gap, gap))
        if self.offset is not None:
            value -= self.offset[nearest]
        best = np.argmin(value, axis=1)
        rows = np.arange(len(x))
        return value[rows, best], nearest[rows, best], t[rows, best]

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(value (N,), closest point (N, 3), radius there (N,), owner (N,))`` for points (N, 3)."""
        n = len(points)
        value = np.empty(n)
        piece = np.empty(n, dtype=np.int64)
        t = np.empty(n)
        todo = np.arange(n)
        k = min(_FIRST_K, self.size)
        while len(todo):
            chunk = max(1, _PAIR_BUDGET // k)
            left = []
            for lo in range(0, len(todo), chunk):
                rows = todo[lo:lo + chunk]
                centre, nearest = self.index.query(points[rows], k=k)
                centre = centre.reshape(len(rows), k)
                nearest = nearest.reshape(len(rows), k)
                # an unseen piece scores at least (k-th midpoint distance - slack)
                bound = centre[:, -1] - self.slack * (1.0 + 1e-12) - 1e-12
                # candidates in piece order: of equal values, the first in tree order wins
                v, p, u = self._exact(points[rows], np.sort(nearest, axis=1))
                value[rows], piece[rows], t[rows] = v, p, u
                left.append(rows[bound < v])
            if k == self.size:
                break
            todo = np.concatenate(left)
            k = min(4 * k, self.size)
        closest = self.a[piece] + t[:, None] * self.ab[piece]
        radius = self.ra[piece] + t * self.dr[piece]
        return value, closest, radius, self.owner[piece]


def distance_to_centerline(points: np.ndarray, tree: VesselTree) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact distance of points to a tree's centerline (every branch polyline; connectors excluded).

    Parameters
    ----------
    points : (N, 3) array_like
        Query points, mm.
    tree : VesselTree

    Returns
    -------
    distance_mm : (N,) array
        Euclidean distance to the nearest point of any segment of the tree's branch polylines, mm.
    closest_mm : (N, 3) array
        That nearest point, mm.
    radius_mm : (N,) array
        The tree's radius there: linear along the segment between its end radii, mm.
    branch : (N,) int64 array
        The branch that holds the nearest point (of equally near points, bit for bit, the first in
        tree order: the lowest branch, then the lowest segment).

    Raises
    ------
    TreeError
        If ``tree`` is not a VesselTree or ``points`` is not a finite (N, 3) array.
    """
    _check_tree(tree, "tree")
    x = _v.points_array(points, "points", error=TreeError)
    if len(x) == 0:
        return np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64)
    return _SegmentIndex.centerline(tree).query(x)


# -- integrals of piecewise-linear functions over the samples --------------------------------------

def _inside(margin: np.ndarray, samples: _Samples) -> tuple[np.ndarray, np.ndarray]:
    """Per interval, the part ``[ta, tb]`` of ``[0, 1]`` where the interpolated margin is <= 0
    (``tb <= ta`` where there is none)."""
    m0 = margin[samples.start]
    m1 = margin[samples.start + 1]
    in0, in1 = m0 <= 0, m1 <= 0
    crossing = np.clip(m0 / np.where(in0 != in1, m0 - m1, 1.0), 0.0, 1.0)
    ta = np.where(in0, 0.0, np.where(in1, crossing, 1.0))
    tb = np.where(in1, 1.0, np.where(in0, crossing, 0.0))
    return ta, tb


def _inside_length(margin: np.ndarray, samples: _Samples) -> np.ndarray:
    """Per interval, the arc length where the interpolated margin is <= 0, mm."""
    ta, tb = _inside(margin, samples)
    return samples.step * np.maximum(tb - ta, 0.0)


def _per_branch(values: np.ndarray, samples: _Samples) -> np.ndarray:
    return np.bincount(samples.branch[samples.start], weights=values, minlength=len(samples.lengths))


def _length_percentile(distance: np.ndarray, samples: _Samples, q: float) -> float:
    """Smallest v with (length where the interpolated distance <= v) >= q * total length."""
    d0 = distance[samples.start]
    d1 = distance[samples.start + 1]
    low, high = np.minimum(d0, d1), np.maximum(d0, d1)
    span = high - low
    flat = span <= 0
    inverse = 1.0 / np.where(flat, 1.0, span)
    h = samples.step
    target = q * h.sum()

    def below(v: float) -> float:
        share = np.where(flat, (low <= v).astype(np.float64), np.clip((v - low) * inverse, 0.0, 1.0))
        return float(h @ share)

    lo, hi = float(distance.min()), float(distance.max())
    if below(lo) >= target:
        return lo
    for _ in range(_BISECTIONS):
        middle = 0.5 * (lo + hi)
        if middle <= lo or middle >= hi:
            break
        if below(middle) >= target:
            hi = middle
        else:
            lo = middle
    return hi


# -- scores -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TreeScores:
    """Scores of a reconstructed tree against the true one (module notes for the definitions).

    Distances in mm, shares in [0, 1], counts as ints; nan where a score is undefined.
    :meth:`as_dict` flattens the overlaps into one key per distance (``ot05mm``, ``ot1mm_reverse``).
    """

    centerline_mean_mm: float  # (mean d_TR + mean d_RT) / 2
    centerline_mean_true_to_rec_mm: float  # length-weighted mean distance of T's centerline to R's
    centerline_mean_rec_to_true_mm: float  # length-weighted mean distance of R's centerline to T's
    centerline_p95_mm: float  # larger of the two directed length-weighted 95th percentiles
    centerline_hausdorff_mm: float  # largest sample distance either way
    overlap_mm: tuple[float, ...]  # the overlap distances d, mm
    overlap: tuple[float, ...]  # per d: share of T's length within d of R's centerline
    overlap_reverse: tuple[float, ...]  # per d: share of R's length within d of T's centerline
    cldice_sensitivity: float  # share of T's length inside R's solid
    cldice_precision: float  # share of R's length inside T's solid
    cldice: float  # harmonic mean of the two (0 when both are 0)
    radius_mae_mm: float  # mean |r_R - r_T| over the matched part of T
    radius_rmse_mm: float  # root mean square of r_R - r_T over the matched part
    radius_bias_mm: float  # mean of r_R - r_T over the matched part
    radius_matched_share: float  # share of T's length within its own radius of R's centerline
    branch_recall: float  # branches_found / branches_true
    branches_true: int  # true branches at least min_branch_mm long
    branches_found: int  # of those, more than half their length within their radius of R
    branch_precision: float  # share of the counted reconstructed branches that are true
    branches_reconstructed: int  # reconstructed branches at least min_branch_mm long
    bifurcations_true: int
    bifurcations_reconstructed: int
    bifurcations_matched: int
    bifurcation_error_mm: float  # mean distance of the matched bifurcation pairs

    def as_dict(self) -> dict[str, float | int]:
        """Every score under a flat key (floats, ints for counts), overlaps as ``ot<d>mm`` and
        ``ot<d>mm_reverse``."""
        out: dict[str, float | int] = {
            "centerline_mean_mm": float(self.centerline_mean_mm),
            "centerline_mean_true_to_rec_mm": float(self.centerline_mean_true_to_rec_mm),
            "centerline_mean_rec_to_true_mm": float(self.centerline_mean_rec_to_true_mm),
            "centerline_p95_mm": float(self.centerline_p95_mm),
            "centerline_hausdorff_mm": float(self.centerline_hausdorff_mm),
        }
        for d, share in zip(self.overlap_mm, self.overlap):
            out[overlap_key(d)] = float(share)
        for d, share in zip(self.overlap_mm, self.overlap_reverse):
            out[overlap_key(d) + "_reverse"] = float(share)
        out.update({
            "cldice_sensitivity": float(self.cldice_sensitivity),
            "cldice_precision": float(self.cldice_precision),
            "cldice": float(self.cldice),
            "radius_mae_mm": float(self.radius_mae_mm),
            "radius_rmse_mm": float(self.radius_rmse_mm),
            "radius_bias_mm": float(self.radius_bias_mm),
            "radius_matched_share": float(self.radius_matched_share),
            "branch_recall": float(self.branch_recall),
            "branches_true": int(self.branches_true),
            "branches_found": int(self.branches_found),
            "branch_precision": float(self.branch_precision),
            "branches_reconstructed": int(self.branches_reconstructed),
            "bifurcations_true": int(self.bifurcations_true),
            "bifurcations_reconstructed": int(self.bifurcations_reconstructed),
            "bifurcations_matched": int(self.bifurcations_matched),
            "bifurcation_error_mm": float(self.bifurcation_error_mm),
        })
        return out


def undefined_scores(truth: VesselTree, *, overlap_mm: Sequence[float] = (0.5, 1.0, 2.0),
                     min_branch_mm: float = 10.0) -> dict[str, float | int]:
    """The keys of :meth:`TreeScores.as_dict` for a reconstruction that has no tree: the counts of
    the true tree (``branches_true``, ``bifurcations_true``), 0 for the other counts, nan for every
    score."""
    _check_tree(truth, "truth")
    out: dict[str, float | int] = {}
    for field_name in ("centerline_mean_mm", "centerline_mean_true_to_rec_mm", "centerline_mean_rec_to_true_mm",
                       "centerline_p95_mm", "centerline_hausdorff_mm"):
        out[field_name] = math.nan
    thresholds = _thresholds(overlap_mm)
    out.update({overlap_key(d): math.nan for d in thresholds})
    out.update({overlap_key(d) + "_reverse": math.nan for d in thresholds})
    out.update({key: math.nan for key in ("cldice_sensitivity", "cldice_precision", "cldice", "radius_mae_mm",
                                          "radius_rmse_mm", "radius_bias_mm", "radius_matched_share",
                                          "branch_recall")})
    out.update({"branches_true": int(sum(b.length_mm >= min_branch_mm for b in truth.branches)), "branches_found": 0,
                "branch_precision": math.nan, "branches_reconstructed": 0,
                "bifurcations_true": len(truth.bifurcations), "bifurcations_reconstructed": 0,
                "bifurcations_matched": 0, "bifurcation_error_mm": math.nan})
    return out


def _radius_errors(margin: np.ndarray, error: np.ndarray, samples: _Samples) -> tuple[float, float, float, float]:
    """Matched length and the integrals of e, |e| and e² over it (e linear per interval)."""
    ta, tb = _inside(margin, samples)
    length = samples.step * np.maximum(tb - ta, 0.0)
    e0 = error[samples.start]
    de = error[samples.start + 1] - e0
    ea, eb = e0 + ta * de, e0 + tb * de
    mean = 0.5 * (ea + eb)
    square = (ea * ea + ea * eb + eb * eb) / 3.0
    size = np.abs(ea) + np.abs(eb)
    # |e| over a part where e changes sign: two triangles, (ea² + eb²) / (2 (|ea| + |eb|))
    absolute = np.where(ea * eb >= 0, 0.5 * size, (ea * ea + eb * eb) / (2.0 * np.where(size > 0, size, 1.0)))
    return (float(length.sum()), float(length @ mean), float(length @ absolute), float(length @ square))


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 else math.nan


def match_bifurcations(true_points: np.ndarray, rec_points: np.ndarray, limit: float) -> tuple[int, float]:
    """``(pairs, mean distance of the pairs or nan)`` of the one-to-one matching of two point sets
    (mm) used for the bifurcations (module notes): the most pairs at most ``limit`` apart, then the
    smallest sum of their distances."""
    true_points = np.asarray(true_points, dtype=np.float64).reshape(-1, 3)
    rec_points = np.asarray(rec_points, dtype=np.float64).reshape(-1, 3)
    if len(true_points) == 0 or len(rec_points) == 0:
        return 0, math.nan
    distance = np.sqrt(((true_points[:, None, :] - rec_points[None, :, :]) ** 2).sum(axis=2))
    # a pair beyond the limit costs more than any set of pairs within it: the fewest such pairs first
    far = limit * (min(distance.shape) + 1) + 1.0
    from scipy.optimize import linear_sum_assignment  # only here: scipy.optimize is slow to import

    rows, cols = linear_sum_assignment(np.where(distance <= limit, distance, far))
    chosen = distance[rows, cols]
    chosen = chosen[chosen <= limit]
    return int(len(chosen)), (float(chosen.mean()) if len(chosen) else math.nan)


def tree_scores(reconstructed: VesselTree, truth: VesselTree, *, sample_step_mm: float = 0.1,
                overlap_mm: Sequence[float] = (0.5, 1.0, 2.0), min_branch_mm: float = 10.0,
                bifurcation_match_mm: float = 5.0) -> TreeScores:
    """Centerline, overlap, clDice, radius, branch and bifurcation scores of ``reconstructed``
    against ``truth`` (definitions in the module notes).

    Parameters
    ----------
    reconstructed : VesselTree
        The tree to score (R), mm.
    truth : VesselTree
        The true tree (T), mm, same frame.
    sample_step_mm : float, keyword-only
        Largest spacing of the centerline samples, mm (> 0).
    overlap_mm : sequence of float, keyword-only
        Distances d of the overlap scores ``ot<d>mm`` / ``ot<d>mm_reverse``, mm (each > 0, at
        least one; a single number is one distance).
    min_branch_mm : float, keyword-only
        Shortest branch the branch scores count, mm (>= 0).
    bifurcation_match_mm : float, keyword-only
        Farthest a true and a reconstructed bifurcation may be to be matched, mm (> 0).

    Returns
    -------
    TreeScores

    Raises
    ------
    TreeError
        If a tree is not a VesselTree or an option is out of range (each message names it).
    """
    _check_tree(reconstructed, "reconstructed")
    _check_tree(truth, "truth")
    step = _v.positive_finite(sample_step_mm, "sample_step_mm", error=TreeError)
    thresholds = _thresholds(overlap_mm)
    min_branch = _non_negative(min_branch_mm, "min_branch_mm")
    match = _v.positive_finite(bifurcation_match_mm, "bifurcation_match_mm", error=TreeError)

    ts = _sample(truth, step)
    rs = _sample(reconstructed, step)
    t_length, r_length = float(ts.step.sum()), float(rs.step.sum())
    d_tr, _, r_rec_at, _ = _SegmentIndex.centerline(reconstructed).query(ts.points)
    d_rt, _, r_true_at, _ = _SegmentIndex.centerline(truth).query(rs.points)

    mean_tr = float(ts.weights @ d_tr) / t_length
    mean_rt = float(rs.weights @ d_rt) / r_length
    p95 = max(_length_percentile(d_tr, ts, _PERCENTILE), _length_percentile(d_rt, rs, _PERCENTILE))
    hausdorff = max(float(d_tr.max()), float(d_rt.max()))
    overlap = tuple(float(_inside_length(d_tr - d, ts).sum()) / t_length for d in thresholds)
    overlap_reverse = tuple(float(_inside_length(d_rt - d, rs).sum()) / r_length for d in thresholds)

    # the signed distance of angiohull.tree.solid.signed_distance_mm (the same minimum over capsules)
    sd_t = _SegmentIndex.solid(reconstructed).query(ts.points)[0]
    sd_r = _SegmentIndex.solid(truth).query(rs.points)[0]
    sensitivity = float(_inside_length(sd_t, ts).sum()) / t_length
    precision = float(_inside_length(sd_r, rs).sum()) / r_length
    total = sensitivity + precision
    cldice = 2.0 * sensitivity * precision / total if total > 0 else 0.0

    margin_t = d_tr - ts.radius
    matched, e_sum, e_abs, e_sq = _radius_errors(margin_t, r_rec_at - ts.radius, ts)
    if matched > 0:
        bias, mae, rmse = e_sum / matched, e_abs / matched, math.sqrt(max(e_sq, 0.0) / matched)
    else:
        bias = mae = rmse = math.nan

    found_length = _per_branch(_inside_length(margin_t, ts), ts)
    counted_t = ts.lengths >= min_branch
    found = counted_t & (found_length > 0.5 * ts.lengths)
    true_length = _per_branch(_inside_length(d_rt - r_true_at, rs), rs)
    counted_r = rs.lengths >= min_branch
    good = counted_r & (true_length > 0.5 * rs.lengths)
    n_true, n_found = int(counted_t.sum()), int(found.sum())
    n_rec, n_good = int(counted_r.sum()), int(good.sum())

    true_bif = truth.bifurcation_points_mm
    rec_bif = reconstructed.bifurcation_points_mm
    n_matched, bif_error = match_bifurcations(true_bif, rec_bif, match)

    return TreeScores(
        centerline_mean_mm=0.5 * (mean_tr + mean_rt),
        centerline_mean_true_to_rec_mm=mean_tr,
        centerline_mean_rec_to_true_mm=mean_rt,
        centerline_p95_mm=p95,
        centerline_hausdorff_mm=hausdorff,
        overlap_mm=thresholds,
        overlap=overlap,
        overlap_reverse=overlap_reverse,
        cldice_sensitivity=sensitivity,
        cldice_precision=precision,
        cldice=cldice,
        radius_mae_mm=mae,
        radius_rmse_mm=rmse,
        radius_bias_mm=bias,
        radius_matched_share=matched / t_length,
        branch_recall=_ratio(n_found, n_true),
        branches_true=n_true,
        branches_found=n_found,
        branch_precision=_ratio(n_good, n_rec),
        branches_reconstructed=n_rec,
        bifurcations_true=int(len(true_bif)),
        bifurcations_reconstructed=int(len(rec_bif)),
        bifurcations_matched=n_matched,
        bifurcation_error_mm=bif_error,
    )
