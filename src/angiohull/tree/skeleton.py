"""A vessel tree from the skeleton of a binary volume: graph, gaps, spurs, root and branches.

Input: a one-voxel-wide skeleton (for example scikit-image's 3D ``skeletonize`` of an occupancy
volume) and a radius estimate per voxel (for example the volume's distance transform). Steps:

1. **Graph.** Skeleton voxels are nodes; 26-neighbours are joined by edges of their length
   (1, sqrt 2 or sqrt 3 voxels). Thinning leaves small cycles where branches meet (three or four
   mutually adjacent voxels) and, where the volume has a hole, larger ones; the minimum spanning
   tree with edge weight ``length / (r_a + r_b)`` removes every cycle at its thinnest edge.
2. **Gaps.** The largest connected part (by length) is the tree. Other parts are joined to it
   by a straight edge between their closest voxels when that gap is at most
   ``r_a + r_b + max_gap_voxels`` voxels (the two skeleton ends recede by about a radius each from
   a hole in the volume). A longer gap is bridged by the path a caller's ``bridge`` finds (the
   reconstruction searches the carved hull before refinement, where a vessel piece the refined
   preset dropped is still present); other parts are dropped and counted. With ``join_order``
   ``"nearest"`` (the default) the part that costs least joins next: a straight join costs its
   gap, a bridge its path's length (never less than the gap, so bridges are only sought for the
   parts whose gap is below the best cost found so far), and the gaps are kept up to date as
   parts join (each pending voxel's distance to the tree lowered to the joined part's where
   nearer: exact, voxel coordinates being whole numbers; measuring every pending part again at
   each join took over 15 minutes on a noisy hull of 3 700 parts). With ``"largest"`` the parts
   join largest first, each to the tree as it is then: a
   part whose way to the tree runs through a smaller part not joined yet is bridged the long way
   round (on a generated left tree, the distal circumflex went 72 mm through the hull onto the
   LAD, as the refined hull had dropped a few millimetres of the circumflex twice).
3. **Spurs.** A terminal segment (from a tip to the first junction) whose length is at most
   ``spur_radii`` times the radius at its junction is a bump of the surface, not a vessel: it is
   removed, and the test repeated until no spur is left. The shortest (in junction radii) go
   first: a removal can make its junction a plain point of a longer segment, so within a round a
   spur is left for the next one when an earlier removal changed its junction (or the far end of a
   segment through that junction). Removed all at once, a short wide trunk (a left main) whose
   skeleton has a small bump near the ostium lost the stretch up to the bump as a spur of the
   bump's junction.
4. **Root.** The tip whose first ``root_window_mm`` of segment have the largest mean radius is the
   ostium (the proximal end of a coronary tree is its widest end).
5. **Branches.** From the root, a branch follows the graph; at a junction it continues into the
   outgoing segment that best continues it (the largest ``cos(turn angle) + radius / largest
   radius / 2``, directions and radii over ``direction_window_mm``), and every other outgoing
   segment starts a child branch at the junction voxel (its first point is the parent's point
   there). Branches are listed parents first.

Positions are voxel centres (``origin_mm + spacing_mm * index``); radii are the given estimates
(rounded to 1e-9 voxel). Smoothing, radii from the views and end extension are the caller's
business (:mod:`angiohull.reconstruction.vessel_tree`).

**Ties.** On a voxel grid many candidates tie exactly: edges of one length between voxels of one
radius, gaps of one length, mirror-image continuations at a symmetric fork, radii that are square
roots of whole numbers. Every choice is therefore made in voxel units, on radii, weights, lengths
and scores rounded to ``_TIE_DECIMALS`` decimals, and dot products are written out rather than left
to a linear-algebra library; the tree is then placed in millimetres. In millimetres the ties were
broken by the last bits of the voxel edge, which come from a linear-algebra solve (the cube of
interest) and differ between machines: the same views gave a different tree on another machine or
with another OpenBLAS kernel (119 of 120 generated trees from two views, Dice3D up to 19.5 points
apart; docs/tree-method.md, "Reproducibility").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sparse
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from ..errors import TreeError
from .model import Branch, VesselTree
from .voxels import coordinates, neighbour_edges

__all__ = ["SkeletonSettings", "SkeletonInfo", "tree_from_skeleton", "rerooted"]

_TIE_DECIMALS = 9
"""Decimals (of a voxel, or of a ratio) that the choices between candidates are rounded to (module
notes, "Ties")."""

@dataclass(frozen=True)
class SkeletonSettings:
    """Parameters of :func:`tree_from_skeleton` (module notes)."""

    spur_radii: float = 2.0  # a terminal segment no longer than this many junction radii is a spur
    max_gap_voxels: float = 3.0  # parts are joined across gaps up to r_a + r_b + this many voxels
    root_window_mm: float = 3.0  # the root is the tip with the widest first root_window_mm
    direction_window_mm: float = 3.0  # directions and radii at a junction are taken over this length
    join_order: str = "nearest"  # parts join the tree nearest first, or "largest" first (module notes)

    def __post_init__(self) -> None:
        if self.join_order not in ("nearest", "largest"):
            raise ValueError(f"SkeletonSettings.join_order must be 'nearest' or 'largest', got {self.join_order!r}")


@dataclass
class SkeletonInfo:
    """What :func:`tree_from_skeleton` did."""

    skeleton_voxels: int = 0
    parts: int = 0  # connected parts of the skeleton
    parts_joined: int = 0  # joined to the tree across a gap
    parts_bridged: int = 0  # of those, by a caller's bridge path
    parts_dropped: int = 0  # too far from the tree
    voxels_dropped: int = 0
    length_dropped_mm: float = 0.0  # skeleton length of the parts dropped
    longest_dropped_mm: float = 0.0  # of the longest of them
    spurs_removed: int = 0
    cycles_cut: int = 0  # edges the spanning tree removed
    notes: list[str] = field(default_factory=list)


def _adjacency(n: int, heads: np.ndarray, tails: np.ndarray) -> list[list[int]]:
    neighbours: list[list[int]] = [[] for _ in range(n)]
    for a, b in zip(heads.tolist(), tails.tolist()):
        neighbours[a].append(b)
        neighbours[b].append(a)
    return neighbours


def _segments(neighbours: list[list[int]], alive: np.ndarray) -> list[list[int]]:
    """Paths between nodes whose degree is not 2 (each listed once, from one end to the other)."""
    degree = np.array([len(nb) for nb in neighbours])
    ends = [v for v in np.flatnonzero(alive) if degree[v] != 2]
    seen_edges: set[tuple[int, int]] = set()
    out = []
    for start in ends:
        for first in neighbours[start]:
            if (start, first) in seen_edges:
                continue
            path = [start, first]
            while degree[path[-1]] == 2:
                a, b = neighbours[path[-1]]
                path.append(b if a == path[-2] else a)
            seen_edges.add((path[0], path[1]))
            seen_edges.add((path[-1], path[-2]))
            out.append(path)
    return out


def _path_length(points: np.ndarray, path: list[int]) -> float:
    return float(np.linalg.norm(np.diff(points[path], axis=0), axis=1).sum())


def _window(points: np.ndarray, path: list[int], window: float) -> list[int]:
    """The leading nodes of ``path`` within ``window`` of arc length, in the units of ``points`` (at
    least two)."""
    steps = np.linalg.norm(np.diff(points[path], axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    count = max(2, int(np.searchsorted(arc, window, side="right")))
    return path[:count]


def tree_from_skeleton(skeleton: np.ndarray, radius_mm: np.ndarray, *, origin_mm: np.ndarray, spacing_mm: float,
                       settings: SkeletonSettings = SkeletonSettings(),
                       bridge: Callable[[np.ndarray, np.ndarray], np.ndarray | None] | None = None,
                       ) -> tuple[VesselTree, SkeletonInfo]:
    """The vessel tree of a skeleton (module notes).

    Parameters
    ----------
    skeleton : (X, Y, Z) bool array
        One-voxel-wide skeleton.
    radius_mm : (X, Y, Z) or (N,) float array
        Radius estimate at each voxel, mm (> 0 on the skeleton), or at the N skeleton voxels in
        ``np.argwhere(skeleton)`` order.
    origin_mm : (3,) array
        Centre of voxel (0, 0, 0), mm.
    spacing_mm : float
        Voxel edge, mm.
    settings : SkeletonSettings
    bridge : callable, optional
        ``bridge(part_mm (P, 3), tree_mm (T, 3)) -> (L, 3) array or None``: a path (L >= 2 points,
        mm) from one of the part's voxels to one of the tree's across a gap longer than the
        small-gap rule, or None where there is none (for example: the shortest path through a
        wider hull). Without it, such parts are dropped.

    Returns
    -------
    tree : VesselTree
    info : SkeletonInfo

    Raises
    ------
    TreeError
        If the skeleton has fewer than two voxels (no branch can be built).
    """
    skeleton = np.asarray(skeleton, dtype=bool)
    if skeleton.ndim != 3:
        raise TreeError(f"skeleton must be a 3D bool array, got shape {skeleton.shape}")
    voxels = coordinates(skeleton)
    info = SkeletonInfo(skeleton_voxels=len(voxels))
    if len(voxels) < 2:
        raise TreeError(f"the skeleton has {len(voxels)} voxel(s); a vessel tree needs at least two")
    radius = np.asarray(radius_mm, dtype=np.float64)
    if radius.shape == skeleton.shape:
        radius = radius[tuple(voxels.T)]
    elif radius.shape != (len(voxels),):
        raise TreeError(f"radius_mm must have the skeleton's shape {skeleton.shape} or one value per skeleton "
                        f"voxel ({len(voxels)},), got shape {radius.shape}")
    # every choice below is made in voxel units, on rounded values (module notes, "Ties")
    spacing_mm = float(spacing_mm)
    origin_mm = np.asarray(origin_mm, dtype=np.float64)
    points = voxels.astype(np.float64)  # voxel units until the branches are built
    radius = np.maximum(np.round(radius / spacing_mm, _TIE_DECIMALS), 0.5)
    n = len(voxels)

    # 1. graph and spanning tree
    heads, tails, lengths = neighbour_edges(voxels, skeleton.shape)
    weights = np.round(lengths / (radius[heads] + radius[tails]), _TIE_DECIMALS)
    graph = sparse.coo_matrix((weights, (heads, tails)), shape=(n, n)).tocsr()
    spanning = minimum_spanning_tree(graph).tocoo()
    info.cycles_cut = int(len(heads) - spanning.nnz)
    heads, tails = spanning.row.astype(np.int64), spanning.col.astype(np.int64)
    edge_length = np.linalg.norm(points[heads] - points[tails], axis=1)

    # 2. parts, joined across small gaps
    count, part = connected_components(sparse.coo_matrix((np.ones(len(heads)), (heads, tails)), shape=(n, n)),
                                       directed=False)
    info.parts = int(count)
    # (float even without edges: NumPy's bincount of nothing is int64, weights or not)
    part_length = np.round(np.bincount(part[heads], weights=edge_length, minlength=count).astype(np.float64),
                           _TIE_DECIMALS)
    part_length += 1e-9 * np.bincount(part, minlength=count)  # single voxels: order by size
    order = np.argsort(-part_length, kind="stable")
    alive = part == order[0]
    extra_heads, extra_tails = [], []
    extra_points: list[np.ndarray] = []
    extra_radius: list[np.ndarray] = []
    pending = {int(p): np.flatnonzero(part == p) for p in order[1:]}
    dropped: list[tuple[int, np.ndarray]] = []
    reach = settings.max_gap_voxels
    nearest_first = settings.join_order != "largest"
    if nearest_first and pending:
        # every pending voxel's distance to the tree, kept up to date as parts join (a join only
        # brings the tree nearer); exact, as the KD-tree's: voxel coordinates are whole numbers, so
        # squared distances are too. Before, every join queried every pending part again: on a
        # noisy hull of thousands of parts that took over 15 minutes.
        waiting = np.concatenate(list(pending.values()))
        sizes = np.array([len(m) for m in pending.values()])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        group = np.repeat(np.arange(len(sizes)), sizes)  # each waiting voxel's part, as an index
        group_part = np.fromiter(pending.keys(), dtype=np.int64, count=len(pending))
        group_of = {int(q): g for g, q in enumerate(group_part)}
        open_group = np.ones(len(sizes), dtype=bool)
        to_tree = cKDTree(points[np.flatnonzero(alive[:n])]).query(points[waiting])[0]
    while pending:
        # the part nearest to the tree joins first (joining the largest first, a part whose gap to
        # the tree's vessel lies in a smaller part not joined yet went the long way round through
        # the support hull, onto another vessel); a bridge costs its path's length, at least the gap
        kept = np.flatnonzero(alive[:n])
        kept_tree = cKDTree(points[kept])
        if nearest_first:  # by (gap, part)
            gaps = _nearest_gaps(to_tree, waiting, starts, group, group_part, open_group)
        else:  # the largest part still pending, whatever its gap
            first = next(p for p in order[1:].tolist() if p in pending)
            distance, nearest = kept_tree.query(points[pending[first]])
            i = int(np.argmin(distance))
            gaps = [(float(distance[i]), first, pending[first][i], kept[nearest[i]])]
        best = None  # (cost, part, a, b, inner path or None)
        for gap, p, a, b in gaps:
            if best is not None and gap >= best[0]:
                break
            if b is None:  # a's nearest tree voxel, as the KD-tree of the tree's voxels gives it
                b = int(kept[kept_tree.query(points[a])[1]])
            if gap <= radius[a] + radius[b] + reach:
                best = (gap, p, a, b, None)
                break  # a straight join costs its gap, the least of what is left
            path = None if bridge is None else bridge(origin_mm + spacing_mm * points[pending[p]],
                                                      origin_mm + spacing_mm * points[kept])
            if path is None or len(path) < 2:
                continue
            path = (np.asarray(path, dtype=np.float64) - origin_mm) / spacing_mm
            length = round(float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()), _TIE_DECIMALS)
            if best is None or length < best[0]:
                members = pending[p]
                a = members[int(np.argmin(np.linalg.norm(points[members] - path[0], axis=1)))]
                b = kept[int(np.argmin(np.linalg.norm(points[kept] - path[-1], axis=1)))]
                best = (length, p, a, b, path[1:-1])
        if best is None:
            if not nearest_first and len(pending) > 1:
                dropped.append((first, pending.pop(first)))  # out of reach; the next largest may join
                continue
            break
        _, p, a, b, inner = best
        if inner is None:
            extra_heads.append(a)
            extra_tails.append(b)
        else:
            first = n + sum(len(x) for x in extra_points)
            chain = [a, *range(first, first + len(inner)), b]
            extra_points.append(inner)
            extra_radius.append(np.interp(np.arange(1, len(inner) + 1), [0, len(inner) + 1], [radius[a], radius[b]]))
            extra_heads.extend(chain[:-1])
            extra_tails.extend(chain[1:])
            info.parts_bridged += 1
        joined = pending.pop(p)
        alive[joined] = True
        info.parts_joined += 1
        if nearest_first and pending:
            g = group_of[p]
            open_group[g] = False
            to_tree = _nearer(to_tree, points[waiting], points[joined])
            to_tree[starts[g]:starts[g] + len(joined)] = np.inf
    for p, members in [*dropped, *pending.items()]:  # out of reach of the tree
        info.parts_dropped += 1
        info.voxels_dropped += len(members)
        info.length_dropped_mm += float(part_length[p]) * spacing_mm
        info.longest_dropped_mm = max(info.longest_dropped_mm, float(part_length[p]) * spacing_mm)
    if extra_points:
        added = sum(len(x) for x in extra_points)
        points = np.vstack([points, *extra_points])
        radius = np.concatenate([radius, *extra_radius])
        alive = np.concatenate([alive, np.ones(added, dtype=bool)])
        n += added
    heads = np.concatenate([heads, np.array(extra_heads, dtype=np.int64)])
    tails = np.concatenate([tails, np.array(extra_tails, dtype=np.int64)])
    keep = alive[heads] & alive[tails]
    neighbours = _adjacency(n, heads[keep], tails[keep])
    if int(alive.sum()) < 2:
        raise TreeError("the skeleton's largest part is a single voxel; a vessel tree needs at least two")

    # 3. spurs, the shortest (in junction radii) first: a removal can make its junction a plain
    # point, and a segment through it longer than a spur, so a spur at a junction that a removal
    # changed (or at the far end of a segment through that junction) waits for the next round
    while True:
        segments = _segments(neighbours, alive)
        degree = np.array([len(nb) for nb in neighbours])
        spurs = []
        through: dict[int, list[int]] = {}  # junction -> the far ends of the segments that meet there
        for path in segments:
            through.setdefault(path[0], []).append(path[-1])
            through.setdefault(path[-1], []).append(path[0])
            tip_first = degree[path[0]] == 1 and degree[path[-1]] >= 3
            tip_last = degree[path[-1]] == 1 and degree[path[0]] >= 3
            if not (tip_first or tip_last):
                continue
            junction = path[-1] if tip_first else path[0]
            ratio = round(_path_length(points, path) / radius[junction], _TIE_DECIMALS)
            if ratio <= settings.spur_radii:
                spurs.append((ratio, junction, path[:-1] if tip_first else path[1:]))
        if not spurs:
            break
        changed: set[int] = set()
        for _, junction, inner in sorted(spurs, key=lambda s: s[0]):
            if junction in changed:
                continue
            changed.add(junction)
            changed.update(through[junction])
            for v in inner:
                for w in neighbours[v]:
                    neighbours[w].remove(v)
                neighbours[v] = []
                alive[v] = False
            info.spurs_removed += 1

    # 4. root: the widest tip
    degree = np.array([len(nb) for nb in neighbours])
    segments = _segments(neighbours, alive)
    tips = []
    for path in segments:
        for oriented in (path, path[::-1]):
            if degree[oriented[0]] == 1:
                window = _window(points, oriented, settings.root_window_mm / spacing_mm)
                tips.append((round(float(radius[window].mean()), _TIE_DECIMALS), oriented[0]))
    if tips:
        root = max(tips)[1]
    else:  # a closed loop cannot survive the spanning tree; a lone point has no tip
        root = int(np.flatnonzero(alive)[0])

    # 5. branches, parents first (in voxel units, then placed in millimetres)
    tree = _branches_from(points, radius, neighbours, root, settings.direction_window_mm / spacing_mm, 1.0)
    return VesselTree(tuple(Branch(origin_mm + spacing_mm * b.points_mm, spacing_mm * b.radius_mm, b.parent,
                                   b.parent_point, b.name) for b in tree.branches)), info


def _nearest_gaps(to_tree: np.ndarray, waiting: np.ndarray, starts: np.ndarray, group: np.ndarray,
                  group_part: np.ndarray, open_group: np.ndarray):
    """``(gap, part, a, None)`` of every pending part (``open_group``) by gap, then part: its least
    distance to the tree and its first voxel at that distance (``a``, in voxel order), lazily (the
    loop stops at the first straight join); ``a``'s nearest tree voxel is found when needed."""
    least = np.minimum.reduceat(to_tree, starts)
    hits = np.flatnonzero(to_tree == least[group])
    first_group, first_hit = np.unique(group[hits], return_index=True)
    first_voxel = np.zeros(len(starts), dtype=np.int64)
    first_voxel[first_group] = waiting[hits[first_hit]]
    candidates = np.flatnonzero(open_group)
    ordered = candidates[np.lexsort((group_part[candidates], least[candidates]))]
    return ((float(least[g]), int(group_part[g]), int(first_voxel[g]), None) for g in ordered)


def _nearer(distance: np.ndarray, queries: np.ndarray, added: np.ndarray) -> np.ndarray:
    """``distance`` lowered to each query point's distance to the ``added`` points where nearer."""
    if len(added) <= 32:
        squared = np.full(len(queries), np.inf)
        for point in added:
            squared = np.minimum(squared, ((queries - point) ** 2).sum(axis=1))
        return np.minimum(distance, np.sqrt(squared))
    return np.minimum(distance, cKDTree(added).query(queries)[0])


def _branches_from(points: np.ndarray, radius: np.ndarray, neighbours: list[list[int]], root: int,
                   window: float, spacing: float, went_on: dict[tuple[int, int], int] | None = None) -> VesselTree:
    """The tree of a graph without cycles, from ``root`` (module notes, step 5); ``window`` (the
    continuation's) and ``spacing`` (between neighbouring nodes) in the units of ``points``: voxels
    from :func:`tree_from_skeleton`, mm from :func:`rerooted`. ``went_on``: where a path from a
    node through the next went on before, kept unless a better continuation is at least as wide."""
    n = len(points)
    ahead_nodes = int(np.ceil(window / spacing)) + 2
    branches: list[Branch] = []
    queue: deque[tuple[list[int], int | None, int | None]] = deque([([root], None, None)])
    visited = np.zeros(n, dtype=bool)
    visited[root] = True
    while queue:
        path, parent, parent_point = queue.popleft()
        own = len(branches)
        branches.append(None)  # type: ignore[arg-type]  # placeholder, filled below
        while True:
            here = path[-1]
            onward = [w for w in neighbours[here] if not visited[w]]
            if not onward:
                break
            if len(onward) == 1:
                nxt = onward[0]
            else:
                before = None if went_on is None else went_on.get((path[-2] if len(path) >= 2 else -1, here))
                nxt = _continuation(points, radius, neighbours, visited, path, onward, window, ahead_nodes, before)
                for w in onward:
                    if w != nxt:
                        visited[w] = True
                        queue.append(([here, w], own, len(path) - 1))
            visited[nxt] = True
            path.append(nxt)
        if len(path) < 2:
            if parent is None:
                raise TreeError("the skeleton's tree has a single voxel; a vessel tree needs at least two")
            continue
        branches[own] = Branch(points[path], radius[path], parent, parent_point, f"b{own}")
    kept = [b for b in branches if b is not None]
    if len(kept) != len(branches):  # pragma: no cover - a child always has its first step
        raise TreeError("internal: a branch of the skeleton's tree was empty")
    return VesselTree(tuple(kept))


def rerooted(tree: VesselTree, branch: int, point: int, *, window_mm: float = 3.0,
             narrower: bool = True) -> VesselTree:
    """The same points and radii as a tree rooted at point ``point`` of branch ``branch``.

    The tree's points become a graph (consecutive points of a branch, and each child's first point
    with its parent point, merged where they coincide); its branches are then traced again from
    the new root as in step 5 of the module notes (at a junction, and at an interior root, a
    branch continues into the neighbour that best continues it, judged over ``window_mm``; the
    others start children). Without ``narrower``, a junction where the tree's branch went on keeps
    that continuation unless the better one is at least as wide (its mean radius over the window).
    Branch names are ``b0, b1, ...`` in the new order.
    """
    offsets = np.concatenate([[0], np.cumsum([b.n_points for b in tree.branches])]).astype(np.int64)
    points, radius, _ = tree.points()
    node = np.arange(len(points))
    for i, b in enumerate(tree.branches):
        if b.parent is not None:
            anchor = offsets[b.parent] + b.parent_point
            if np.linalg.norm(points[offsets[i]] - points[anchor]) <= 1e-9:
                node[offsets[i]] = node[anchor]
    neighbours: list[list[int]] = [[] for _ in range(len(points))]

    def join(u: int, v: int) -> None:
        u, v = int(node[u]), int(node[v])
        if u != v and v not in neighbours[u]:
            neighbours[u].append(v)
            neighbours[v].append(u)

    steps = []
    for i, b in enumerate(tree.branches):
        for k in range(offsets[i], offsets[i + 1] - 1):
            join(k, k + 1)
        steps.append(np.linalg.norm(np.diff(b.points_mm, axis=0), axis=1))
        if b.parent is not None:
            join(offsets[b.parent] + b.parent_point, offsets[i])
    spacing = float(np.median(np.concatenate(steps))) if steps else 1.0
    root = int(node[offsets[branch] + point])
    went_on = None
    if not narrower:  # where each branch went on: (a, b) -> c for its consecutive points a, b, c, either way
        went_on = {}
        for i, b in enumerate(tree.branches):
            ids = node[offsets[i]:offsets[i + 1]]
            for a, here, c in zip(ids[:-2], ids[1:-1], ids[2:]):
                went_on[(int(a), int(here))] = int(c)
                went_on[(int(c), int(here))] = int(a)
        if point + 1 < tree.branches[branch].n_points:  # from the root: where its branch went
            went_on[(-1, root)] = int(node[offsets[branch] + point + 1])
    return _branches_from(points, radius, neighbours, root, window_mm, spacing, went_on)


def _follow(neighbours: list[list[int]], visited: np.ndarray, start: int, first: int, nodes: int) -> list[int]:
    """Up to ``nodes`` nodes from ``start`` through ``first`` along unvisited nodes (first choice at
    junctions): enough to estimate a direction."""
    path = [start, first]
    while len(path) < nodes:
        onward = [w for w in neighbours[path[-1]] if w != path[-2] and not visited[w]]
        if not onward:
            break
        path.append(onward[0])
    return path


def _continuation(points: np.ndarray, radius: np.ndarray, neighbours: list[list[int]], visited: np.ndarray,
                  path: list[int], onward: list[int], window: float, nodes: int, before: int | None = None) -> int:
    """The outgoing neighbour that best continues ``path`` (module notes, step 5); ``before``, one
    of ``onward``, is kept unless the best is at least as wide (:func:`rerooted`)."""
    here = path[-1]
    back = _window(points, path[::-1], window)
    incoming = points[here] - points[back[-1]]
    scores = []
    widths = []
    directions = []
    for w in onward:
        ahead = _window(points, _follow(neighbours, visited, here, w, nodes), window)
        directions.append(points[ahead[-1]] - points[here])
        widths.append(float(radius[ahead[1:]].mean()))
    widest = max(widths)
    for direction, width in zip(directions, widths):
        # written out, not ``@``: a linear-algebra library's dot product may round differently
        # from machine to machine, and mirror-image continuations tie (module notes, "Ties")
        norm = math.sqrt(_dot3(incoming, incoming) * _dot3(direction, direction))
        cosine = _dot3(incoming, direction) / norm if norm > 0 else 0.0
        scores.append(round(cosine + 0.5 * width / widest, _TIE_DECIMALS))
    best = int(np.argmax(scores))
    if before in onward and (widths[best] < widths[onward.index(before)] or len(path) < 2):
        return before  # (at the root there is no way in to continue: where the tree went)
    return onward[best]


def _dot3(a: np.ndarray, b: np.ndarray) -> float:
    """The dot product of two 3-vectors in plain floating point (the same on every machine)."""
    return float(a[0]) * float(b[0]) + float(a[1]) * float(b[1]) + float(a[2]) * float(b[2])
