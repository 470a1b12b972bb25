"""The ``tree`` method: the vessel tree from centerline correspondences across the views, with tubes
fitted to the masks (beyond the paper; docs/tree-method.md).

A visual hull of two views holds phantom volume wherever the cones of two vessels cross; the
views' 2D centerlines and widths say where the vessels are. Steps:

1. **2D centerline graphs** (:mod:`.graph2d`): each mask is thinned, its skeleton traced into
   chains between ends and junctions, thinning spurs removed, a half-width per pixel.
2. **Correspondence** (:mod:`.matching`): each view's skeleton pixels are matched into a partner
   view (with two views, each into the other; with more, each into the view most nearly
   perpendicular to it, every candidate checked against the remaining views' masks and
   skeletons): candidates where the epipolar line crosses the partner's mask core (its pixels at
   least ``core_fraction`` of the local half-width deep), costs for the radius
   the two views show at that depth, 3D continuity and turns onto crossing vessels, minimised
   exactly over the pixel graph. Then ``claim_rounds`` more rounds, in which a candidate whose
   partner pixel the reverse matching placed elsewhere costs more. With two views, a per-view bias in the
   widths (one view's edges drawn farther out) is measured on the matchings and taken off where
   the radii compare (:func:`.matching.with_width_bias`).
3. **Tubes**: each matched pixel, with the radius both views show, is a ball, joined by a tube
   to its matched neighbour; their lattice points form a volume.
4. **Tree and fit** (its rules in :mod:`.pruning`): that volume's vessel tree (:func:`..vessel_tree.hull_tree`: skeleton, graph,
   pieces joined through the visual hull, largest first for the tubes of two views'
   correspondences (``correspondence_join_order``: the parts include phantom pieces, and a true
   part bridged onto a nearby phantom goes with it when the phantom is pruned), then centres and radii fitted to every view's mask,
   ends moved to the masks' ends). A branch whose subtree (it and its descendants) the rest of
   the tree covers (projected tubes overlapping by half a radius) over ``explained_share`` of its
   points in every view is removed with its descendants, one subtree at a time, the most covered
   first: they add nothing any view shows (a phantom where two vessels' cones cross, and the
   phantom branches it carries), while a subtree with pixels nothing else explains in some view
   stays. Then a subtree that the views' own matchings do not reproduce goes too, when the rest
   covers at least ``unreproduced_explained`` of it in every view: a tree point is *reproduced*
   unless, in some view, the skeleton pixel under it was matched by that view's own matching to a
   3D point more than ``reproduced_mm`` away (a vessel of A matched to the wrong vessel of B gives
   points that B's own matching puts elsewhere); a subtree less than ``reproduced_share``
   reproduced goes, the least reproduced first. What covered a removed subtree may have gone
   after it (a phantom that made a true branch look explained, taken by the second rule): a
   removed branch whose parent stays comes back when the kept tree covers its subtree less than
   its rule asked (``restore_uncovered``, :func:`restore_uncovered_branches`; the least covered
   first, its children candidates in turn). Last, the stretches inside branches: runs of at
   least ``stretch_min_mm`` of points that the matchings contradict and that tree points
   farther than ``stretch_apart_mm`` cover in every view are taken out of the tubes, and the
   tree is fitted and pruned again from the rest (pieces joined through the hull), and with them
   every branch that carries others whose own points are reproduced less than ``reproduced_share``
   and covered by reproduced points of the other branches at least ``unreproduced_explained`` in
   every view (a phantom that a true branch it carries keeps reproduced enough as a subtree);
   this ``stretch_rounds`` times at most, each round on the tree the last one rebuilt, while
   something goes (3 by default: each round costs a tree build, the support hull's graph built
   once for all; 3 rounds gain 0.2-1.1 Dice3D points over one on two views, docs/tree-method.md).
   Then, with two views, the skeleton pixels of each view that no tree point explains (its
   projected disc, plus a pixel, does not hold them) are matched into the other view again, the
   explained ones pinned to the tree points that explain them (:func:`.matching.anchored_match`:
   the partner's distance to the other view's skeleton free, the other view showing the vessel
   wider free; a match kept where matched neighbours join it to a pinned pixel), and the tree is
   built again from its own tubes and the new ones (``rematch_rounds`` times at most, while at
   least ``rematch_min_pixels`` of a view's pixels join): where one view shows a vessel alone and
   the other shows it merged with another (an end folded back along its parent, two vessels side
   by side), the first matching's radius term sent it to a wrong vessel, a phantom the prunings
   took, and its pixels were left with nothing. Free too are the pixels that only branches the
   other view finds redundant explain (:func:`redundant_branches`: their own points covered there
   by the rest at least ``rematch_redundant_share``, in this view less than ``explained_share``:
   a phantom standing in for a vessel this view shows alone); such a branch leaves the rebuild's
   tubes when at least ``rematch_replace_share`` of its freed pixels join elsewhere, and stays,
   its pixels' new matches dropped, when not.
   The builds of these rounds fit their trees once; the final tree is then fitted once more
   (:func:`..vessel_tree.refit_tree`, ``TreeSettings.fit_passes``; the pass in every round's
   build instead moved the rounds' choices more than it gained, docs/tree-method.md), where a
   view that cannot measure a point keeps its disc inside the run it found
   (``TreeSettings.bound_unmeasured``).
   **With two views, one tree per matching** (``alternative_claim_costs``): steps 2-4 run again with
   each alternative claim cost (the first round of matchings, which no claim enters, shared), and of
   the final trees the one judged best (below) is kept: the one whose tubes' silhouettes agree best
   with the masks (mean Dice over the views, :mod:`.agreement`), less a penalty for length; a
   matching that gives the same volume and own matchings as an earlier one is not built again. A
   wrong pairing (a vessel of one view with the wrong vessel of the other) is consistent with both
   silhouettes only until its tree has been pruned and fitted: then it leaves mask pixels to nothing
   or draws tubes outside the masks, and the larger claim cost, under which the reverse matching's
   disagreement weighs more, often pairs that vessel right. Judging the first trees instead of the
   final ones kept little of the gain (docs/tree-method.md). **The judge** is the agreement less a
   penalty for length: ``length_weight`` times the tree's length plus ``redundant_weight`` times the
   length of its branches only one view needs (:func:`redundant_branches`, both directions: their
   own points the rest covers in one view at least ``rematch_redundant_share``, in the other less
   than ``explained_share``), over the mean length of the matchings' own trees. Of trees that
   explain the masks alike, the one with a wrong pairing is most often the longer, and it often
   carries a branch that hides under another in one view while it explains the other view's pixels
   of a vessel it is not: among candidates agreeing within 0.01 of each other and the best, the
   shorter tree was the nearer to the truth in 85 % of the pairs more than 1 mm apart, the better
   agreement in 64 % (docs/tree-method.md). On Linux with two CPUs or more and no other Python
   thread (``fork_alternatives``, :func:`.forking._can_fork`), the alternative matchings' trees are
   built in forked children while this process builds the first, a process per tree up to twice
   the CPUs (:func:`.forking._in_processes`; the same trees: a child runs the same code on the
   same arrays and sends its trees back pickled; if it fails they are built here).
   No Python thread is running, so none holds a lock the child would need; the BLAS library's own
   threads are fork-safe (multiprocessing's fork start method relies on it too).
   **Hypotheses of a wrong pairing** (two views, ``hypotheses``): a tree that agrees less than
   ``hypothesis_gate`` with the masks is built again ``hypotheses`` times, each time with one of
   its pieces taken for a wrong pairing: the matchings run again (every round, and the rematch of
   unexplained pixels) with the candidates within that piece's radius (at least 0.5 mm) plus
   ``avoid_margin_mm`` of its axis costing ``avoid_cost`` more (:class:`.matching.Avoid`), so its
   pixels pair with something else or nothing. The pieces tried are those touching the most
   unexplained mask pixels (:func:`.agreement.suspect_pieces`), of the side branches and the
   root's windows ``root_window_mm`` long (half overlapping): where a long vessel of one view was
   paired with a shorter wrong one of the other (a foreshortened true partner, the distal RCA
   against the acute marginal), the rest of the shorter vessel's own view is left beside it
   unexplained, beside a side branch or, where the root itself was paired so, beside a stretch of
   the root (since 2026-12-07; docs/tree-method.md). A hypothesis's tree is kept where it is judged
   best of all and by at least ``hypothesis_margin`` more than the best of the matchings' own trees
   (many hypotheses, each a little different, would otherwise win by noise: on the segmented
   angiograms of the benchmark, every hypothesis of every tree tried and the best kept put the
   centerline 0.590 mm off against 0.575 without any). The hypotheses of every matching's tree are
   built after those trees, each in a process of its own (as the alternative matchings' trees).
   **Last, with two views, the kept tree slid along the rays** (``slide``, :mod:`.sliding`): a
   point moved along view A's ray through it stays where A sees it, and moves in view B along
   B's epipolar line. Where B's mask holds a piece of at least ``SlideSettings.min_pixels`` pixels
   that the tree's tubes leave unexplained and one branch alone comes near it, the run of that
   branch's points by the piece (junctions excepted) is moved along A's rays by the offsets, linear
   between knots 2 mm apart, that best explain B's mask (its pixels covered less the tubes'
   pixels outside it, less ``length_px_per_mm`` per mm the run grows), kept where that gains at
   least ``min_gain`` of the piece's pixels. The case: a vessel one view shows folded on itself,
   its two arms merged into one band; that view's skeleton cuts across the fold inside its tip,
   so the matching pairs the other view's clean band with the cut, and the tree, right in the
   other view, lies at the wrong depth along its rays and leaves the fold's tip unexplained.
5. **Lumen points**: the lattice points inside the fitted tree's tubes.

Arrays and projections in, points and a tree out; nothing here reads files.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from itertools import combinations
from typing import Callable, Sequence

import numpy as np
from scipy import ndimage as ndi

from ...errors import ReconstructionError
from ...geometry import Projection, degrees_from_one_line
from ...tree import VesselTree
from ..cube import Lattice
from ..vessel_tree import TREE_SETTINGS, SupportBridge, TreeBuild, TreeSettings, hull_tree, refit_tree
from .graph2d import CenterlineGraph2D, centerline_graph
from .agreement import Suspect, mask_agreement, suspect_pieces, tube_silhouette
from .matching import (MATCH_SETTINGS, Avoid, MatchSettings, ViewData, anchored_match, mask_core, match_pixels,
                       with_width_bias)
from .sliding import SLIDE_SETTINGS, SlideSettings, slid_along_rays
from .forking import _can_fork, _ForkedBuilds, _in_processes  # noqa: F401 (the tests reach them here)
from .tubes import lattice_points_in_tubes
# step 4's rules (the tests reach the private ones here too)
from .pruning import (_DiscPairs, _explained_pruning, _holding, _kept, _nearest_discs, _tube_segments,  # noqa: F401
                      _unreproduced_pruning, _window_medians, _without, contradicted_stretches, covered_points,
                      explained_shares, explaining_points, prune_explained_branches, prune_unreproduced_branches,
                      redundant_branches, reproduced_points, restore_uncovered_branches, tree_disc_pairs,
                      tree_lumen_points, unreproduced_inner_branches, without_radius_spikes)

__all__ = ["ModelSettings", "MODEL_SETTINGS", "ModelBuild", "model_tree", "centerline_graph", "CenterlineGraph2D",
           "MatchSettings", "lattice_points_in_tubes", "explained_shares", "prune_explained_branches",
           "reproduced_points", "prune_unreproduced_branches", "unreproduced_inner_branches", "covered_points",
           "contradicted_stretches", "restore_uncovered_branches", "mask_agreement", "Suspect", "suspect_pieces",
           "tube_silhouette"]


@dataclass(frozen=True)
class ModelSettings:
    """Parameters of the ``tree`` method (module notes); the same for every case."""

    match: MatchSettings = field(default_factory=lambda: MATCH_SETTINGS)
    tree: TreeSettings = field(default_factory=lambda: TREE_SETTINGS)
    speck_px: int = 20  # a mask's 8-connected pieces smaller than this are specks: dropped before the carving
    salt_pieces_per_px: float = 0.005  # 3+ views: a mask with more specks than this per pixel ...
    salt_min_pieces: int = 10  # ... and at least this many is read without them (salt; a clean mask's few stay)
    # two views: a mask's holes of at most pinhole_px pixels are filled before anything reads it where they number
    # more than pepper_holes_per_px per mask pixel and at least pepper_min_holes (pepper noise; a clean mask's few,
    # where vessels cross, stay)
    pinhole_px: int = 9
    pepper_holes_per_px: float = 0.005
    pepper_min_holes: int = 10
    max_segment_mm: float = 2.0  # matched neighbours farther apart than this are not joined by a tube
    lumen_margin_steps: float = 0.5  # lumen points: lattice points within this many lattice steps of the tubes
    spike_window_mm: float = 3.0  # a radius above spike_ratio times the median over this much arc either side ...
    spike_ratio: float = 1.25  # ... is brought down to it (a stenosis, a narrowing, is kept)
    explained_share: float = 0.9  # a branch and its descendants this much of which the others cover in every view go
    explained_reach_radii: float = 0.5  # covered: within the other disc's radius plus this many of its own
    reproduced_mm: float = 2.0  # a point the views' own matchings place within this is reproduced (module notes)
    reproduced_share: float = 0.3  # a subtree reproduced less than this ...
    unreproduced_explained: float = 0.3  # ... and covered by the rest this much in every view goes
    stretch_min_mm: float = 3.0  # a run of contradicted, covered points inside a branch this long goes (notes)
    stretch_apart_mm: float = 5.0  # ... covered by tree points farther than this from it
    stretch_rounds: int = 3  # times the stretch step (with carrying branches) runs, each on the tree the last rebuilt (notes)
    claim_rounds: int = 2  # matchings again with each view's pixels claimed by the other's matching
    correspondence_join_order: str = "largest"  # the volume of step 3's tubes: its parts join largest first (notes)
    restore_uncovered: bool = True  # a pruned branch the kept tree no longer covers as its rule asked comes back (notes)
    rematch_rounds: int = 1  # two views: pixels the tree leaves unexplained matched again, anchored (notes), ...
    rematch_min_pixels: int = 5  # ... while at least this many of a view's join the tree, each time built again
    rematch_redundant_share: float = 0.9  # ... also those only branches the other view finds redundant explain (notes):
    rematch_replace_share: float = 0.5  # ... such a branch leaves the rebuild when this share of its freed pixels join
    alternative_claim_costs: tuple[float, ...] = (3.0,)  # two views: the matchings again with each, a tree each, and
    # the tree judged best kept (its tubes' agreement with the masks less the lengths' penalty below; module notes)
    fork_alternatives: bool = True  # ... their trees built in a forked process meanwhile, where that is safe (notes)
    # two views, hypotheses of a wrong pairing (module notes): a tree agreeing less than hypothesis_gate with the
    # masks is built again once per piece of the `hypotheses` touching the most unexplained mask pixels (in pieces
    # of unexplained_min_pixels or more; a side branch, or a window of the root root_window_mm long, half
    # overlapping the next; 0: the root is no suspect), the candidates within that piece's radius (at least
    # 0.5 mm) plus avoid_margin_mm costing avoid_cost more; a hypothesis's tree is kept where it is judged best of
    # all, and by at least hypothesis_margin more than the matchings' own trees
    hypotheses: int = 3
    root_window_mm: float = 15.0
    hypothesis_gate: float = 0.975
    unexplained_min_pixels: int = 5
    avoid_cost: float = 10.0
    avoid_margin_mm: float = 1.0
    hypothesis_margin: float = 0.005
    # two views, how the trees are judged (module notes): their agreement with the masks less length_weight times
    # their length and redundant_weight times the length of their branches only one view needs, both over the mean
    # length of the matchings' own trees (of trees that explain the masks alike, the wrong pairing's is longer)
    length_weight: float = 0.1
    redundant_weight: float = 0.1
    # two views, the kept tree's runs slid along one view's rays where the other view's mask holds a piece the tree
    # leaves unexplained (:mod:`.sliding`; None: not)
    slide: SlideSettings | None = field(default_factory=lambda: SLIDE_SETTINGS)


MODEL_SETTINGS = ModelSettings()


@dataclass(frozen=True)
class ModelBuild:
    """What :func:`model_tree` did, for reports."""

    pairs: tuple[tuple[int, int], ...]  # (view, partner) pairs matched
    matched_share: tuple[float, ...]  # per pair: share of the chain pixels given a match
    skeleton_pixels: tuple[int, ...]  # per view
    explained_removed: int  # branches removed because the rest of the tree covers them in every view
    tree_build: TreeBuild
    timings_s: dict[str, float]
    unreproduced_removed: int = 0  # branches removed because the views' own matchings do not reproduce them
    stretch_points_removed: int = 0  # points of contradicted, covered stretches inside branches (tree built again)
    inner_removed: int = 0  # branches with children taken out of the tubes as unreproduced (tree built again)
    rebuilds: int = 0  # times the tree was built again (stretches and such branches out, or pixels matched again)
    restored: int = 0  # pruned branches put back because what covered them went too
    rematched_pixels: int = 0  # skeleton pixels nothing explained, matched again anchored to the tree (tree built again)
    replaced_branches: int = 0  # branches redundant in one view whose pixels in the other were matched again elsewhere
    claim_costs: tuple[float, ...] = ()  # two views: the matchings' claim costs, one tree each (module notes) ...
    mask_agreement: tuple[float, ...] = ()  # ... each tree's mean Dice with the masks (the same tree again: its own)
    judged_score: tuple[float, ...] = ()  # ... that less the lengths' penalty (module notes), which decides
    kept_claim_cost: float | None = None  # ... and the claim cost of the tree kept (the best judged; None: one tree)
    hypotheses: tuple[tuple[float, float, float, float], ...] = ()  # two views: per hypothesis tree (module notes)
    # its claim cost, the length of the piece whose pairing it avoided (mm), its agreement with the masks and score
    hypotheses_of_root: tuple[bool, ...] = ()  # ... per hypothesis, whether that piece was a window of the root
    kept_hypothesis: int | None = None  # ... the one kept (None: a matching's own tree)
    width_bias_px: float | None = None  # two views: how much wider view 1 shows the vessels (half-width, px) ...
    width_bias_taken: bool = False  # ... and whether it was taken off where the radii compare (matching notes, 7.)
    slid_runs: int = 0  # two views: runs of the kept tree moved along one view's rays (:mod:`.sliding`)


def _viewing_direction(projection: Projection) -> np.ndarray:
    centre = projection.camera_centre_mm
    return -centre / np.linalg.norm(centre)


def _partners(projections: Sequence[Projection]) -> list[tuple[int, int]]:
    if len(projections) == 2:
        return [(0, 1), (1, 0)]
    directions = np.array([_viewing_direction(p) for p in projections])
    cosine = np.abs(directions @ directions.T)
    np.fill_diagonal(cosine, np.inf)
    return [(a, int(np.argmin(cosine[a]))) for a in range(len(projections))]


def _view_data(projection: Projection, mask: np.ndarray,
               core_fraction: float = MATCH_SETTINGS.core_fraction) -> ViewData:
    graph = centerline_graph(mask)
    index = np.full(mask.shape, -1, dtype=np.int64)
    uv = graph.uv_px.astype(np.int64)
    index[uv[:, 1], uv[:, 0]] = np.arange(len(uv))
    if len(uv):
        skeleton_px, (rows, cols) = ndi.distance_transform_edt(index < 0, return_indices=True)
        nearest = index[rows, cols]
    else:
        skeleton_px, nearest = np.full(mask.shape, np.inf), index
    inside_px = ndi.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    rows, cols = np.nonzero(mask)
    box = (np.array([cols.min() - 2.0, rows.min() - 2.0]), np.array([cols.max() + 2.0, rows.max() + 2.0]))
    return ViewData(projection=projection, mask=mask, graph=graph,
                    image=mask_core(mask, graph, inside_px, skeleton_px, nearest, core_fraction).astype(np.float32),
                    box_uv=box, inside_px=inside_px, nearest_skeleton=nearest,
                    outside_px=ndi.distance_transform_edt(~mask), skeleton_px=skeleton_px,
                    focal_px=float(max(projection.focal_lengths_px)))


_AVOID_MIN_RADIUS_MM = 0.5  # a hypothesis avoids at least this radius around a thin branch's axis (plus the margin)


@dataclass
class _Correspondence:
    """One matching's volume (step 3) and what judges its tree: per view its own matching's 3D
    point per skeleton pixel (nan where unmatched)."""

    claim_cost: float
    initial: np.ndarray
    shares: tuple[float, ...]
    own: list[np.ndarray]


@dataclass
class _Candidate:
    """A final tree of the two-view method (module notes): a matching's own, or a hypothesis's."""

    tree: VesselTree
    build: TreeBuild
    counts: dict[str, int]
    agreement: float  # mean Dice of its tubes' silhouettes and the masks
    correspondence: _Correspondence
    avoided_mm: float | None = None  # a hypothesis: the length of the piece whose pairing it avoided ...
    avoided_root: bool = False  # ... and whether that was a window of the root (else a side branch)
    length_mm: float = 0.0  # the tree's length
    redundant_mm: float = 0.0  # ... and its branches' that only one view needs (redundant in the other)
    score: float = np.nan  # the agreement less the lengths' penalty (module notes), set once every own tree is built

    def judged(self, settings: "ModelSettings", own_length_mm: float) -> float:
        """The agreement less the lengths' penalty, the lengths over ``own_length_mm`` (the mean
        length of the matchings' own trees)."""
        penalty = settings.length_weight * self.length_mm + settings.redundant_weight * self.redundant_mm
        return self.agreement - penalty / max(own_length_mm, 1e-9)


class _Matchings:
    """Steps 1-3 (module notes): the views' data and the pairs matched, then a
    :class:`_Correspondence` per claim cost and, for a hypothesis, per region avoided (the first
    round of matchings, which neither a claim nor an avoided region enters, and the candidates are
    computed once)."""

    def __init__(self, projections: Sequence[Projection], masks: Sequence[np.ndarray], lattice: Lattice,
                 settings: ModelSettings):
        self.settings, self.lattice = settings, lattice
        self.pairs = tuple(_partners(projections))
        # the candidates, transitions and first round's matchings (two views: the width bias's first round's)
        self._caches = {pair: {} for pair in self.pairs}
        # each view's data in a process of its own where that is safe (forked children: the same
        # arrays back, given the caller's projection and mask objects again)
        views = _in_processes([lambda p=p, m=m: _view_data(p, m, settings.match.core_fraction)
                               for p, m in zip(projections, masks)], settings.fork_alternatives)
        self.views, self.width_bias_px = with_width_bias(
            [replace(v, projection=p, mask=m) for v, p, m in zip(views, projections, masks)], settings.match,
            self._caches)
        self.nearest = [v.nearest_skeleton for v in self.views]
        self._others = {(a, b): [self.views[k] for k in range(len(self.views)) if k not in (a, b)]
                        for a, b in self.pairs}
        self._first: dict | None = None
        self.tubes_s = 0.0  # time spent on the tubes' lattice points

    def _round(self, match: MatchSettings, previous: dict | None, avoid: Avoid | None) -> dict:
        out = {}
        for a, b in self.pairs:
            # B's 3D point per skeleton pixel, from B's own matching into A
            claims = previous[(b, a)][0] if previous is not None and (b, a) in previous else None
            out[(a, b)] = match_pixels(self.views[a], self.views[b], self._others[(a, b)], match, claims,
                                       self._caches[(a, b)], avoid)
        return out

    def correspondence(self, claim_cost: float, avoid: Avoid | None = None) -> tuple[_Correspondence, str]:
        """The matchings with ``claim_cost`` (avoiding ``avoid``), their tubes' volume, and a line
        for the progress. Raises ReconstructionError where nothing matches."""
        settings = self.settings
        match = replace(settings.match, claim_cost=claim_cost)
        if avoid is None:
            if self._first is None:
                self._first = self._round(settings.match, None, None)
            results = self._first
        else:
            results = self._round(settings.match, None, avoid)
        for _ in range(settings.claim_rounds):
            results = self._round(match, results, avoid)
        tubes, shares = [], []
        for a, b in self.pairs:
            points, radii, parent = results[(a, b)]
            shares.append(float(np.isfinite(radii).mean()) if len(radii) else 0.0)
            tubes.append(_matched_tubes(points, radii, parent, settings.max_segment_mm))
        line = (f"correspondence (claim cost {claim_cost:g}{', a branch avoided' if avoid is not None else ''}): "
                + ", ".join(f"view {a} -> {b}: {s:.0%} matched" for (a, b), s in zip(self.pairs, shares)))
        starts, ends, r0, r1 = (np.concatenate(x) for x in zip(*tubes))
        if len(starts) == 0:
            cause = _along_one_line([v.projection for v in self.views])
            raise ReconstructionError("the tree method found no correspondence between the views' centerlines; "
                                      + (cause or "check the calibration and that the masks show the same vessels"))
        own = [np.full((v.graph.n_pixels, 3), np.nan) for v in self.views]
        for a, b in self.pairs:
            own[a] = results[(a, b)][0]
        start = time.perf_counter()
        initial = lattice_points_in_tubes(starts, ends, r0, r1, self.lattice)
        self.tubes_s += time.perf_counter() - start
        return _Correspondence(claim_cost, initial, tuple(shares), own), line


def _matched_tubes(points: np.ndarray, radii: np.ndarray, parent: np.ndarray, max_segment_mm: float,
                   new: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(starts, ends, start radii, end radii) of a matching's tubes: from each matched pixel to its
    matched neighbour in the forest (at most ``max_segment_mm`` apart), and a ball at each matched
    pixel; with ``new`` ((P,) bool), only the tubes that touch a new pixel and the new pixels' balls."""
    matched = np.isfinite(radii)
    child = np.flatnonzero((parent >= 0) & matched)
    child = child[matched[parent[child]]]
    child = child[np.linalg.norm(points[child] - points[parent[child]], axis=1) <= max_segment_mm]
    ball = np.flatnonzero(matched)
    if new is not None:
        child, ball = child[new[child] | new[parent[child]]], np.flatnonzero(new)
    return (np.concatenate([points[child], points[ball]]), np.concatenate([points[parent[child]], points[ball]]),
            np.concatenate([radii[child], radii[ball]]), np.concatenate([radii[parent[child]], radii[ball]]))


def _tree_from_volume(projections: Sequence[Projection], masks: Sequence[np.ndarray], lattice: Lattice,
                      initial: np.ndarray, own: list[np.ndarray] | None, nearest: list[np.ndarray] | None,
                      views: list[ViewData] | None, pairs: Sequence[tuple[int, int]], bridge: SupportBridge | None,
                      settings: ModelSettings, avoid: Avoid | None = None
                      ) -> tuple[VesselTree, TreeBuild, dict[str, int]]:
    """Step 4 (module notes): the tree of ``initial``'s volume, fitted and pruned, its stretches and
    unexplained pixels handled; with the counts of what each rule did. ``own`` (each view's own
    matching's 3D point per skeleton pixel), ``nearest`` and ``views`` are None when the volume is
    not the correspondences' tubes. ``avoid``: the region the matchings avoided (a hypothesis), avoided
    again when unexplained pixels are matched again."""

    def fitted_and_pruned(volume: np.ndarray) -> tuple[VesselTree, TreeBuild, int, int, int]:
        tree_settings = settings.tree
        if own is not None:  # the correspondences' tubes: phantom pieces among the parts (module notes)
            tree_settings = replace(tree_settings, skeleton=replace(tree_settings.skeleton,
                                                                    join_order=settings.correspondence_join_order))
        built, tree_build = hull_tree(volume, lattice, projections, masks, support_bridge=bridge,
                                      settings=tree_settings)
        # the disc pairs of the built tree, searched once for the three rules (branches only go)
        disc_pairs = _DiscPairs(built, projections, settings.explained_reach_radii)
        tree, kept = _explained_pruning(built, projections, settings.explained_share, settings.explained_reach_radii,
                                        disc_pairs)
        explained_kept = np.isin(np.arange(built.n_branches), kept)
        if own is not None:  # the correspondences made the volume: their own matchings judge its branches
            tree, still = _unreproduced_pruning(
                tree, projections, own, nearest, tolerance_mm=settings.reproduced_mm, share=settings.reproduced_share,
                explained=settings.unreproduced_explained, reach_radii=settings.explained_reach_radii, pairs=disc_pairs)
            kept = [kept[k] for k in still]
        alive = np.isin(np.arange(built.n_branches), kept)
        pruned, unreproduced = int((~explained_kept).sum()), int((explained_kept & ~alive).sum())
        restored = 0
        if settings.restore_uncovered and not alive.all():
            # each pruned branch stays out while the kept tree covers it as its rule asked (notes)
            removal_cover = np.where(explained_kept, settings.unreproduced_explained,
                                     np.nextafter(settings.explained_share, np.inf))
            alive, restored = restore_uncovered_branches(built, alive, removal_cover, projections,
                                                         settings.explained_reach_radii, disc_pairs.whole())
            if restored:
                tree = _kept(built, alive)
        return tree, tree_build, pruned, unreproduced, restored

    tree, tree_build, pruned, unreproduced, restored = fitted_and_pruned(initial)
    tree = without_radius_spikes(tree, settings.spike_window_mm, settings.spike_ratio)
    stretch_points = inner_removed = rebuilds = 0
    while own is not None and rebuilds < settings.stretch_rounds:  # ... and the stretches inside branches
        disc_pairs = tree_disc_pairs(tree, projections, settings.explained_reach_radii)  # searched once for both
        stretches = contradicted_stretches(tree, projections, own, nearest, tolerance_mm=settings.reproduced_mm,
                                           reach_radii=settings.explained_reach_radii,
                                           apart_mm=settings.stretch_apart_mm, min_length_mm=settings.stretch_min_mm,
                                           pairs=disc_pairs)
        inner = unreproduced_inner_branches(tree, projections, own, nearest, tolerance_mm=settings.reproduced_mm,
                                            share=settings.reproduced_share,
                                            explained=settings.unreproduced_explained,
                                            reach_radii=settings.explained_reach_radii, pairs=disc_pairs)
        out = stretches | inner
        if not out.any():
            break
        rest = lattice_points_in_tubes(*_tube_segments(tree, ~out), lattice)
        if len(rest) < 2:
            break
        stretch_points += int((stretches & ~inner).sum())
        inner_removed += len(np.unique(tree.points()[2][inner]))
        rebuilds += 1  # out of the tubes, and the tree built again through the hull from the rest
        tree, tree_build, more_pruned, more_unreproduced, more_restored = fitted_and_pruned(rest)
        pruned, unreproduced = pruned + more_pruned, unreproduced + more_unreproduced
        restored += more_restored
        if rebuilds < settings.stretch_rounds:  # judged again in the next round
            tree = without_radius_spikes(tree, settings.spike_window_mm, settings.spike_ratio)
    tree = without_radius_spikes(tree, settings.spike_window_mm, settings.spike_ratio)
    rematched = replaced = 0
    for _ in range(settings.rematch_rounds if own is not None and len(projections) == 2 else 0):
        # the pixels nothing in the tree explains, or only branches the other view finds redundant,
        # matched again anchored to it; such a branch goes where its pixels join elsewhere (notes)
        tubes = []
        points, radius, owner = tree.points()
        drop = np.zeros(len(points), dtype=bool)
        redundant_per_pair = redundant_branches(tree, projections, pairs, settings.rematch_redundant_share,
                                                settings.explained_share, settings.explained_reach_radii)
        for (a, b), redundant in zip(pairs, redundant_per_pair):
            discs = _nearest_discs(tree, projections[a], views[a].graph.uv_px)  # searched once for both
            which_any = _holding(discs, 1.0)
            which = _holding(discs, 1.0, by=~np.isin(owner, redundant))
            if (which < 0).sum() < settings.rematch_min_pixels:
                continue
            anchor = np.where((which >= 0)[:, None], points[np.maximum(which, 0)], np.nan)
            got, got_radii, parent, new = anchored_match(views[a], views[b], anchor, radius[np.maximum(which, 0)],
                                                         settings.match, settings.max_segment_mm, avoid)
            freed_from = np.where((which < 0) & (which_any >= 0), owner[np.maximum(which_any, 0)], -1)
            for branch in redundant:
                mine = freed_from == branch
                if mine.any() and new[mine].mean() >= settings.rematch_replace_share:
                    drop |= owner == branch
                else:  # it stays, and so do its pixels' matches
                    new &= ~mine
            if new.sum() >= settings.rematch_min_pixels:
                tubes.append(_matched_tubes(got, got_radii, parent, settings.max_segment_mm, new))
                rematched += int(new.sum())
        if not tubes:
            break
        replaced += len(np.unique(owner[drop]))
        tree, tree_build, more_pruned, more_unreproduced, more_restored = fitted_and_pruned(
            lattice_points_in_tubes(*(np.concatenate(x) for x in zip(_tube_segments(tree, ~drop), *tubes)), lattice))
        pruned, unreproduced, restored = pruned + more_pruned, unreproduced + more_unreproduced, restored + more_restored
        rebuilds += 1
        tree = without_radius_spikes(tree, settings.spike_window_mm, settings.spike_ratio)
    if own is not None and len(projections) < 3 and settings.tree.fit_passes > 1:  # fitted again (module notes)
        tree, tree_build = refit_tree(tree, projections, masks, build=tree_build, passes=settings.tree.fit_passes - 1,
                                      settings=settings.tree)
        tree = without_radius_spikes(tree, settings.spike_window_mm, settings.spike_ratio)
    counts = dict(pruned=pruned, unreproduced=unreproduced, restored=restored, stretch_points=stretch_points,
                  inner_removed=inner_removed, rebuilds=rebuilds, rematched=rematched, replaced=replaced)
    return tree, tree_build, counts


def _from_one_line_deg(projections: Sequence[Projection]) -> float:
    """How far from looking along one line the views are, at most over their pairs (degrees)."""
    return max(degrees_from_one_line(a, b) for a, b in combinations(projections, 2))


def _along_one_line(projections: Sequence[Projection], within_deg: float = 5.0) -> str | None:
    """Where every pair of views looks along nearly one line (within ``within_deg``): what to say
    instead of a finer lattice (the rays of paired pixels then run along each other, and meet
    nowhere). None otherwise."""
    nearest = _from_one_line_deg(projections)
    if nearest >= within_deg:
        return None
    return (f"the views look along one line (their central rays {nearest:.1f} degrees from it at most), so the "
            f"rays of the pixels they pair run along each other and fix no point; use views 30 degrees apart or more")


def model_tree(projections: Sequence[Projection], masks: Sequence[np.ndarray], lattice: Lattice, *,
               support_points_mm: np.ndarray | None = None, initial_points_mm: np.ndarray | None = None,
               settings: ModelSettings = MODEL_SETTINGS,
               progress: Callable[[str], None] | None = None) -> tuple[np.ndarray, VesselTree, ModelBuild]:
    """Reconstruct with the ``tree`` method (module notes).

    Parameters
    ----------
    projections, masks : sequences
        Two or more views (masks boolean, shapes the projections' image shapes).
    lattice : Lattice
        The cube of interest whose points make the lumen points.
    support_points_mm : (S, 3) array, optional
        The visual hull's points on ``lattice``: pieces of the matched tubes that lie apart are
        joined along the shortest path through it (as the refined preset's tree does).
    initial_points_mm : (N, 3) array, optional
        The volume whose tree is fitted, instead of the correspondences' tubes (with three views
        or more :func:`angiohull.reconstruction.reconstruct` passes the refined hull: the hull of
        three views is no longer ambiguous, and its skeleton is the better start).
    settings : ModelSettings
    progress : callable, optional
        Called with a line per stage.

    Returns
    -------
    lumen_points_mm : (N, 3) array
        Lattice points inside the fitted tubes.
    tree : VesselTree
    build : ModelBuild

    Raises
    ------
    ReconstructionError
        With fewer than two views, or when no correspondence is found.
    """
    if len(projections) < 2:
        raise ReconstructionError(f"the tree method needs two views or more, got {len(projections)}")
    say = progress or (lambda _text: None)
    timings: dict[str, float] = {}
    masks = [np.asarray(m, dtype=bool) for m in masks]
    nearest = views = None
    width_bias: tuple[float | None, bool] = (None, False)
    if initial_points_mm is None:  # with two views, one matching per claim cost, and the best tree kept (notes)
        claim_costs = (settings.match.claim_cost,) + (settings.alternative_claim_costs if len(projections) == 2
                                                      else ())
        start = time.perf_counter()
        matchings = _Matchings(projections, masks, lattice, settings)
        timings["centerlines_2d"] = time.perf_counter() - start
        say(f"2D centerlines: {', '.join(str(v.graph.n_pixels) for v in matchings.views)} skeleton pixels")
        if len(matchings.views) == 2 and settings.match.width_bias:
            taken = abs(matchings.width_bias_px) >= settings.match.width_bias_min_px
            width_bias = (float(matchings.width_bias_px), bool(taken))
            say(f"view 1 shows the vessels {matchings.width_bias_px:+.2f} px wider (half-width) than view 0"
                + (": taken off where the matching compares radii" if taken else ""))
        start = time.perf_counter()
        correspondences = []
        for claim_cost in claim_costs:
            corr, line = matchings.correspondence(claim_cost)
            say(line)
            correspondences.append(corr)
        timings["correspondence"] = time.perf_counter() - start - matchings.tubes_s
        timings["tubes"] = matchings.tubes_s
        pairs, nearest, views = matchings.pairs, matchings.nearest, matchings.views
        skeleton_pixels = tuple(v.graph.n_pixels for v in views)
    else:
        matchings, pairs, skeleton_pixels = None, (), ()
        correspondences = [_Correspondence(settings.match.claim_cost, np.asarray(initial_points_mm, dtype=float),
                                           (), None)]
    if len(correspondences[0].initial) < 2:
        raise ReconstructionError("the tree method's volume holds fewer than two lattice points; "
                                  + (_along_one_line(projections) or "use a finer lattice"))

    tree_start = time.perf_counter()  # the bridge and every matching's tree, their agreement apart
    bridge = None  # the support hull's graphs, built once for every rebuild
    if support_points_mm is not None and len(support_points_mm):
        bridge = SupportBridge(np.asarray(support_points_mm, dtype=np.float64), lattice, settings.tree.max_bridge_mm,
                               views=(projections, masks))
    timings["tree"] = timings["agreement"] = 0.0  # (keys in the stages' order)
    same: list[int | None] = []  # per matching, an earlier one that gives the same volume (the same tree)
    for k, corr in enumerate(correspondences):
        same.append(next((j for j in range(k) if np.array_equal(corr.initial, correspondences[j].initial)
                          and all(np.array_equal(x, y, equal_nan=True)
                                  for x, y in zip(corr.own, correspondences[j].own))), None))
    todo = [k for k in range(len(correspondences))
            if same[k] is None and (k == 0 or len(correspondences[k].initial) >= 2)]
    judged = len(correspondences) > 1  # two views: the trees' agreement with the masks and lengths decide
    agreement_s = [0.0]  # the agreement's time in this process

    def judging(tree: VesselTree) -> dict[str, float]:
        """What judges a tree (module notes): its agreement, its length and its redundant branches'."""
        start = time.perf_counter()
        agreement = float(mask_agreement(tree, projections, masks).mean())
        redundant = np.unique(np.concatenate(redundant_branches(
            tree, projections, pairs, settings.rematch_redundant_share, settings.explained_share,
            settings.explained_reach_radii)))
        out = dict(agreement=agreement, length_mm=tree.length_mm,
                   redundant_mm=float(sum(tree.branches[k].length_mm for k in redundant)))
        agreement_s[0] += time.perf_counter() - start
        return out

    def settings_of(corr: _Correspondence) -> ModelSettings:
        return replace(settings, match=replace(settings.match, claim_cost=corr.claim_cost))

    def tree_of(k: int) -> _Candidate:
        corr = correspondences[k]
        built = _tree_from_volume(projections, masks, lattice, corr.initial, corr.own, nearest, views, pairs, bridge,
                                  settings_of(corr))
        if not judged:
            return _Candidate(*built, np.nan, corr)
        return _Candidate(*built, correspondence=corr, **judging(built[0]))

    def hypothesis(k: int, tree: VesselTree, suspect: Suspect) -> _Candidate | None:
        """Matching ``k``'s tree built again with the pairing of its piece ``suspect`` avoided."""
        corr, b = correspondences[k], tree.branches[suspect.branch]
        points, radius = b.points_mm[suspect.first:suspect.end], b.radius_mm[suspect.first:suspect.end]
        avoid = Avoid(points, np.maximum(radius, _AVOID_MIN_RADIUS_MM) + settings.avoid_margin_mm, settings.avoid_cost)
        try:
            other, _ = matchings.correspondence(corr.claim_cost, avoid)
            if len(other.initial) < 2:
                return None
            built = _tree_from_volume(projections, masks, lattice, other.initial, other.own, nearest, views, pairs,
                                      bridge, settings_of(corr), avoid)
        except ReconstructionError:  # no tree without that piece's pairing: no hypothesis
            return None
        avoided_mm = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
        return _Candidate(*built, correspondence=other, avoided_mm=avoided_mm, avoided_root=suspect.branch == 0,
                          **judging(built[0]))

    trees = dict(zip(todo, _in_processes([lambda k=k: tree_of(k) for k in todo], settings.fork_alternatives)))
    own_length_mm = float(np.mean([trees[k].length_mm for k in todo]))
    for k in todo:
        trees[k].score = trees[k].judged(settings, own_length_mm) if judged else np.nan
    agreement, score = [], []
    for k in range(len(correspondences)):  # the same tree again, or none
        for out, key in ((agreement, "agreement"), (score, "score")):
            out.append(getattr(trees[k], key) if k in trees else out[same[k]] if same[k] is not None else -np.inf)
    best = max((trees[k] for k in todo), key=lambda c: c.score)  # the first of equals
    timings["agreement"] = agreement_s[0]
    timings["tree"] = time.perf_counter() - tree_start - timings["agreement"]
    hypotheses: list[_Candidate] = []
    start = time.perf_counter()
    if judged and settings.hypotheses > 0:  # step 4's hypotheses of a wrong pairing (module notes)
        tasks = [(k, suspect) for k in todo if trees[k].agreement < settings.hypothesis_gate
                 for suspect in suspect_pieces(trees[k].tree, projections, masks, settings.hypotheses,
                                               settings.unexplained_min_pixels, root_window_mm=settings.root_window_mm)]
        if tasks:
            say(f"{len(tasks)} hypotheses of a wrong pairing (trees agreeing less than {settings.hypothesis_gate:g})")
        built = _in_processes([lambda k=k, s=s: hypothesis(k, trees[k].tree, s) for k, s in tasks],
                              settings.fork_alternatives)
        hypotheses = [h for h in built if h is not None]
        bar = best.score + settings.hypothesis_margin
        for h in hypotheses:
            h.score = h.judged(settings, own_length_mm)
            if h.score >= bar and h.score > best.score:
                best = h
    if judged:  # their matchings, trees and agreement
        timings["hypotheses"] = time.perf_counter() - start
    if judged:
        tried = (f"; {len(hypotheses)} hypotheses of a wrong pairing: "
                 + ", ".join(f"{h.agreement:.4f} ({h.score:.4f})" for h in hypotheses)) if hypotheses else ""
        say(f"trees' agreement with the masks (mean Dice over the views; judged, less the lengths' penalty): "
            + ", ".join(f"claim cost {c.claim_cost:g}: {a:.4f} ({j:.4f})"
                        for c, a, j in zip(correspondences, agreement, score))
            + tried + f"; kept claim cost {best.correspondence.claim_cost:g}"
            + (f", the tree without the pairing of a {best.avoided_mm:.0f} mm "
               + ("stretch of the root" if best.avoided_root else "branch") if best.avoided_mm else ""))
    else:
        del timings["agreement"]
    tree, tree_build, counts = best.tree, best.build, best.counts
    say(f"tree: {tree.n_branches} branches, fitted to the views ({counts['pruned']} explained by the others "
        f"removed, {counts['unreproduced']} that the views' own matchings do not reproduce, {counts['restored']} "
        f"of these put back, {counts['stretch_points']} points of stretches they contradict, "
        f"{counts['inner_removed']} branches that carry others, {counts['rematched']} unexplained pixels matched "
        f"again, replacing {counts['replaced']} branches; {counts['rebuilds']} rebuilds)")

    slid = 0
    if len(projections) == 2 and settings.slide is not None:  # the kept tree's runs slid along rays (notes)
        start = time.perf_counter()
        tree, slid = slid_along_rays(tree, projections, masks, settings=settings.slide)
        timings["slide"] = time.perf_counter() - start
        if slid:
            say(f"{slid} runs of the tree moved along one view's rays to explain the other view's mask")
    start = time.perf_counter()
    lumen = tree_lumen_points(tree, lattice, settings.lumen_margin_steps * lattice.spacing_mm)
    timings["lumen"] = time.perf_counter() - start
    kept = best.correspondence
    build = ModelBuild(pairs=pairs, matched_share=kept.shares, skeleton_pixels=skeleton_pixels,
                       explained_removed=counts["pruned"], unreproduced_removed=counts["unreproduced"],
                       stretch_points_removed=counts["stretch_points"], inner_removed=counts["inner_removed"],
                       rebuilds=counts["rebuilds"], restored=counts["restored"], rematched_pixels=counts["rematched"],
                       replaced_branches=counts["replaced"], tree_build=tree_build, timings_s=timings,
                       claim_costs=tuple(c.claim_cost for c in correspondences) if judged else (),
                       mask_agreement=tuple(agreement) if judged else (),
                       judged_score=tuple(score) if judged else (),
                       kept_claim_cost=kept.claim_cost if judged else None,
                       hypotheses=tuple((h.correspondence.claim_cost, h.avoided_mm, h.agreement, h.score)
                                        for h in hypotheses),
                       hypotheses_of_root=tuple(h.avoided_root for h in hypotheses),
                       kept_hypothesis=next((j for j, h in enumerate(hypotheses) if h is best), None),
                       width_bias_px=width_bias[0], width_bias_taken=width_bias[1], slid_runs=slid)
    return lumen, tree, build
