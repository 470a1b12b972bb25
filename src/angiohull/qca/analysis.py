"""The whole quantitative coronary analysis of one vessel tree (:func:`analyse_tree`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from ..errors import QcaError
from ..geometry import Projection
from ..tree import VesselTree
from .attenuation import AttenuationFitSettings, ViewCalibration
from .bifurcations import BifurcationAnalysis, BifurcationSettings, analyse_bifurcations
from .profile import (DiameterProfile, Lesion, ProfileSettings, ReferenceFit, find_lesions, reference_fit,
                      smoothed_along)
from .vessels import TreeVessels, Vessel, VesselSettings, tree_vessels
from .views import ViewMap, ViewMapSettings, view_map, view_report

__all__ = ["QcaSettings", "BranchQca", "QcaResult", "analyse_tree", "branch_profile", "vessel_profiles",
           "LESION_COLUMNS", "BRANCH_COLUMNS"]

LESION_COLUMNS = ("lesion", "branch", "branch_name", "x_mm", "y_mm", "z_mm", "mld_mm", "reference_diameter_mm",
                  "diameter_stenosis_pct", "area_stenosis_pct", "lesion_length_mm", "start_mm", "end_mm",
                  "mld_arc_mm", "best_view", "best_view_foreshortening", "best_view_overlap", "mld_source")
BRANCH_COLUMNS = ("branch", "name", "parent", "parent_point", "length_mm", "mean_diameter_mm", "min_diameter_mm",
                  "max_diameter_mm", "reference_start_mm", "reference_end_mm", "lesions",
                  "max_diameter_stenosis_pct", "tortuosity_curvature_rad_per_cm", "tortuosity_soam_rad_per_cm",
                  "tortuosity_distance_metric")


@dataclass(frozen=True)
class QcaSettings:
    """Every setting of the analysis (the same defaults for every tree)."""

    profile: ProfileSettings = field(default_factory=ProfileSettings)
    vessels: VesselSettings = field(default_factory=VesselSettings)
    bifurcation: BifurcationSettings = field(default_factory=BifurcationSettings)
    view_map: ViewMapSettings = field(default_factory=ViewMapSettings)
    lesion_view_margin_mm: float = 5.0  # a lesion's working view covers it and this much either side
    lesion_views: bool = True  # compute a view map for every lesion
    attenuation: AttenuationFitSettings = field(default_factory=AttenuationFitSettings)  # MLD from the angiograms


@dataclass(frozen=True)
class BranchQca:
    index: int
    name: str
    parent: int | None
    parent_point: int | None
    length_mm: float
    mean_diameter_mm: float
    min_diameter_mm: float
    max_diameter_mm: float
    profile: DiameterProfile
    tortuosity: dict[str, float]

    def row(self) -> dict[str, Any]:
        ref = self.profile.reference
        lesions = self.profile.lesions
        analysed = self.profile.arc_mm[self.profile.analysed]
        if not analysed.size:
            ref = None
        return {"branch": self.index, "name": self.name, "parent": self.parent, "parent_point": self.parent_point,
                "length_mm": self.length_mm, "mean_diameter_mm": self.mean_diameter_mm,
                "min_diameter_mm": self.min_diameter_mm, "max_diameter_mm": self.max_diameter_mm,
                "reference_start_mm": None if ref is None else float(ref(analysed[0])),
                "reference_end_mm": None if ref is None else float(ref(analysed[-1])),
                "lesions": len(lesions),
                "max_diameter_stenosis_pct": max((les.diameter_stenosis_pct for les in lesions), default=None),
                "tortuosity_curvature_rad_per_cm": self.tortuosity.get("curvature_rad_per_cm"),
                "tortuosity_soam_rad_per_cm": self.tortuosity.get("soam_rad_per_cm"),
                "tortuosity_distance_metric": self.tortuosity.get("distance_metric")}


@dataclass(frozen=True)
class QcaResult:
    tree: VesselTree
    settings: QcaSettings
    branches: tuple[BranchQca, ...]
    lesions: tuple[Lesion, ...]  # every branch's, ordered by branch then arc length
    bifurcations: tuple[BifurcationAnalysis, ...]
    lesion_views: tuple[ViewMap, ...]  # one per lesion (empty when settings.lesion_views is False)
    views: tuple[dict, ...]  # per acquired view: foreshortening and overlap per branch
    calibrations: tuple[ViewCalibration, ...] = ()  # per view, when lesions were measured on the angiograms

    def lesion_rows(self) -> list[dict[str, Any]]:
        rows = []
        views = self.lesion_views if len(self.lesion_views) == len(self.lesions) else [None] * len(self.lesions)
        for i, (les, vm) in enumerate(zip(self.lesions, views)):
            best = vm.to_dict() if vm is not None else {}
            rows.append({"lesion": i, "branch": les.branch, "branch_name": self.tree.branches[les.branch].name,
                         "x_mm": les.mld_point_mm[0], "y_mm": les.mld_point_mm[1], "z_mm": les.mld_point_mm[2],
                         "mld_mm": les.mld_mm, "reference_diameter_mm": les.reference_diameter_mm,
                         "diameter_stenosis_pct": les.diameter_stenosis_pct,
                         "area_stenosis_pct": les.area_stenosis_pct, "lesion_length_mm": les.length_mm,
                         "start_mm": les.start_mm, "end_mm": les.end_mm, "mld_arc_mm": les.mld_arc_mm,
                         "best_view": best.get("best_view"), "best_view_foreshortening": best.get("best_foreshortening"),
                         "best_view_overlap": best.get("best_overlap"), "mld_source": les.mld_source})
        return rows

    def branch_rows(self) -> list[dict[str, Any]]:
        return [b.row() for b in self.branches]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``qca.json``): settings, branches with profiles, lesions, bifurcations, views."""
        branches = []
        for b in self.branches:
            p = b.profile
            branches.append({**b.row(), "reference_reason": p.reason or None,
                             "profile": {"arc_mm": np.round(p.arc_mm, 4).tolist(),
                                         "diameter_mm": np.round(p.diameter_mm, 4).tolist(),
                                         "analysed": p.analysed.tolist(),
                                         "reference_mm": _rounded_or_none(p.reference_mm()),
                                         "smoothed_diameter_mm": _rounded_or_none(p.smoothed_diameter_mm)}})
        return _json_safe({
            "format": "angiohull-qca", "version": 1,
            "settings": _settings_dict(self.settings),
            "tree": {"n_branches": self.tree.n_branches, "n_bifurcations": len(self.tree.bifurcations),
                     "length_mm": self.tree.length_mm},
            "branches": branches,
            "lesions": [{**row, **les.to_dict()} for row, les in zip(self.lesion_rows(), self.lesions)],
            "bifurcations": [b.to_dict() for b in self.bifurcations],
            "lesion_views": [vm.to_dict(grid=True) for vm in self.lesion_views],
            "views": list(self.views),
            "attenuation_calibrations": [c.to_dict() for c in self.calibrations],
        })


def _rounded_or_none(values: np.ndarray | None) -> list[float | None] | None:
    """A profile array for JSON: 4 decimals, None for nan (no value there)."""
    if values is None:
        return None
    return [None if not math.isfinite(x) else round(float(x), 4) for x in values]


def _settings_dict(settings: QcaSettings) -> dict[str, Any]:
    from dataclasses import asdict

    return asdict(settings)


def _json_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _check_tree(tree: Any) -> VesselTree:
    if tree is None:
        raise QcaError("quantitative analysis needs a vessel tree, got None (the reconstruction built no tree: "
                       "see its tree_error)")
    if not isinstance(tree, VesselTree):
        raise QcaError(f"quantitative analysis needs a VesselTree, got {type(tree).__name__}")
    return tree


def _vessel_name(tree: VesselTree, vessel: Vessel) -> str:
    def one(i: int) -> str:
        name = tree.branches[i].name
        return f"{i} ({name!r})" if name else str(i)

    if len(vessel.branches) == 1:
        return f"branch {one(vessel.branches[0])}"
    return "branches " + " + ".join(one(i) for i in vessel.branches) + " (read as one vessel)"


def vessel_profiles(tree: VesselTree, vessel: Vessel, settings: ProfileSettings = ProfileSettings(), *,
                    strict: bool = True) -> dict[int, DiameterProfile]:
    """The diameter profile of each branch of one vessel (:mod:`.vessels`): the reference is fitted
    and the lesions are sought along the whole vessel, then each branch gets its own part.

    A lesion is listed under the branch that holds its point of minimal lumen diameter, with its
    arc lengths along that branch (a lesion that begins on the branch this one continues starts
    below 0).
    """
    arc = vessel.arc_mm
    diameter = 2.0 * vessel.radius_mm
    analysed = np.ones(arc.shape, dtype=bool)
    head = tree.branches[vessel.branches[0]]
    if head.parent is not None:
        parent = tree.branches[head.parent]
        gap = float(np.linalg.norm(head.points_mm[0] - parent.points_mm[head.parent_point]))
        analysed = arc > max(float(parent.radius_mm[head.parent_point]) - gap, 0.0)
    what = _vessel_name(tree, vessel)
    idx = np.flatnonzero(analysed)
    fit = None
    reason = ""
    lesions: tuple[Lesion, ...] = ()
    try:
        if len(idx) < 2:
            raise QcaError(f"{what}: no point lies outside its parent's lumen; the reference fit needs at least "
                           f"{settings.min_reference_length_mm:g} mm")
        fit = reference_fit(arc[idx], diameter[idx], settings, what=what)
    except QcaError as exc:
        if strict:
            raise
        reason = str(exc)
    smoothed = np.full(arc.shape, np.nan)
    if fit is not None:
        smoothed[idx] = smoothed_along(arc[idx], diameter[idx], settings.detection_smoothing_mm)
        lesions = find_lesions(-1, arc[idx], diameter[idx], fit(arc[idx]), vessel.points_mm[idx], settings,
                               smoothed_mm=smoothed[idx])
        kept = np.zeros(arc.shape, dtype=bool)
        kept[idx] = fit.kept
    out = {}
    for k, index in enumerate(vessel.branches):
        b = tree.branches[index]
        offset = vessel.offsets_mm[k]
        mine = vessel.owner == index
        b_analysed = np.zeros(b.n_points, dtype=bool)
        b_analysed[vessel.point[mine]] = analysed[mine]
        b_smoothed = np.full(b.n_points, np.nan)
        b_smoothed[vessel.point[mine]] = smoothed[mine]
        b_fit = None
        b_lesions: list[Lesion] = []
        if fit is not None:
            b_kept = np.zeros(b.n_points, dtype=bool)
            b_kept[vessel.point[mine]] = kept[mine]
            b_fit = ReferenceFit(fit.diameter_at_start_mm + fit.slope_mm_per_mm * offset, fit.slope_mm_per_mm,
                                 fit.noise_mm, b_kept)
            for les in lesions:
                at = int(np.searchsorted(arc, les.mld_arc_mm))
                if vessel.owner[at] == index:
                    b_lesions.append(replace(les, branch=index, start_mm=les.start_mm - offset,
                                             end_mm=les.end_mm - offset, mld_arc_mm=les.mld_arc_mm - offset))
        out[index] = DiameterProfile(index, b.arc_length_mm, 2.0 * b.radius_mm, b_analysed, b_fit,
                                     tuple(sorted(b_lesions, key=lambda les: les.start_mm)), reason,
                                     vessel.branches, b_smoothed)
    return out


def branch_profile(tree: VesselTree, branch: int, settings: ProfileSettings = ProfileSettings(), *,
                   strict: bool = True, vessels: VesselSettings = VesselSettings()) -> DiameterProfile:
    """The diameter profile, reference and lesions of one branch (:mod:`.profile`), read along its
    vessel (:mod:`.vessels`, :func:`vessel_profiles`).

    Raises
    ------
    QcaError
        If the branch does not exist, or (``strict``) its vessel is too short for the reference fit;
        with ``strict=False`` such a branch gets a profile without reference or lesions, and
        ``reason`` says why.
    """
    tree = _check_tree(tree)
    if isinstance(branch, bool) or not isinstance(branch, (int, np.integer)) or not 0 <= branch < tree.n_branches:
        raise QcaError(f"branch {branch!r} does not exist: the tree has branches 0 to {tree.n_branches - 1}")
    vessel = tree_vessels(tree, vessels).of(int(branch))
    return vessel_profiles(tree, vessel, settings, strict=strict)[int(branch)]


def _tortuosity(points: np.ndarray) -> dict[str, float]:
    from ..synthetic.tortuosity import curvature_metric, distance_metric, sum_of_angles_metric

    try:
        return {"curvature_rad_per_cm": curvature_metric(points), "soam_rad_per_cm": sum_of_angles_metric(points),
                "distance_metric": distance_metric(points)}
    except ValueError:  # too short for the 1 mm resampling
        return {}


def analyse_tree(tree: VesselTree, projections: Sequence[Projection] = (), view_names: Sequence[str] | None = None,
                 settings: QcaSettings = QcaSettings(), attenuation: Sequence[np.ndarray] | None = None) -> QcaResult:
    """Quantitative coronary analysis of a vessel tree.

    Parameters
    ----------
    tree : VesselTree
        Any method's tree, or a true one (mm, patient frame).
    projections : sequence of Projection, optional
        The acquired views: each branch's foreshortening and overlap in each (``views``).
    view_names : sequence of str, optional
    settings : QcaSettings
    attenuation : sequence of (rows, cols) arrays, optional
        One flattened attenuation image per projection (the angiogram's ``log(background /
        image)``, for example :attr:`angiohull.segmentation.SegmentationResult.lumen_attenuation`): each
        lesion's minimal lumen diameter is then measured again on them (:mod:`.attenuation`;
        ``Lesion.mld_source`` says where it was), which a threshold's mask cannot give for
        lumens a few pixels wide. Needs ``projections``.

    Returns
    -------
    QcaResult
        Per branch: length, diameter profile, reference, lesions, tortuosity; per bifurcation:
        angles and Medina flags; per lesion: its view map and best working view; per view: the
        branches' foreshortening and overlap. Branches too short for a reference fit are kept
        without lesions (``profile.reason``).

    Raises
    ------
    QcaError
        If ``tree`` is None, not a VesselTree, or has no branch long enough for a reference fit;
        if ``attenuation`` is given without one image per projection, or an image's shape is not
        its projection's.
    """
    tree = _check_tree(tree)
    if attenuation is not None and len(attenuation) != len(projections):
        raise QcaError(f"attenuation needs one image per projection: {len(attenuation)} images for "
                       f"{len(projections)} projections")
    if view_names is not None and (isinstance(view_names, str) or len(view_names) != len(projections)):
        raise QcaError(f"view_names needs one name per projection: {view_names!r} for {len(projections)} projections")
    vessels = tree_vessels(tree, settings.vessels)
    profiles: dict[int, DiameterProfile] = {}
    for vessel in vessels.vessels:
        profiles.update(vessel_profiles(tree, vessel, settings.profile, strict=False))
    branches = []
    for i, b in enumerate(tree.branches):
        profile = profiles[i]
        diameter = 2.0 * b.radius_mm
        branches.append(BranchQca(i, b.name, b.parent, b.parent_point, b.length_mm, _mean_along(diameter, b.arc_length_mm),
                                  float(diameter.min()), float(diameter.max()), profile, _tortuosity(b.points_mm)))
    if all(b.profile.reference is None for b in branches):
        longest = max(branches, key=lambda b: b.length_mm)
        points = tree.branches[longest.index].n_points
        raise QcaError(f"no branch of the tree is long enough for a reference diameter fit (the longest, branch "
                       f"{longest.index}, is {longest.length_mm:.1f} mm with {points} points; the fit needs "
                       f"{settings.profile.min_reference_length_mm:g} mm and {settings.profile.min_reference_points} "
                       f"points: ProfileSettings.min_reference_length_mm, min_reference_points; a branch of few "
                       f"points can be resampled first, VesselTree.resampled)")
    calibrations: tuple[ViewCalibration, ...] = ()
    if attenuation is not None and any(b.profile.lesions for b in branches):
        branches, calibrations = _lesions_on_images(tree, branches, projections, attenuation, settings.attenuation)
    lesions = tuple(les for b in branches for les in b.profile.lesions)
    bifurcations = analyse_bifurcations(tree, lesions, settings.bifurcation, vessels=vessels)
    maps = []
    if settings.lesion_views:
        for les in lesions:
            length = tree.branches[les.branch].length_mm
            lo = max(0.0, les.start_mm - settings.lesion_view_margin_mm)
            hi = min(length, les.end_mm + settings.lesion_view_margin_mm)
            maps.append(view_map(tree, les.branch, lo, hi, settings.view_map))
    views = tuple(view_report(tree, projections, view_names, near_mm=settings.view_map.near_mm)) if projections else ()
    return QcaResult(tree, settings, tuple(branches), lesions, bifurcations, tuple(maps), views, calibrations)


def _lesions_on_images(tree: VesselTree, branches: list[BranchQca], projections: Sequence[Projection],
                       attenuation: Sequence[np.ndarray], settings: AttenuationFitSettings
                       ) -> tuple[list[BranchQca], tuple[ViewCalibration, ...]]:
    """Every lesion's MLD measured again on the angiograms (:mod:`.attenuation`, step 3): the least
    image diameter of its branch's points within its span, over the views whose image diameters
    beside the lesion agree with the tree's (step 4); a lesion the images show no narrowing at
    keeps the tree's values."""
    from .attenuation import calibrate_views, image_diameters

    every = [les for b in branches for les in b.profile.lesions]
    calibrations = tuple(calibrate_views(tree, projections, attenuation, np.array([les.mld_point_mm for les in every]),
                                         settings))
    offsets = np.concatenate([[0], np.cumsum([b.n_points for b in tree.branches])])
    out = []
    for bq in branches:
        if not bq.profile.lesions:
            out.append(bq)
            continue
        branch = tree.branches[bq.index]
        arc = branch.arc_length_mm
        measured = []
        for les in bq.profile.lesions:
            span = np.flatnonzero((arc >= les.start_mm - 1e-9) & (arc <= les.end_mm + 1e-9))
            if span.size == 0:
                span = np.array([int(np.argmin(np.abs(arc - les.mld_arc_mm)))])
            before = (arc >= les.start_mm - settings.flank_mm) & (arc < les.start_mm - settings.flank_gap_mm)
            after = (arc > les.end_mm + settings.flank_gap_mm) & (arc <= les.end_mm + settings.flank_mm)
            flank = np.flatnonzero(before | after)
            both = np.concatenate([span, flank])
            m = image_diameters(tree, offsets[bq.index] + both, projections, attenuation, calibrations,
                                np.full(both.size, 0.5 * les.reference_diameter_mm), settings)
            per_view = m.per_view_mm[:, :span.size]
            agree = np.zeros(len(projections), dtype=bool)
            for v in range(len(projections)):  # a view whose model reproduces the vessel beside the lesion
                beside = m.per_view_mm[v, span.size:]
                ok = np.isfinite(beside)
                if ok.sum() >= settings.min_flank_points:
                    ratio = float(np.median(beside[ok] / (2.0 * branch.radius_mm[flank[ok]])))
                    agree[v] = abs(math.log(ratio)) <= math.log(1.0 + settings.flank_agreement)
            per_view = np.where(agree[:, None], per_view, np.nan)
            seen = np.isfinite(per_view).any(axis=0)
            if not seen.any():
                measured.append(les)
                continue
            diameter = np.full(span.size, np.inf)
            diameter[seen] = np.nanmedian(per_view[:, seen], axis=0)
            k = int(np.argmin(diameter))
            mld = float(diameter[k])
            if mld >= les.reference_diameter_mm:  # no narrowing on the images: they see something else there
                measured.append(les)
                continue
            ratio = mld / les.reference_diameter_mm
            measured.append(replace(les, mld_arc_mm=float(arc[span[k]]),
                                    mld_point_mm=tuple(float(x) for x in branch.points_mm[span[k]]), mld_mm=mld,
                                    diameter_stenosis_pct=100.0 * (1.0 - ratio),
                                    area_stenosis_pct=100.0 * (1.0 - ratio * ratio), mld_source="images"))
        out.append(replace(bq, profile=replace(bq.profile, lesions=tuple(measured))))
    return out, calibrations


def _mean_along(values: np.ndarray, arc: np.ndarray) -> float:
    """Arc-length weighted mean (trapezoid) of a per-point quantity."""
    if arc[-1] <= 0:
        return float(values.mean())
    return float(np.sum(0.5 * (values[1:] + values[:-1]) * np.diff(arc)) / arc[-1])


def segment_view_map(tree: VesselTree, branch: int, start_mm: float | None = None, end_mm: float | None = None,
                     settings: QcaSettings = QcaSettings()) -> ViewMap:
    """The working-view map of a chosen segment (:func:`.views.view_map`)."""
    return view_map(_check_tree(tree), branch, start_mm, end_mm, settings.view_map)
