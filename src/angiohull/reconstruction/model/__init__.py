"""The ``tree`` method: the vessel tree from centerline correspondences across the views, with tubes
fitted to the masks (beyond the paper; docs/tree-method.md).

A visual hull of two views holds phantom volume wherever the cones of two vessels cross; the
views' 2D centerlines and widths say where the vessels are. Steps:

1. **2D centerline graphs** (:mod:`.graph2d`): each mask is thinned, its skeleton traced into
   chains between ends and junctions, thinning spurs removed, a half-width per pixel.
2. **Correspondence** (:mod:`.matching`): each view's chains are matched into a partner view (with
   two views, each into the other; with more, each into the view most nearly perpendicular to it,
   every candidate checked against the remaining views' masks and skeletons) by a dynamic
   programme along each chain over the epipolar candidates, which weighs distance to the epipolar
   line, the radius the two views show at that depth, 3D continuity and turns onto crossing
   vessels.
3. **Tubes**: the matched points, with the radius both views show, joined along their chains,
   give a union of tubes on the lattice of the cube of interest.
4. **Tree and fit**: that volume's vessel tree (:func:`..vessel_tree.hull_tree`: skeleton, graph,
   then centres and radii fitted to every view's mask, ends moved to the masks' ends).
5. **Lumen points**: the lattice points inside the fitted tree's tubes.

Arrays and projections in, points and a tree out; nothing here reads files.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import ndimage as ndi

from ...errors import ReconstructionError
from ...geometry import Projection
from ...tree import VesselTree
from ..cube import Lattice
from ..vessel_tree import TREE_SETTINGS, TreeBuild, TreeSettings, hull_tree
from .graph2d import CenterlineGraph2D, centerline_graph
from .matching import MATCH_SETTINGS, MatchSettings, ViewData, match_chains
from .tubes import lattice_points_in_tubes

__all__ = ["ModelSettings", "MODEL_SETTINGS", "ModelBuild", "model_tree", "centerline_graph", "CenterlineGraph2D",
           "MatchSettings", "lattice_points_in_tubes"]


@dataclass(frozen=True)
class ModelSettings:
    """Parameters of the ``tree`` method (module notes); the same for every case."""

    match: MatchSettings = field(default_factory=lambda: MATCH_SETTINGS)
    tree: TreeSettings = field(default_factory=lambda: TREE_SETTINGS)
    max_segment_mm: float = 2.0  # matched neighbours farther apart than this are not joined by a tube
    lumen_margin_mm: float = 0.0  # lumen points: lattice points within this of the fitted tubes
    claim_rounds: int = 2  # matchings again with each view's pixels claimed by the other's matching


MODEL_SETTINGS = ModelSettings()


@dataclass(frozen=True)
class ModelBuild:
    """What :func:`model_tree` did, for reports."""

    pairs: tuple[tuple[int, int], ...]  # (view, partner) pairs matched
    matched_share: tuple[float, ...]  # per pair: share of the chain pixels given a match
    skeleton_pixels: tuple[int, ...]  # per view
    tree_build: TreeBuild
    timings_s: dict[str, float]


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


def _view_data(projection: Projection, mask: np.ndarray) -> ViewData:
    graph = centerline_graph(mask)
    index = np.full(mask.shape, -1, dtype=np.int64)
    uv = graph.uv_px.astype(np.int64)
    index[uv[:, 1], uv[:, 0]] = np.arange(len(uv))
    if len(uv):
        skeleton_px, (rows, cols) = ndi.distance_transform_edt(index < 0, return_indices=True)
        nearest = index[rows, cols]
    else:
        skeleton_px, nearest = np.full(mask.shape, np.inf), index
    rows, cols = np.nonzero(mask)
    box = (np.array([cols.min() - 2.0, rows.min() - 2.0]), np.array([cols.max() + 2.0, rows.max() + 2.0]))
    return ViewData(projection=projection, mask=mask, graph=graph, image=mask.astype(np.float32), box_uv=box,
                    inside_px=ndi.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1],
                    nearest_skeleton=nearest, outside_px=ndi.distance_transform_edt(~mask),
                    skeleton_px=skeleton_px, focal_px=float(max(projection.focal_lengths_px)))


def _tubes(points: list[np.ndarray], radii: list[np.ndarray], max_segment_mm: float):
    starts, ends, r0, r1 = [], [], [], []
    for pts, rad in zip(points, radii):
        ok = np.isfinite(rad)
        if not ok.any():
            continue
        # neighbours both matched and close: a tube; every matched point: a ball
        both = ok[:-1] & ok[1:]
        if len(pts) > 1 and both.any():
            a, b = pts[:-1][both], pts[1:][both]
            near = np.linalg.norm(b - a, axis=1) <= max_segment_mm
            starts.append(a[near]), ends.append(b[near])
            r0.append(rad[:-1][both][near]), r1.append(rad[1:][both][near])
        starts.append(pts[ok]), ends.append(pts[ok]), r0.append(rad[ok]), r1.append(rad[ok])
    if not starts:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    return np.concatenate(starts), np.concatenate(ends), np.concatenate(r0), np.concatenate(r1)


def tree_lumen_points(tree: VesselTree, lattice: Lattice, margin_mm: float = 0.0) -> np.ndarray:
    """The lattice points inside the tree's tubes (within ``margin_mm`` of them), mm."""
    starts, ends, r0, r1 = [], [], [], []
    for b in tree.branches:
        starts.append(b.points_mm[:-1]), ends.append(b.points_mm[1:])
        r0.append(b.radius_mm[:-1]), r1.append(b.radius_mm[1:])
        if b.parent is not None:
            anchor = tree.branches[b.parent].points_mm[b.parent_point]
            starts.append(anchor[None]), ends.append(b.points_mm[:1])
            r0.append(b.radius_mm[:1]), r1.append(b.radius_mm[:1])
    return lattice_points_in_tubes(np.concatenate(starts), np.concatenate(ends), np.concatenate(r0),
                                   np.concatenate(r1), lattice, margin_mm=margin_mm)


def model_tree(projections: Sequence[Projection], masks: Sequence[np.ndarray], lattice: Lattice, *,
               support_points_mm: np.ndarray | None = None, settings: ModelSettings = MODEL_SETTINGS,
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
    start = time.perf_counter()
    views = [_view_data(p, np.asarray(m, dtype=bool)) for p, m in zip(projections, masks)]
    timings["centerlines_2d"] = time.perf_counter() - start
    say(f"2D centerlines: {', '.join(str(v.graph.n_pixels) for v in views)} skeleton pixels")

    start = time.perf_counter()
    pairs = _partners(projections)
    results, caches = {}, {pair: {} for pair in pairs}
    for rounds in range(1 + settings.claim_rounds):
        previous, results = results, {}
        for a, b in pairs:
            others = [views[k] for k in range(len(views)) if k not in (a, b)]
            claims = None
            if (b, a) in previous:
                # B's 3D point per skeleton pixel, from B's own matching into A
                pixels, points, _ = previous[(b, a)]
                claims = np.full((views[b].graph.n_pixels, 3), np.nan)
                claims[np.concatenate(pixels)] = np.concatenate(points)
            results[(a, b)] = match_chains(views[a], views[b], others, settings.match, claims, caches[(a, b)])
    all_points, all_radii, shares = [], [], []
    for a, b in pairs:
        _, points, radii = results[(a, b)]
        all_points += points
        all_radii += radii
        total = sum(len(r) for r in radii)
        shares.append(sum(int(np.isfinite(r).sum()) for r in radii) / total if total else 0.0)
    timings["correspondence"] = time.perf_counter() - start
    say("correspondence: " + ", ".join(f"view {a} -> {b}: {s:.0%} matched" for (a, b), s in zip(pairs, shares)))

    start = time.perf_counter()
    a, b, r0, r1 = _tubes(all_points, all_radii, settings.max_segment_mm)
    if len(a) == 0:
        raise ReconstructionError("the tree method found no correspondence between the views' centerlines; "
                                  "check the calibration and that the masks show the same vessels")
    initial = lattice_points_in_tubes(a, b, r0, r1, lattice)
    timings["tubes"] = time.perf_counter() - start
    if len(initial) < 2:
        raise ReconstructionError("the matched tubes hold fewer than two lattice points; use a finer lattice")

    start = time.perf_counter()
    tree, tree_build = hull_tree(initial, lattice, projections, [v.mask for v in views],
                                 support_points_mm=support_points_mm, settings=settings.tree)
    timings["tree"] = time.perf_counter() - start
    say(f"tree: {tree.n_branches} branches, fitted to the views")

    start = time.perf_counter()
    lumen = tree_lumen_points(tree, lattice, settings.lumen_margin_mm)
    timings["lumen"] = time.perf_counter() - start
    build = ModelBuild(pairs=tuple(pairs), matched_share=tuple(shares),
                       skeleton_pixels=tuple(v.graph.n_pixels for v in views), tree_build=tree_build,
                       timings_s=timings)
    return lumen, tree, build
