"""Vessels: the paths along which a tree's diameters and bifurcation arms are read.

A branch of a :class:`~angiohull.tree.VesselTree` is usually one vessel from where it leaves its
parent to its tip. A reconstructed tree sometimes splits a vessel in two: the skeleton's
continuation rule (docs/vessel-tree.md, step 2) looks 3 mm ahead, so where a straight **stub**
(a few radii of hull left where the vessel narrows, bends or meets another) carries on from a
junction, the branch runs into the stub and the vessel itself goes on as a child. On the QCA
benchmark's 60 generated trees reconstructed from 3 views (exact masks), 49 children in 29 trees
left their parent less than 6 mm before the parent's end (in the true trees, only the left main's
two children at its end), several at stenoses, which then lay at the end of a short branch with
nothing healthy beyond them for the reference fit.

The analysis therefore reads the tree as vessels. A branch **continues into** one of its children
when:

* the parent holds no more than ``stub_radii`` times its radius there (or the child's mean radius
  over its first 3 mm, when wider: a lesion at the junction narrows the parent there) past that
  child's junction (the rest of the parent is a stub), and does not end where two or more children begin (a
  bifurcation at the parent's end, as at the end of a left main), and
* among the children in that stub, that child best continues the parent: the largest
  ``cos(turn) + (radius / largest radius) / 2`` over 3 mm (the tree builder's own rule), and
* no child that leaves the parent before the stub carries more of the tree (the length of the
  child and all its descendants): where one does, the parent's own path past that earlier child
  is a second path through a wide vessel, not the vessel's continuation.

A **vessel** is a branch that continues nobody's path, followed by the child it continues into, and
so on: the first branch's points up to the junction of its continuation, then the continuation's
points, and so on to the last branch's end. Each branch belongs to exactly one vessel; a
continued branch's points past the junction (the stub) belong to none. A junction where a branch
continues into its only child there is not a bifurcation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _validation as _v
from ..errors import QcaError
from ..tree import VesselTree
from ..tree.model import point_at_arc

__all__ = ["VesselSettings", "Vessel", "TreeVessels", "tree_vessels"]

_DIRECTION_MM = 3.0  # the tree builder's direction window (docs/vessel-tree.md, step 2)


@dataclass(frozen=True)
class VesselSettings:
    """How a tree is read as vessels (module notes); the same for every tree."""

    stub_radii: float = 4.0  # a parent's part past a child's junction of at most this many radii is a stub

    def __post_init__(self) -> None:
        if not _v.finite(self.stub_radii, "VesselSettings.stub_radii", error=QcaError) >= 0.0:
            raise QcaError(f"VesselSettings.stub_radii must be >= 0, got {self.stub_radii!r}")


@dataclass(frozen=True)
class Vessel:
    """One vessel: pieces of one or more branches read end to end (V samples).

    ``arc_mm`` runs from 0 at the first branch's first point; a branch's point ``i`` that lies on
    the vessel sits at arc ``offsets_mm[k] + arc_i`` with ``k`` its place in ``branches`` and
    ``arc_i`` its arc length along its own branch.
    """

    branches: tuple[int, ...]  # proximal first
    offsets_mm: tuple[float, ...]  # vessel arc length of each branch's first point
    points_mm: np.ndarray  # (V, 3)
    radius_mm: np.ndarray  # (V,)
    arc_mm: np.ndarray  # (V,) increasing
    owner: np.ndarray  # (V,) branch of each sample
    point: np.ndarray  # (V,) index of each sample in its branch

    def offset_of(self, branch: int) -> float:
        return self.offsets_mm[self.branches.index(branch)]


@dataclass(frozen=True)
class TreeVessels:
    """The vessels of a tree and the continuations that join its branches into them."""

    vessels: tuple[Vessel, ...]
    continues_into: dict[int, int]  # parent branch -> the child that continues it
    vessel_of: tuple[int, ...]  # (B,) the vessel each branch belongs to

    def of(self, branch: int) -> Vessel:
        return self.vessels[self.vessel_of[branch]]


def _subtree_lengths(tree: VesselTree) -> list[float]:
    """Length of each branch with all its descendants (parents are listed before children)."""
    total = [b.length_mm for b in tree.branches]
    for i in range(tree.n_branches - 1, 0, -1):
        total[tree.branches[i].parent] += total[i]  # type: ignore[index]
    return total


def _start_radius(branch) -> float:
    """Mean radius of a branch over its first ``_DIRECTION_MM`` (its first point alone when shorter)."""
    near = branch.radius_mm[branch.arc_length_mm <= _DIRECTION_MM]
    return float(near.mean()) if near.size else float(branch.radius_mm[0])


def _continuation(tree: VesselTree, parent: int, children: list[int], subtree: list[float],
                  settings: VesselSettings) -> int | None:
    p = tree.branches[parent]
    arc = p.arc_length_mm
    end = float(arc[-1])
    at = {c: tree.branches[c].parent_point for c in children}
    # the radius there, or the child's own over its first 3 mm when wider (a lesion at the junction
    # narrows the parent there and would shorten the stub it may hold)
    reach = {c: max(float(p.radius_mm[at[c]]), _start_radius(tree.branches[c])) for c in children}
    stub = [c for c in children if end - arc[at[c]] <= settings.stub_radii * reach[c]]
    if not stub:
        return None
    at_end = [c for c in stub if tree.branches[c].parent_point == p.n_points - 1]
    if len(at_end) >= 2:
        return None  # the parent ends where two or more children begin: a bifurcation, no stub
    scores = {}
    for c in stub:
        child = tree.branches[c]
        s0 = float(arc[child.parent_point])
        here = p.points_mm[child.parent_point]
        incoming = here - point_at_arc(p.points_mm, arc, max(s0 - _DIRECTION_MM, 0.0))
        carc = child.arc_length_mm
        outgoing = point_at_arc(child.points_mm, carc, min(_DIRECTION_MM, float(carc[-1]))) - child.points_mm[0]
        norm = float(np.linalg.norm(incoming) * np.linalg.norm(outgoing))
        cosine = float(incoming @ outgoing) / norm if norm > 0 else 0.0
        ahead = child.radius_mm[1:][carc[1:] <= _DIRECTION_MM]
        width = float(ahead.mean()) if ahead.size else float(child.radius_mm[-1])
        scores[c] = (cosine, width)
    widest = max(w for _, w in scores.values())
    best = max(stub, key=lambda c: scores[c][0] + 0.5 * scores[c][1] / widest)
    if any(subtree[c] > subtree[best] for c in children if c not in stub):
        return None
    return best


def tree_vessels(tree: VesselTree, settings: VesselSettings = VesselSettings()) -> TreeVessels:
    """The vessels of ``tree`` (module notes)."""
    children: dict[int, list[int]] = {}
    for i, b in enumerate(tree.branches):
        if b.parent is not None:
            children.setdefault(b.parent, []).append(i)
    subtree = _subtree_lengths(tree)
    continues_into = {}
    for parent, kids in children.items():
        best = _continuation(tree, parent, kids, subtree, settings)
        if best is not None:
            continues_into[parent] = best
    continued = set(continues_into.values())
    vessels = []
    vessel_of = [0] * tree.n_branches
    for head in range(tree.n_branches):
        if head in continued:
            continue
        chain = [head]
        while chain[-1] in continues_into:
            chain.append(continues_into[chain[-1]])
        points, radius, arcs, owner, point, offsets = [], [], [], [], [], []
        offset, last = 0.0, None  # last: the vessel's last point so far (a branch may add none)
        for k, b in enumerate(chain):
            branch = tree.branches[b]
            arc = branch.arc_length_mm
            if k > 0:
                previous = tree.branches[chain[k - 1]]
                offset += float(previous.arc_length_mm[branch.parent_point]) \
                    + float(np.linalg.norm(branch.points_mm[0] - previous.points_mm[branch.parent_point]))
            stop = tree.branches[chain[k + 1]].parent_point + 1 if k + 1 < len(chain) else branch.n_points
            start = 1 if last is not None and np.linalg.norm(branch.points_mm[0] - last) <= 1e-9 else 0
            start = min(start, stop)
            offsets.append(offset)
            points.append(branch.points_mm[start:stop])
            radius.append(branch.radius_mm[start:stop])
            arcs.append(offset + arc[start:stop])
            owner.append(np.full(stop - start, b))
            point.append(np.arange(start, stop))
            if stop > start:
                last = branch.points_mm[stop - 1]
            vessel_of[b] = len(vessels)
        vessels.append(Vessel(tuple(chain), tuple(offsets), np.concatenate(points), np.concatenate(radius),
                              np.concatenate(arcs), np.concatenate(owner), np.concatenate(point)))
    return TreeVessels(tuple(vessels), continues_into, tuple(vessel_of))
