"""Synthetic coronary trees with known geometry: a small parameter record, drawn from a seed, that
replays one tree exactly.

Two steps, kept apart so any case can be replayed:

1. :func:`draw_tree_params` draws every random quantity of a tree from a numpy Generator (or
   seed) into a :class:`TreeParams` record: the pose and size of the heart, and per branch its
   length, radii, course on the heart surface, tortuosity waves and stenoses. The record is a
   small JSON document (:meth:`TreeParams.to_json` / :meth:`TreeParams.from_json`).
2. :func:`build_tree` turns a record into a :class:`CoronaryTree` with no randomness: centreline
   polylines (0.5 mm steps) with a radius per vertex, the branch topology, the tube solid as a
   :class:`~angiohull.synthetic.phantom.TubePhantom` (exact silhouettes, surface and lumen points).

The anatomy model
-----------------
The heart is a surface of revolution about its long axis (base -> apex): a cylinder of radius
``base_radius_mm`` above the atrioventricular (AV) plane (``s < 0``) and a half ellipsoid below it,
``rho(s) = R sqrt(1 - (s / H)^2)`` for ``0 <= s <= H = base_to_apex_mm``. A point of the surface has
coordinates ``(s_mm, theta_deg)``: ``s`` along the long axis from the AV plane towards the apex,
``theta`` around it from the anterior direction, positive towards the patient's left. The long axis
points to the patient's left (``apex_azimuth_deg`` from anterior in the transverse plane), anterior
and down (``apex_elevation_deg`` below the transverse plane), as a heart lies in a supine patient,
so that LAO views look roughly along it (the RCA shows as a "C") and RAO views across it (an "L").

Each vessel's *course* is a few control points ``(s, theta)`` on that surface, joined by a cubic
spline in 3D; a side branch's control points are relative to where it leaves its parent and its
first point is exactly on the parent's centreline. Tortuosity is a sum of sinusoidal waves across
the course (ramped in over the first 10 mm so that a branch leaves its parent smoothly); the
vessel is then cut at its drawn length. Radii taper linearly with arc length; a stenosis multiplies
the radius by ``1 - severity * g`` with ``g`` a Gaussian (``sigma = length / 6``) or raised-cosine
window (support ``length``) of peak 1, so ``severity`` is the diameter reduction at its centre.

The whole tree is finally translated so that the centre of its bounding box lies at
``heart.centre_offset_mm`` from the isocentre (the operator centres the vessels, imperfectly).

Tortuosity levels are defined by a measured index, :func:`tree_tortuosity_index` (the arc-length
weighted mean of :func:`~angiohull.synthetic.tortuosity.curvature_metric` over the branches, rad/cm):
a drawn tree is kept only if its index falls in its level's band (:data:`TORTUOSITY_BANDS`), else
its waves are drawn again.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Literal, Optional, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from scipy.interpolate import CubicSpline

from .. import _validation as _v
from .. import options
from ..errors import AngiohullError
from ..tree import Branch as TreeBranch
from ..tree import VesselTree
from .phantom import Tube, TubePhantom
from .tortuosity import arc_length_mm, curvature_metric, distance_metric, sum_of_angles_metric

__all__ = [
    "TREE_KINDS", "TORTUOSITY_LEVELS", "TORTUOSITY_BANDS", "CENTERLINE_STEP_MM",
    "HeartPose", "Wave", "Stenosis", "BranchParams", "TreeParams",
    "Branch", "CoronaryTree", "draw_tree_params", "build_tree", "generate_tree", "tree_tortuosity_index",
    "min_bend_radius_mm",
]

TREE_KINDS = options.TREE_KINDS
"""The trees the generator makes: the right coronary artery, or the left (left main, LAD, LCx)."""

TORTUOSITY_LEVELS = options.TORTUOSITY_LEVELS

TORTUOSITY_BANDS: dict[str, tuple[float, float]] = {
    "simple": (0.0, 0.55),
    "moderate": (0.6, 1.05),
    "tortuous": (1.2, 2.0),
}
"""Accepted range of :func:`tree_tortuosity_index` (rad/cm) per level; the gaps keep levels apart."""

CENTERLINE_STEP_MM = 0.5
"""Arc-length step of the built centrelines, mm."""

_RAMP_MM = 10.0  # tortuosity waves ramp in over this arc length, mm
_DENSE_STEP_MM = 0.1  # step of the dense course from which the vertices are cut, mm
_MAX_WAVE_DRAWS = 200  # redraws of the waves before giving up on a tortuosity band
_MAX_S_FRACTION = 0.95  # control points are kept at s <= 0.95 H (the surface is a point at the apex)
_MIN_BEND_RATIO = 1.2  # radius of curvature >= 1.2 x the vessel's largest radius: no tube folds
_WAVE_BEND_RATIO = 1.5  # the waves of a branch bend it no tighter than 1.5 x its largest radius


class _Record(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class HeartPose(_Record):
    """Where the heart lies and how large it is (all drawn per tree)."""

    apex_azimuth_deg: float = Field(description="long axis in the transverse plane, from anterior towards the patient's left")
    apex_elevation_deg: float = Field(description="long axis below the transverse plane (towards the feet)")
    roll_deg: float = Field(description="rotation of the surface coordinates about the long axis")
    base_radius_mm: float = Field(gt=0, description="radius of the AV groove")
    base_to_apex_mm: float = Field(gt=0, description="long-axis distance from the AV plane to the apex")
    centre_offset_mm: tuple[float, float, float] = Field(description="bounding-box centre of the tree, from the isocentre")


class Wave(_Record):
    """One sinusoidal tortuosity wave across a vessel's course."""

    amplitude_mm: float = Field(ge=0)
    wavelength_mm: float = Field(gt=0)
    phase_rad: float
    direction_rad: float = Field(description="direction in the normal plane: 0 = away from the heart axis")


class Stenosis(_Record):
    """A focal narrowing: the radius times ``1 - severity * window(arc - centre_mm)``."""

    centre_mm: float = Field(ge=0, description="arc length from the branch's origin")
    length_mm: float = Field(gt=0, description="extent (Gaussian: 6 sigma; cosine: support)")
    severity: float = Field(gt=0, lt=1, description="diameter reduction at the centre, fraction")
    profile: Literal["gaussian", "cosine"]


class BranchParams(_Record):
    """One vessel of a tree."""

    name: str
    parent: Optional[int] = Field(description="index of the parent branch in TreeParams.branches; None for a root")
    origin_fraction: float = Field(ge=0, le=1, description="where it leaves the parent, fraction of the parent's length")
    length_mm: float = Field(gt=0)
    radius_start_mm: float = Field(gt=0)
    radius_end_mm: float = Field(gt=0)
    course_deg: tuple[tuple[float, float], ...] = Field(
        description="control points (s_mm, theta_deg) on the heart surface; relative to the origin for a side branch")
    waves: tuple[Wave, ...] = ()
    stenoses: tuple[Stenosis, ...] = ()

    @model_validator(mode="after")
    def _enough_points(self) -> "BranchParams":
        if len(self.course_deg) < 2:
            raise ValueError(f"branch {self.name!r}: course_deg needs at least 2 control points")
        return self


class TreeParams(_Record):
    """Everything that was drawn for one tree; :func:`build_tree` replays it exactly."""

    format: Literal[1] = 1
    kind: Literal["rca", "left"]
    tortuosity: Literal["simple", "moderate", "tortuous"]
    seed: Optional[int] = Field(default=None, description="the seed it was drawn from, when one was given (informative)")
    heart: HeartPose
    branches: tuple[BranchParams, ...]

    @model_validator(mode="after")
    def _topology(self) -> "TreeParams":
        if not self.branches:
            raise ValueError("a tree needs at least one branch")
        if self.branches[0].parent is not None:
            raise ValueError("branches[0] must be a root (parent None)")
        for i, branch in enumerate(self.branches):
            if branch.parent is not None and not 0 <= branch.parent < i:
                raise ValueError(f"branches[{i}].parent must name an earlier branch, got {branch.parent}")
        return self

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (floats exact)."""
        return self.model_dump(mode="json")

    def to_json(self) -> str:
        """The record as JSON text; :meth:`from_json` gives back an equal record."""
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, data: Any, where: str = "tree record") -> "TreeParams":
        """Validate a dict (e.g. from JSON); errors name the field."""
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            first = exc.errors()[0]
            loc = ".".join(str(p) for p in first["loc"])
            raise AngiohullError(f"{where}: {loc}: {first['msg']} (got {first.get('input')!r:.80})") from None

    @classmethod
    def from_json(cls, text: str, where: str = "tree record") -> "TreeParams":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise AngiohullError(f"{where}: not valid JSON ({exc})") from None
        return cls.from_dict(data, where)


# -- built tree ----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Branch:
    """A built vessel: centreline, radii and where it hangs in the tree."""

    name: str
    parent: Optional[int]  # index of the parent branch, None for a root
    origin_vertex: Optional[int]  # vertex of the parent's centreline it leaves from
    centerline_mm: np.ndarray  # (M, 3) vertices, CENTERLINE_STEP_MM apart along the arc
    radius_mm: np.ndarray  # (M,) lumen radius with stenoses, mm
    reference_radius_mm: np.ndarray  # (M,) radius of the taper alone (no stenosis), mm
    stenoses: tuple[Stenosis, ...]

    @property
    def length_mm(self) -> float:
        return float(arc_length_mm(self.centerline_mm)[-1])

    def tortuosity(self) -> dict[str, float]:
        """Indices of this branch: curvature (rad/cm), SOAM (rad/cm), distance metric."""
        return {"curvature_rad_per_cm": curvature_metric(self.centerline_mm),
                "soam_rad_per_cm": sum_of_angles_metric(self.centerline_mm),
                "distance_metric": distance_metric(self.centerline_mm)}


@dataclass(frozen=True, eq=False)
class CoronaryTree:
    """A built tree: its record, its branches and its tube solid."""

    params: TreeParams
    branches: tuple[Branch, ...]
    phantom: TubePhantom = field(repr=False)

    @property
    def kind(self) -> str:
        return self.params.kind

    def tortuosity_index(self) -> float:
        """:func:`tree_tortuosity_index` of this tree (rad/cm)."""
        return tree_tortuosity_index(self.branches)

    def summary(self) -> dict[str, Any]:
        """Measured facts per branch and for the tree (JSON-ready)."""
        branches = []
        for b in self.branches:
            branches.append({
                "name": b.name, "parent": b.parent, "origin_vertex": b.origin_vertex,
                "length_mm": b.length_mm, "radius_start_mm": float(b.radius_mm[0]),
                "radius_end_mm": float(b.radius_mm[-1]), **b.tortuosity(),
                "stenoses": [s.model_dump() for s in b.stenoses],
            })
        lower, upper = self.phantom.bounding_box_mm()
        return {"kind": self.kind, "tortuosity": self.params.tortuosity,
                "tortuosity_index_rad_per_cm": self.tortuosity_index(),
                "bounding_box_mm": [lower.tolist(), upper.tolist()], "branches": branches}

    def centerlines(self) -> dict[str, np.ndarray]:
        """Per branch name, an (M, 4) array of ``x, y, z, radius`` in mm."""
        return {b.name: np.column_stack([b.centerline_mm, b.radius_mm]) for b in self.branches}

    def vessel_tree(self) -> VesselTree:
        """The true tree as a :class:`~angiohull.tree.VesselTree` (the same points and radii as
        ``gt_centerlines.npz``; each branch leaves its parent at its ``origin_vertex``)."""
        return VesselTree(tuple(TreeBranch(b.centerline_mm, b.radius_mm, b.parent, b.origin_vertex, b.name)
                                for b in self.branches))


def min_bend_radius_mm(centerline_mm: np.ndarray) -> float:
    """Smallest radius of curvature of a polyline, from the turning angle at each inner vertex."""
    steps = np.diff(centerline_mm, axis=0)
    length = np.linalg.norm(steps, axis=1)
    unit = steps / length[:, None]
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", unit[:-1], unit[1:]), -1.0, 1.0))
    curvature = angle / (0.5 * (length[:-1] + length[1:]))
    return float(1.0 / curvature.max()) if curvature.size and curvature.max() > 0 else float("inf")


def _folds(branch: Branch) -> bool:
    return min_bend_radius_mm(branch.centerline_mm) < _MIN_BEND_RATIO * float(branch.radius_mm.max())


def tree_tortuosity_index(branches: Sequence[Branch]) -> float:
    """Arc-length weighted mean of the branches' curvature metric (rad/cm); defines the levels."""
    lengths = np.array([b.length_mm for b in branches])
    values = np.array([curvature_metric(b.centerline_mm) for b in branches])
    return float((lengths * values).sum() / lengths.sum())


# -- heart frame ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class _HeartFrame:
    base_centre: np.ndarray  # centre of the AV plane, mm (before the final translation)
    axis: np.ndarray  # unit, base -> apex
    anterior: np.ndarray  # unit, theta = 0
    left: np.ndarray  # unit, theta = +90
    radius: float
    height: float

    @classmethod
    def of(cls, pose: HeartPose) -> "_HeartFrame":
        az, el, roll = (math.radians(x) for x in (pose.apex_azimuth_deg, pose.apex_elevation_deg, pose.roll_deg))
        axis = np.array([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), -math.sin(el)])
        anterior = np.array([0.0, -1.0, 0.0]) - axis * (-axis[1])
        anterior /= np.linalg.norm(anterior)
        left = np.cross(axis, anterior)
        if left[0] < 0:  # make theta = +90 point to the patient's left (+x)
            left = -left
        anterior, left = (math.cos(roll) * anterior + math.sin(roll) * left,
                          -math.sin(roll) * anterior + math.cos(roll) * left)
        # The heart's centre (about a third of the way from base to apex) at the isocentre.
        base_centre = -0.35 * pose.base_to_apex_mm * axis
        return cls(base_centre, axis, anterior, left, pose.base_radius_mm, pose.base_to_apex_mm)

    def surface(self, s_mm: np.ndarray, theta_deg: np.ndarray) -> np.ndarray:
        s = np.asarray(s_mm, dtype=np.float64)
        t = np.radians(np.asarray(theta_deg, dtype=np.float64))
        s = np.minimum(s, _MAX_S_FRACTION * self.height)  # never onto the apex itself
        rho = self.radius * np.sqrt(1.0 - (np.clip(s, 0.0, None) / self.height) ** 2)
        return (self.base_centre + s[..., None] * self.axis
                + rho[..., None] * (np.cos(t)[..., None] * self.anterior + np.sin(t)[..., None] * self.left))

    def coordinates(self, point: np.ndarray) -> tuple[float, float]:
        rel = np.asarray(point) - self.base_centre
        s = float(rel @ self.axis)
        theta = math.degrees(math.atan2(float(rel @ self.left), float(rel @ self.anterior)))
        return s, theta

    def outward(self, points: np.ndarray) -> np.ndarray:
        """Unit vectors away from the long axis (arbitrary but finite on the axis)."""
        rel = points - self.base_centre
        radial = rel - (rel @ self.axis)[:, None] * self.axis
        norm = np.linalg.norm(radial, axis=1, keepdims=True)
        return np.where(norm > 1e-9, radial / np.where(norm > 1e-9, norm, 1.0), self.anterior)


# -- building ------------------------------------------------------------------------------------
def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _course(frame: _HeartFrame, params: BranchParams, origin: Optional[np.ndarray]) -> np.ndarray:
    """Dense points (about _DENSE_STEP_MM apart) of the branch's course with its waves, long enough."""
    control = np.array(params.course_deg, dtype=np.float64)
    if origin is None:
        points = frame.surface(control[:, 0], control[:, 1])
    else:
        s0, theta0 = frame.coordinates(origin)
        points = frame.surface(control[:, 0] + s0, control[:, 1] + theta0)
        points[0] = origin
    chord = arc_length_mm(points)
    keep = np.concatenate([[True], np.diff(chord) > 1e-9])
    points, chord = points[keep], chord[keep]
    spline = CubicSpline(chord, points, bc_type="natural")
    t = np.linspace(0.0, chord[-1], max(8, int(math.ceil(chord[-1] / (_DENSE_STEP_MM / 2))) + 1))
    base = spline(t)
    # The course must be at least as long as the vessel: extend it straight along its last tangent.
    base_arc = arc_length_mm(base)
    if base_arc[-1] < 1.05 * params.length_mm:
        direction = base[-1] - base[-2]
        direction /= np.linalg.norm(direction)
        extra = np.arange(1, int(math.ceil((1.05 * params.length_mm - base_arc[-1]) / _DENSE_STEP_MM)) + 2)
        base = np.concatenate([base, base[-1] + (extra * _DENSE_STEP_MM)[:, None] * direction])
        base_arc = arc_length_mm(base)
    if params.waves:
        tangent = np.gradient(base, axis=0)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        normal = frame.outward(base)
        normal = normal - np.einsum("ij,ij->i", normal, tangent)[:, None] * tangent
        norm = np.linalg.norm(normal, axis=1, keepdims=True)
        fallback = np.cross(tangent, frame.axis)
        normal = np.where(norm > 1e-6, normal / np.where(norm > 1e-6, norm, 1.0), fallback)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        binormal = np.cross(tangent, normal)
        offset = np.zeros_like(base)
        for wave in params.waves:
            height = wave.amplitude_mm * np.sin(2.0 * math.pi * base_arc / wave.wavelength_mm + wave.phase_rad)
            direction = math.cos(wave.direction_rad) * normal + math.sin(wave.direction_rad) * binormal
            offset += height[:, None] * direction
        base = base + _smoothstep(base_arc / _RAMP_MM)[:, None] * offset
    return base


def _cut(dense: np.ndarray, length_mm: float) -> np.ndarray:
    """Vertices CENTERLINE_STEP_MM apart in arc length along ``dense``, from 0 to ``length_mm``."""
    arc = arc_length_mm(dense)
    if arc[-1] < length_mm:
        raise AngiohullError(f"internal: a course of {arc[-1]:.1f} mm cannot hold a vessel of {length_mm:.1f} mm")
    n = max(2, int(math.ceil(length_mm / CENTERLINE_STEP_MM)) + 1)
    stations = np.linspace(0.0, length_mm, n)
    return np.stack([np.interp(stations, arc, dense[:, k]) for k in range(3)], axis=1)


def _window(arc: np.ndarray, stenosis: Stenosis) -> np.ndarray:
    x = arc - stenosis.centre_mm
    if stenosis.profile == "gaussian":
        sigma = stenosis.length_mm / 6.0
        return np.exp(-0.5 * (x / sigma) ** 2)
    inside = np.abs(x) <= 0.5 * stenosis.length_mm
    return np.where(inside, 0.5 * (1.0 + np.cos(2.0 * math.pi * x / stenosis.length_mm)), 0.0)


def _radii(params: BranchParams, centerline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    arc = arc_length_mm(centerline)
    reference = params.radius_start_mm + (params.radius_end_mm - params.radius_start_mm) * arc / arc[-1]
    factor = np.ones_like(arc)
    for stenosis in params.stenoses:
        factor *= 1.0 - stenosis.severity * _window(arc, stenosis)
    return reference * factor, reference


def _build_branch(frame: _HeartFrame, bp: BranchParams, parent: Optional[Branch]) -> Branch:
    origin = origin_vertex = None
    if parent is not None:
        origin_vertex = int(round(bp.origin_fraction * (parent.centerline_mm.shape[0] - 1)))
        origin = parent.centerline_mm[origin_vertex]
    centerline = _cut(_course(frame, bp, origin), bp.length_mm)
    radius, reference = _radii(bp, centerline)
    return Branch(bp.name, bp.parent, origin_vertex, centerline, radius, reference, bp.stenoses)


def _build_branches(params: TreeParams) -> tuple[list[Branch], _HeartFrame]:
    frame = _HeartFrame.of(params.heart)
    branches: list[Branch] = []
    for bp in params.branches:
        branches.append(_build_branch(frame, bp, None if bp.parent is None else branches[bp.parent]))
    return branches, frame


def build_tree(params: TreeParams) -> CoronaryTree:
    """Build the tree a record describes (deterministic: the same record gives the same arrays).

    Parameters
    ----------
    params : TreeParams or dict
        The record (a dict is validated first).

    Returns
    -------
    CoronaryTree
    """
    if not isinstance(params, TreeParams):
        params = TreeParams.from_dict(params)
    branches, _ = _build_branches(params)
    lower = np.min([b.centerline_mm.min(axis=0) for b in branches], axis=0)
    upper = np.max([b.centerline_mm.max(axis=0) for b in branches], axis=0)
    shift = np.asarray(params.heart.centre_offset_mm) - 0.5 * (lower + upper)
    placed = []
    for b in branches:
        centre = _v.readonly_copy(b.centerline_mm + shift)
        placed.append(Branch(b.name, b.parent, b.origin_vertex, centre, _v.readonly_copy(b.radius_mm),
                             _v.readonly_copy(b.reference_radius_mm), b.stenoses))
    phantom = TubePhantom(tuple(Tube(b.centerline_mm, b.radius_mm) for b in placed), f"{params.kind}-{params.tortuosity}")
    return CoronaryTree(params, tuple(placed), phantom)


# -- drawing -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _BranchPlan:
    """How to draw one kind of branch (ranges from the literature the issue quotes)."""

    name: str
    parent: Optional[int]
    origin: tuple[float, float]  # origin fraction range on the parent
    length_mm: tuple[float, float]
    radius_start_mm: tuple[float, float]
    end_ratio: tuple[float, float]  # radius_end / radius_start
    course: tuple[tuple[float, float], ...]  # nominal control points (s_mm, theta_deg)
    max_stenoses: int
    jitter: tuple[float, float] = (3.0, 6.0)  # uniform +- jitter of each control point after the first (mm, deg)
    wavy: bool = True  # gets tortuosity waves (not the short left main)


def _plans(kind: str, rng: np.random.Generator, height: float) -> list[_BranchPlan]:
    # Courses stay below s = 0.9 H (the surface narrows to a point at the apex); the LAD goes
    # round the apex on a ring of radius about 0.4 R rather than over it.
    h = height
    if kind == "rca":
        return [
            _BranchPlan("RCA", None, (0.0, 0.0), (120.0, 140.0), (2.0, 2.5), (0.30, 0.40),
                        ((-10, -30), (-2, -60), (2, -100), (3, -140), (3, -180), (7, -203), (20, -218),
                         (36, -228), (0.72 * h, -234), (0.85 * h, -238)), 2),
            _BranchPlan("conus", 0, (0.03, 0.12), (0.8 * 35.0, 1.2 * 35.0), (0.9, 1.1), (0.55, 0.7),
                        ((0, 0), (3, 25), (8, 50), (14, 75), (20, 100), (26, 120)), 1),
            _BranchPlan("acute_marginal", 0, (0.18, 0.35), (0.8 * 51.0, 1.2 * 51.0), (1.0, 1.2), (0.55, 0.7),
                        ((0, 0), (12, -6), (26, -10), (40, -10), (0.66 * h, -6), (0.82 * h, 0)), 1),
            _BranchPlan("posterior_descending", 0, (0.55, 0.65), (0.8 * 55.0, 1.2 * 55.0), (1.0, 1.2), (0.55, 0.7),
                        ((0, 0), (12, 8), (26, 14), (40, 18), (0.66 * h, 20), (0.82 * h, 20)), 1),
        ]
    plans = [
        _BranchPlan("left_main", None, (0.0, 0.0), (8.0, 12.0), (2.0, 2.5), (0.9, 0.95),
                    ((-8, 40), (-2, 54), (4, 68)), 0, jitter=(1.0, 2.0), wavy=False),
        _BranchPlan("LAD", 0, (1.0, 1.0), (100.0, 130.0), (1.75, 2.4), (0.30, 0.40),
                    ((0, 0), (6, -20), (20, -35), (40, -40), (0.7 * h, -42), (0.86 * h, -30), (0.9 * h, 20),
                     (0.86 * h, 70), (0.78 * h, 110), (0.66 * h, 130)), 2),
        _BranchPlan("LCx", 0, (1.0, 1.0), (80.0, 100.0), (1.5, 2.25), (0.35, 0.5),
                    ((0, 0), (3, 25), (4, 55), (4, 85), (8, 110), (20, 125), (38, 130), (0.7 * h, 132),
                     (0.82 * h, 134)), 1),
    ]
    n_diagonal = int(rng.integers(1, 4))
    n_marginal = int(rng.integers(1, 3))
    for i in range(n_diagonal):
        plans.append(_BranchPlan(f"diagonal_{i + 1}", 1, (0.15, 0.5), (30.0, 60.0), (0.8, 1.2), (0.5, 0.7),
                                 ((0, 0), (6, 15), (12, 30), (18, 45), (22, 60), (25, 75), (27, 90)), 1))
    for i in range(n_marginal):
        plans.append(_BranchPlan(f"obtuse_marginal_{i + 1}", 2, (0.3, 0.75), (30.0, 55.0), (0.8, 1.1), (0.5, 0.7),
                                 ((0, 0), (12, -5), (26, -8), (40, -8), (52, -5), (60, -2)), 1))
    return plans


_WAVE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    # count (inclusive), amplitude (mm), wavelength (mm) of the waves of one branch
    "simple": {"count": (1, 2), "amplitude_mm": (0.1, 0.5), "wavelength_mm": (40.0, 80.0)},
    "moderate": {"count": (2, 3), "amplitude_mm": (0.6, 1.5), "wavelength_mm": (20.0, 36.0)},
    "tortuous": {"count": (3, 4), "amplitude_mm": (2.0, 4.0), "wavelength_mm": (12.0, 24.0)},
}


def _draw_waves(rng: np.random.Generator, level: str, radius_mm: float) -> tuple[Wave, ...]:
    """Waves of one branch whose largest radius is ``radius_mm``.

    A wave's peak curvature is ``amplitude (2 pi / wavelength)^2``; the amplitudes are capped so that
    each wave's peak curvature is at most ``1 / (1.5 radius sqrt(count))``: waves of different
    wavelengths seldom peak together, so their sum usually stays below ``1 / (1.5 radius)``; a branch
    that still bends tighter than its radius allows is drawn again (see :func:`draw_tree_params`).
    """
    ranges = _WAVE_RANGES[level]
    count = int(rng.integers(ranges["count"][0], ranges["count"][1] + 1))
    cap_per_wave = 1.0 / (_WAVE_BEND_RATIO * radius_mm * math.sqrt(count))
    waves = []
    for _ in range(count):
        amplitude = float(rng.uniform(*ranges["amplitude_mm"]))
        wavelength = float(rng.uniform(*ranges["wavelength_mm"]))
        amplitude = min(amplitude, cap_per_wave * wavelength ** 2 / (4.0 * math.pi ** 2))
        waves.append(Wave(amplitude_mm=amplitude, wavelength_mm=wavelength,
                          phase_rad=float(rng.uniform(0.0, 2.0 * math.pi)),
                          direction_rad=float(rng.uniform(0.0, 2.0 * math.pi))))
    return tuple(waves)


def _distinct_fractions(rng: np.random.Generator, plans: list[_BranchPlan]) -> list[float]:
    """Origin fractions; siblings on one parent at least 0.08 of its length apart."""
    for _ in range(1000):
        fractions = [float(rng.uniform(*p.origin)) if p.origin[0] != p.origin[1] else p.origin[0] for p in plans]
        ok = True
        for i, a in enumerate(plans):
            for j in range(i):
                b = plans[j]
                if a.parent is not None and a.parent == b.parent and a.origin[0] != a.origin[1] \
                        and b.origin[0] != b.origin[1] and abs(fractions[i] - fractions[j]) < 0.08:
                    ok = False
        if ok:
            return fractions
    raise AngiohullError("internal: could not place the side branches apart")  # pragma: no cover


def _draw_stenoses(rng: np.random.Generator, count: int, length_mm: float,
                   avoid_mm: Sequence[float]) -> tuple[Stenosis, ...]:
    """Up to ``count`` stenoses, 5 mm clear of the origin, of every bifurcation and of each other."""
    placed: list[Stenosis] = []
    for _ in range(count):
        extent = float(rng.uniform(6.0, 16.0))
        severity = float(rng.uniform(0.30, 0.80))
        profile = "gaussian" if rng.random() < 0.5 else "cosine"
        half = 0.5 * extent
        for _ in range(100):
            centre = float(rng.uniform(half + 5.0, length_mm - half - 3.0)) if length_mm > extent + 8.0 else None
            if centre is None:
                break
            clear_of_branches = all(abs(centre - a) >= half + 5.0 for a in avoid_mm)
            clear_of_others = all(abs(centre - s.centre_mm) >= half + 0.5 * s.length_mm + 2.0 for s in placed)
            if clear_of_branches and clear_of_others:
                placed.append(Stenosis(centre_mm=centre, length_mm=extent, severity=severity, profile=profile))
                break
    return tuple(sorted(placed, key=lambda s: s.centre_mm))


def draw_tree_params(kind: str = "rca", tortuosity: str = "moderate",
                     rng: np.random.Generator | int | None = None) -> TreeParams:
    """Draw the record of one tree.

    Parameters
    ----------
    kind : {"rca", "left"}
        Right coronary tree (RCA with conus, acute marginal and posterior descending branches) or
        left tree (left main, LAD, LCx, 1-3 diagonals, 1-2 obtuse marginals).
    tortuosity : {"simple", "moderate", "tortuous"}
        Level; the tree's measured :func:`tree_tortuosity_index` lies in
        ``TORTUOSITY_BANDS[tortuosity]``.
    rng : numpy.random.Generator or int or None
        The source of every random draw (an int is a seed; None draws fresh entropy).

    Returns
    -------
    TreeParams
    """
    if kind not in TREE_KINDS:
        raise AngiohullError(f"tree kind must be one of {', '.join(TREE_KINDS)}, got {kind!r}")
    if tortuosity not in TORTUOSITY_LEVELS:
        raise AngiohullError(f"tortuosity must be one of {', '.join(TORTUOSITY_LEVELS)}, got {tortuosity!r}")
    seed = int(rng) if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) else None
    generator = np.random.default_rng(rng)
    heart = HeartPose(
        apex_azimuth_deg=float(generator.uniform(35.0, 55.0)),
        apex_elevation_deg=float(generator.uniform(20.0, 40.0)),
        roll_deg=float(generator.uniform(-10.0, 10.0)),
        base_radius_mm=float(generator.uniform(28.0, 34.0)),
        base_to_apex_mm=float(generator.uniform(75.0, 90.0)),
        centre_offset_mm=tuple(float(x) for x in generator.uniform(-3.0, 3.0, size=3)),
    )
    plans = _plans(kind, generator, heart.base_to_apex_mm)
    fractions = _distinct_fractions(generator, plans)
    geometry = []
    for plan, fraction in zip(plans, fractions):
        length = float(generator.uniform(*plan.length_mm))
        r0 = float(generator.uniform(*plan.radius_start_mm))
        r1 = r0 * float(generator.uniform(*plan.end_ratio))
        course = [plan.course[0]]
        for s, theta in plan.course[1:]:
            course.append((float(s + generator.uniform(-plan.jitter[0], plan.jitter[0])),
                           float(theta + generator.uniform(-plan.jitter[1], plan.jitter[1]))))
        geometry.append((plan, fraction, length, r0, r1, tuple((float(a), float(b)) for a, b in course)))
    stenoses = []
    for index, (plan, _, length, _, _, _) in enumerate(geometry):
        children = [f * length for (p, f, *_rest) in geometry if p.parent == index]
        count = int(generator.integers(0, plan.max_stenoses + 1))
        stenoses.append(_draw_stenoses(generator, count, length, children))
    low, high = TORTUOSITY_BANDS[tortuosity]
    frame = _HeartFrame.of(heart)
    for _ in range(_MAX_WAVE_DRAWS):
        # Waves branch by branch (each redrawn until its tube does not fold), then the tree's
        # tortuosity index must fall in the level's band, else all waves are drawn again.
        records: list[BranchParams] = []
        built: list[Branch] = []
        for (plan, fraction, length, r0, r1, course), sten in zip(geometry, stenoses):
            for _ in range(_MAX_WAVE_DRAWS):
                waves = _draw_waves(generator, tortuosity, r0) if plan.wavy else ()
                record = BranchParams(name=plan.name, parent=plan.parent, origin_fraction=fraction, length_mm=length,
                                      radius_start_mm=r0, radius_end_mm=r1, course_deg=course, waves=waves,
                                      stenoses=sten)
                branch = _build_branch(frame, record, None if plan.parent is None else built[plan.parent])
                if not _folds(branch):
                    break
            else:  # pragma: no cover - the courses are smooth and the waves' curvature is capped
                raise AngiohullError(f"could not draw a {plan.name} of a {tortuosity} {kind} tree that does not fold")
            records.append(record)
            built.append(branch)
        if low <= tree_tortuosity_index(built) <= high:
            return TreeParams(kind=kind, tortuosity=tortuosity, seed=seed, heart=heart, branches=tuple(records))
    raise AngiohullError(  # pragma: no cover - the bands are set well inside what the waves give
        f"could not draw a {tortuosity} {kind} tree within its tortuosity band after {_MAX_WAVE_DRAWS} tries")


def generate_tree(kind: str = "rca", tortuosity: str = "moderate",
                  rng: np.random.Generator | int | None = None) -> CoronaryTree:
    """:func:`draw_tree_params` then :func:`build_tree`."""
    return build_tree(draw_tree_params(kind, tortuosity, rng))
