"""The vessel tree: ordered centerlines with radii and their topology (docs/conventions.md, "The vessel tree").

Notation: a tree has B branches; branch ``b`` has ``M_b >= 2`` points ``points_mm[b]`` (mm, DICOM
patient frame, listed from the proximal end) with a lumen radius ``radius_mm[b]`` (mm, > 0) per
point. Branch 0 is the root: it starts at the ostium. Every other branch ``b`` has a parent
``p < b`` and leaves it at the parent's point ``parent_point`` (an index into the parent's points);
its own first point is where it starts (for a built tree: that very point). A *bifurcation* is a
parent point that one or more branches leave from; bifurcations are derived from the topology and
never stored.

Listing parents before their children is the one canonical order: it makes every valid tree
acyclic with exactly one root, and it is the order SWC files need. :meth:`VesselTree.reordered`
brings any rooted list of branches into it.

The solid of a tree (its lumen) is the union over every branch segment ``(i, i + 1)`` of the closed
capsule of radius ``(r_i + r_{i+1}) / 2`` around that segment, as for the synthetic tubes
(:mod:`angiohull.synthetic.phantom`), plus, for a branch whose first point is not on its parent's
point, the capsule from that parent point to the branch's first point with the branch's first
radius. :meth:`VesselTree.capsules` lists them.
"""

from __future__ import annotations

import copy

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .. import _validation as _v
from ..errors import TreeError

__all__ = ["Branch", "VesselTree", "Bifurcation", "TREE_JSON_FORMAT", "arc_length_mm", "point_at_arc"]

TREE_JSON_FORMAT = "angiohull-vessel-tree"
"""The ``format`` field of :meth:`VesselTree.to_dict` (``tree.json``)."""
_TREE_JSON_VERSION = 1


def _float_array(value: Any, shape_text: str, name: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise TreeError(f"{name} must be {shape_text}, got {type(value).__name__}") from None


@dataclass(frozen=True, eq=False)
class Branch:
    """One vessel of a tree: an ordered polyline with a radius per point.

    Parameters
    ----------
    points_mm : array_like, shape (M, 3)
        Centerline points, mm, from the proximal end; ``M >= 2`` and no two consecutive points equal.
    radius_mm : array_like, shape (M,) or scalar
        Lumen radius at each point, mm, finite and > 0 (a scalar applies to every point).
    parent : int or None
        Index of the parent branch in the tree (None for the root).
    parent_point : int or None
        Index of the parent's point where this branch leaves it (None for the root).
    name : str
        A label ("RCA", "conus", "b3", ...).

    Arrays are stored as read-only float64 copies; equality is identity, as for arrays.

    Raises
    ------
    TreeError
        If a shape is wrong, a value is not finite, a radius is not > 0, two consecutive points are
        equal, or only one of ``parent`` and ``parent_point`` is given.
    """

    points_mm: np.ndarray  # (M, 3) centerline points, mm, proximal first
    radius_mm: np.ndarray  # (M,) lumen radius per point, mm, > 0
    parent: int | None = None  # parent branch index; None for the root
    parent_point: int | None = None  # index of the parent's point this branch leaves from
    name: str = ""

    def __post_init__(self) -> None:
        label = f"branch {self.name!r}" if self.name else "branch"
        points = _float_array(self.points_mm, "an (M, 3) array of x, y, z in mm", f"{label}: points_mm")
        if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] < 2:
            raise TreeError(f"{label}: points_mm must be an (M, 3) array of x, y, z in mm with M >= 2, "
                            f"got shape {points.shape}")
        if not np.isfinite(points).all():
            bad = int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])
            raise TreeError(f"{label}: points_mm[{bad}] is not finite ({points[bad].tolist()})")
        steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
        if not (steps > 0).all():
            bad = int(np.flatnonzero(steps <= 0)[0])
            raise TreeError(f"{label}: points {bad} and {bad + 1} are equal ({points[bad].tolist()}); "
                            f"a centerline needs distinct consecutive points (drop the duplicate)")
        radius = _float_array(self.radius_mm, f"{points.shape[0]} radii in mm", f"{label}: radius_mm")
        if radius.ndim == 0:
            radius = np.full(points.shape[0], float(radius))
        if radius.shape != (points.shape[0],):
            raise TreeError(f"{label}: radius_mm must hold one radius per point, shape ({points.shape[0]},), "
                            f"got shape {radius.shape}")
        good = np.isfinite(radius) & (radius > 0)
        if not good.all():
            bad = int(np.flatnonzero(~good)[0])
            raise TreeError(f"{label}: radius_mm[{bad}] = {float(radius[bad])!r}; radii must be finite and > 0 mm")
        if (self.parent is None) != (self.parent_point is None):
            raise TreeError(f"{label}: give both parent and parent_point (a side branch) or neither (the root), "
                            f"got parent={self.parent!r}, parent_point={self.parent_point!r}")
        for key in ("parent", "parent_point"):
            value = getattr(self, key)
            if value is not None:
                if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 0:
                    raise TreeError(f"{label}: {key} must be an index >= 0 or None, got {value!r}")
                object.__setattr__(self, key, int(value))
        if not isinstance(self.name, str):
            raise TreeError(f"branch name must be a str, got {self.name!r}")
        object.__setattr__(self, "points_mm", _v.readonly_copy(points))
        object.__setattr__(self, "radius_mm", _v.readonly_copy(radius))

    def _with_parent(self, parent: int | None) -> "Branch":
        """This branch under another parent index (``None`` only for a root; the parent point
        kept): for the edits that only renumber a tree's branches. Its arrays, checked and
        read-only already, are shared, not checked and copied again."""
        out = copy.copy(self)  # every field, the arrays shared (a field added later comes along)
        object.__setattr__(out, "parent", None if parent is None else int(parent))
        return out

    @property
    def n_points(self) -> int:
        """M, the number of centerline points."""
        return int(self.points_mm.shape[0])

    @property
    def arc_length_mm(self) -> np.ndarray:
        """(M,) arc length of each point from the branch's first point, mm (0 first)."""
        return arc_length_mm(self.points_mm)

    @property
    def length_mm(self) -> float:
        """Length of the polyline, mm."""
        return float(np.linalg.norm(np.diff(self.points_mm, axis=0), axis=1).sum())

    def tangents(self) -> np.ndarray:
        """(M, 3) unit tangents: central differences in arc length inside, one-sided at the ends."""
        gradient = np.gradient(self.points_mm, self.arc_length_mm, axis=0)
        return gradient / np.linalg.norm(gradient, axis=1, keepdims=True)

    def resampled(self, step_mm: float) -> "Branch":
        """The branch with points every ``step_mm`` or less of arc length (the ends kept; evenly
        spaced, ``ceil(length / step)`` steps), positions and radii interpolated linearly.

        ``parent_point`` is not remapped here (see :meth:`VesselTree.resampled`).
        """
        arc = self.arc_length_mm
        s = np.linspace(0.0, arc[-1], _steps(arc[-1], step_mm) + 1)
        points = np.column_stack([np.interp(s, arc, self.points_mm[:, k]) for k in range(3)])
        return Branch(points, np.interp(s, arc, self.radius_mm), self.parent, self.parent_point, self.name)

    def __repr__(self) -> str:
        where = "root" if self.parent is None else f"parent={self.parent} at point {self.parent_point}"
        return (f"Branch({self.name!r}, {self.n_points} points, {self.length_mm:.1f} mm, radius "
                f"{self.radius_mm.min():.2f}-{self.radius_mm.max():.2f} mm, {where})")


def arc_length_mm(points_mm: np.ndarray) -> np.ndarray:
    """(M,) arc length of each point of a polyline (M, 3) from its first point, mm (0 first)."""
    steps = np.linalg.norm(np.diff(np.asarray(points_mm, dtype=np.float64), axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def point_at_arc(points_mm: np.ndarray, arc_mm: np.ndarray, at_mm: float) -> np.ndarray:
    """The point at arc length ``at_mm`` of the polyline ``points_mm`` ((M, 3); ``arc_mm`` its
    increasing arc lengths), interpolated linearly; clamped to the ends outside ``arc_mm``."""
    return np.array([np.interp(at_mm, arc_mm, points_mm[:, k]) for k in range(3)])


MAX_RESAMPLED_POINTS = 10_000_000
"""A branch resampled to more points than this is refused (a step far below any vessel's scale)."""


def _steps(length_mm: float, step_mm: float) -> int:
    step = _v.positive_finite(step_mm, "step_mm", error=TreeError)
    steps = max(1, int(np.ceil(length_mm / step - 1e-9)))
    if steps > MAX_RESAMPLED_POINTS:
        raise TreeError(f"a step of {step:g} mm cuts a branch of {length_mm:.1f} mm into {steps:,} pieces, more than "
                        f"{MAX_RESAMPLED_POINTS:,}; use a larger step_mm")
    return steps


@dataclass(frozen=True)
class Bifurcation:
    """A point of a branch that other branches leave from (derived from the topology)."""

    parent: int  # index of the branch that carries the point
    parent_point: int  # index of the point on it
    children: tuple[int, ...]  # branches that leave there, in tree order
    position_mm: tuple[float, float, float]  # the parent's point, mm


@dataclass(frozen=True, eq=False)
class VesselTree:
    """A tree of vessels (see the module notes for the notation and the canonical order).

    Parameters
    ----------
    branches : sequence of Branch
        At least one. ``branches[0]`` is the root (``parent is None``); every other branch ``b`` has
        ``parent < b`` and ``parent_point`` a valid index of the parent's points.

    Raises
    ------
    TreeError
        If there is no branch, the first is not the only root, a parent is not listed before its
        child, or a parent point does not exist.
    """

    branches: tuple[Branch, ...]

    def __post_init__(self) -> None:
        if isinstance(self.branches, Branch):
            raise TreeError("VesselTree.branches must be a sequence of Branch, got a single Branch; wrap it: (branch,)")
        try:
            branches = tuple(self.branches)
        except TypeError:
            raise TreeError(f"VesselTree.branches must be a sequence of Branch, got {type(self.branches).__name__}") from None
        if not branches:
            raise TreeError("a vessel tree needs at least one branch, got none")
        for b, branch in enumerate(branches):
            if not isinstance(branch, Branch):
                raise TreeError(f"VesselTree.branches[{b}] must be a Branch, got {type(branch).__name__}")
        if branches[0].parent is not None:
            raise TreeError(f"branches[0] must be the root (parent None), got parent={branches[0].parent}; "
                            f"list the root first (VesselTree.reordered does this)")
        for b, branch in enumerate(branches[1:], start=1):
            if branch.parent is None:
                raise TreeError(f"branches[{b}] ({branch.name!r}) has no parent, but the tree already has a root "
                                f"(branches[0]); a tree has exactly one root")
            if branch.parent >= b:
                raise TreeError(f"branches[{b}] ({branch.name!r}) has parent {branch.parent}, which is not listed "
                                f"before it; parents come first (a cycle or an unordered list: see VesselTree.reordered)")
            parent = branches[branch.parent]
            if branch.parent_point >= parent.n_points:
                raise TreeError(f"branches[{b}] ({branch.name!r}) leaves its parent {branch.parent} at point "
                                f"{branch.parent_point}, but the parent has {parent.n_points} points")
        object.__setattr__(self, "branches", branches)

    # -- construction ----------------------------------------------------------------------------
    @classmethod
    def reordered(cls, branches: Sequence[Branch]) -> "VesselTree":
        """A tree from branches in any order whose parents index ``branches`` itself: exactly one
        root, no cycle. Returns them parents first (breadth-first from the root, children in their
        given order), with the parent indices renumbered.

        Raises
        ------
        TreeError
            If there is not exactly one root, a parent index does not exist, or parents form a
            cycle (a branch that cannot be reached from the root).
        """
        branches = list(branches)
        roots = [i for i, b in enumerate(branches) if b.parent is None]
        if len(roots) != 1:
            raise TreeError(f"a tree has exactly one root (a branch without parent), got {len(roots)}: {roots}")
        children: dict[int, list[int]] = {i: [] for i in range(len(branches))}
        for i, b in enumerate(branches):
            if b.parent is not None:
                if b.parent >= len(branches):
                    raise TreeError(f"branch {i} ({b.name!r}) has parent {b.parent}, but there are {len(branches)} branches")
                children[b.parent].append(i)
        order = [roots[0]]
        for i in order:
            order.extend(children[i])
        if len(order) != len(branches):
            lost = sorted(set(range(len(branches))) - set(order))
            raise TreeError(f"branches {lost} cannot be reached from the root: their parents form a cycle")
        new_index = {old: new for new, old in enumerate(order)}
        out = []
        for old in order:
            b = branches[old]
            parent = None if b.parent is None else new_index[b.parent]
            out.append(Branch(b.points_mm, b.radius_mm, parent, b.parent_point, b.name))
        return cls(tuple(out))

    @classmethod
    def attached_to_nearest(cls, polylines: Sequence[np.ndarray], radii: Sequence[np.ndarray],
                            names: Sequence[str] | None = None) -> "VesselTree":
        """A tree from polylines without topology (e.g. the authors' ``gt_centerlines.npy``): the
        first is the root, and each later one leaves the point, among the points of the branches
        before it, nearest to its own first point."""
        if len(polylines) != len(radii):
            raise TreeError(f"got {len(polylines)} polylines but {len(radii)} radius arrays")
        names = list(names) if names is not None else [f"b{i}" for i in range(len(polylines))]
        branches: list[Branch] = []
        for i, (points, radius) in enumerate(zip(polylines, radii)):
            if i == 0:
                branches.append(Branch(points, radius, None, None, names[i]))
                continue
            start = np.asarray(points, dtype=np.float64)[0]
            best = min(((float(np.linalg.norm(b.points_mm - start, axis=1).min()), j) for j, b in enumerate(branches)))
            j = best[1]
            k = int(np.argmin(np.linalg.norm(branches[j].points_mm - start, axis=1)))
            branches.append(Branch(points, radius, j, k, names[i]))
        return cls(tuple(branches))

    # -- topology -------------------------------------------------------------------------------
    @property
    def n_branches(self) -> int:
        return len(self.branches)

    @property
    def root(self) -> Branch:
        return self.branches[0]

    def children(self, branch: int) -> tuple[int, ...]:
        """Indices of the branches whose parent is ``branch``, in tree order."""
        return tuple(i for i, b in enumerate(self.branches) if b.parent == branch)

    @property
    def bifurcations(self) -> tuple[Bifurcation, ...]:
        """One per parent point that branches leave from, ordered by (parent, point)."""
        groups: dict[tuple[int, int], list[int]] = {}
        for i, b in enumerate(self.branches[1:], start=1):
            groups.setdefault((b.parent, b.parent_point), []).append(i)
        out = []
        for (parent, point), kids in sorted(groups.items()):
            position = self.branches[parent].points_mm[point]
            out.append(Bifurcation(parent, point, tuple(kids), tuple(float(x) for x in position)))
        return tuple(out)

    @property
    def bifurcation_points_mm(self) -> np.ndarray:
        """(J, 3) positions of the bifurcations, mm."""
        bifurcations = self.bifurcations
        if not bifurcations:
            return np.zeros((0, 3))
        return np.array([b.position_mm for b in bifurcations])

    # -- geometry -------------------------------------------------------------------------------
    @property
    def n_points(self) -> int:
        return sum(b.n_points for b in self.branches)

    @property
    def length_mm(self) -> float:
        """Total centerline length, mm (every branch's polyline, connectors not counted)."""
        return float(sum(b.length_mm for b in self.branches))

    @property
    def radius_range_mm(self) -> tuple[float, float]:
        return (float(min(b.radius_mm.min() for b in self.branches)),
                float(max(b.radius_mm.max() for b in self.branches)))

    def points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All points: ``(points_mm (N, 3), radius_mm (N,), branch index (N,))``, branch after branch."""
        return (np.concatenate([b.points_mm for b in self.branches]),
                np.concatenate([b.radius_mm for b in self.branches]),
                np.concatenate([np.full(b.n_points, i, dtype=np.int64) for i, b in enumerate(self.branches)]))

    def bounding_box_mm(self, *, with_radius: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """``(lower (3,), upper (3,))`` of the points, grown by each point's radius by default."""
        points, radius, _ = self.points()
        grow = radius[:, None] if with_radius else 0.0
        return (points - grow).min(axis=0), (points + grow).max(axis=0)

    def capsules(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The capsules whose union is the lumen (module notes):
        ``(starts (S, 3), ends (S, 3), radius (S,), branch index (S,))``, mm."""
        starts, ends, radius, owner = [], [], [], []
        for i, b in enumerate(self.branches):
            if b.parent is not None:
                anchor = self.branches[b.parent].points_mm[b.parent_point]
                if np.linalg.norm(anchor - b.points_mm[0]) > 0:
                    starts.append(anchor[None])
                    ends.append(b.points_mm[:1])
                    radius.append(b.radius_mm[:1])
                    owner.append(np.array([i]))
            starts.append(b.points_mm[:-1])
            ends.append(b.points_mm[1:])
            radius.append(0.5 * (b.radius_mm[:-1] + b.radius_mm[1:]))
            owner.append(np.full(b.n_points - 1, i, dtype=np.int64))
        return (np.concatenate(starts), np.concatenate(ends), np.concatenate(radius),
                np.concatenate(owner).astype(np.int64))

    def resampled(self, step_mm: float) -> "VesselTree":
        """The tree with every branch resampled at ``step_mm`` or less (:meth:`Branch.resampled`);
        each child's parent point moves to the resampled point nearest in arc length (at most half
        a step away along the parent)."""
        branches = []
        for b in self.branches:
            new = b.resampled(step_mm)
            if b.parent is not None:
                parent_arc = self.branches[b.parent].arc_length_mm
                steps = _steps(parent_arc[-1], step_mm)
                point = int(round(parent_arc[b.parent_point] / parent_arc[-1] * steps))
                new = Branch(new.points_mm, new.radius_mm, b.parent, point, b.name)
            branches.append(new)
        return VesselTree(tuple(branches))

    def transformed(self, matrix: np.ndarray) -> "VesselTree":
        """The tree moved by a 4x4 rigid (or mirroring) transform of homogeneous mm coordinates;
        radii unchanged."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise TreeError(f"transform must be a finite 4x4 matrix, got shape {m.shape}")
        return VesselTree(tuple(Branch(b.points_mm @ m[:3, :3].T + m[:3, 3], b.radius_mm, b.parent, b.parent_point,
                                       b.name) for b in self.branches))

    # -- JSON ---------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready description (the content of ``tree.json``): every branch with its parent,
        parent point, length, points and radii, plus the derived bifurcations and totals."""
        return {
            "format": TREE_JSON_FORMAT,
            "version": _TREE_JSON_VERSION,
            "units": "mm",
            "frame": "DICOM patient coordinates (LPS), origin at the isocentre",
            "n_branches": self.n_branches,
            "length_mm": self.length_mm,
            "branches": [
                {"index": i, "name": b.name, "parent": b.parent, "parent_point": b.parent_point,
                 "n_points": b.n_points, "length_mm": b.length_mm,
                 "points_mm": b.points_mm.tolist(), "radius_mm": b.radius_mm.tolist()}
                for i, b in enumerate(self.branches)
            ],
            "bifurcations": [
                {"parent": f.parent, "parent_point": f.parent_point, "children": list(f.children),
                 "position_mm": list(f.position_mm)}
                for f in self.bifurcations
            ],
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "tree") -> "VesselTree":
        """Read :meth:`to_dict`'s output back (derived fields are ignored); ``where`` names the
        source in error messages."""
        if not isinstance(data, dict) or data.get("format") != TREE_JSON_FORMAT:
            raise TreeError(f"{where}: not an angiohull vessel tree (expected a JSON object with "
                            f"\"format\": \"{TREE_JSON_FORMAT}\")")
        if data.get("version") != _TREE_JSON_VERSION:
            raise TreeError(f"{where}: unsupported vessel tree version {data.get('version')!r} "
                            f"(this angiohull reads version {_TREE_JSON_VERSION})")
        items = data.get("branches")
        if not isinstance(items, list):
            raise TreeError(f"{where}: \"branches\" must be a list")
        branches = []
        for i, item in enumerate(items):
            if not isinstance(item, dict):
                raise TreeError(f"{where}: branches[{i}] must be an object")
            missing = [k for k in ("points_mm", "radius_mm", "parent", "parent_point") if k not in item]
            if missing:
                raise TreeError(f"{where}: branches[{i}] lacks {missing}")
            try:
                branches.append(Branch(item["points_mm"], item["radius_mm"], item["parent"], item["parent_point"],
                                       str(item.get("name", ""))))
            except TreeError as exc:
                raise TreeError(f"{where}: branches[{i}]: {exc}") from None
        try:
            return cls(tuple(branches))
        except TreeError as exc:
            raise TreeError(f"{where}: {exc}") from None

    def __repr__(self) -> str:
        low, high = self.radius_range_mm
        return (f"VesselTree({self.n_branches} branches, {len(self.bifurcations)} bifurcations, "
                f"{self.length_mm:.1f} mm, radius {low:.2f}-{high:.2f} mm)")

