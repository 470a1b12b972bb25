"""What a view shows of a vessel tree: foreshortening, overlap, and the best working views.

Definitions (points and radii in mm, patient frame):

* **Foreshortening** of a polyline in a view: its projected length over its true length, where a
  step of length ``l`` along unit direction ``t`` at a point whose ray from the source has unit
  direction ``e`` projects to ``l sqrt(1 - (t . e)^2)`` (its length on the detector divided by
  the magnification at its depth). 1 = seen side on, 0 = seen end on.
* **Overlap**: a point of the tree is *overlapped* in a view when the projected lumen disc of
  another part of the tree covers its projected centre, i.e. their projected centres are closer
  than the sum of their projected radii, while the two points are more than
  ``r_a + r_b + near_mm`` apart in 3D (nearer points are the same stretch of vessel or the two
  sides of a bifurcation, which every view shows joined). Projected radii are ``r f / depth``.
* **View map** of a segment (a branch and an arc-length range): over a grid of C-arm angles
  within reach (primary LAO + / RAO -, secondary CRA + / CAU -, DICOM's convention, isocentric
  C-arm at the given SID and SOD; default RAO 90 to LAO 90, CAU 45 to CRA 45, every 5 degrees),
  the segment's foreshortening and the share of its points overlapped by the rest of the tree.
  The **best** view maximises ``foreshortening x (1 - overlap)``, sought on the map and then on
  a 1-degree grid around the map's best cell; scores within ``tie_score`` (0.01) of the highest
  are ties, which go to the smallest total angulation (|primary| + |secondary|).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .. import _validation as _v
from ..errors import QcaError
from ..geometry import CArmGeometry, Projection, format_clinical_angles
from ..tree import VesselTree

__all__ = ["ViewMapSettings", "ViewMap", "foreshortening", "overlapped_points", "view_map", "carm_frames",
           "segment_points", "view_report", "carm_for"]


@dataclass(frozen=True)
class ViewMapSettings:
    primary_range_deg: tuple[float, float] = (-90.0, 90.0)  # RAO 90 .. LAO 90
    secondary_range_deg: tuple[float, float] = (-45.0, 45.0)  # CAU 45 .. CRA 45
    step_deg: float = 5.0  # the map's grid
    refine_step_deg: float = 1.0  # the best view is then sought on this step around the map's best (0: not)
    sid_mm: float = 1200.0
    sod_mm: float = 800.0
    near_mm: float = 1.0  # points nearer than r_a + r_b + near_mm in 3D never overlap each other
    sample_mm: float = 0.5  # the tree is resampled this finely for the map
    tie_score: float = 0.01  # scores this close to the best count as ties (then: least angulation)

    def __post_init__(self) -> None:
        if not 0.0 <= _v.finite(self.tie_score, "ViewMapSettings.tie_score", error=QcaError) < 1.0:
            raise QcaError(f"ViewMapSettings.tie_score must lie in [0, 1), got {self.tie_score!r}")
        for name in ("step_deg", "sid_mm", "sod_mm", "near_mm", "sample_mm"):
            _v.positive_finite(getattr(self, name), f"ViewMapSettings.{name}", error=QcaError)
        refine = _v.finite(self.refine_step_deg, "ViewMapSettings.refine_step_deg", error=QcaError)
        if refine < 0:
            raise QcaError(f"ViewMapSettings.refine_step_deg must be >= 0 (0: no refinement), got {refine!r}")
        if self.sod_mm >= self.sid_mm:
            raise QcaError(f"ViewMapSettings.sod_mm must be smaller than sid_mm, got sod_mm={self.sod_mm} >= "
                           f"sid_mm={self.sid_mm}")


@dataclass(frozen=True)
class ViewMap:
    """Foreshortening and overlap of one segment over a grid of C-arm angles."""

    branch: int
    start_mm: float
    end_mm: float
    primary_deg: np.ndarray  # (P,)
    secondary_deg: np.ndarray  # (S,)
    foreshortening: np.ndarray  # (S, P) projected / true length
    overlap: np.ndarray  # (S, P) share of the segment's points overlapped
    best_primary_deg: float
    best_secondary_deg: float
    best_foreshortening: float  # at the best angles (which may lie between the map's cells)
    best_overlap: float

    @property
    def score(self) -> np.ndarray:
        return self.foreshortening * (1.0 - self.overlap)

    @property
    def best_name(self) -> str:
        return format_clinical_angles(self.best_primary_deg, self.best_secondary_deg)

    def at(self, primary_deg: float, secondary_deg: float) -> tuple[float, float]:
        """``(foreshortening, overlap)`` at the grid angles nearest the ones given."""
        i = int(np.argmin(np.abs(self.secondary_deg - secondary_deg)))
        j = int(np.argmin(np.abs(self.primary_deg - primary_deg)))
        return float(self.foreshortening[i, j]), float(self.overlap[i, j])

    def to_dict(self, *, grid: bool = False) -> dict:
        out = {"branch": self.branch, "start_mm": self.start_mm, "end_mm": self.end_mm,
               "best_view": self.best_name, "best_primary_deg": self.best_primary_deg,
               "best_secondary_deg": self.best_secondary_deg,
               "best_foreshortening": self.best_foreshortening, "best_overlap": self.best_overlap}
        if grid:
            out.update(primary_deg=self.primary_deg.tolist(), secondary_deg=self.secondary_deg.tolist(),
                       foreshortening=np.round(self.foreshortening, 4).tolist(),
                       overlap=np.round(self.overlap, 4).tolist())
        return out


def _steps(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoints (n-1, 3), unit directions (n-1, 3) and lengths (n-1,) of a polyline's steps."""
    step = np.diff(points, axis=0)
    length = np.linalg.norm(step, axis=1)
    return 0.5 * (points[1:] + points[:-1]), step / length[:, None], length


def foreshortening(points_mm: np.ndarray, camera_centre_mm: np.ndarray) -> float:
    """Projected length over true length of a polyline (module notes) seen from a point source."""
    points = np.asarray(points_mm, dtype=np.float64)
    mid, unit, length = _steps(points)
    ray = mid - np.asarray(camera_centre_mm, dtype=np.float64)
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    along = np.einsum("ij,ij->i", unit, ray)
    return float((length * np.sqrt(np.clip(1.0 - along * along, 0.0, None))).sum() / length.sum())


def overlapped_points(query: np.ndarray, uv: np.ndarray, radius_2d: np.ndarray, points_mm: np.ndarray,
                      radius_mm: np.ndarray, near_mm: float = 1.0) -> np.ndarray:
    """(Q,) bool: whether each query point (indices into the tree's points) is overlapped (module
    notes). ``uv`` (N, 2) and ``radius_2d`` (N,) are the projected centres and radii in one unit."""
    from scipy.spatial import cKDTree

    query = np.asarray(query, dtype=np.int64)
    out = np.zeros(len(query), dtype=bool)
    if len(query) == 0:
        return out
    reach = float(radius_2d.max()) * 2.0
    pairs = cKDTree(uv).query_ball_point(uv[query], r=reach)
    for k, (q, near) in enumerate(zip(query, pairs)):
        if not near:
            continue
        near = np.asarray(near, dtype=np.int64)
        covers = np.linalg.norm(uv[near] - uv[q], axis=1) < radius_2d[near] + radius_2d[q]
        apart = np.linalg.norm(points_mm[near] - points_mm[q], axis=1) > radius_mm[near] + radius_mm[q] + near_mm
        out[k] = bool((covers & apart).any())
    return out


def segment_points(tree: VesselTree, branch: int, start_mm: float | None = None,
                   end_mm: float | None = None, step_mm: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """``(points (n, 3), radii (n,))`` of ``branch`` between two arc lengths (default: all of it),
    ``step_mm`` apart or less.

    Raises
    ------
    QcaError
        If the branch does not exist or the range is empty or outside the branch.
    """
    if isinstance(branch, bool) or not isinstance(branch, (int, np.integer)) or not 0 <= branch < tree.n_branches:
        raise QcaError(f"branch {branch!r} does not exist: the tree has branches 0 to {tree.n_branches - 1}")
    b = tree.branches[int(branch)]
    arc = b.arc_length_mm
    lo = 0.0 if start_mm is None else float(start_mm)
    hi = float(arc[-1]) if end_mm is None else float(end_mm)
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo < -1e-9 or hi > arc[-1] + 1e-9 or hi - lo <= 0:
        length = math.floor(float(arc[-1]) * 1000.0) / 1000.0  # rounded down: the end it names is accepted
        raise QcaError(f"segment {lo:g}-{hi:g} mm of branch {branch} ({b.name!r}) does not exist: the branch is "
                       f"{length:.3f} mm long; give 0 <= start < end <= {length:.3f} mm")
    lo, hi = max(lo, 0.0), min(hi, float(arc[-1]))
    s = np.linspace(lo, hi, max(2, int(math.ceil((hi - lo) / step_mm)) + 1))
    points = np.column_stack([np.interp(s, arc, b.points_mm[:, k]) for k in range(3)])
    return points, np.interp(s, arc, b.radius_mm)


def carm_frames(primary_deg: np.ndarray, secondary_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(d, col, row)`` unit vectors (n, 3) of C-arm poses (see :class:`~angiohull.geometry.CArmGeometry`)."""
    a, b = np.radians(primary_deg), np.radians(secondary_deg)
    d = np.stack([np.sin(a) * np.cos(b), -np.cos(a) * np.cos(b), np.sin(b)], axis=-1)
    col = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)
    row = np.stack([np.sin(a) * np.sin(b), -np.cos(a) * np.sin(b), -np.cos(b)], axis=-1)
    return d, col, row


def _overlap_in_views(segment: np.ndarray, segment_radius: np.ndarray, cand_points: np.ndarray,
                      cand_radius: np.ndarray, apart: np.ndarray, d: np.ndarray, col: np.ndarray,
                      row: np.ndarray, sod_mm: float) -> np.ndarray:
    """(V, n) bool: each segment point overlapped in each view (module notes), by the definition:
    per view, every pair of a segment point and a point apart from it whose projections can meet
    (those inside the segment's projected bounding box grown by the largest reach)."""
    V, n = len(d), len(segment)
    out = np.zeros((V, n), dtype=bool)
    if not apart.any():
        return out
    inv_ws = 1.0 / (segment @ d.T + sod_mm)  # (n, V)
    us, vs = (segment @ col.T) * inv_ws, (segment @ row.T) * inv_ws
    inv_wc = 1.0 / (cand_points @ d.T + sod_mm)  # (m, V)
    uc, vc = (cand_points @ col.T) * inv_wc, (cand_points @ row.T) * inv_wc
    rs, rc = segment_radius[:, None] * inv_ws, cand_radius[:, None] * inv_wc
    grow = rs.max(axis=0) + rc.max(axis=0)  # (V,)
    near = ((uc >= us.min(axis=0) - grow) & (uc <= us.max(axis=0) + grow)
            & (vc >= vs.min(axis=0) - grow) & (vc <= vs.max(axis=0) + grow))  # (m, V)
    for v in np.flatnonzero(near.any(axis=0)):
        k = np.flatnonzero(near[:, v])
        reach = rs[:, v, None] + rc[k, v][None, :]
        dist2 = (us[:, v, None] - uc[k, v][None, :]) ** 2 + (vs[:, v, None] - vc[k, v][None, :]) ** 2
        out[v] = ((dist2 < reach * reach) & apart[:, k]).any(axis=1)
    return out


def view_map(tree: VesselTree, branch: int, start_mm: float | None = None, end_mm: float | None = None,
             settings: ViewMapSettings = ViewMapSettings()) -> ViewMap:
    """The view map of a segment of ``tree`` (module notes).

    Raises
    ------
    QcaError
        If the segment does not exist, or the angle ranges are outside a C-arm's.
    """
    (p0, p1), (s0, s1) = settings.primary_range_deg, settings.secondary_range_deg
    if not (-180.0 <= p0 <= p1 <= 180.0 and -90.0 <= s0 <= s1 <= 90.0 and settings.step_deg > 0):
        raise QcaError(f"view map: primary range {settings.primary_range_deg} must lie within [-180, 180] and "
                       f"secondary range {settings.secondary_range_deg} within [-90, 90] degrees, low to high, "
                       f"with a positive step (got {settings.step_deg!r})")
    segment, segment_radius = segment_points(tree, branch, start_mm, end_mm, settings.sample_mm)
    b = tree.branches[int(branch)]
    lo = 0.0 if start_mm is None else float(start_mm)
    hi = b.length_mm if end_mm is None else float(end_mm)
    resampled = tree.resampled(settings.sample_mm)
    others, others_radius, _ = resampled.points()
    points = np.concatenate([segment, others])
    radius = np.concatenate([segment_radius, others_radius])
    # 3D separation of every segment point from every point, once: the views only change 2D distances
    apart = (np.linalg.norm(segment[:, None, :] - points[None, :, :], axis=2)
             > segment_radius[:, None] + radius[None, :] + settings.near_mm)
    candidates = np.flatnonzero(apart.any(axis=0))
    segment_data = (segment, segment_radius, points[candidates], radius[candidates], apart[:, candidates])

    def evaluate(primary_deg: np.ndarray, secondary_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d, col, row = carm_frames(primary_deg, secondary_deg)
        return (_foreshortening_in_views(segment, -settings.sod_mm * d),
                _overlap_in_views(*segment_data, d, col, row, settings.sod_mm).mean(axis=1))

    primary = np.arange(p0, p1 + 1e-9, settings.step_deg)
    secondary = np.arange(s0, s1 + 1e-9, settings.step_deg)
    grid_s, grid_p = np.meshgrid(secondary, primary, indexing="ij")
    fs, ov = (x.reshape(grid_p.shape) for x in evaluate(grid_p.ravel(), grid_s.ravel()))
    flat_p, flat_s, flat_score = grid_p.ravel(), grid_s.ravel(), (fs * (1.0 - ov)).ravel()
    k = _best(flat_p, flat_s, flat_score, settings.tie_score)
    best = (float(flat_p[k]), float(flat_s[k]), float(fs.ravel()[k]), float(ov.ravel()[k]))
    if settings.refine_step_deg and settings.refine_step_deg < settings.step_deg:
        # the best cell's neighbourhood again, on the finer step
        offsets = np.arange(-settings.step_deg, settings.step_deg + 1e-9, settings.refine_step_deg)
        fine_p = np.unique(np.clip(best[0] + offsets, p0, p1))
        fine_s = np.unique(np.clip(best[1] + offsets, s0, s1))
        fp, fsec = (x.ravel() for x in np.meshgrid(fine_p, fine_s, indexing="xy"))
        f_fs, f_ov = evaluate(fp, fsec)
        k = _best(fp, fsec, f_fs * (1.0 - f_ov), settings.tie_score, float(flat_score.max()))
        best = (float(fp[k]), float(fsec[k]), float(f_fs[k]), float(f_ov[k]))
    return ViewMap(int(branch), lo, hi, primary, secondary, fs, ov, *best)


def _foreshortening_in_views(segment: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """(V,) foreshortening of a polyline seen from each of ``sources`` (V, 3)."""
    mid, unit, length = _steps(segment)
    ray = mid[None, :, :] - sources[:, None, :]
    ray /= np.linalg.norm(ray, axis=2, keepdims=True)
    along = np.einsum("vij,ij->vi", ray, unit)
    return (length * np.sqrt(np.clip(1.0 - along * along, 0.0, None))).sum(axis=1) / length.sum()


def _best(primary: np.ndarray, secondary: np.ndarray, score: np.ndarray, tie: float,
          highest: float | None = None) -> int:
    """Index of the view of the highest score (or of ``highest``, a score seen elsewhere, when
    larger); scores within ``tie`` of it are ties, which go to the smallest total angulation, then
    to the first listed."""
    top = max(float(score.max()), highest if highest is not None else -np.inf)
    best = np.flatnonzero(score >= top - tie - 1e-12)
    return int(best[np.argmin(np.abs(primary[best]) + np.abs(secondary[best]))])


def view_report(tree: VesselTree, projections: Sequence[Projection], names: Sequence[str] | None = None, *,
                near_mm: float = 1.0, sample_mm: float = 0.5) -> list[dict]:
    """Per view: each branch's foreshortening, its share of points overlapped by other parts of
    the tree, and the overlapped arc-length runs ``[start, end]`` (mm)."""
    resampled = tree.resampled(sample_mm)
    points, radius, index = resampled.points()
    arcs = [b.arc_length_mm for b in resampled.branches]
    arc = np.concatenate(arcs)
    out = []
    names = list(names) if names is not None else [f"view {i + 1}" for i in range(len(projections))]
    for name, projection in zip(names, projections):
        uv = projection.project(points)
        focal = float(np.mean(projection.focal_lengths_px))
        radius_px = radius * focal / projection.depth_mm(points)
        covered = overlapped_points(np.arange(len(points)), uv, radius_px, points, radius, near_mm)
        branches = []
        for b, branch in enumerate(resampled.branches):
            mine = index == b
            flags = covered[mine]
            runs = _runs(arc[mine], flags)
            branches.append({"branch": b, "name": branch.name,
                             "foreshortening": foreshortening(branch.points_mm, projection.camera_centre_mm),
                             "overlapped_share": float(flags.mean()), "overlapped_mm": runs})
        out.append({"view": name, "branches": branches})
    return out


def _runs(arc: np.ndarray, flags: np.ndarray) -> list[list[float]]:
    """Arc-length runs ``[start, end]`` where ``flags`` is True."""
    runs = []
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    edges = np.diff(padded)
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1):
        runs.append([float(arc[a]), float(arc[b])])
    return runs


def carm_for(primary_deg: float, secondary_deg: float, settings: ViewMapSettings = ViewMapSettings()) -> CArmGeometry:
    """A C-arm at the map's SID and SOD (for drawing or checking a best view)."""
    return CArmGeometry(primary_deg, secondary_deg, settings.sid_mm, settings.sod_mm, (0.2, 0.2), (1024, 1024))
