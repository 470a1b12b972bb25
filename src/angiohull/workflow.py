"""Running the library on a study: reconstruct, score, and write the outputs.

This sits above reconstruction and metrics (it reads nothing itself: the caller loads the
:class:`~angiohull.study.Study`) and below the CLI. Figures are drawn by the CLI with
:mod:`angiohull.viz`.
"""

from __future__ import annotations

import json
import math
import platform
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .io import write_points_ply
from .metrics import PAPER_DETECTOR_SPACING_MM, dice2d, dice2d_paper, paper_dilation_side_px, scores_3d
from .rasterise import cell_silhouette
from .reconstruction import DEFAULT_RESOLUTION, DEFAULT_THRESHOLD_PX, ReconstructionResult, reconstruct
from .reconstruction.calibration import Calibration, calibrate_shifts, shift_projection
from .study import Study, View

__all__ = ["ReconstructOptions", "reconstruct_study", "calibrate_study", "view_silhouettes", "evaluation_scores", "build_report", "write_outputs", "json_safe"]


@dataclass(frozen=True)
class ReconstructOptions:
    """Options of a study reconstruction (the CLI's flags)."""

    resolution: int | None = DEFAULT_RESOLUTION  # K, lattice points per axis (None: the preset's)
    threshold_px: float = DEFAULT_THRESHOLD_PX  # strict distance threshold, px
    engine: str = "auto"  # carving engine (auto: the fastest exact one)
    centerlines: bool = True  # extract centerline points
    device: str = "cpu"  # where the lookup/octree engines run: cpu or cuda
    min_views: int | None = None  # robust carving: views that must keep a point (None: all, the paper)
    calibrate: bool = False  # estimate per-view image shifts first (calibrate_study)
    calibrate_scale: bool = False  # also per-view image scales (implies calibrate; three views or more)
    preset: str = "paper"  # "paper" (as published) or "refined" (reconstruction.refine)

    def __post_init__(self) -> None:
        if self.calibrate_scale and not self.calibrate:  # scales are estimated with the shifts
            object.__setattr__(self, "calibrate", True)


def reconstruct_study(study: Study, options: ReconstructOptions = ReconstructOptions()) -> ReconstructionResult:
    """Reconstruct a loaded study with the given options (views in the study's order)."""
    return reconstruct(
        study.projections, study.masks,
        resolution=options.resolution, threshold_px=options.threshold_px, engine=options.engine,
        centerlines=options.centerlines, view_names=study.names, device=options.device, min_views=options.min_views,
        preset=options.preset,
    )


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
                    max_shift_px: float = 60.0) -> tuple[Study, Calibration]:
    """Estimate per-view image shifts, and scales with ``options.calibrate_scale``
    (:func:`~angiohull.reconstruction.calibration.calibrate_shifts`), and return the study with them
    applied, and the calibration."""
    calibration = calibrate_shifts(study.projections, study.masks, threshold_px=options.threshold_px,
                                   max_shift_px=max_shift_px, estimate_scale=options.calibrate_scale)
    views = tuple(_corrected_view(v, du, dv, f)
                  for v, (du, dv), f in zip(study.views, calibration.shifts_px, calibration.scales))
    return replace(study, views=views), calibration


def view_silhouettes(study: Study, result: ReconstructionResult) -> list[np.ndarray]:
    """The reconstruction's silhouette in each view at pixel resolution (bool images)."""
    return [cell_silhouette(result.vessel_points_mm, p, result.lattice_spacing_mm) for p in study.projections]


def _detector_spacing_mm(view) -> float | None:
    """Detector column spacing of a C-arm view; None for a bare matrix (unknown)."""
    return None if view.carm is None else view.carm.pixel_spacing_mm[1]


def evaluation_scores(study: Study, result: ReconstructionResult, silhouettes: list[np.ndarray]) -> dict[str, Any]:
    """The scores of ``angiohull evaluate``: 3D against the ground truth, 2D against the masks.

    ``silhouettes`` are the reconstruction's silhouettes from :func:`view_silhouettes`.

    Keys: ``dice3d``, ``iou3d`` (percent), ``chamfer_mm``, ``dice2d_paper``, ``dice2d`` (percent,
    mean over views), ``time_s`` (the reconstruction alone), ``n_points``.
    """
    if study.ground_truth_mm is None:
        raise ValueError("the study has no ground truth; add 'ground_truth: gt.npy' to its study.yaml")
    s3 = scores_3d(result.vessel_points_mm, study.ground_truth_mm)
    paper = dice2d_paper(result.vessel_points_mm, study.projections, study.masks,
                         detector_spacings_mm=[_detector_spacing_mm(v) for v in study.views])
    plain = [dice2d(s, m) for s, m in zip(silhouettes, study.masks)]
    return {
        "dice3d": s3.dice3d,
        "iou3d": s3.iou3d,
        "chamfer_mm": s3.chamfer_mm,
        "dice2d_paper": float(np.mean(paper)),
        "dice2d": float(np.mean(plain)),
        "time_s": result.time_s,
        "n_points": int(len(result.vessel_points_mm)),
    }


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
        "study": str(study.root) if study.root is not None else None,
        "options": {"resolution": result.lattice.resolution, "threshold_px": options.threshold_px,
                    "engine": options.engine, "centerlines": options.centerlines, "device": options.device,
                    "min_views": options.min_views, "calibrate": options.calibrate,
                    "calibrate_scale": options.calibrate_scale, "preset": options.preset},
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
    if scores is not None:
        report["scores"] = scores
    return json_safe(report)


def write_outputs(out_dir: Path, study: Study, result: ReconstructionResult, report: dict[str, Any]) -> dict[str, Path]:
    """Write ``vessel.ply``, ``centerlines.ply`` (when computed) and ``report.json`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"vessel": out / "vessel.ply", "report": out / "report.json"}
    write_points_ply(paths["vessel"], result.vessel_points_mm, comment="angiohull visual hull (kept lattice points)")
    if result.centerline_points_mm is not None:
        paths["centerlines"] = out / "centerlines.ply"
        write_points_ply(paths["centerlines"], result.centerline_points_mm, comment="angiohull centerline points")
    paths["report"].write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return paths
