"""Bifurcation angles and the Medina classification of a vessel tree.

At a bifurcation (a parent point that branches leave from, :attr:`VesselTree.bifurcations`) the
*arms* are the vessels that meet there:

* the **proximal main** arm: back along the parent's vessel (:mod:`.vessels`; absent when the
  branches leave the vessel's first point);
* the **distal main** arm: the parent's vessel onwards when it carries on past the point (inside
  the parent, or into the child it continues into), else the widest child (largest mean diameter
  over its arm);
* one **side** arm per other child, along the child's vessel.

A junction where a branch continues into its only child there is no bifurcation. An arm's
direction is the unit chord between its points ``o`` and ``o + arm_mm`` of arc from the
bifurcation point, where ``o`` is ``arm_offset_radii`` times the parent's radius there: the core of
a bifurcation, where the vessels merge, says little about where each of them goes (shortened to
what the arm holds; arms with less than ``min_arm_mm`` beyond ``o`` get no direction). The chord
is 10 mm long: a reconstructed centerline wanders by about 0.2 mm, which turns a 5 mm chord by
about 3 degrees (docs/qca.md).
For each side arm the **proximal angle** is the angle between the proximal main and side arms'
directions and the **distal angle** (the bifurcation angle) the angle between the distal main and
side arms' directions, in degrees; a straight continuation of the proximal main has a proximal
angle of 180 degrees. The **Medina** triple (proximal main, distal main, side) flags each segment
1 when a lesion of at least ``medina_stenosis_pct`` percent diameter stenosis overlaps its first
``medina_reach_mm`` from the bifurcation point, else 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from ..tree import VesselTree
from ..tree.model import point_at_arc
from .profile import Lesion
from .vessels import TreeVessels, Vessel, VesselSettings, tree_vessels

__all__ = ["BifurcationSettings", "Arm", "SideBranchAngles", "BifurcationAnalysis", "analyse_bifurcations",
           "arm_direction"]


@dataclass(frozen=True)
class BifurcationSettings:
    arm_mm: float = 10.0  # chord length of an arm's direction, mm
    arm_offset_radii: float = 2.0  # the chord starts this many parent radii from the bifurcation point
    min_arm_mm: float = 1.0  # shorter arms get no direction
    medina_stenosis_pct: float = 50.0
    medina_reach_mm: float = 10.0


@dataclass(frozen=True)
class Arm:
    """One vessel at a bifurcation, as arc-length range ``[start_mm, end_mm]`` of ``branch`` read
    away from the bifurcation (``reverse``: towards the branch's start)."""

    role: str  # "proximal main", "distal main" or "side"
    branch: int
    start_mm: float  # arc length of the bifurcation point on this branch
    reverse: bool  # True: the arm runs towards decreasing arc length (the proximal main)
    direction: tuple[float, float, float] | None  # unit chord, None when the arm is too short
    mean_diameter_mm: float
    near_mm: tuple[float, float, float] | None = None  # the chord's ends (patient frame, mm); None
    far_mm: tuple[float, float, float] | None = None  # when the arm is too short

    def to_dict(self) -> dict:
        return {"role": self.role, "branch": self.branch, "start_mm": self.start_mm,
                "direction": None if self.direction is None else list(self.direction),
                "mean_diameter_mm": self.mean_diameter_mm,
                "chord_mm": None if self.near_mm is None else [list(self.near_mm), list(self.far_mm)]}


@dataclass(frozen=True)
class SideBranchAngles:
    side_branch: int
    proximal_angle_deg: float  # between the proximal main and the side arm (nan without a proximal arm)
    distal_angle_deg: float  # between the distal main and the side arm
    medina: tuple[int, int, int]  # (proximal main, distal main, side)

    @property
    def medina_text(self) -> str:
        return ",".join(str(x) for x in self.medina)

    def to_dict(self) -> dict:
        return {"side_branch": self.side_branch, "proximal_angle_deg": _json_float(self.proximal_angle_deg),
                "distal_angle_deg": _json_float(self.distal_angle_deg), "medina": self.medina_text}


@dataclass(frozen=True)
class BifurcationAnalysis:
    parent: int
    parent_point: int
    position_mm: tuple[float, float, float]
    arms: tuple[Arm, ...]
    sides: tuple[SideBranchAngles, ...]

    def to_dict(self) -> dict:
        return {"parent": self.parent, "parent_point": self.parent_point, "position_mm": list(self.position_mm),
                "arms": [a.to_dict() for a in self.arms], "side_branches": [s.to_dict() for s in self.sides]}


def _json_float(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def arm_direction(points_mm: np.ndarray, arc_mm: np.ndarray, start_mm: float, reverse: bool,
                  settings: BifurcationSettings = BifurcationSettings(), *,
                  offset_mm: float = 0.0) -> tuple[np.ndarray | None, float]:
    """``(unit chord or None, chord length)`` of the arm that leaves arc ``start_mm`` of a
    polyline forwards or (``reverse``) backwards: the chord between the arm's points
    ``offset_mm`` and ``offset_mm + arm_mm`` from the start (shortened to what the polyline holds;
    None when that is less than ``min_arm_mm``)."""
    available = start_mm - arc_mm[0] if reverse else arc_mm[-1] - start_mm
    length = min(settings.arm_mm, available - offset_mm)
    if length < settings.min_arm_mm:
        return None, max(length, 0.0)
    sign = -1.0 if reverse else 1.0
    near = point_at_arc(points_mm, arc_mm, start_mm + sign * offset_mm)
    far = point_at_arc(points_mm, arc_mm, start_mm + sign * (offset_mm + length))
    chord = far - near
    norm = float(np.linalg.norm(chord))
    return (chord / norm if norm > 0 else None), length


def _arm(vessel: Vessel, start: float, reverse: bool, settings: BifurcationSettings, offset: float):
    """(direction or None, length, near point or None, far point or None) of an arm along a vessel."""
    direction, length = arm_direction(vessel.points_mm, vessel.arc_mm, start, reverse, settings, offset_mm=offset)
    if direction is None:
        return None, length, None, None
    sign = -1.0 if reverse else 1.0
    near = point_at_arc(vessel.points_mm, vessel.arc_mm, start + sign * offset)
    far = point_at_arc(vessel.points_mm, vessel.arc_mm, start + sign * (offset + length))
    return (tuple(float(x) for x in direction), length, tuple(float(x) for x in near), tuple(float(x) for x in far))


def _angle_deg(a: tuple[float, float, float] | None, b: tuple[float, float, float] | None) -> float:
    if a is None or b is None:
        return math.nan
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


def _mean_diameter(radius: np.ndarray, arc: np.ndarray, start: float, length: float, reverse: bool) -> float:
    lo, hi = (start - length, start) if reverse else (start, start + length)
    inside = (arc >= lo - 1e-9) & (arc <= hi + 1e-9)
    values = radius[inside] if inside.any() else radius[[int(np.argmin(np.abs(arc - start)))]]
    return float(2.0 * values.mean())


def _flagged(lesions: Sequence[Lesion], vessel: Vessel, start: float, reach: float, reverse: bool, pct: float) -> int:
    """1 when a lesion of at least ``pct`` %DS on ``vessel`` overlaps its arc ``start`` to
    ``start -+ reach`` (vessel arc lengths)."""
    lo, hi = (start - reach, start) if reverse else (start, start + reach)
    for les in lesions:
        if les.branch not in vessel.branches or les.diameter_stenosis_pct < pct:
            continue
        offset = vessel.offset_of(les.branch)
        if les.end_mm + offset >= lo and les.start_mm + offset <= hi:
            return 1
    return 0


def analyse_bifurcations(tree: VesselTree, lesions: Sequence[Lesion] = (),
                         settings: BifurcationSettings = BifurcationSettings(), *,
                         vessels: TreeVessels | VesselSettings | None = None) -> tuple[BifurcationAnalysis, ...]:
    """Arms, angles and Medina flags of every bifurcation of ``tree`` (module notes).

    ``vessels``: how the tree reads as vessels (:func:`~angiohull.qca.vessels.tree_vessels`, or
    its settings; default ``VesselSettings()``). Arms run along vessels; a junction where a branch
    continues into its only child there is no bifurcation.
    """
    if not isinstance(vessels, TreeVessels):
        vessels = tree_vessels(tree, vessels if vessels is not None else VesselSettings())
    out = []
    for bif in tree.bifurcations:
        parent = tree.branches[bif.parent]
        v = vessels.of(bif.parent)
        p_offset = v.offset_of(bif.parent)
        continuation = vessels.continues_into.get(bif.parent)
        sides_of = [c for c in bif.children if c != continuation]
        if not sides_of:
            continue  # the branch carries on into its only child here: one vessel, no bifurcation
        # where the bifurcation sits on the parent's vessel (a junction on the stub
        # past the continuation's junction counts as at that junction; a stub whose continuation
        # leaves its first point adds no sample to the vessel: its junctions are at its start)
        owned = v.arc_mm[v.owner == bif.parent]
        s0 = min(p_offset + float(parent.arc_length_mm[bif.parent_point]), float(owned.max()) if owned.size else p_offset)
        offset = settings.arm_offset_radii * float(parent.radius_mm[bif.parent_point])

        def arm(role: str, vessel: Vessel, branch: int, start: float, reverse: bool) -> Arm:
            direction, length, near, far = _arm(vessel, start, reverse, settings, offset)
            return Arm(role, branch, start - vessel.offset_of(branch), reverse, direction,
                       _mean_diameter(vessel.radius_mm, vessel.arc_mm, start, max(length, 0.0), reverse), near, far)

        arms: list[Arm] = []
        if s0 > v.arc_mm[0] + 1e-9:
            arms.append(arm("proximal main", v, bif.parent, s0, True))
        candidates = [arm("side", vessels.of(c), c, vessels.of(c).offset_of(c), False) for c in sides_of]
        if s0 < v.arc_mm[-1] - 1e-9:  # the parent's vessel carries on
            owner = int(v.owner[int(np.searchsorted(v.arc_mm, s0 + 1e-9))])
            distal = arm("distal main", v, owner, s0, False)
        else:
            widest = max(range(len(candidates)), key=lambda i: candidates[i].mean_diameter_mm)
            c = candidates.pop(widest)
            distal = replace(c, role="distal main")
        arms.append(distal)
        arms.extend(candidates)
        proximal = arms[0] if arms[0].role == "proximal main" else None
        sides = []
        for side in candidates:
            medina = (
                0 if proximal is None else _flagged(lesions, v, s0, settings.medina_reach_mm, True,
                                                    settings.medina_stenosis_pct),
                _flagged(lesions, vessels.of(distal.branch), vessels.of(distal.branch).offset_of(distal.branch)
                         + distal.start_mm, settings.medina_reach_mm, False, settings.medina_stenosis_pct),
                _flagged(lesions, vessels.of(side.branch), vessels.of(side.branch).offset_of(side.branch),
                         settings.medina_reach_mm, False, settings.medina_stenosis_pct),
            )
            sides.append(SideBranchAngles(side.branch, _angle_deg(None if proximal is None else proximal.direction,
                                                                  side.direction),
                                          _angle_deg(distal.direction, side.direction), medina))
        out.append(BifurcationAnalysis(bif.parent, bif.parent_point, bif.position_mm, tuple(arms), tuple(sides)))
    return tuple(out)
