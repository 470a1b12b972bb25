"""Running the library on a study: reconstruct, score, and write the outputs.

This sits above reconstruction and metrics (it reads nothing itself: the caller loads the
:class:`~angiohull.study.Study`) and below the CLI. Figures are drawn by the CLI with
:mod:`angiohull.viz`.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

import numpy as np

from . import __version__, compiled
from .io import write_points_ply
from .metrics import PAPER_DETECTOR_SPACING_MM, dice2d, dice2d_paper, paper_dilation_side_px, scores_3d
from .rasterise import boundary_cells, cell_silhouette
from .reconstruction import DEFAULT_THRESHOLD_PX, ReconstructionResult, reconstruct
from .reconstruction.calibration import (AGREEMENT_MIN_COVERAGE, Calibration, calibrate_shifts, shift_projection,
                                         view_coverage)
from .reconstruction.checks import (MIN_VIEW_SEPARATION_DEG, VIEW_ORDER_MARGIN, agreement_warning, edge_pixels,
                                    edge_runs, edge_warning, epipolar_check_applies, epipolar_offset_px,
                                    epipolar_warning, one_view_warning, view_angle_warning, view_order_warning,
                                    view_separation_deg)
from . import _validation as _v
from .errors import AngiohullError, GeometryError, OutputError, QcaError, ReconstructionError, StudyError, ViewerError
from .geometry import Projection
from .study import Study, View
from .tree import VesselTree

if TYPE_CHECKING:  # pragma: no cover
    from .qca import QcaResult, ViewMap
    from .tree.solid import SurfaceMesh

__all__ = ["ReconstructOptions", "reconstruct_study", "calibrate_study", "view_agreement", "agreement_warning",
           "view_separation_deg", "view_angle_warning", "MIN_VIEW_SEPARATION_DEG", "two_view_hint", "one_view_warning",
           "edge_warning", "edge_runs", "edge_pixels", "epipolar_offset_px", "epipolar_warning",
           "epipolar_check_applies", "view_order_agreement", "view_order_warning", "VIEW_ORDER_MARGIN",
           "AGREEMENT_MIN_COVERAGE",
           "ambiguity_warning", "view_silhouettes", "evaluation_scores", "tree_evaluation_scores", "tree_summary",
           "build_report", "write_outputs", "ExtraOutput", "json_safe", "load_result_for_qca", "report_projections",
           "write_qca_outputs", "ResultFolder", "load_result_folder", "output_folder", "check_output_folder",
           "StagedFolder", "folder_holds_only", "study_inputs", "output_file", "check_output_file"]


@dataclass(frozen=True)
class ReconstructOptions:
    """Options of a study reconstruction (the CLI's flags)."""

    resolution: int | None = None  # K, lattice points per axis (None: the preset's or the tree method's)
    threshold_px: float = DEFAULT_THRESHOLD_PX  # strict distance threshold, px
    engine: str = "auto"  # carving engine (auto: the fastest exact one)
    centerlines: bool = True  # extract centerline points
    device: str = "cpu"  # where the lookup/octree engines run: cpu or cuda
    min_views: int | None = None  # robust carving: views that must keep a point (None: all, the paper)
    calibrate: bool = False  # estimate per-view image shifts first (calibrate_study)
    calibrate_scale: bool = False  # also per-view image scales (implies calibrate; three views or more)
    preset: str | None = None  # the hull's: "paper" (as published, its default) or "refined" (reconstruction.refine)
    tree: bool = True  # build the vessel tree (and, when writing outputs, its mesh, label volume and exports)
    method: str | None = None  # "tree" (reconstruction.model) or "hull" (the paper's); None: options.chosen_method
    check_view_order: bool = False  # two views, the tree method: also build it with the masks swapped (view_order_agreement)

    def __post_init__(self) -> None:
        from .reconstruction import MAX_DENSE_RESOLUTION, check_threshold_px

        if self.calibrate_scale and not self.calibrate:  # scales are estimated with the shifts
            object.__setattr__(self, "calibrate", True)
        object.__setattr__(self, "threshold_px", check_threshold_px(self.threshold_px))
        if self.resolution is not None:
            k = _v.positive_int(self.resolution, "resolution", error=ReconstructionError)
            if not 2 <= k <= MAX_DENSE_RESOLUTION:
                raise ReconstructionError(f"resolution (lattice points per axis) must be within [2, "
                                          f"{MAX_DENSE_RESOLUTION}], got {k}: K**3 points are carved")
        if self.min_views is not None:
            _v.positive_int(self.min_views, "min_views", error=ReconstructionError)
        from .options import METHODS, chosen_method

        object.__setattr__(self, "method", chosen_method(self.method, self.preset, self.min_views, self.tree))
        object.__setattr__(self, "preset", "paper" if self.preset is None else self.preset)
        if self.method not in METHODS:
            raise ReconstructionError(f"unknown method {self.method!r}; choose one of {list(METHODS)}")
        if self.method == "tree" and (self.preset != "paper" or self.min_views is not None):
            raise ReconstructionError("the tree method has no preset or min_views (they choose how the hull is carved); "
                                      "drop --preset/--min-views or use --method hull")
        if self.check_view_order and self.method != "tree":
            raise ReconstructionError("the view-order check (--check-view-order) compares the tree method's trees; "
                                      "drop --method hull/--preset/--min-views, or the check")


def reconstruct_study(study: Study, options: ReconstructOptions = ReconstructOptions(), *,
                      progress: Callable[[str], None] | None = None, warn: bool = True) -> ReconstructionResult:
    """Reconstruct a loaded study with the given options (views in the study's order); ``progress``
    gets a line per stage of the tree method; ``warn``: the input checks of :func:`reconstruct`
    (the command line runs its own, calibration included)."""
    return reconstruct(
        study.projections, study.masks,
        resolution=options.resolution, threshold_px=options.threshold_px, engine=options.engine,
        centerlines=options.centerlines, view_names=study.names, device=options.device, min_views=options.min_views,
        preset=options.preset, tree=options.tree, method=options.method, progress=progress, warn=warn,
    )


def view_order_agreement(study: Study, result: ReconstructionResult) -> tuple[float, float | None]:
    """Two views: the tree method's agreement with the study's masks as given (``result``, its
    reconstruction) and with the two masks swapped between the views
    (:func:`angiohull.reconstruction.view_order_agreement`)."""
    from .reconstruction import view_order_agreement as agreement

    return agreement(study.projections, study.masks, result)


def _corrected_view(view: View, du_px: float, dv_px: float, scale: float = 1.0) -> View:
    """The view with its image scaled by ``scale`` about the principal point and then shifted by
    (du, dv): a C-arm view keeps its pose, with the source-to-image distance times ``scale`` and the
    principal point moved (exactly ``T(du, dv) S P``); a bare matrix is multiplied by both."""
    if du_px == 0 and dv_px == 0 and scale == 1.0:
        return view
    if view.carm is not None:
        du0, dv0 = view.carm.principal_offset_px
        carm = replace(view.carm, sid_mm=view.carm.sid_mm * scale, principal_offset_px=(du0 + du_px, dv0 + dv_px))
        return replace(view, carm=carm, projection=carm.projection())
    return replace(view, projection=shift_projection(view.projection.magnified(scale), du_px, dv_px))


def calibrate_study(study: Study, options: ReconstructOptions = ReconstructOptions(), *,
                    max_shift_px: float = 60.0,
                    progress: Callable[[str], None] | None = None) -> tuple[Study, Calibration]:
    """Estimate per-view image shifts, and scales with ``options.calibrate_scale``
    (:func:`~angiohull.reconstruction.calibration.calibrate_shifts`), and return the study with them
    applied, and the calibration."""
    calibration = calibrate_shifts(study.projections, study.masks, threshold_px=options.threshold_px,
                                   max_shift_px=max_shift_px, estimate_scale=options.calibrate_scale,
                                   progress=progress)
    views = tuple(_corrected_view(v, du, dv, f)
                  for v, (du, dv), f in zip(study.views, calibration.shifts_px, calibration.scales))
    return replace(study, views=views), calibration


def view_agreement(study: Study, options: ReconstructOptions = ReconstructOptions()) -> dict[str, float]:
    """Per view name, the fraction of its mask the paper's hull of all views covers
    (:func:`~angiohull.reconstruction.calibration.view_coverage`): 1 when the views agree."""
    return dict(zip(study.names, view_coverage(study.projections, study.masks, threshold_px=options.threshold_px)))


def two_view_hint(n_views: int, method: str) -> str | None:
    """The note to give when two views are reconstructed with the visual hull (None otherwise):
    the hull of two views keeps phantom volume wherever two vessels' cones cross, and the tree
    method is the one for that case (figures: docs/results/tree-method.md, 2026-12-05)."""
    if n_views != 2 or method != "hull":
        return None
    return ("note: two views: their visual hull keeps phantom volume wherever two vessels' cones cross "
            "(generated trees in two clinical views, exact masks: Dice3D 56 % with the paper preset, 68 % refined); "
            "the tree method (the default without --method hull, --preset or --min-views) rebuilds the tree from "
            "centerline correspondences instead (90 %, docs/tree-method.md)")


def ambiguity_warning(calibration: Calibration, names: Sequence[str]) -> str | None:
    """The warning to give when another view's correction explains the views as well (None if none)."""
    if not calibration.ambiguous_with:
        return None
    moved = [names[i] for i, (du, dv) in enumerate(calibration.shifts_px) if math.hypot(du, dv) >= 1.0]
    options = "; ".join(f"{names[v]} by ({d[0]:+.1f}, {d[1]:+.1f}) px (the object {t:.1f} mm away)"
                        for v, d, r, t in calibration.ambiguous_with)
    return (f"calibration is ambiguous: instead of moving {', '.join(moved)}, moving {options} explains the masks "
            f"as well; these views look from nearly the same direction, so the 3D position is uncertain by that "
            f"much (report.json: calibration.ambiguous_with); a view from another direction would decide it")


def view_silhouettes(study: Study, result: ReconstructionResult) -> list[np.ndarray]:
    """The reconstruction's silhouette in each view at pixel resolution (bool images)."""
    h = result.lattice_spacing_mm
    # the interior cells add nothing seen from outside: dropped once for all views
    points = boundary_cells(result.vessel_points_mm, h, [p.camera_centre_mm for p in study.projections])
    return [cell_silhouette(points, p, h, skip_interior=False) for p in study.projections]


def _detector_spacing_mm(view) -> float | None:
    """Detector column spacing of a C-arm view; None for a bare matrix (unknown)."""
    return None if view.carm is None else view.carm.pixel_spacing_mm[1]


def evaluation_scores(study: Study, result: ReconstructionResult, silhouettes: list[np.ndarray]) -> dict[str, Any]:
    """The scores of ``angiohull evaluate``: 3D against the ground truth, 2D against the masks, and,
    when the study has a true tree and the reconstruction built one (or tried), the tree scores
    (:func:`tree_evaluation_scores`).

    ``silhouettes`` are the reconstruction's silhouettes from :func:`view_silhouettes`.

    Keys: ``dice3d``, ``iou3d`` (percent), ``chamfer_mm``, ``dice2d_paper``, ``dice2d`` (percent,
    mean over views), ``time_s`` (the reconstruction alone), ``n_points``; with a true tree, every
    key of :meth:`~angiohull.metrics.tree.TreeScores.as_dict` (shares in [0, 1], distances in mm)
    and ``tree_s`` (time to build the tree).
    """
    if study.ground_truth_mm is None:
        raise ValueError("the study has no ground truth; add 'ground_truth: gt.npy' to its study.yaml")
    s3 = scores_3d(result.vessel_points_mm, study.ground_truth_mm)
    paper = dice2d_paper(result.vessel_points_mm, study.projections, study.masks,
                         detector_spacings_mm=[_detector_spacing_mm(v) for v in study.views])
    plain = [dice2d(s, m) for s, m in zip(silhouettes, study.masks)]
    scores = {
        "dice3d": s3.dice3d,
        "iou3d": s3.iou3d,
        "chamfer_mm": s3.chamfer_mm,
        "dice2d_paper": float(np.mean(paper)),
        "dice2d": float(np.mean(plain)),
        "time_s": result.time_s,
        "n_points": int(len(result.vessel_points_mm)),
    }
    if study.ground_truth_tree is not None and (result.tree is not None or result.tree_error is not None):
        scores.update(tree_evaluation_scores(study, result))  # (not when the tree was not asked for: --no-tree)
    return scores


def tree_evaluation_scores(study: Study, result: ReconstructionResult) -> dict[str, Any]:
    """The tree scores of a reconstruction against the study's true tree
    (:func:`angiohull.metrics.tree.tree_scores`), plus ``tree_s``. Where no tree could be built, the
    scores are nan (the counts of the true tree stay), and ``tree_error`` says why.

    Raises
    ------
    StudyError
        If the study has no true tree, or the reconstruction was run without one (``tree=False``).
    """
    from .metrics.tree import tree_scores, undefined_scores

    where = study.root if study.root is not None else "study"
    if study.ground_truth_tree is None:
        raise StudyError(f"{where}: the study has no true vessel tree for the tree scores; add "
                         f"'ground_truth_tree: gt_centerlines.npz' (.npz, .npy or .json) to its study.yaml")
    if result.tree is None and result.tree_error is None:
        raise StudyError(f"{where}: the reconstruction was run without its vessel tree (tree=False); the tree "
                         f"scores need one")
    if result.tree is not None:
        scores: dict[str, Any] = tree_scores(result.tree, study.ground_truth_tree).as_dict()
    else:  # no tree could be built: every score of the reconstruction undefined
        scores = undefined_scores(study.ground_truth_tree)
        scores["tree_error"] = result.tree_error
    scores["tree_s"] = result.timings_s.get("tree", math.nan)
    return scores


def tree_summary(tree: VesselTree | None, build: Any = None, error: str | None = None) -> dict[str, Any]:
    """The ``tree`` section of ``report.json``: counts, length, radii, how it was built (or why not)."""
    if tree is None:
        return {"built": False, "error": error}
    low, high = tree.radius_range_mm
    out: dict[str, Any] = {
        "built": True, "n_branches": tree.n_branches, "n_bifurcations": len(tree.bifurcations),
        "length_mm": tree.length_mm, "radius_min_mm": low, "radius_max_mm": high,
        "branches": [{"name": b.name, "parent": b.parent, "parent_point": b.parent_point, "n_points": b.n_points,
                      "length_mm": b.length_mm, "radius_mean_mm": float(b.radius_mm.mean())} for b in tree.branches],
    }
    if build is not None:
        sk = build.skeleton
        out["build"] = {
            "skeleton_voxels": sk.skeleton_voxels, "skeleton_parts": sk.parts, "parts_joined": sk.parts_joined,
            "parts_bridged_through_carved_hull": sk.parts_bridged, "parts_dropped": sk.parts_dropped,
            "voxels_dropped": sk.voxels_dropped, "length_dropped_mm": sk.length_dropped_mm,
            "spurs_removed": sk.spurs_removed, "cycles_cut": sk.cycles_cut,
            "points_fitted": build.points_fitted, "view_sees_share": list(build.seen_share),
            "points_no_view_sees": build.unseen_points, "unseen_leaves_removed": build.unseen_leaves_removed,
            "unseen_stub_points_removed": build.unseen_stub_points_removed,
            "fold_points_reread": build.fold_points_reread,
            "unseen_head_points_removed": build.unseen_head_points_removed,
            "tips_moved_mm": list(build.tips_moved_mm), "root_moved_to_ostium_mm": build.rerooted_mm,
            "junctions_moved_mm": list(build.junctions_moved_mm), "fit_passes": build.fit_passes,
            "timings_s": dict(build.timings_s),
        }
    return out


def json_safe(value: Any) -> Any:
    """Replace nan/inf by None and NumPy scalars/arrays by Python ones, recursively."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, Path):
        return str(value)
    return value


def build_report(study: Study, result: ReconstructionResult, options: ReconstructOptions,
                 silhouettes: list[np.ndarray], scores: dict[str, Any] | None = None) -> dict[str, Any]:
    """The content of ``report.json``: inputs, options, timings, per-view Dice2D, point counts."""
    views = []
    for i, (view, silhouette) in enumerate(zip(study.views, silhouettes)):
        entry: dict[str, Any] = {
            "name": view.name,
            "mask": str(view.mask_path) if view.mask_path is not None else None,
            "image_shape": list(view.projection.image_shape),
            "mask_pixels": int(np.count_nonzero(view.mask)),
            "geometry_source": view.source,
            "projection_matrix": view.projection.matrix.tolist(),
            "camera_centre_mm": view.projection.camera_centre_mm.tolist(),
            "applied_as": result.view_order.index(i),
            "survivors_after_view": result.survivors_per_view[result.view_order.index(i)],
            "dice2d_reprojection": dice2d(silhouette, view.mask),
            "dice2d_paper_dilation_px": paper_dilation_side_px(_detector_spacing_mm(view)),
        }
        if view.carm is not None:
            c = view.carm
            entry["carm"] = {"primary_deg": c.primary_deg, "secondary_deg": c.secondary_deg, "clinical": c.clinical_name(),
                             "sid_mm": c.sid_mm, "sod_mm": c.sod_mm, "pixel_spacing_mm": list(c.pixel_spacing_mm)}
        views.append(entry)
    report: dict[str, Any] = {
        "angiohull_version": __version__,
        "python": platform.python_version(),
        "kernels": compiled.status(),  # numba's compiled kernels or the NumPy code (the same results)
        "study": str(study.root) if study.root is not None else None,
        "options": {"resolution": result.lattice.resolution, "threshold_px": options.threshold_px,
                    "engine": options.engine, "centerlines": options.centerlines, "device": options.device,
                    "min_views": options.min_views, "calibrate": options.calibrate,
                    "calibrate_scale": options.calibrate_scale, "preset": options.preset, "tree": options.tree,
                    "method": options.method},
        "engine": result.engine,
        "cube_of_interest": {"half_edge_mm": result.lattice.half_edge_mm, "resolution": result.lattice.resolution,
                             "lattice_spacing_mm": result.lattice_spacing_mm, "n_lattice_points": result.lattice.n_points},
        "timings_s": dict(result.timings_s),
        "n_vessel_points": int(len(result.vessel_points_mm)),
        "n_centerline_points": None if result.centerline_points_mm is None else int(len(result.centerline_points_mm)),
        "views": views,
        "dice2d_reprojection_mean": float(np.mean([v["dice2d_reprojection"] for v in views])),
        "notes": {
            "dice2d_reprojection": "plain Dice2D, percent: the silhouette of the kept lattice cells at pixel resolution vs the input mask, no dilation",
            "dice2d_paper_dilation_px": f"side of the square dilation of the paper's Dice2D protocol: ceil(3 mm / detector spacing); views given as a bare matrix use the paper's {PAPER_DETECTOR_SPACING_MM} mm",
        },
    }
    if options.tree:
        report["tree"] = tree_summary(result.tree, result.tree_build, result.tree_error)
    if result.method == "tree" and result.model_build is not None:
        build = result.model_build
        report["tree_method"] = {
            "pairs": [[result.view_names[a], result.view_names[b]] for a, b in build.pairs],
            "matched_share": [float(x) for x in build.matched_share],
            "skeleton_pixels": dict(zip(result.view_names, (int(n) for n in build.skeleton_pixels))),
            "branches_removed": {"explained_by_the_others": int(build.explained_removed),
                                 "not_reproduced_by_the_matchings": int(build.unreproduced_removed),
                                 "carrying_others_not_reproduced": int(build.inner_removed)},
            "pruned_branches_put_back": int(build.restored),
            "unexplained_pixels_matched_again": int(build.rematched_pixels),
            "redundant_branches_replaced": int(build.replaced_branches),
            "runs_slid_along_rays": int(build.slid_runs),  # two views: the kept tree's last step
            "contradicted_stretch_points_removed": int(build.stretch_points_removed),
            "rebuilds": int(build.rebuilds),
            "timings_s": {k: float(v) for k, v in build.timings_s.items()},
        }
        if build.width_bias_px is not None:  # two views: one view's mask drawn wider (docs/tree-method.md, step 3)
            report["tree_method"]["width_bias"] = {"view_1_wider_by_px": round(build.width_bias_px, 3),
                                                   "taken_off": build.width_bias_taken}
        if build.claim_costs:  # two views: a tree per matching, the one judged best kept
            report["tree_method"]["matchings"] = {
                "claim_costs": [float(c) for c in build.claim_costs],
                "mask_agreement_dice": [float(a) for a in build.mask_agreement],
                "judged_score": [float(j) for j in build.judged_score],  # the agreement less the lengths' penalty
                "kept_claim_cost": float(build.kept_claim_cost),
                # trees built again, each with a piece's pairing taken for wrong (module notes): a side
                # branch, or a window of the root
                "hypotheses": [{"claim_cost": float(c), "avoided": "root window" if root else "side branch",
                                "avoided_length_mm": float(length), "mask_agreement_dice": float(a),
                                "judged_score": float(j)}
                               for (c, length, a, j), root in zip(build.hypotheses, build.hypotheses_of_root)],
                "kept_hypothesis": build.kept_hypothesis,
            }
    if scores is not None:
        report["scores"] = scores
    return json_safe(report)


ExtraOutput = tuple[str, Callable[[Path, dict[str, Any]], None]]
"""An output of another layer (the viewer, drawn by the CLI through :mod:`angiohull.viewer`) that
:func:`write_outputs` writes with the others: its file name and a function ``write(path, outputs)``
that writes the file at ``path``; ``outputs`` holds ``"mesh"`` (the tree's
:class:`~angiohull.tree.solid.SurfaceMesh`, or None) and ``"report"`` (the report as written)."""


def write_outputs(out_dir: Path, study: Study, result: ReconstructionResult, report: dict[str, Any], *,
                  extra: dict[str, ExtraOutput] | None = None) -> dict[str, Path]:
    """Write ``vessel.ply``, ``centerlines.ply`` (when computed), the tree's exports (when it was
    built: ``centerlines.vtp``, ``tree.swc``, ``tree.json``, ``vessel.stl``, ``lumen.nii.gz``,
    :func:`angiohull.exports.write_tree_exports`), ``report.json`` (with the mesh, label volume
    and export timings added to ``report["timings_s"]``) and the ``extra`` outputs (``{key: (file
    name, write)}``, :data:`ExtraOutput`; written last) into ``out_dir``, all or nothing: every
    file is written into a hidden folder inside ``out_dir`` first and moved into place when all are
    written.

    Raises
    ------
    OutputError
        If ``out_dir`` or a file cannot be written (the message names the path and the reason);
        then no file of this call is left (an ``out_dir`` created by this call is removed again).
    """
    from .exports import write_tree_exports

    def write(staging: Path) -> dict[str, str]:
        names = {"vessel": "vessel.ply", "report": "report.json"}
        mesh = None
        write_points_ply(staging / names["vessel"], result.vessel_points_mm,
                         comment="angiohull visual hull (kept lattice points)" if result.method == "hull" else
                         "angiohull tree method: lattice points inside the fitted tubes")
        if result.centerline_points_mm is not None:
            names["centerlines"] = "centerlines.ply"
            write_points_ply(staging / names["centerlines"], result.centerline_points_mm,
                             comment="angiohull centerline points")
        if result.tree is not None:
            from .tree.solid import surface_and_labels

            timings = report.setdefault("timings_s", {})
            start = time.perf_counter()
            mesh, lumen = surface_and_labels(result.tree)
            timings["mesh_and_lumen"] = time.perf_counter() - start
            start = time.perf_counter()
            exported = write_tree_exports(staging, result.tree, mesh=mesh, lumen=lumen)
            timings["exports"] = time.perf_counter() - start
            names.update({key: path.name for key, path in exported.items()})
            tree_report = report.setdefault("tree", {})
            tree_report["mesh"] = {"step_mm": mesh.step_mm, "n_vertices": int(len(mesh.vertices_mm)),
                                   "n_faces": int(len(mesh.faces)), "volume_mm3": mesh.volume_mm3}
            tree_report["lumen"] = {"spacing_mm": lumen.spacing_mm, "shape": list(lumen.labels.shape),
                                    "volume_mm3": lumen.volume_mm3}
        (staging / names["report"]).write_text(json.dumps(json_safe(report), indent=2) + "\n", encoding="utf-8")
        for key, (name, write_extra) in (extra or {}).items():
            write_extra(staging / name, {"mesh": mesh, "report": report})
            names[key] = name
        return names

    return _write_all_or_nothing(Path(out_dir), write)


def _write_all_or_nothing(out: Path, write: Callable[[Path], dict[str, str]]) -> dict[str, Path]:
    """Run ``write(staging)``, which writes files into a hidden folder inside ``out`` and returns
    ``{key: file name}``, then move every file into ``out``. On any failure no file of this call
    is left (an ``out`` created by this call is removed again) and an OSError becomes an
    :class:`OutputError` that names the folder and the reason.

    This merges files into a folder that may hold others (the library's :func:`write_outputs`);
    the command line writes whole result folders with :func:`output_folder`, which stages the
    folder beside its target and so never leaves files of an earlier run behind.
    """
    import shutil

    created = [] if out.exists() else _missing_folders(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        staging = _new_folder(out, ".angiohull-partial-")
    except OSError as exc:
        _remove_created(created)
        raise _output_error(exc, out) from None
    try:
        names = write(staging)
        for name in names.values():
            (staging / name).replace(out / name)
    except BaseException as exc:
        shutil.rmtree(staging, ignore_errors=True)
        _remove_created(created)
        if isinstance(exc, OSError):
            raise _output_error(exc, out) from None
        raise
    shutil.rmtree(staging, ignore_errors=True)
    return {key: out / name for key, name in names.items()}


# -- whole output folders: checked, staged beside the target, swapped into place ---------------------
def _output_error(exc: OSError, target: Path, what: str = "the outputs") -> OutputError:
    """An OSError while writing ``what`` into ``target`` as one line naming the folder and the reason."""
    import errno

    reason = exc.strerror or str(exc) or type(exc).__name__
    hint = ""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        hint = "; nothing was written: free some space and run the command again"
    elif exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        hint = "; nothing was written: choose a folder you may write to"
    return OutputError(f"cannot write {what} into {target}: {reason}{hint}")


def _missing_folders(path: Path) -> list[Path]:
    """The folders a ``mkdir(parents=True)`` of ``path`` would create, outermost first."""
    missing = []
    for folder in [path, *path.parents]:
        if os.path.lexists(folder):
            break
        missing.append(folder)
    return missing[::-1]


def _remove_created(folders: Sequence[Path]) -> None:
    """Remove folders this call created (outermost first in ``folders``), if they are still empty."""
    for folder in reversed(folders):
        try:
            folder.rmdir()
        except OSError:
            pass


def _new_folder(parent: Path, prefix: str) -> Path:
    """A new folder ``parent/prefix<random>`` with the usual permissions (mkdtemp's are 0700)."""
    import secrets

    while True:
        folder = parent / f"{prefix}{secrets.token_hex(4)}"
        try:
            folder.mkdir()
            return folder
        except FileExistsError:  # pragma: no cover - 2**32 names
            continue


def _listing(folder: Path, limit: int = 3) -> str:
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir())
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def folder_holds_only(folder: Path, names: Sequence[str]) -> bool:
    """True when every entry of ``folder`` matches one of ``names`` (file names or glob patterns):
    what an earlier run of the same command leaves, so that the command may replace it."""
    from fnmatch import fnmatchcase

    try:
        return all(any(fnmatchcase(p.name, pattern) for pattern in names) for p in folder.iterdir())
    except OSError:
        return False


def study_inputs(study: Study) -> list[Path]:
    """The files a loaded study was read from: its folder's ``study.yaml``, the masks, images,
    DICOM files and ground truths (what an output folder must never hold)."""
    from .study import STUDY_FILE

    files = [] if study.root is None else [Path(study.root) / STUDY_FILE]
    for view in study.views:
        files += [p for p in (view.mask_path, view.image_path, view.dicom_path) if p is not None]
    files += [p for p in (study.ground_truth_path, study.ground_truth_tree_path) if p is not None]
    return files


@dataclass(frozen=True)
class StagedFolder:
    """The folder a command writes its outputs into (``path``, hidden, beside ``target``) and the
    folder it becomes once everything is written (``target``)."""

    path: Path
    target: Path

    def final(self, path: Path) -> Path:
        """Where ``path`` (inside :attr:`path`) will be once the outputs are in place."""
        return self.target / Path(path).relative_to(self.path)


def check_output_folder(target: str | Path, *, inputs: Sequence[str | Path] = (), overwrite: bool = False,
                        replaceable: Callable[[Path], bool] | None = None, option: str = "--overwrite",
                        what: str = "the outputs") -> Path:
    """Check that a command may write ``what`` into the folder ``target``; return its absolute path.

    Refused, each with an :class:`OutputError` that names the folder, what is wrong and what to do:

    * ``target`` is a file, or one of its parents is;
    * ``target`` is, or holds, one of ``inputs`` (replacing the folder would replace the input);
    * ``target`` is a folder that is not empty, unless ``overwrite`` is set or ``replaceable(target)``
      says it holds only what an earlier run of the same command wrote (e.g. the demo's folder).

    Symbolic links in ``target`` are resolved: the folder they point to is the one written.
    """
    target = Path(os.path.realpath(os.fspath(target)))
    existing = next((p for p in [target, *target.parents] if os.path.lexists(p)), None)
    if existing is not None and existing != target and not existing.is_dir():
        raise OutputError(f"cannot write {what} into {target}: {existing} is a file, not a folder")
    for item in inputs:
        source = Path(os.path.realpath(os.fspath(item)))
        if source == target or target in source.parents:
            raise OutputError(f"{target}: holds {source}, an input of this command; writing {what} there would "
                              f"replace it: choose an output folder that holds none of the inputs")
    if os.path.lexists(target):
        if not target.is_dir():
            raise OutputError(f"{target}: is a file; {what} go into a folder: give a new or empty folder")
        try:
            empty = not any(target.iterdir())
        except OSError as exc:
            raise _output_error(exc, target, what) from None
        if not empty and not overwrite and not (replaceable is not None and replaceable(target)):
            raise OutputError(f"{target}: is not empty (holds {_listing(target)}); {what} go into a new or empty "
                              f"folder: choose another, or add {option} to replace what is there")
    return target


@contextmanager
def output_folder(target: str | Path, *, inputs: Sequence[str | Path] = (), overwrite: bool = False,
                  replaceable: Callable[[Path], bool] | None = None, option: str = "--overwrite",
                  what: str = "the outputs") -> Iterator[StagedFolder]:
    """Write a whole output folder all or nothing: checked, staged beside ``target``, swapped into place.

    ``target`` is checked first (:func:`check_output_folder`). The body writes into
    ``staged.path``, a new hidden folder beside ``target`` (same file system); when the body
    returns, an existing ``target`` is moved aside, the staged folder renamed to ``target`` and
    the old one deleted. So a run never leaves files of an earlier run behind, and when the body
    fails (a full disk, bad input found late, an interrupt) the staged folder is deleted and
    ``target`` is exactly as before: an earlier result is kept.

    Yields
    ------
    StagedFolder

    Raises
    ------
    OutputError
        From the checks, or when a folder or file cannot be written (an :class:`OSError` in the
        body: the message names ``target`` and the reason, e.g. "No space left on device").
    """
    import shutil

    target = check_output_folder(target, inputs=inputs, overwrite=overwrite, replaceable=replaceable, option=option,
                                 what=what)
    created = _missing_folders(target.parent)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        staged = StagedFolder(_new_folder(target.parent, f".{target.name}.angiohull-partial-"), target)
    except OSError as exc:
        _remove_created(created)
        raise _output_error(exc, target, what) from None
    try:
        yield staged
        if os.path.lexists(target):
            old = target.parent / f".{target.name}.angiohull-old-{staged.path.name.rsplit('-', 1)[-1]}"
            os.rename(target, old)
            try:
                os.rename(staged.path, target)
            except BaseException:
                os.rename(old, target)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(staged.path, target)
    except BaseException as exc:
        shutil.rmtree(staged.path, ignore_errors=True)
        _remove_created(created)
        if isinstance(exc, OSError):
            raise _output_error(exc, target, what) from None
        if isinstance(exc, AngiohullError) and str(staged.path) in str(exc):
            try:  # name the folder the user asked for, not the hidden staging folder
                renamed = type(exc)(str(exc).replace(str(staged.path), str(target)))
            except TypeError:
                raise exc
            raise renamed from None
        raise


def check_output_file(target: str | Path, *, inputs: Sequence[str | Path] = (), overwrite: bool = False,
                      option: str = "--overwrite", what: str = "the output") -> Path:
    """The checks of :func:`output_file` alone (before the work); returns the absolute path."""
    target = Path(os.path.realpath(os.fspath(target)))
    existing = next((p for p in target.parents if os.path.lexists(p)), None)
    if existing is not None and not existing.is_dir():
        raise OutputError(f"cannot write {what} {target}: {existing} is a file, not a folder")
    for item in inputs:
        if Path(os.path.realpath(os.fspath(item))) == target:
            raise OutputError(f"{target}: is an input of this command; writing {what} there would replace it: "
                              f"choose another output file")
    if os.path.isdir(target):
        raise OutputError(f"{target}: is a folder; give the file to write {what} to, e.g. {target / 'mask.png'}")
    if os.path.lexists(target) and not overwrite:
        raise OutputError(f"{target}: exists; choose another file, or add {option} to replace it")
    return target


@contextmanager
def output_file(target: str | Path, *, inputs: Sequence[str | Path] = (), overwrite: bool = False,
                option: str = "--overwrite", what: str = "the output") -> Iterator[Path]:
    """Write one output file all or nothing (the single-file form of :func:`output_folder`).

    Refused with an :class:`OutputError`: ``target`` is a folder, a parent is a file, ``target``
    is one of ``inputs``, or it exists and ``overwrite`` is not set. The body writes the path
    yielded (a hidden file beside ``target`` with the same extension); when the body returns, it
    is renamed over ``target`` (atomic); when it fails, it is deleted and ``target`` is untouched.
    """
    target = check_output_file(target, inputs=inputs, overwrite=overwrite, option=option, what=what)
    created = _missing_folders(target.parent)
    import secrets

    partial = target.parent / f".{target.stem}.angiohull-partial-{secrets.token_hex(4)}{target.suffix}"
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        yield partial
        os.replace(partial, target)
    except BaseException as exc:
        try:
            partial.unlink()
        except OSError:
            pass
        _remove_created(created)
        if isinstance(exc, OSError):
            raise _output_error(exc, target, what) from None
        if isinstance(exc, AngiohullError) and str(partial) in str(exc):
            try:
                renamed = type(exc)(str(exc).replace(str(partial), str(target)))
            except TypeError:
                raise exc
            raise renamed from None
        raise


# -- quantitative coronary analysis of a written result: load, write ---------------------------------
_RERUN = "run `angiohull reconstruct STUDY_DIR -o OUT_DIR` again to rewrite it"


def _read_json_object(path: Path, error: type[AngiohullError] = QcaError, rerun: str = _RERUN) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise error(f"{path}: cannot read it ({reason}); {rerun}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not JSON ({exc.msg} at line {exc.lineno}, column {exc.colno}); {rerun}") from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a JSON object, got {type(data).__name__}; {rerun}")
    return data


def report_projections(report: dict[str, Any], where: str = "report.json") -> tuple[list[Projection], list[str]]:
    """The views of a ``report.json`` (:func:`build_report`) as projections, with their names:
    each entry of ``views`` needs ``projection_matrix`` (3x4) and ``image_shape`` (rows, cols);
    ``name`` defaults to ``"view N"`` (from 1).

    Raises
    ------
    QcaError
        If ``views`` is not a list, or a view lacks a valid matrix or image shape; the message
        names ``where``, the view and the field.
    """
    views = report.get("views", [])
    if not isinstance(views, list):
        raise QcaError(f"{where}: \"views\" must be a list of views, got {type(views).__name__}; {_RERUN}")
    projections, names = [], []
    for i, view in enumerate(views):
        if not isinstance(view, dict):
            raise QcaError(f"{where}: views[{i}] must be an object, got {type(view).__name__}; {_RERUN}")
        name = view.get("name")
        name = str(name) if name not in (None, "") else f"view {i + 1}"
        label = f"{where}: views[{i}] ({name!r})"
        for key in ("projection_matrix", "image_shape"):
            if key not in view:
                raise QcaError(f"{label} has no \"{key}\"; {_RERUN}, or remove report.json to analyse the tree "
                               f"without the per-view foreshortening and overlap")
        shape = view["image_shape"]
        if not isinstance(shape, (list, tuple)):
            raise QcaError(f"{label}.image_shape must be [rows, cols], got {shape!r}; {_RERUN}")
        try:
            projections.append(Projection(view["projection_matrix"], tuple(shape)))
        except GeometryError as exc:
            raise QcaError(f"{label}.projection_matrix / image_shape: {exc}; {_RERUN}") from None
        names.append(name)
    return projections, names


def load_result_for_qca(result_dir: str | Path) -> tuple[VesselTree, list[Projection], list[str]]:
    """The vessel tree and acquired views of a reconstruction's output folder, for
    :func:`angiohull.qca.analyse_tree`.

    Reads ``RESULT_DIR/tree.json`` (:func:`angiohull.exports.read_tree_json`) and, when present,
    the ``views`` of ``RESULT_DIR/report.json`` (:func:`report_projections`); without a
    ``report.json`` the view lists are empty (the analysis then has no per-view section).

    Returns
    -------
    (VesselTree, list of Projection, list of str)
        The tree (mm, patient frame), the views as the reconstruction used them (after any
        calibration) and their names.

    Raises
    ------
    QcaError
        If the folder does not exist, holds no ``tree.json`` (e.g. a reconstruction run with
        ``--no-tree``, or one that built no tree: ``report.json``'s ``tree.error`` is quoted), or
        ``report.json`` is unreadable or has a view without a valid matrix.
    StudyError
        If ``tree.json`` is not a valid vessel tree (the message starts with its path).
    """
    from .exports import read_tree_json

    folder = Path(result_dir)
    if not folder.exists():
        raise QcaError(f"{folder}: no such folder; give the OUT_DIR of `angiohull reconstruct STUDY_DIR -o OUT_DIR`")
    if not folder.is_dir():
        raise QcaError(f"{folder}: not a folder; give the OUT_DIR of `angiohull reconstruct` (the folder that holds "
                       f"tree.json), not a file in it")
    tree_path, report_path = folder / "tree.json", folder / "report.json"
    report = _read_json_object(report_path) if report_path.is_file() else None
    if not tree_path.is_file():
        why = ""
        tree_info = report.get("tree") if report is not None else None
        if isinstance(tree_info, dict) and tree_info.get("built") is False:
            why = f" (the reconstruction built no vessel tree: {tree_info.get('error')})"
        elif report is not None and isinstance(report.get("options"), dict) and report["options"].get("tree") is False:
            why = " (the reconstruction was run with --no-tree)"
        raise QcaError(f"{tree_path}: not found{why}; the quantitative analysis needs the vessel tree: run "
                       f"`angiohull reconstruct STUDY_DIR -o {folder}` without --no-tree")
    try:
        tree = read_tree_json(tree_path)
    except StudyError as exc:
        if (folder / "study.yaml").is_file():  # e.g. the tree record of `angiohull synth`
            raise StudyError(f"{exc}; {folder} is a study folder: reconstruct it first (`angiohull reconstruct "
                             f"{folder} -o OUT_DIR`, or with --qca), then run `angiohull qca OUT_DIR`") from None
        raise
    if report is None:
        return tree, [], []
    projections, names = report_projections(report, str(report_path))
    return tree, projections, names


# -- a written result as a whole, for the viewer --------------------------------------------------------
@dataclass(frozen=True)
class ResultFolder:
    """What :func:`load_result_folder` found in a reconstruction's output folder."""

    folder: Path
    report: dict[str, Any]  # report.json
    vessel_points_mm: np.ndarray  # vessel.ply, (N, 3) mm
    centerline_points_mm: np.ndarray | None  # centerlines.ply, or None
    tree: VesselTree | None  # tree.json, or None
    mesh: "SurfaceMesh | None"  # vessel.stl, or None
    projections: list[Projection]  # report.json's views, as the reconstruction used them
    names: list[str]
    sids_mm: list[float | None]  # each view's source-to-detector distance (C-arm views), else None
    lesions: list[dict[str, Any]]  # qca/qca.json's "lesions" (empty without a qca.json)
    study: Study | None  # the study, for its ground truth; None when it was not found
    notes: list[str]  # what is left out and why, one line each


_RERUN_VIEW = "run `angiohull reconstruct STUDY_DIR -o OUT_DIR` again to rewrite it"


def load_result_folder(result_dir: str | Path, study_dir: str | Path | None = None) -> ResultFolder:
    """Read a reconstruction's output folder for the viewer (``angiohull view``).

    Needs ``report.json`` and ``vessel.ply``; reads ``centerlines.ply``, ``tree.json``, ``vessel.stl``
    and ``qca/qca.json`` when they are there. The ground truth comes from the study: ``study_dir``,
    or else the folder ``report.json`` names (``"study"``, relative to the working folder when it is
    relative); when that one cannot be loaded the result has no study and a note says why.

    Raises
    ------
    ViewerError
        If the folder does not exist, has no ``report.json`` or ``vessel.ply``, or ``qca.json``'s
        ``lesions`` is not a list of objects.
    QcaError, StudyError
        If report.json's views, tree.json or another file present is unreadable or invalid (the
        message names the file); a ``study_dir`` given that cannot be loaded.
    """
    from .exports import read_mesh_stl, read_tree_json
    from .io import read_points

    folder = Path(result_dir)
    if not folder.is_dir():
        what = "not a folder" if folder.exists() else "no such folder"
        raise ViewerError(f"{folder}: {what}; give the OUT_DIR of `angiohull reconstruct STUDY_DIR -o OUT_DIR`")
    report_path = folder / "report.json"
    if not report_path.is_file():
        hint = (f"; {folder} is a study folder: reconstruct it first (`angiohull reconstruct {folder} -o OUT_DIR`)"
                if (folder / "study.yaml").is_file() else "; give the OUT_DIR of `angiohull reconstruct`")
        raise ViewerError(f"{report_path}: not found{hint}")
    report = _read_json_object(report_path, ViewerError, _RERUN_VIEW)
    vessel_path = folder / "vessel.ply"
    if not vessel_path.is_file():
        raise ViewerError(f"{vessel_path}: not found; {_RERUN_VIEW}")
    notes: list[str] = []
    try:
        vessel = read_points(vessel_path)
    except StudyError as exc:
        raise ViewerError(f"{exc}; {_RERUN_VIEW}") from None
    centerlines = read_points(folder / "centerlines.ply") if (folder / "centerlines.ply").is_file() else None
    tree = read_tree_json(folder / "tree.json") if (folder / "tree.json").is_file() else None
    mesh = read_mesh_stl(folder / "vessel.stl") if (folder / "vessel.stl").is_file() else None
    projections, names = report_projections(report, str(report_path))
    sids: list[float | None] = []
    for view in report.get("views", []):
        carm = view.get("carm") if isinstance(view, dict) else None
        sid = carm.get("sid_mm") if isinstance(carm, dict) else None
        sids.append(float(sid) if isinstance(sid, (int, float)) and math.isfinite(sid) and sid > 0 else None)
    lesions: list[dict[str, Any]] = []
    qca_path = folder / "qca" / "qca.json"
    if qca_path.is_file():
        qca = _read_json_object(qca_path, ViewerError, "run `angiohull qca RESULT_DIR` again to rewrite it")
        rows = qca.get("lesions", [])
        if not isinstance(rows, list) or not all(isinstance(row, dict) for row in rows):
            raise ViewerError(f"{qca_path}: \"lesions\" must be a list of objects; run `angiohull qca {folder}` again")
        lesions = rows
    study = None
    if study_dir is not None:
        from .study import load_study

        study = load_study(study_dir)
    else:
        named = report.get("study")
        if isinstance(named, str) and named:
            from .study import load_study

            try:
                study = load_study(named)
            except AngiohullError as exc:
                first = str(exc).splitlines()[0]
                notes.append(f"no ground truth: the study {named} that report.json names cannot be loaded "
                             f"({first}); give it with --study STUDY_DIR")
        else:
            notes.append("no ground truth: report.json names no study; give it with --study STUDY_DIR")
    if study is not None and study.ground_truth_mm is None and study.ground_truth_tree is None:
        notes.append(f"no ground truth: the study {study.root} has none")
    return ResultFolder(folder=folder, report=report, vessel_points_mm=vessel, centerline_points_mm=centerlines,
                        tree=tree, mesh=mesh, projections=projections, names=names, sids_mm=sids, lesions=lesions,
                        study=study, notes=notes)


def _csv_cell(value: Any) -> str:
    """One CSV cell: floats at full (repr) precision, None and non-finite numbers empty."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value)).lower()
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value)) if math.isfinite(value) else ""
    return str(value)


def _write_csv(path: Path, columns: Sequence[str], rows: Sequence[dict[str, Any]]) -> None:
    import csv

    with path.open("w", encoding="utf-8", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_csv_cell(row.get(column)) for column in columns])


def write_qca_outputs(out_dir: str | Path, result: "QcaResult",
                      segment_views: Sequence["ViewMap"] = ()) -> dict[str, Path]:
    """Write a quantitative analysis into ``out_dir``, all or nothing (as :func:`write_outputs`):

    * ``qca.json``: :meth:`QcaResult.to_dict`, plus ``segment_views`` (each map with its grid,
      as ``lesion_views``) when segment maps are given;
    * ``lesions.csv``: one row per lesion, columns :data:`angiohull.qca.LESION_COLUMNS` (only the
      header when there is no lesion);
    * ``branches.csv``: one row per branch, columns :data:`angiohull.qca.BRANCH_COLUMNS`.

    Numbers in the CSV files are written at full precision (``repr``); None and nan are empty cells.

    Returns
    -------
    dict
        ``{"qca": path, "lesions": path, "branches": path}``.

    Raises
    ------
    OutputError
        If ``out_dir`` or a file cannot be written; then no file of this call is left.
    """
    from .qca import BRANCH_COLUMNS, LESION_COLUMNS, QcaResult

    if not isinstance(result, QcaResult):
        raise QcaError(f"write_qca_outputs needs a QcaResult (angiohull.qca.analyse_tree), got {type(result).__name__}")
    content = result.to_dict()
    if segment_views:
        content["segment_views"] = json_safe([vm.to_dict(grid=True) for vm in segment_views])

    def write(staging: Path) -> dict[str, str]:
        names = {"qca": "qca.json", "lesions": "lesions.csv", "branches": "branches.csv"}
        (staging / names["qca"]).write_text(json.dumps(content, indent=1) + "\n", encoding="utf-8")
        _write_csv(staging / names["lesions"], LESION_COLUMNS, result.lesion_rows())
        _write_csv(staging / names["branches"], BRANCH_COLUMNS, result.branch_rows())
        return names

    return _write_all_or_nothing(Path(out_dir), write)
