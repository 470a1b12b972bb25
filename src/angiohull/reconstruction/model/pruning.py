"""Step 4's rules of the ``tree`` method (module notes of :mod:`angiohull.reconstruction.model`):
what covers a branch in the views (projected discs of the rest of the tree, the pixels a tree point
explains, branches only one view needs), the prunings that use it (branches the others explain in
every view, branches and stretches the views' own matchings do not reproduce, pruned branches put
back when what covered them went too), and the tree edits they make (kept branches, radius spikes,
the tubes' segments and their lattice points).

Arrays, projections and trees in; trees, masks and shares out.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from ...geometry import Projection
from ...tree import Branch, VesselTree
from ..cube import Lattice
from .tubes import lattice_points_in_tubes

__all__ = ["explained_shares", "prune_explained_branches", "reproduced_points", "prune_unreproduced_branches",
           "unreproduced_inner_branches", "covered_points", "contradicted_stretches", "restore_uncovered_branches",
           "without_radius_spikes", "tree_lumen_points", "explaining_points", "redundant_branches", "tree_disc_pairs"]


def _kept(tree: VesselTree, alive: np.ndarray) -> VesselTree:
    """The tree of the branches where ``alive`` ((B,) bool) holds, in their order (every kept
    branch's parent kept)."""
    index = np.cumsum(alive) - 1
    return VesselTree(tuple(b._with_parent(None if b.parent is None else int(index[b.parent]))
                            for b, keep in zip(tree.branches, alive) if keep))


def _without(tree: VesselTree, leaf: int) -> VesselTree:
    """The tree without leaf branch ``leaf`` (indices after it shift down by one)."""
    return _kept(tree, np.arange(tree.n_branches) != leaf)


def _subtrees(tree: VesselTree) -> list[np.ndarray]:
    """Per branch, the branches of its subtree (itself and every descendant), ascending."""
    members = [[b] for b in range(tree.n_branches)]
    for b in range(tree.n_branches - 1, 0, -1):  # children come after their parents
        members[tree.branches[b].parent] += members[b]
    return [np.sort(m) for m in members]


def _subtree_points(tree: VesselTree, owner: np.ndarray) -> np.ndarray:
    """(B, N) bool: per branch, the points (``owner``: each point's branch) of its subtree, the rows
    of ``np.isin(owner, _subtrees(tree)[b])`` without a search per branch."""
    within = np.eye(tree.n_branches, dtype=bool)  # within[b, c]: c lies in b's subtree
    for c in range(tree.n_branches - 1, 0, -1):  # children come after their parents: c's row is whole
        within[tree.branches[c].parent] |= within[c]
    return within[:, owner]


def _overlapping_discs(points: np.ndarray, radius: np.ndarray, projection: Projection,
                       reach_radii: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pairs (i, j) of points whose projected discs (radius plus half a pixel) may overlap in
    ``projection``, and per pair whether i's projection lies within j's disc radius plus
    ``reach_radii`` times its own (``i_in_j``), and the other way round (``j_in_i``)."""
    from scipy.spatial import cKDTree

    uv = projection.project(points)
    rho = radius * max(projection.focal_lengths_px) / projection.depth_mm(points) + 0.5
    pairs = cKDTree(uv).query_pairs(float((1.0 + reach_radii) * rho.max()), output_type="ndarray")
    i, j = (pairs[:, 0], pairs[:, 1]) if len(pairs) else (np.zeros(0, np.int64), np.zeros(0, np.int64))
    du, dv = uv[i, 0] - uv[j, 0], uv[i, 1] - uv[j, 1]
    gap = np.sqrt(du * du + dv * dv)  # np.linalg.norm(uv[i] - uv[j], axis=1), without its reduction's overhead
    return i, j, gap <= rho[j] + reach_radii * rho[i], gap <= rho[i] + reach_radii * rho[j]


def explained_shares(tree: VesselTree, projections: Sequence[Projection], reach_radii: float,
                     pairs: list | None = None) -> np.ndarray:
    """(B, V): per branch and view, the share of the points of the branch's subtree (the branch
    and its descendants) that the rest of the tree covers there. A point's disc is its projected
    radius plus half a pixel; the point is covered when its projection lies within the disc's
    radius of a point outside the subtree plus ``reach_radii`` times its own (0: its centre inside
    the other disc; 0.5: the two discs overlap by at least half its radius; 1: they touch). With
    ``pairs``, the tree's disc pairs per view, they are not searched again (:class:`_DiscPairs`)."""
    return _covered_shares(tree, projections, reach_radii, _subtree_points(tree, tree.points()[2]), pairs=pairs)


class _DiscPairs:
    """:func:`_overlapping_discs` of a tree's points in every view, searched once and served for
    the tree and for what is left of it as branches go (a pair's flags depend on its two points
    alone; the search's radius, the largest disc's, only widens what it finds)."""

    def __init__(self, tree: VesselTree, projections: Sequence[Projection], reach_radii: float):
        points, radius, self._owner = tree.points()
        self._views = [_overlapping_discs(points, radius, p, reach_radii) for p in projections]
        self._ids = list(range(tree.n_branches))  # each branch's index in the first tree
        self._keep = np.ones(len(points), dtype=bool)

    def whole(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """The pairs per view of the whole first tree, whatever went since."""
        return self._views

    def without(self, branch: int) -> None:
        """Branch ``branch`` (its index in the tree now) went, as :func:`_without` takes it (the
        others' points keep their order)."""
        self._keep[self._owner == self._ids.pop(branch)] = False

    def current(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """The pairs per view among the points left, in the tree's indices now."""
        if self._keep.all():
            return self._views
        index = np.cumsum(self._keep) - 1
        out = []
        for i, j, i_in_j, j_in_i in self._views:
            both = self._keep[i] & self._keep[j]
            out.append((index[i[both]], index[j[both]], i_in_j[both], j_in_i[both]))
        return out


def _covered_shares(tree: VesselTree, projections: Sequence[Projection], reach_radii: float,
                    groups: Sequence[np.ndarray], by: np.ndarray | None = None,
                    pairs: list | None = None) -> np.ndarray:
    """(G, V): per group of points ((N,) bool over ``tree.points()``) and view, the share of the
    group's points that points outside it cover there (:func:`explained_shares`); with ``by``
    ((N,) bool), only those points cover; with ``pairs``, the tree's disc pairs per view
    (:class:`_DiscPairs`)."""
    points, radius, _ = tree.points()
    by = np.ones(len(points), dtype=bool) if by is None else by
    members = np.array(groups, dtype=bool).reshape(len(groups), len(points))
    counts = np.maximum(members.sum(axis=1), 1)
    out = np.zeros((len(groups), len(projections)))
    if len(groups) == 0:
        return out
    # the points by their groups (a class: the points in the same groups; the groups are whole
    # branches, so a class per branch or fewer): a point is covered from outside a group when a
    # point of a class outside it covers it
    rows = np.ascontiguousarray(np.packbits(members, axis=0).T)  # (N, ceil(G / 8)): each point's groups
    first_of_class, point_class = np.unique(rows.view(np.dtype((np.void, rows.shape[1]))).ravel(), return_index=True,
                                            return_inverse=True)[1:]
    point_class = point_class.ravel()
    outside = (~members[:, first_of_class]).T.astype(np.float32)  # (K, G): the groups each class lies outside
    for v, projection in enumerate(projections):
        i, j, i_in_j, j_in_i = (_overlapping_discs(points, radius, projection, reach_radii) if pairs is None
                                else pairs[v])
        if len(i) == 0:
            continue
        # covering[p, k]: a point of class k covers p's disc; p of a group is covered when a point
        # outside it covers p
        first, second = i_in_j & by[j], j_in_i & by[i]
        covering = np.zeros((len(points), len(first_of_class)), dtype=np.float32)
        covering[i[first], point_class[j[first]]] = 1.0
        covering[j[second], point_class[i[second]]] = 1.0
        by_outside = covering @ outside > 0  # (N, G); sums of a few ones, exact
        out[:, v] = np.count_nonzero(by_outside.T & members, axis=1) / counts
    return out


def prune_explained_branches(tree: VesselTree, projections: Sequence[Projection], share: float,
                             reach_radii: float) -> tuple[VesselTree, int]:
    """Remove, one subtree at a time (the most covered first, of equally covered ones the one with
    the most points), a branch and its descendants when the rest of the tree covers over
    ``share`` of their points in every view (:func:`explained_shares`): they add nothing that any
    view shows (a phantom where two vessels' cones cross, and the phantoms it leads to), while a
    subtree with pixels nothing else explains in some view stays. The root's subtree, the whole
    tree, always stays. Returns the tree and how many branches went."""
    pruned, kept = _explained_pruning(tree, projections, share, reach_radii)
    return pruned, tree.n_branches - len(kept)


def _explained_pruning(tree: VesselTree, projections: Sequence[Projection], share: float,
                       reach_radii: float, pairs: _DiscPairs | None = None) -> tuple[VesselTree, list[int]]:
    """:func:`prune_explained_branches`: the tree, and the indices its branches had in ``tree``.
    ``pairs``: ``tree``'s :class:`_DiscPairs`, told of every branch that goes (searched here when
    not given)."""
    kept = list(range(tree.n_branches))
    if pairs is None:
        pairs = _DiscPairs(tree, projections, reach_radii)  # searched once; branches only go
    while tree.n_branches > 1:
        shares = explained_shares(tree, projections, reach_radii, pairs=pairs.current()).min(axis=1)
        sizes = np.array([sum(tree.branches[b].n_points for b in members) for members in _subtrees(tree)])
        candidates = [b for b in range(1, tree.n_branches) if shares[b] > share]
        if not candidates:
            break
        best = max(candidates, key=lambda b: (shares[b], sizes[b]))  # of equally covered subtrees the largest
        for b in _subtrees(tree)[best][::-1]:  # descendants after their parents: leaves go first
            tree = _without(tree, int(b))
            pairs.without(int(b))
            kept.pop(int(b))
    return tree, kept


def reproduced_points(tree: VesselTree, projections: Sequence[Projection], own_points_mm: Sequence[np.ndarray],
                      nearest_skeleton: Sequence[np.ndarray], tolerance_mm: float) -> np.ndarray:
    """(N,) per point of ``tree.points()``: False where, in some view, the skeleton pixel nearest the
    pixel the point projects into was matched by that view's own matching (``own_points_mm[v]``,
    (P_v, 3), nan where unmatched) to a 3D point farther than ``tolerance_mm`` from it; True
    otherwise (also where the view has no match there, or the point projects outside the image:
    a bridge through the hull, or a stretch the view did not match, is not evidence against it).
    ``nearest_skeleton[v]`` is the view's (rows, cols) map of the nearest skeleton pixel's index
    (-1: none)."""
    return ~_contradicted(tree.points()[0], projections, own_points_mm, nearest_skeleton, tolerance_mm)


def _contradicted(points: np.ndarray, projections: Sequence[Projection], own_points_mm: Sequence[np.ndarray],
                  nearest_skeleton: Sequence[np.ndarray], tolerance_mm: float) -> np.ndarray:
    """(N,) the points that some view's own matching puts elsewhere (:func:`reproduced_points`)."""
    contradicted = np.zeros(len(points), dtype=bool)
    for projection, own, nearest in zip(projections, own_points_mm, nearest_skeleton):
        rows, cols = nearest.shape
        uv = np.rint(projection.project(points)).astype(np.int64)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < cols) & (uv[:, 1] >= 0) & (uv[:, 1] < rows)
        pixel = np.full(len(points), -1, dtype=np.int64)
        pixel[inside] = nearest[uv[inside, 1], uv[inside, 0]]
        known = np.flatnonzero(pixel >= 0)
        gap = np.linalg.norm(own[pixel[known]] - points[known], axis=1)  # nan where unmatched
        contradicted[known[gap > tolerance_mm]] = True
    return contradicted


def prune_unreproduced_branches(tree: VesselTree, projections: Sequence[Projection],
                                own_points_mm: Sequence[np.ndarray], nearest_skeleton: Sequence[np.ndarray], *,
                                tolerance_mm: float, share: float, explained: float,
                                reach_radii: float) -> tuple[VesselTree, int]:
    """Remove, one subtree at a time (the least reproduced first, of equally reproduced ones the
    most covered), a branch and its descendants when less than ``share`` of their points are
    reproduced (:func:`reproduced_points`) and the rest of the tree covers at least ``explained``
    of them in every view (:func:`explained_shares`). A vessel of one view matched to the wrong
    vessel of the other lies where neither view's own matching puts those pixels, and the rest of
    the tree shows the same pixels; a subtree that nothing else explains in some view stays,
    whatever the matchings say. The root's subtree always stays. Returns the tree and how many
    branches went."""
    pruned, kept = _unreproduced_pruning(tree, projections, own_points_mm, nearest_skeleton, tolerance_mm=tolerance_mm,
                                         share=share, explained=explained, reach_radii=reach_radii)
    return pruned, tree.n_branches - len(kept)


def _unreproduced_pruning(tree: VesselTree, projections: Sequence[Projection], own_points_mm: Sequence[np.ndarray],
                          nearest_skeleton: Sequence[np.ndarray], *, tolerance_mm: float, share: float,
                          explained: float, reach_radii: float,
                          pairs: _DiscPairs | None = None) -> tuple[VesselTree, list[int]]:
    """:func:`prune_unreproduced_branches`: the tree, and the indices its branches had in ``tree``.
    ``pairs``: the :class:`_DiscPairs` of a tree that ``tree`` is what is left of (the one before
    :func:`_explained_pruning`, told of what went there), told of every branch that goes here
    (else searched when first needed)."""
    kept = list(range(tree.n_branches))
    while tree.n_branches > 1:
        reproduced = reproduced_points(tree, projections, own_points_mm, nearest_skeleton, tolerance_mm)
        _, _, owner = tree.points()
        subtrees = _subtrees(tree)
        shares = np.array([reproduced[members].mean() for members in _subtree_points(tree, owner)])
        if not (shares[1:] < share).any():
            break  # the coverage is not needed: nothing is unreproduced enough
        if pairs is None:
            pairs = _DiscPairs(tree, projections, reach_radii)
        covered = explained_shares(tree, projections, reach_radii, pairs=pairs.current()).min(axis=1)
        candidates = [b for b in range(1, tree.n_branches) if shares[b] < share and covered[b] >= explained]
        if not candidates:
            break
        worst = min(candidates, key=lambda b: (shares[b], -covered[b]))
        for b in subtrees[worst][::-1]:  # descendants after their parents: leaves go first
            tree = _without(tree, int(b))
            pairs.without(int(b))
            kept.pop(int(b))
    return tree, kept


def restore_uncovered_branches(tree: VesselTree, alive: np.ndarray, removal_cover: np.ndarray,
                               projections: Sequence[Projection], reach_radii: float,
                               pairs: list | None = None) -> tuple[np.ndarray, int]:
    """Put back the pruned branches that what is kept no longer covers as their removal asked.

    A prune removes a subtree for what the rest of the tree covers of it then (the explained rule:
    over 90 % in every view; the unreproduced rule: 30 %); what covered it may go later (a phantom
    that made a true branch look explained, removed by the next rule), leaving pixels that nothing
    kept explains. Of the removed branches whose parent is kept, the one whose subtree (as in
    ``tree``) the kept branches cover least, relative to its ``removal_cover``, comes back when
    that cover (the smallest over the views, :func:`explained_shares`' measure) is below
    ``removal_cover``; its removed children become candidates in turn; until none is below.

    Parameters
    ----------
    tree : VesselTree
        The tree before the prunings.
    alive : (B,) bool array
        The branches the prunings kept (every kept branch's parent kept; the root kept).
    removal_cover : (B,) array
        Per branch, the cover of its subtree at or above which it stays removed (its rule's
        threshold; for a rule that removes above a share, the next float above it).
    projections : sequence of Projection
    reach_radii : float
        :func:`explained_shares`' reach.
    pairs : list, optional
        ``tree``'s disc pairs per view (:meth:`_DiscPairs.whole`), when the prunings searched them.

    Returns
    -------
    alive : (B,) bool array
        The branches kept, those put back included.
    restored : int
        How many came back.
    """
    alive = np.array(alive, dtype=bool)
    removal_cover = np.asarray(removal_cover, dtype=float)
    owner = tree.points()[2]
    subtree_points = _subtree_points(tree, owner)
    if pairs is None:  # the tree stays whole: searched once
        pairs = _DiscPairs(tree, projections, reach_radii).current()
    restored = 0
    while True:
        roots = [b for b in range(1, tree.n_branches) if not alive[b] and alive[tree.branches[b].parent]]
        if not roots:
            break
        covered = _covered_shares(tree, projections, reach_radii, subtree_points[roots],
                                  by=alive[owner], pairs=pairs).min(axis=1)
        below = covered - removal_cover[roots]
        pick = int(np.argmin(below))
        if below[pick] >= 0:
            break
        alive[roots[pick]] = True
        restored += 1
    return alive, restored


def unreproduced_inner_branches(tree: VesselTree, projections: Sequence[Projection],
                                own_points_mm: Sequence[np.ndarray], nearest_skeleton: Sequence[np.ndarray], *,
                                tolerance_mm: float, share: float, explained: float,
                                reach_radii: float, pairs: list | None = None) -> np.ndarray:
    """(N,) per point of ``tree.points()``: it belongs to a branch that carries children (not the
    root) of whose own points less than ``share`` are reproduced (:func:`reproduced_points`) and
    at least ``explained`` are covered in every view by reproduced points of the other branches
    (:func:`explained_shares`' measure; its children count as others). The subtree rule
    (:func:`prune_unreproduced_branches`) weighs a branch with its descendants: a phantom that
    carries a true branch (the views' mismatch ran on into a vessel both show) is reproduced
    enough with it and stays, and the true branch could not go with it. Its points are taken out
    of the tubes like a contradicted stretch; the children are joined again through the hull.
    ``pairs``: the tree's disc pairs per view (:func:`tree_disc_pairs`), when already searched."""
    points, _, owner = tree.points()
    reproduced = reproduced_points(tree, projections, own_points_mm, nearest_skeleton, tolerance_mm)
    carries = np.zeros(tree.n_branches, dtype=bool)
    carries[[b.parent for b in tree.branches[1:]]] = True
    carries[0] = False
    candidates = [b for b in np.flatnonzero(carries) if reproduced[owner == b].mean() < share]
    marked = np.zeros(len(points), dtype=bool)
    if not candidates:
        return marked
    groups = [owner == b for b in candidates]
    covered = _covered_shares(tree, projections, reach_radii, groups, by=reproduced, pairs=pairs).min(axis=1)
    for members, c in zip(groups, covered):
        if c >= explained:
            marked |= members
    return marked


def tree_disc_pairs(tree: VesselTree, projections: Sequence[Projection], reach_radii: float) -> list:
    """:func:`_overlapping_discs` of the tree's points in every view: searched once for the rules
    that read them on one tree (``pairs`` of :func:`covered_points`, :func:`contradicted_stretches`
    and :func:`unreproduced_inner_branches`)."""
    points, radius, _ = tree.points()
    return [_overlapping_discs(points, radius, projection, reach_radii) for projection in projections]


def covered_points(tree: VesselTree, projections: Sequence[Projection], reach_radii: float,
                   apart_mm: float, by: np.ndarray | None = None, pairs: list | None = None) -> np.ndarray:
    """(N,) per point of ``tree.points()``: in every view its projected disc (radius plus half a
    pixel) overlaps the disc of a tree point more than ``apart_mm`` from it in 3D by the measure of
    :func:`explained_shares` (its projection within the other's radius plus ``reach_radii`` of its
    own). The points of its own vessel nearby, and of the branches at its junction, do not count;
    with ``by`` ((N,) bool), only those points cover. ``pairs``: the tree's disc pairs per view
    (:func:`tree_disc_pairs`), when already searched."""
    points, radius, _ = tree.points()
    by = np.ones(len(points), dtype=bool) if by is None else by
    covered = np.ones(len(points), dtype=bool)
    for v, projection in enumerate(projections):
        i, j, i_in_j, j_in_i = (_overlapping_discs(points, radius, projection, reach_radii) if pairs is None
                                else pairs[v])
        apart = np.linalg.norm(points[i] - points[j], axis=1) > apart_mm
        seen = np.zeros(len(points), dtype=bool)
        seen[i[i_in_j & apart & by[j]]] = True
        seen[j[j_in_i & apart & by[i]]] = True
        covered &= seen
    return covered


def contradicted_stretches(tree: VesselTree, projections: Sequence[Projection], own_points_mm: Sequence[np.ndarray],
                           nearest_skeleton: Sequence[np.ndarray], *, tolerance_mm: float, reach_radii: float,
                           apart_mm: float, min_length_mm: float, pairs: list | None = None) -> np.ndarray:
    """(N,) per point of ``tree.points()``: it lies in a run of consecutive points of its branch, at
    least ``min_length_mm`` of arc long, each of which some view's own matching puts elsewhere
    (farther than ``tolerance_mm``, :func:`reproduced_points`) and tree points farther than
    ``apart_mm`` cover in every view (:func:`covered_points`; contradicted ones too): a stretch of
    a vessel of A matched to the wrong vessel of B inside a branch, which no subtree rule can take
    out. A true stretch taken out is joined again through the hull, a phantom one left in stays.
    ``pairs``: the tree's disc pairs per view (:func:`tree_disc_pairs`), when already searched."""
    points, _, _ = tree.points()
    contradicted = _contradicted(points, projections, own_points_mm, nearest_skeleton, tolerance_mm)
    suspect = contradicted & covered_points(tree, projections, reach_radii, apart_mm, pairs=pairs)
    marked = np.zeros(len(points), dtype=bool)
    offset = 0
    for branch in tree.branches:
        run = suspect[offset:offset + branch.n_points]
        arc = branch.arc_length_mm
        edges = np.flatnonzero(np.diff(np.concatenate([[0], run.astype(np.int8), [0]])))
        for first, stop in zip(edges[::2], edges[1::2]):  # runs [first, stop)
            if arc[stop - 1] - arc[first] >= min_length_mm:
                marked[offset + first:offset + stop] = True
        offset += branch.n_points
    return marked


def _tube_segments(tree: VesselTree, keep: np.ndarray | None = None):
    """(starts, ends, start radii, end radii) of the tree's tubes: between neighbouring points of a
    branch and from a child's parent point to its first point; with ``keep`` ((N,) bool over
    ``tree.points()``), only the segments whose two ends are kept."""
    starts, ends, r0, r1 = [], [], [], []
    offset = 0
    for b in tree.branches:
        kept = np.ones(b.n_points, dtype=bool) if keep is None else keep[offset:offset + b.n_points]
        k = np.flatnonzero(kept[:-1] & kept[1:])
        starts.append(b.points_mm[k]), ends.append(b.points_mm[k + 1])
        r0.append(b.radius_mm[k]), r1.append(b.radius_mm[k + 1])
        if b.parent is not None and kept[0]:
            anchor = tree.branches[b.parent].points_mm[b.parent_point]
            starts.append(anchor[None]), ends.append(b.points_mm[:1])
            r0.append(b.radius_mm[:1]), r1.append(b.radius_mm[:1])
        offset += b.n_points
    return tuple(np.concatenate(x) for x in (starts, ends, r0, r1))


def _window_medians(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(M,) the median of ``values[lo[k]:hi[k]]`` for every k (windows not empty), as ``np.median``
    gives it (the middle value, or the mean of the two middle ones), all windows at once."""
    width = hi - lo
    index = lo[:, None] + np.arange(width.max())[None, :]
    window = np.where(index < hi[:, None], values[np.minimum(index, len(values) - 1)], np.inf)
    window.sort(axis=1)  # the padding last
    rows = np.arange(len(lo))
    return (window[rows, (width - 1) // 2] + window[rows, width // 2]) / 2


def without_radius_spikes(tree: VesselTree, window_mm: float, ratio: float) -> VesselTree:
    """The tree with every radius above ``ratio`` times the median of its branch's radii within
    ``window_mm`` of arc either side brought down to that bound. The lumen of the tree method is
    the union of its tubes, and a few points whose cross-sections merged with another vessel's in
    every view (at a junction, at the ostium) would each add a ball several times too wide."""
    branches = []
    for b in tree.branches:
        arc = b.arc_length_mm
        lo = np.searchsorted(arc, arc - window_mm, side="left")
        hi = np.searchsorted(arc, arc + window_mm, side="right")
        radius = np.minimum(b.radius_mm, ratio * _window_medians(b.radius_mm, lo, hi))
        branches.append(Branch(b.points_mm, radius, b.parent, b.parent_point, b.name))
    return VesselTree(tuple(branches))


def tree_lumen_points(tree: VesselTree, lattice: Lattice, margin_mm: float = 0.0) -> np.ndarray:
    """The lattice points inside the tree's tubes (within ``margin_mm`` of them), mm."""
    return lattice_points_in_tubes(*_tube_segments(tree), lattice, margin_mm=margin_mm)


def explaining_points(tree: VesselTree, projection: Projection, pixels_uv: np.ndarray,
                      slack_px: float = 1.0, by: np.ndarray | None = None) -> np.ndarray:
    """(P,) per pixel (``pixels_uv``, (P, 2)): the index in ``tree.points()`` of the nearest tree point
    whose projected disc (its radius at its depth, plus ``slack_px``) holds the pixel, among the 16
    nearest in the image; -1 where none does (nothing in the tree explains that pixel). With ``by``
    ((N,) bool over ``tree.points()``), only those points explain."""
    return _holding(_nearest_discs(tree, projection, pixels_uv), slack_px, by)


def _nearest_discs(tree: VesselTree, projection: Projection, pixels_uv: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel the 16 nearest tree points in the image ((P, k) distances in px and indices), and
    every tree point's projected radius (px): what :func:`explaining_points` reads, searched once
    for several ``by``."""
    pixels_uv = np.asarray(pixels_uv, dtype=float).reshape(-1, 2)
    points, radius, _ = tree.points()
    if len(points) == 0 or len(pixels_uv) == 0:
        return np.zeros((len(pixels_uv), 0)), np.zeros((len(pixels_uv), 0), dtype=np.int64), np.zeros(len(points))
    uv = projection.project(points)
    radius_px = radius * max(projection.focal_lengths_px) / projection.depth_mm(points)
    k = min(16, len(points))
    distance, index = cKDTree(uv).query(pixels_uv, k=k)
    return distance.reshape(len(pixels_uv), k), index.reshape(len(pixels_uv), k), radius_px


def _holding(discs: tuple[np.ndarray, np.ndarray, np.ndarray], slack_px: float,
             by: np.ndarray | None = None) -> np.ndarray:
    """:func:`explaining_points` from :func:`_nearest_discs`' search."""
    distance, index, radius_px = discs
    out = np.full(len(distance), -1, dtype=np.int64)
    if index.shape[1] == 0:
        return out
    if by is not None:
        radius_px = np.where(by, radius_px, -np.inf)
    holds = distance <= radius_px[index] + slack_px
    first = np.argmax(holds, axis=1)
    found = holds.any(axis=1)
    out[found] = index[found, first[found]]
    return out


def redundant_branches(tree: VesselTree, projections: Sequence[Projection], view_pairs: Sequence[tuple[int, int]],
                       share: float, needed_share: float, reach_radii: float) -> list[np.ndarray]:
    """Per (view, other) pair of ``view_pairs``: the indices of the branches whose own points the rest
    of the tree covers (:func:`explained_shares`' measure) at least ``share`` in view ``other`` and
    less than ``needed_share`` in view ``view``: a branch only ``view`` needs (a phantom standing in
    for a vessel there, or the true vessel whose phantom covers it in ``other``). The covers are
    measured once for every pair."""
    owner = tree.points()[2]
    cover = _covered_shares(tree, projections, reach_radii, [owner == k for k in range(tree.n_branches)])
    return [np.flatnonzero((cover[:, other] >= share) & (cover[:, view] < needed_share)) for view, other in view_pairs]
