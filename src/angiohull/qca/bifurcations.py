"""Bifurcation angles and the Medina classification of a vessel tree.

At a bifurcation (a parent point that branches leave from, :attr:`VesselTree.bifurcations`) the
*arms* are the vessels that meet there:

* the **proximal main** arm: back along the parent (absent when the branches leave the parent's
  first point);
* the **distal main** arm: the parent's continuation when the point is inside the parent, else the
  widest child (largest mean diameter over its arm);
* one **side** arm per other child.

An arm's direction is the unit chord between its points ``o`` and ``o + arm_mm`` of arc from the
bifurcation point, where ``o`` is ``arm_offset_radii`` times the parent's radius there: the core of
a bifurcation, where the vessels merge, says little about where each of them goes (shortened to
what the arm holds; arms with less than ``min_arm_mm`` beyond ``o`` get no direction).
For each side arm the **proximal angle** is the angle between the proximal main and side arms'
directions and the **distal angle** (the bifurcation angle) the angle between the distal main and
side arms' directions, in degrees; a straight continuation of the proximal main has a proximal
angle of 180 degrees. The **Medina** triple (proximal main, distal main, side) flags each segment
1 when a lesion of at least ``medina_stenosis_pct`` percent diameter stenosis overlaps its first
``medina_reach_mm`` from the bifurcation point, else 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..tree import VesselTree
from .profile import Lesion

__all__ = ["BifurcationSettings", "Arm", "SideBranchAngles", "BifurcationAnalysis", "analyse_bifurcations",
           "arm_direction"]


@dataclass(frozen=True)
class BifurcationSettings:
    arm_mm: float = 5.0  # chord length of an arm's direction, mm
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

    def to_dict(self) -> dict:
        return {"role": self.role, "branch": self.branch, "start_mm": self.start_mm,
                "direction": None if self.direction is None else list(self.direction),
                "mean_diameter_mm": self.mean_diameter_mm}


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


def _point_at(points: np.ndarray, arc: np.ndarray, s: float) -> np.ndarray:
    return np.array([np.interp(s, arc, points[:, k]) for k in range(3)])


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
    near = _point_at(points_mm, arc_mm, start_mm + sign * offset_mm)
    far = _point_at(points_mm, arc_mm, start_mm + sign * (offset_mm + length))
    chord = far - near
    norm = float(np.linalg.norm(chord))
    return (chord / norm if norm > 0 else None), length


def _angle_deg(a: tuple[float, float, float] | None, b: tuple[float, float, float] | None) -> float:
    if a is None or b is None:
        return math.nan
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


def _mean_diameter(radius: np.ndarray, arc: np.ndarray, start: float, length: float, reverse: bool) -> float:
    lo, hi = (start - length, start) if reverse else (start, start + length)
    inside = (arc >= lo - 1e-9) & (arc <= hi + 1e-9)
    values = radius[inside] if inside.any() else radius[[int(np.argmin(np.abs(arc - start)))]]
    return float(2.0 * values.mean())


def _flagged(lesions: Sequence[Lesion], branch: int, start: float, reach: float, reverse: bool, pct: float) -> int:
    lo, hi = (start - reach, start) if reverse else (start, start + reach)
    return int(any(les.branch == branch and les.diameter_stenosis_pct >= pct and les.end_mm >= lo and les.start_mm <= hi
                   for les in lesions))


def analyse_bifurcations(tree: VesselTree, lesions: Sequence[Lesion] = (),
                         settings: BifurcationSettings = BifurcationSettings()) -> tuple[BifurcationAnalysis, ...]:
    """Arms, angles and Medina flags of every bifurcation of ``tree`` (module notes)."""
    arcs = [b.arc_length_mm for b in tree.branches]
    out = []
    for bif in tree.bifurcations:
        parent = tree.branches[bif.parent]
        arc_p = arcs[bif.parent]
        s0 = float(arc_p[bif.parent_point])
        arms: list[Arm] = []
        offset = settings.arm_offset_radii * float(parent.radius_mm[bif.parent_point])

        def arm(role: str, index: int, start: float, reverse: bool) -> Arm:
            branch = tree.branches[index]
            direction, length = arm_direction(branch.points_mm, arcs[index], start, reverse, settings,
                                              offset_mm=offset)
            return Arm(role, index, start, reverse, None if direction is None else tuple(float(x) for x in direction),
                       _mean_diameter(branch.radius_mm, arcs[index], start, max(length, 0.0), reverse))

        if bif.parent_point > 0:
            arms.append(arm("proximal main", bif.parent, s0, True))
        candidates = [arm("side", c, 0.0, False) for c in bif.children]
        if bif.parent_point < parent.n_points - 1:
            distal = arm("distal main", bif.parent, s0, False)
        else:
            widest = max(range(len(candidates)), key=lambda i: candidates[i].mean_diameter_mm)
            c = candidates.pop(widest)
            distal = Arm("distal main", c.branch, c.start_mm, c.reverse, c.direction, c.mean_diameter_mm)
        arms.append(distal)
        arms.extend(candidates)
        proximal = arms[0] if arms[0].role == "proximal main" else None
        sides = []
        for side in candidates:
            medina = (
                0 if proximal is None else _flagged(lesions, proximal.branch, s0, settings.medina_reach_mm, True,
                                                    settings.medina_stenosis_pct),
                _flagged(lesions, distal.branch, distal.start_mm, settings.medina_reach_mm, False,
                         settings.medina_stenosis_pct),
                _flagged(lesions, side.branch, 0.0, settings.medina_reach_mm, False, settings.medina_stenosis_pct),
            )
            sides.append(SideBranchAngles(side.branch, _angle_deg(None if proximal is None else proximal.direction,
                                                                  side.direction),
                                          _angle_deg(distal.direction, side.direction), medina))
        out.append(BifurcationAnalysis(bif.parent, bif.parent_point, bif.position_mm, tuple(arms), tuple(sides)))
    return tuple(out)
