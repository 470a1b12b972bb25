"""Command-line interface: parses arguments and calls the library (``main(argv=None)``)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import math
import warnings
from pathlib import Path
from typing import Sequence, TextIO

from . import __version__
from .errors import AgreementWarning, AngiohullError, DicomGeometryWarning, InputWarning, QcaError, TreeWarning
from .options import (AUTO_ENGINE, DEFAULT_RESOLUTION, DEFAULT_THRESHOLD_PX, ENGINE_CHOICES, METHODS, PRESETS, RASTERISERS,
                      REFINED_RESOLUTION, TORTUOSITY_LEVELS, TREE_KINDS, chosen_method)

# Only the light modules above are imported at start-up (``angiohull --help`` needs no NumPy); each
# command imports what it uses. The options of a command that need a heavy module to be listed
# (segmentation parameters, shipped experiments) are built only when that command is run.

__all__ = ["main", "build_parser"]


class _Progress:
    """Stage messages on stderr (silent with --quiet or --json, where stdout carries results)."""

    def __init__(self, enabled: bool, stream: TextIO | None = None):
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.start = time.perf_counter()

    def __call__(self, message: str) -> None:
        if self.enabled:
            print(f"[{time.perf_counter() - self.start:6.2f} s] {message}", file=self.stream, flush=True)


def _add_reconstruction_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--resolution", "-k", type=int, default=None, metavar="K",
                        help=f"lattice points per axis of the cube of interest (default {REFINED_RESOLUTION}; "
                             f"{DEFAULT_RESOLUTION} for the hull's paper preset)")
    parser.add_argument("--threshold", type=float, default=DEFAULT_THRESHOLD_PX, metavar="PX",
                        help=f"keep a point when its projection is closer than PX to a mask pixel centre (default {DEFAULT_THRESHOLD_PX})")
    parser.add_argument("--engine", choices=ENGINE_CHOICES, default="auto",
                        help=f"carving engine: kdtree (the paper's reference), lookup, octree; all keep the same "
                             f"points; auto (default) = {AUTO_ENGINE}, the fastest")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="run the lookup/octree engine on the CPU (default) or a CUDA GPU (needs CuPy: "
                             "pip install 'angiohull[gpu]'); same points either way")


def _add_beyond_paper_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--method", choices=METHODS, default=None,
                        help="tree (the default, beyond the paper; two views or more): the vessel tree from "
                             "centerline correspondences across the views, tubes fitted to the masks "
                             "(docs/tree-method.md); hull (the default with --preset or --min-views): the visual "
                             "hull, the paper's method")
    parser.add_argument("--preset", choices=PRESETS, default=None,
                        help="how the hull is carved (picks --method hull when no method is named): paper (the "
                             "hull's default): the method as published; refined: specks removed from the masks, a "
                             "finer lattice, small disconnected parts dropped and the hull trimmed to the vessel "
                             "radii the views show (docs/beyond-the-paper.md)")
    parser.add_argument("--calibrate", action="store_true",
                        help="first estimate a per-view image shift that makes the views agree (header "
                             "geometry off by pixels to tens of pixels); the shifts go to report.json")
    parser.add_argument("--calibrate-scale", action="store_true",
                        help="--calibrate, and also a per-view image scale (a magnification the header has wrong, "
                             "within 15 %%; three views or more)")
    parser.add_argument("--min-views", type=int, default=None, metavar="K",
                        help="robust carving of the hull (picks --method hull when no method is named): keep a point "
                             "when at least K views keep it (default: all, the paper)")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of the ``angiohull`` command.

    With ``command``, the options of the other commands that need heavy imports to be listed are
    left out (``main`` passes the command it was given, so ``angiohull --help`` stays quick); by
    default every command is complete."""
    global _FULL
    _FULL = command
    parser = argparse.ArgumentParser(
        prog="angiohull",
        description="Visual-hull reconstruction of coronary arteries from a few X-ray angiography views "
                    "(Lau & Dziubich, Appl. Sci. 2025).",
    )
    parser.add_argument("--version", action="version", version=f"angiohull {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("reconstruct", help="reconstruct a study folder and write PLY, tree exports, report and figure",
                       description="Carve the visual hull of a study's masks and build its vessel tree; write "
                                   "vessel.ply, centerlines.ply, the tree (centerlines.vtp, tree.swc, tree.json), its "
                                   "surface (vessel.stl) and lumen labels (lumen.nii.gz), report.json, figure.png "
                                   "and viewer.html (interactive 3D) into OUT_DIR; a study with a ground truth is "
                                   "scored too, as by evaluate.")
    p.add_argument("study", type=Path, metavar="STUDY_DIR", help="study folder (or its study.yaml)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT_DIR", help="folder for the outputs")
    p.add_argument("--overwrite", action="store_true",
                   help="replace what OUT_DIR holds (a non-empty OUT_DIR is refused otherwise); the new outputs are "
                        "written beside it first and replace it only once complete")
    _add_reconstruction_options(p)
    _add_beyond_paper_options(p)
    p.add_argument("--no-centerlines", action="store_true", help="skip the centerline extraction (centerlines.ply)")
    p.add_argument("--no-tree", action="store_true",
                   help="skip the vessel tree and its exports (centerlines.vtp, tree.swc, tree.json, vessel.stl, "
                        "lumen.nii.gz)")
    p.add_argument("--no-figure", action="store_true", help="do not draw figure.png (nor, with --qca, the QCA figures)")
    p.add_argument("--no-viewer", action="store_true",
                   help="do not write viewer.html (the interactive 3D viewer; `angiohull view OUT_DIR` writes it later)")
    p.add_argument("--qca", action="store_true",
                   help="then run the quantitative coronary analysis of the tree (as `angiohull qca OUT_DIR`) and "
                        "write qca.json, lesions.csv, branches.csv and its figures into OUT_DIR/qca/")
    p.add_argument("--check-view-order", action="store_true",
                   help="two views, the tree method: build it again with the two masks swapped between the views and "
                        "warn when that explains them better (a mask given for the wrong view, which the other checks "
                        "mostly miss); the time of a second reconstruction; both agreements go to report.json: "
                        "view_order")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")

    p = sub.add_parser("evaluate", help="reconstruct a study and score it against its ground truth",
                       description="Reconstruct a study and score it: Dice3D, IoU3D, Chamfer (3 mm voxels), "
                                   "Dice2D (paper protocol and plain), time of the reconstruction alone; with a true "
                                   "vessel tree (ground_truth_tree: in study.yaml, or --ground-truth-tree) also the "
                                   "tree scores: centerline distance, overlap Ot(d), clDice, radius error, branch "
                                   "recall and precision, bifurcations (docs/vessel-tree.md).")
    p.add_argument("study", type=Path, metavar="STUDY_DIR", help="study folder with a ground_truth")
    _add_reconstruction_options(p)
    _add_beyond_paper_options(p)
    p.add_argument("--ground-truth-tree", type=Path, default=None, metavar="FILE",
                   help="the true vessel tree to score against (gt_centerlines.npz of angiohull synth, the authors' "
                        "gt_centerlines.npy, or a tree.json); overrides the study's ground_truth_tree:")
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")

    p = sub.add_parser("demo", help="run the whole pipeline on a built-in synthetic RCA tree",
                       description="Generate a synthetic right coronary tree (fixed seed), render it into three "
                                   "clinical views (or two, --views 2), reconstruct it, score it, and write "
                                   "everything into OUT_DIR.")
    p.add_argument("-o", "--output", type=Path, default=Path("angiohull-demo"), metavar="OUT_DIR",
                   help="output folder (default ./angiohull-demo)")
    p.add_argument("--views", type=int, choices=(2, 3), default=3, metavar="N",
                   help="3 (default): RAO 30 CRA 30, LAO 60 CRA 30, RAO 30 CAU 30; 2: RAO 30 CAU 25 and LAO 45 "
                        "CRA 20, the clinical standard, where the tree method matters most")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a non-empty OUT_DIR (an earlier demo's folder is replaced without it)")
    _add_reconstruction_options(p)
    _add_beyond_paper_options(p)

    p = sub.add_parser("synth", help="generate a synthetic coronary tree study with ground truth",
                       description="Draw a synthetic coronary tree (seeded), render its masks in the given views, "
                                   "apply corruptions, and write a study folder with gt.npy (surface points), "
                                   "gt_lumen.npy, gt_centerlines.npz, tree.json (the tree's record) and "
                                   "synthetic.json (options, seed, corruption records).")
    p.add_argument("output", type=Path, metavar="OUT_DIR", help="study folder to write")
    p.add_argument("--overwrite", action="store_true", help="replace what OUT_DIR holds (refused otherwise)")
    p.add_argument("--tree", choices=TREE_KINDS, default="rca", help="right coronary tree or left tree (default rca)")
    p.add_argument("--tortuosity", default="moderate", metavar="LEVEL",
                   help=f"one of {', '.join(TORTUOSITY_LEVELS)} (default moderate)")
    p.add_argument("--views", default="clinical", metavar="VIEWS",
                   help="'perpendicular', 'clinical' (RAO 30 CRA 30; LAO 60 CRA 30; RAO 30 CAU 30, the default) "
                        "or clinical angles separated by ';', e.g. \"RAO 30 CRA 30; LAO 60 CRA 30\"")
    p.add_argument("--sid-mm", type=float, default=1200.0, help="source-to-detector distance (default 1200)")
    p.add_argument("--sod-mm", type=float, default=800.0, help="source-to-isocentre distance (default 800)")
    p.add_argument("--pixel-mm", type=float, default=0.35, help="detector pixel spacing (default 0.35)")
    p.add_argument("--size", type=int, default=512, help="detector rows = columns (default 512)")
    p.add_argument("--rasteriser", choices=RASTERISERS, default="exact",
                   help="exact silhouette (default) or the paper's rasteriser (splat, close, blur)")
    p.add_argument("--corrupt", action="append", default=[], metavar="KIND=VALUES[@VIEWS]",
                   help="repeatable: translate=TX,TY (px) | scale=F | rotate=DEG | fp=P | fn=P | missing=N | "
                        "blob=N | catheter=N; @0,2 or @all picks views (default: view 0 for translate/scale/"
                        "rotate, all views otherwise)")
    p.add_argument("--seed", type=int, default=None, help="seed of every random draw (default: fresh, recorded)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    _add_qca_parser(sub)
    _add_view_parser(sub)
    _add_dicom_commands(sub)
    _add_experiment_parsers(sub)
    return parser


def _format_scores(scores: dict) -> str:
    def fmt(value, unit="", digits=2):
        return "n/a" if value is None else f"{value:.{digits}f}{unit}"
    text = (f"Dice3D {fmt(scores['dice3d'], ' %')}  IoU3D {fmt(scores['iou3d'], ' %')}  "
            f"Chamfer {fmt(scores['chamfer_mm'], ' mm', 3)}  Dice2D(paper) {fmt(scores['dice2d_paper'], ' %')}  "
            f"Dice2D(plain) {fmt(scores['dice2d'], ' %')}  time {fmt(scores['time_s'], ' s', 3)}  points {scores['n_points']}")
    if "centerline_mean_mm" in scores:
        text += (f"\ntree: centerline mean {fmt(scores['centerline_mean_mm'], ' mm', 3)}  p95 "
                 f"{fmt(scores['centerline_p95_mm'], ' mm', 2)}  Ot(1 mm) {fmt(scores['ot1mm'], '', 3)}  clDice "
                 f"{fmt(scores['cldice'], '', 3)}  radius MAE {fmt(scores['radius_mae_mm'], ' mm', 3)} (bias "
                 f"{fmt(scores['radius_bias_mm'], ' mm', 3)})  branches found {scores['branches_found']} of "
                 f"{scores['branches_true']}  bifurcations matched {scores['bifurcations_matched']} of "
                 f"{scores['bifurcations_true']}")
        if scores.get("tree_error"):
            text += f" (no tree: {scores['tree_error']})"
    return text


def _score_lines(scores: dict) -> list[str]:
    """The scores of _format_scores in one or two short lines (3D and 2D; the tree's), for the figure."""
    def fmt(key, unit="", digits=1):
        value = scores.get(key)
        return "n/a" if value is None else f"{value:.{digits}f}{unit}"

    lines = [f"Dice3D {fmt('dice3d', ' %')} · IoU3D {fmt('iou3d', ' %')} · Chamfer {fmt('chamfer_mm', ' mm', 2)} · "
             f"Dice2D {fmt('dice2d_paper', ' %')} (paper protocol), {fmt('dice2d', ' %')} (plain)"]
    if "centerline_mean_mm" in scores:
        lines.append(f"tree: centerline distance {fmt('centerline_mean_mm', ' mm', 2)} (p95 "
                     f"{fmt('centerline_p95_mm', ' mm', 2)}) · Ot(1 mm) {fmt('ot1mm', '', 2)} · clDice "
                     f"{fmt('cldice', '', 2)} · radius MAE {fmt('radius_mae_mm', ' mm', 2)} (bias "
                     f"{fmt('radius_bias_mm', ' mm', 2)}) · branches found {scores.get('branches_found')} of "
                     f"{scores.get('branches_true')} · bifurcations matched {scores.get('bifurcations_matched')} of "
                     f"{scores.get('bifurcations_true')}")
    return lines


def _view_images(study) -> list | None:
    """Per view, the angiogram an ``image:`` view was segmented from (read again: the study keeps only
    the mask), else None; None when no view has one. A DICOM image without a recorded frame is read
    with the automatic frame choice again (the default settings)."""
    if all(view.image_path is None for view in study.views):
        return None
    from . import io
    from .dicom import read_xa_view

    images = []
    for view in study.views:
        image = None
        if view.image_path is not None:
            try:
                if view.image_path.suffix.lower() in io.IMAGE_SUFFIXES:
                    image = io.read_image(view.image_path)
                else:
                    image = read_xa_view(view.image_path, view.frame).image
            except AngiohullError:  # drawn without it; the study loaded it once already
                image = None
            if image is not None and image.shape[:2] != view.mask.shape:
                image = None
        images.append(image)
    return images


def _run_title(study, result, options, calibration) -> str:
    """What was run, for the figure's and the viewer's title: study, lattice, preset, calibration."""
    if calibration is None:
        calibrated = "no calibration"
    else:
        largest = max(((du * du + dv * dv) ** 0.5 for du, dv in calibration.shifts_px), default=0.0)
        calibrated = f"calibrated shifts (largest {largest:.1f} px)"
        if options.calibrate_scale:
            calibrated += f" and scales ({min(calibration.scales):.3f}-{max(calibration.scales):.3f})"
    name = f"{study.root.name} — " if study.root is not None and study.root.name else ""
    return (f"angiohull — {name}K={result.lattice.resolution}, threshold {options.threshold_px:g} px, engine "
            f"{result.engine}, {_method_name(result.method, result.preset)}, {calibrated}")


def _chosen_method(args) -> str:
    """The method the command's flags choose (:func:`angiohull.options.chosen_method`)."""
    return chosen_method(getattr(args, "method", None), getattr(args, "preset", None),
                         getattr(args, "min_views", None), not getattr(args, "no_tree", False))


def _method_name(method: str | None, preset: str | None) -> str:
    """The method for a title: "tree method", or the hull's "paper preset" / "refined preset"."""
    return "tree method" if method == "tree" else f"{preset or '?'} preset"


def _viewer_views(study) -> list:
    from .viewer import ViewerView

    return [ViewerView(view.name, view.projection, None if view.carm is None else view.carm.sid_mm)
            for view in study.views]


def _check_viewer_available() -> None:
    """Fail before the work when plotly (a dependency) is missing, not after it."""
    from importlib.util import find_spec

    if find_spec("plotly") is None:
        raise AngiohullError("viewer.html needs the Python package plotly, which is not installed: pip install "
                             "plotly, or pass --no-viewer")


def _format_tree(report: dict) -> str | None:
    tree = report.get("tree")
    if not tree:
        return None
    if not tree.get("built"):
        return f"no vessel tree: {tree.get('error')}"
    return (f"vessel tree: {tree['n_branches']} branches, {tree['n_bifurcations']} bifurcations, "
            f"{tree['length_mm']:.1f} mm, radius {tree['radius_min_mm']:.2f}-{tree['radius_max_mm']:.2f} mm")


def _check_reconstruction_flags(args) -> None:
    """--threshold, --resolution and --min-views within their bounds, before any file is read (the
    message names the flag)."""
    from .reconstruction import MAX_DENSE_RESOLUTION, check_threshold_px

    check_threshold_px(args.threshold, "--threshold")
    if args.resolution is not None and not 2 <= args.resolution <= MAX_DENSE_RESOLUTION:
        raise AngiohullError(f"--resolution must be within [2, {MAX_DENSE_RESOLUTION}] lattice points per axis, got "
                             f"{args.resolution}: K**3 points are carved (the paper uses 100)")
    if getattr(args, "min_views", None) is not None and args.min_views < 1:
        raise AngiohullError(f"--min-views must be at least 1, got {args.min_views}")


def _relocated(value, old: str, new: str):
    """``value`` (JSON data) with every text that starts with the folder ``old`` moved to ``new``."""
    if isinstance(value, dict):
        return {k: _relocated(v, old, new) for k, v in value.items()}
    if isinstance(value, list):
        return [_relocated(v, old, new) for v in value]
    if isinstance(value, str) and (value == old or value.startswith(old + "/")):
        return new + value[len(old):]
    return value


def _run_study(study, options, staged, progress: _Progress, *, figure: bool, score: bool, viewer: bool = False,
               viewer_state: dict | None = None):
    """Reconstruct (and score) a loaded study; with ``staged`` (a workflow.StagedFolder), write
    the outputs (with viewer.html when ``viewer``) and the figure into ``staged.path``.

    ``viewer_state``, when given, receives the viewer's inputs (mesh included) so that the caller
    can write the page again with more layers (the lesions of ``reconstruct --qca``)."""
    from . import workflow

    calibration = None
    if options.calibrate:
        what = "shifts and scales" if options.calibrate_scale else "shifts"
        progress(f"calibrating {len(study.views)} views (per-view image {what})")
        study, calibration = workflow.calibrate_study(study, options, progress=progress)
        shifts = ", ".join(f"{n} ({du:+.1f}, {dv:+.1f})" for n, (du, dv) in zip(study.names, calibration.shifts_px))
        progress(f"shifts (du, dv) px: {shifts} ({calibration.outcome.split(':')[0]}, {calibration.time_s:.1f} s)")
        if options.calibrate_scale:
            progress("scales: " + ", ".join(f"{n} {f:.4f}" for n, f in zip(study.names, calibration.scales)))
        moved_px = max(math.hypot(du, dv) for du, dv in calibration.shifts_px)
        if len(study.views) == 2 and moved_px >= 1.0 and not calibration.outcome.startswith("reverted"):
            progress("note: two views determine only the shift across the epipolar lines: the vessels' shape comes "
                     "back, but the whole object may sit millimetres from where it is along the rest of the shift, "
                     "which two views cannot see (one view moved 20 px: 4.2-4.8 mm; docs/tree-method.md)")
        if calibration.outcome.startswith("reverted"):
            warnings.warn(f"calibration {calibration.outcome}", AgreementWarning, stacklevel=1)
        ambiguity = workflow.ambiguity_warning(calibration, study.names)
        if ambiguity:
            warnings.warn(ambiguity, AgreementWarning, stacklevel=1)
        agreement = dict(zip(study.names, calibration.coverage_after))
        epipolar_px = None  # (the calibration of two views applies it)
    else:
        agreement = workflow.view_agreement(study, options)
        epipolar_px = (workflow.epipolar_offset_px(study.projections, study.masks)
                       if workflow.epipolar_check_applies(study.masks) else None)
    edges = workflow.edge_pixels(study.masks, study.names)
    message = workflow.agreement_warning(agreement, calibrated=options.calibrate, edges=edges)
    if message:
        warnings.warn(message, AgreementWarning, stacklevel=1)
    message = workflow.epipolar_warning(epipolar_px or 0.0, study.names, cut=any(edges.values()))
    if message:
        warnings.warn(message, AgreementWarning, stacklevel=1)
    separation = workflow.view_separation_deg(study.projections, study.names)
    message = workflow.view_angle_warning(separation) or workflow.one_view_warning(len(study.views))
    if message:
        warnings.warn(message, InputWarning, stacklevel=1)
    message = workflow.edge_warning(study.masks, study.names)
    if message:
        warnings.warn(message, InputWarning, stacklevel=1)
    hint = workflow.two_view_hint(len(study.views), options.method)
    if hint:
        progress(hint)
    what = _method_name(options.method, options.preset)
    progress(f"reconstructing {len(study.views)} views ({what}) with engine {options.engine}")
    result = workflow.reconstruct_study(study, options, progress=progress, warn=False)  # checked above
    progress(f"kept {len(result.vessel_points_mm)} of {result.lattice.n_points} lattice points "
             f"(carving {result.timings_s['carve']:.3f} s)")
    if options.tree:
        if result.tree is not None:
            tree_s = result.timings_s.get("tree", result.timings_s.get("tree_tree", 0.0))  # hull / tree method
            progress(f"vessel tree: {result.tree.n_branches} branches, {len(result.tree.bifurcations)} bifurcations, "
                     f"{result.tree.length_mm:.1f} mm ({tree_s:.3f} s)")
            skeleton = result.tree_build.skeleton
            if skeleton.longest_dropped_mm >= 10.0:  # the shortest branch the tree scores count
                warnings.warn(f"the vessel tree leaves out {skeleton.parts_dropped} part(s) of the hull "
                              f"({skeleton.length_dropped_mm:.0f} mm of skeleton, the longest "
                              f"{skeleton.longest_dropped_mm:.0f} mm) that no short gap or path through the "
                              f"carving joins to it (report.json: tree.build)", TreeWarning, stacklevel=1)
        else:
            warnings.warn(f"no vessel tree: {result.tree_error}", TreeWarning, stacklevel=1)
    view_order = None
    if options.check_view_order:
        if len(study.views) != 2:
            progress(f"view order: not checked (the check swaps two views' masks; with {len(study.views)} views the "
                     f"views' agreement, checked above, warns of masks swapped between them)")
        else:
            progress("checking the view order: the tree method again with the two masks swapped between the views")
            given, swapped = workflow.view_order_agreement(study, result)
            message = workflow.view_order_warning(given, swapped, study.names)
            view_order = {"agreement_given": round(given, 4),
                          "agreement_swapped": None if swapped is None else round(swapped, 4),
                          "warn_above": workflow.VIEW_ORDER_MARGIN, "warned": message is not None}
            progress(f"view order: mean Dice of the trees' silhouettes {given:.4f} as given, "
                     + ("no tree with the masks swapped" if swapped is None else f"{swapped:.4f} swapped"))
            if message:
                warnings.warn(message, AgreementWarning, stacklevel=1)
    silhouettes = workflow.view_silhouettes(study, result)
    scores = workflow.json_safe(workflow.evaluation_scores(study, result, silhouettes)) if score else None
    report = workflow.build_report(study, result, options, silhouettes, scores)
    if view_order is not None:
        report["view_order"] = view_order
    report["view_separation_deg"] = {"pairs": separation, "warn_below": workflow.MIN_VIEW_SEPARATION_DEG}
    report["view_agreement"] = {"coverage": agreement, "min_coverage": workflow.AGREEMENT_MIN_COVERAGE,
                                "disagreeing": [n for n, c in agreement.items() if c < workflow.AGREEMENT_MIN_COVERAGE],
                                "after_calibration": calibration is not None}
    if epipolar_px is not None:  # two views: the shift across view 1's epipolar lines their masks ask for
        report["view_agreement"]["epipolar_offset_px"] = round(epipolar_px, 2)
    if calibration is not None:
        report["calibration"] = workflow.json_safe(calibration.to_dict(study.names))
    title = _run_title(study, result, options, calibration)
    if staged is not None:
        # a study written into the staged folder (the demo's) is reported where it will be
        report = _relocated(report, str(staged.path), str(staged.target))
        extra = {}
        if viewer:
            inputs = dict(vessel_points_mm=result.vessel_points_mm, tree=result.tree,
                          centerline_points_mm=result.centerline_points_mm, views=_viewer_views(study),
                          ground_truth_mm=study.ground_truth_mm, ground_truth_tree=study.ground_truth_tree,
                          title=title, subtitle=_score_lines(scores) if scores else ())
            state = viewer_state if viewer_state is not None else {}
            state.update(inputs)

            def write_viewer(path: Path, outputs: dict) -> None:
                from .viewer import viewer_html

                progress("writing viewer.html")
                mesh = outputs["mesh"]
                if mesh is not None:
                    state.update(mesh_vertices_mm=mesh.vertices_mm, mesh_faces=mesh.faces)
                path.write_text(viewer_html(**state), encoding="utf-8")

            extra["viewer"] = ("viewer.html", write_viewer)
        paths = workflow.write_outputs(staged.path, study, result, report, extra=extra)
        if figure:
            from .viz import reconstruction_figure

            progress("drawing figure.png")
            paths["figure"] = reconstruction_figure(
                staged.path / "figure.png", vessel_points_mm=result.vessel_points_mm, masks=study.masks,
                reprojections=silhouettes, view_names=study.names, centerline_points_mm=result.centerline_points_mm,
                ground_truth_mm=study.ground_truth_mm, view_scores=[v["dice2d_reprojection"] for v in report["views"]],
                title=title, scores=_score_lines(scores) if scores else None, images=_view_images(study),
                lattice_spacing_mm=result.lattice_spacing_mm,
            )
        for name, path in paths.items():
            progress(f"wrote {name}: {staged.final(path)}")
    return result, report, scores


def _cmd_reconstruct(args) -> int:
    from .study import load_study
    from .workflow import ReconstructOptions, check_output_folder, output_folder, study_inputs

    if args.qca and args.no_tree:
        raise AngiohullError("--qca analyses the vessel tree, which --no-tree skips; drop one of them")
    if not args.no_viewer:
        _check_viewer_available()
    _check_reconstruction_flags(args)
    check_output_folder(args.output, inputs=[args.study], overwrite=args.overwrite)  # before the work
    progress = _Progress(not args.quiet)
    study = load_study(args.study)
    options = ReconstructOptions(args.resolution, args.threshold, args.engine, not args.no_centerlines, args.device,
                                 min_views=args.min_views, calibrate=args.calibrate,
                                 calibrate_scale=args.calibrate_scale, preset=args.preset, tree=not args.no_tree,
                                 method=args.method, check_view_order=args.check_view_order)
    qca_error, qca_lines = None, []
    viewer_state: dict = {}
    with output_folder(args.output, inputs=[args.study, *study_inputs(study)], overwrite=args.overwrite) as staged:
        result, report, scores = _run_study(study, options, staged, progress, figure=not args.no_figure,
                                            score=study.ground_truth_mm is not None, viewer=not args.no_viewer,
                                            viewer_state=viewer_state)
        if args.qca and result.tree is not None:
            from .workflow import report_projections

            # the views as the reconstruction used them (after any calibration), as report.json records them
            projections, names = report_projections(report, str(staged.target / "report.json"))
            try:
                qca_paths, qca_lines = _run_qca(result.tree, projections, names, staged.path / "qca", progress,
                                                segments=(), figures=not args.no_figure, lesion_views=True,
                                                final_dir=staged.target / "qca",
                                                attenuation=_study_attenuation(study, names, progress))
            except QcaError as error:  # the reconstruction's outputs are kept
                qca_error = QcaError(f"--qca: {error} (the reconstruction's outputs are in {staged.target}/)")
            else:
                if not args.no_viewer:  # the page again, now with the lesions
                    from .viewer import write_viewer

                    lesions = json.loads(qca_paths["qca"].read_text(encoding="utf-8"))["lesions"]
                    if lesions:
                        progress(f"writing viewer.html again with {len(lesions)} lesion "
                                 f"marker{'s' if len(lesions) != 1 else ''}")
                        write_viewer(staged.path / "viewer.html", **viewer_state, lesions=lesions)
    if not args.quiet:
        if scores is not None:
            print(_format_scores(scores))
        per_view = ", ".join(f"{v['name']} {v['dice2d_reprojection']:.1f} %" for v in report["views"])
        print(f"{report['n_vessel_points']} vessel points, {report['n_centerline_points']} centerline points; "
              f"reprojection Dice2D: {per_view}")
        tree_line = _format_tree(report)
        if tree_line:
            print(tree_line)
    if args.qca:
        if result.tree is None:
            raise AngiohullError(f"--qca: the reconstruction built no vessel tree ({result.tree_error}), so there is "
                                 f"nothing to analyse; the other outputs are in {staged.target}/")
        if qca_error is not None:
            raise qca_error
        if not args.quiet:
            print("\n".join(qca_lines))
    return 0


def _cmd_evaluate(args) -> int:
    from .study import load_study
    from .workflow import ReconstructOptions

    _check_reconstruction_flags(args)
    progress = _Progress(not args.json)
    study = load_study(args.study)
    if study.ground_truth_mm is None:
        raise AngiohullError(f"{args.study}: the study has no ground truth; add 'ground_truth: gt.npy' to its study.yaml")
    if args.ground_truth_tree is not None:
        from dataclasses import replace

        from .exports import read_true_tree

        study = replace(study, ground_truth_tree=read_true_tree(args.ground_truth_tree),
                        ground_truth_tree_path=args.ground_truth_tree)
    options = ReconstructOptions(args.resolution, args.threshold, args.engine, centerlines=False, device=args.device,
                                 min_views=args.min_views, calibrate=args.calibrate,
                                 calibrate_scale=args.calibrate_scale, preset=args.preset,
                                 tree=study.ground_truth_tree is not None
                                 or _chosen_method(args) == "tree",
                                 method=args.method)
    _, _, scores = _run_study(study, options, None, progress, figure=False, score=True)
    if args.json:
        print(json.dumps(scores))
    else:
        print(_format_scores(scores))
    return 0


DEMO_OUTPUTS = ("study", "vessel.ply", "centerlines.ply", "centerlines.vtp", "tree.swc", "tree.json", "vessel.stl",
                "lumen.nii.gz", "report.json", "figure.png", "viewer.html", "qca")
"""What `angiohull demo` writes: a folder holding only these is an earlier demo, which a new one replaces."""


def _cmd_demo(args) -> int:
    from .demo import write_demo_study
    from .study import load_study
    from .workflow import ReconstructOptions, folder_holds_only, output_folder

    _check_reconstruction_flags(args)
    options = ReconstructOptions(args.resolution, args.threshold, args.engine, centerlines=True, device=args.device,
                                 min_views=args.min_views, calibrate=args.calibrate,
                                 calibrate_scale=args.calibrate_scale, preset=args.preset, method=args.method)
    _check_viewer_available()
    progress = _Progress(True)
    # the demo's own earlier output (run it twice) is replaced; any other non-empty folder needs --overwrite
    with output_folder(args.output, overwrite=args.overwrite, what="the demo",
                       replaceable=lambda folder: folder_holds_only(folder, DEMO_OUTPUTS)) as staged:
        progress(f"drawing the built-in synthetic RCA tree (seed 2025) and rendering {('two', 'three')[args.views - 2]} "
                 f"clinical views")
        study_yaml = write_demo_study(staged.path / "study", args.views)
        progress(f"wrote the study: {staged.final(study_yaml)}")
        study = load_study(study_yaml)
        _, report, scores = _run_study(study, options, staged, progress, figure=True, score=True, viewer=True)
    out = staged.target
    print(_format_scores(scores))
    print(f"outputs in {out}/: vessel.ply, centerlines.ply, centerlines.vtp, tree.swc, tree.json, vessel.stl, "
          f"lumen.nii.gz, report.json, viewer.html, figure.png; the study is in {out}/study/")
    return 0


SYNTH_KEPT_WARNING = 0.25
"""synth warns when corruptions leave a view less than this share of its true vessel pixels."""


def _cmd_synth(args) -> int:
    import numpy as np

    from .synthetic.case import SynthOptions, make_case, write_case
    from .workflow import check_output_folder, output_folder

    progress = _Progress(not args.quiet)
    options = SynthOptions(kind=args.tree, tortuosity=args.tortuosity, views=args.views, sid_mm=args.sid_mm,
                           sod_mm=args.sod_mm, pixel_mm=args.pixel_mm, size=args.size, rasteriser=args.rasteriser,
                           corruptions=tuple(args.corrupt), seed=args.seed)
    check_output_folder(args.output, overwrite=args.overwrite, what="the study")  # before the work
    progress(f"drawing a {options.tortuosity} {options.kind} tree and rendering {len(options.geometries())} views "
             f"({options.rasteriser} rasteriser)")
    case = make_case(options)
    for view, clean in zip(case.views, case.clean_masks):
        kept, total = int(np.count_nonzero(view.mask)), int(np.count_nonzero(clean))  # a shift moves, keeps
        if kept < SYNTH_KEPT_WARNING * total:
            warnings.warn(f"--corrupt: view {view.name} is left with {kept} of its {total} vessel pixels "
                          f"({100.0 * kept / total:.0f} %): the corruptions erased most of the vessel, so little is "
                          f"left to reconstruct from", InputWarning, stacklevel=1)
    with output_folder(args.output, overwrite=args.overwrite, what="the study") as staged:
        study_yaml = staged.final(write_case(staged.path, case))
    if not args.quiet:
        summary = case.tree.summary()
        lengths = ", ".join(f"{b['name']} {b['length_mm']:.0f} mm" for b in summary["branches"])
        stenoses = sum(len(b["stenoses"]) for b in summary["branches"])
        print(f"{study_yaml}: seed {case.seed}; {lengths}; tortuosity index "
              f"{summary['tortuosity_index_rad_per_cm']:.2f} rad/cm; {stenoses} stenos{'is' if stenoses == 1 else 'es'}")
        for view, records, changed in zip(case.views, case.corruptions, case.changed_pixels):
            for record, count in zip(records, changed):
                print(f"  {view.name}: {record.kind} {record.to_dict()} changed {count} pixels")
    return 0


# -- quantitative coronary analysis: qca ----------------------------------------------------------
_SEGMENT_FORM = "BRANCH or BRANCH:START-END (branch index, arc lengths in mm), e.g. 2 or 2:10-30"


def _segment_spec(text: str) -> tuple[int, float | None, float | None]:
    """``"2"`` -> (2, None, None): the whole branch; ``"2:10-30"`` -> (2, 10.0, 30.0)."""
    import re

    number = r"(\d+(?:\.\d*)?|\.\d+)"
    match = re.fullmatch(rf"\s*(\d+)\s*(?::\s*{number}\s*-\s*{number}\s*)?", text)
    if match is None:
        raise argparse.ArgumentTypeError(f"expected {_SEGMENT_FORM}; got {text!r}")
    branch, start, end = match.groups()
    return int(branch), (None if start is None else float(start)), (None if end is None else float(end))


def _add_qca_parser(sub) -> None:
    p = sub.add_parser("qca", help="quantitative coronary analysis of a reconstruction's vessel tree",
                       description="Quantitative coronary analysis (3D QCA) of the vessel tree of a reconstruction "
                                   "(RESULT_DIR/tree.json, and the acquired views from RESULT_DIR/report.json when "
                                   "present): per branch the length, diameter profile, reference taper and "
                                   "tortuosity; per lesion the minimal lumen diameter, % diameter stenosis, length "
                                   "and best working view; per bifurcation the angles and Medina flags; per view "
                                   "each branch's foreshortening and overlap. Writes qca.json, lesions.csv, "
                                   "branches.csv, profiles.png and one view_map_*.png per lesion and segment.")
    p.add_argument("result", type=Path, metavar="RESULT_DIR",
                   help="output folder of `angiohull reconstruct` (holds tree.json)")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="OUT_DIR",
                   help="folder for the outputs (default RESULT_DIR/qca)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a non-empty OUT_DIR (a folder holding only an earlier analysis is replaced without it)")
    p.add_argument("--segment", type=_segment_spec, action="append", default=[], metavar="BRANCH[:START-END]",
                   help="repeatable: also the view map of this segment (view_map_segment_*.png, and under "
                        "segment_views in qca.json), e.g. 2:10-30 = branch 2 from 10 to 30 mm of arc, 2 = all of "
                        "branch 2")
    p.add_argument("--no-figures", action="store_true", help="write only qca.json, lesions.csv and branches.csv")
    p.add_argument("--no-views", action="store_true",
                   help="no view map per lesion (faster; no best working view in lesions.csv)")
    p.add_argument("--study", type=Path, default=None, metavar="STUDY_DIR",
                   help="the study the result was reconstructed from: where its views are angiograms (image:), each "
                        "lesion's minimal lumen diameter is measured on them, as `reconstruct --qca` does "
                        "(docs/qca.md); the study is loaded (and segmented) again")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def _format_mm_range(value: float) -> str:
    """An arc length for a file name or a title: 0.1 mm precision, no trailing zeros (10, 12.5)."""
    text = f"{value:.1f}"
    return text[:-2] if text.endswith(".0") else text


def _branch_text(tree, index: int) -> str:
    name = tree.branches[index].name
    return f"branch {index} ({name})" if name else f"branch {index}"


def _format_lesion(i: int, row: dict) -> str:
    branch = f"branch {row['branch']}" + (f" ({row['branch_name']})" if row["branch_name"] else "")
    source = " (angiograms)" if row.get("mld_source") == "images" else ""
    text = (f"lesion {i}: {branch} {row['diameter_stenosis_pct']:.1f} % DS, MLD {row['mld_mm']:.2f} mm{source}, ref "
            f"{row['reference_diameter_mm']:.2f} mm, {row['lesion_length_mm']:.1f} mm long at "
            f"({row['x_mm']:.1f}, {row['y_mm']:.1f}, {row['z_mm']:.1f}) mm")
    if row.get("best_view"):
        text += f"; best view {row['best_view']}"
    return text


def _study_attenuation(study, names, progress: _Progress) -> list | None:
    """The flattened attenuation of each named view of ``study`` (views segmented from their
    angiograms, ``image:``), in ``names`` order, for measuring lesions on the angiograms; None (and
    a progress line saying why) where a view has none.

    Raises
    ------
    QcaError
        If a name is not a view of the study.
    """
    by_name = {view.name: view for view in study.views}
    missing = [name for name in names if name not in by_name]
    if missing:
        raise QcaError(f"the study has no view named {', '.join(repr(n) for n in missing)} (its views: "
                       f"{', '.join(repr(v.name) for v in study.views)}); give the study the result was reconstructed from")
    without = [name for name in names if by_name[name].attenuation is None]
    if without:
        progress(f"lesions measured on the tree's diameters: view{'s' if len(without) > 1 else ''} "
                 f"{', '.join(without)} {'are masks' if len(without) > 1 else 'is a mask'} (image: views, segmented "
                 f"from their angiograms, give the attenuation to measure lesions on)")
        return None
    return [by_name[name].attenuation for name in names]


def _run_qca(tree, projections, names, out_dir: Path, progress: _Progress, *, segments, figures: bool,
             lesion_views: bool, final_dir: Path, attenuation=None) -> tuple[dict[str, Path], list[str]]:
    """Analyse ``tree`` (its lesions measured on ``attenuation``, one image per projection, when
    given), write the files and figures into ``out_dir`` (to be moved to ``final_dir``); return the
    paths written and the lines that report the lesions."""
    from .qca import QcaSettings, analyse_tree, segment_view_map
    from .qca.views import segment_points
    from .workflow import write_qca_outputs

    settings = QcaSettings(lesion_views=lesion_views)
    for branch, start, end in segments:  # a segment that does not exist fails before the analysis
        segment_points(tree, branch, start, end)
    progress(f"analysing the vessel tree ({tree.n_branches} branches, {len(tree.bifurcations)} bifurcations"
             f"{f', {len(projections)} views' if projections else ', no acquired views'})")
    if attenuation is not None:
        progress(f"lesions' minimal lumen diameters measured on the {len(attenuation)} angiograms")
    result = analyse_tree(tree, projections, names, settings, attenuation=attenuation)
    segment_maps = []
    for branch, start, end in segments:
        progress(f"view map of {_branch_text(tree, branch)} "
                 f"{'' if start is None else f'{start:g}-{end:g} mm'}".rstrip())
        segment_maps.append(segment_view_map(tree, branch, start, end, settings))
    paths = write_qca_outputs(out_dir, result, segment_maps)
    if figures:
        from .viz import qca_profiles_figure, qca_view_map_figure

        progress("drawing profiles.png and the view maps")
        paths["profiles"] = qca_profiles_figure(result, out_dir / "profiles.png")
        for i, (lesion, vm) in enumerate(zip(result.lesions, result.lesion_views)):
            title = (f"lesion {i}: {_branch_text(tree, lesion.branch)}, {lesion.diameter_stenosis_pct:.0f} % DS; "
                     f"arc {vm.start_mm:.1f}-{vm.end_mm:.1f} mm")
            paths[f"view_map_lesion_{i}"] = qca_view_map_figure(vm, out_dir / f"view_map_lesion_{i}.png", title)
        for vm in segment_maps:
            key = f"view_map_segment_{vm.branch}_{_format_mm_range(vm.start_mm)}-{_format_mm_range(vm.end_mm)}"
            title = f"segment: {_branch_text(tree, vm.branch)}, arc {vm.start_mm:.1f}-{vm.end_mm:.1f} mm"
            paths[key] = qca_view_map_figure(vm, out_dir / f"{key}.png", title)
    lines = [_format_lesion(i, row) for i, row in enumerate(result.lesion_rows())]
    for vm in segment_maps:
        fs, overlap = vm.best_foreshortening, vm.best_overlap
        lines.append(f"segment {_branch_text(tree, vm.branch)} {vm.start_mm:.1f}-{vm.end_mm:.1f} mm: best view "
                     f"{vm.best_name} (foreshortening {fs:.2f}, overlap {100.0 * overlap:.0f} %)")
    worst = max(result.lesions, key=lambda les: les.diameter_stenosis_pct, default=None)
    without = sum(b.profile.reference is None for b in result.branches)
    summary = (f"{len(result.lesions)} lesion{'s' if len(result.lesions) != 1 else ''} in {tree.n_branches} "
               f"branch{'es' if tree.n_branches != 1 else ''} ({tree.length_mm:.1f} mm), "
               f"{len(result.bifurcations)} bifurcation{'s' if len(result.bifurcations) != 1 else ''}")
    if worst is not None:
        summary += f"; max {worst.diameter_stenosis_pct:.1f} % DS ({_branch_text(tree, worst.branch)})"
    if without:
        summary += f"; {without} branch{'es' if without != 1 else ''} too short for a reference diameter"
    if attenuation is not None and result.lesions:
        on_images = sum(les.mld_source == "images" for les in result.lesions)
        summary += (f"; {on_images} of {len(result.lesions)} MLDs measured on the angiograms"
                    + ("" if on_images == len(result.lesions) else
                       " (the others: no view saw the lesion clear of other vessels, none read the vessel beside "
                       "it as the tree does, or the images showed no narrowing there)"))
    lines.append(summary)
    lines.append(f"outputs in {final_dir}/: {', '.join(path.name for path in paths.values())}")
    return paths, lines


QCA_OUTPUTS = ("qca.json", "lesions.csv", "branches.csv", "profiles.png", "view_map_*.png")
"""What `angiohull qca` writes: a folder holding only these is an earlier analysis, replaced by a new one."""


def _cmd_qca(args) -> int:
    from .workflow import folder_holds_only, load_result_for_qca, output_folder

    progress = _Progress(not args.quiet)
    tree, projections, names = load_result_for_qca(args.result)
    if not projections:
        why = "its report.json lists none" if (args.result / "report.json").is_file() else "no report.json"
        progress(f"no acquired views in {args.result} ({why}): qca.json gets no per-view foreshortening and overlap")
    attenuation = None
    if args.study is not None:
        if not projections:
            raise QcaError(f"--study: {args.result} lists no acquired views (report.json), so the angiograms cannot be "
                           f"matched to the tree's views")
        from .study import load_study

        progress(f"loading {args.study} for its angiograms")
        attenuation = _study_attenuation(load_study(args.study), names, progress)
    out = args.output if args.output is not None else args.result / "qca"
    inputs = [args.result / name for name in ("tree.json", "report.json") if (args.result / name).exists()]
    # its own folder (RESULT_DIR/qca by default) holding only an earlier analysis is replaced
    with output_folder(out, inputs=inputs, overwrite=args.overwrite, what="the analysis",
                       replaceable=lambda folder: folder_holds_only(folder, QCA_OUTPUTS)) as staged:
        _, lines = _run_qca(tree, projections, names, staged.path, progress, segments=args.segment,
                            figures=not args.no_figures, lesion_views=not args.no_views, final_dir=staged.target,
                            attenuation=attenuation)
    if not args.quiet:
        print("\n".join(lines))
    return 0


# -- the interactive viewer: view ---------------------------------------------------------------------
def _add_view_parser(sub) -> None:
    p = sub.add_parser("view", help="write (again) the interactive 3D viewer of a reconstruction, and open it",
                       description="Write RESULT_DIR/viewer.html from the files of a reconstruction (report.json, "
                                   "vessel.ply, and when present tree.json, vessel.stl, centerlines.ply, qca/qca.json; "
                                   "the ground truth from the study report.json names, or --study): one self-contained "
                                   "page, offline, with the vessel surface or points, the centerlines coloured by "
                                   "radius, the truth and the error colouring, each view's source, detector and X-ray "
                                   "cone, and the lesions of a quantitative analysis.")
    p.add_argument("result", type=Path, metavar="RESULT_DIR", help="output folder of `angiohull reconstruct`")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="FILE",
                   help="the page to write (default RESULT_DIR/viewer.html)")
    p.add_argument("--study", type=Path, default=None, metavar="STUDY_DIR",
                   help="the study, for its ground truth (default: the one report.json names, when it is there)")
    p.add_argument("--open", action="store_true", help="then open the page in the web browser")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def _cmd_view(args) -> int:
    from .viewer import ViewerView, write_viewer
    from .workflow import load_result_folder

    _check_viewer_available()
    found = load_result_folder(args.result, args.study)
    report = found.report
    study = found.study
    options = report.get("options") if isinstance(report.get("options"), dict) else {}
    name = ""
    if isinstance(report.get("study"), str) and report["study"]:
        name = f"{Path(report['study']).name} — "
    threshold = options.get("threshold_px")
    threshold = f"{threshold:g}" if isinstance(threshold, (int, float)) else "?"
    title = (f"angiohull — {name}K={options.get('resolution', '?')}, threshold {threshold} px, "
             f"engine {report.get('engine', '?')}, {_method_name(options.get('method'), options.get('preset'))}, "
             + ("calibrated" if options.get("calibrate") else "no calibration"))
    scores = report.get("scores")
    mesh = found.mesh
    out = args.output if args.output is not None else found.folder / "viewer.html"
    if out.is_dir():
        raise AngiohullError(f"{out}: is a folder; -o names the page to write, e.g. {out / 'viewer.html'}")
    path = write_viewer(
        out, vessel_points_mm=found.vessel_points_mm, tree=found.tree,
        mesh_vertices_mm=None if mesh is None else mesh.vertices_mm, mesh_faces=None if mesh is None else mesh.faces,
        centerline_points_mm=found.centerline_points_mm,
        views=[ViewerView(n, p, sid) for n, p, sid in zip(found.names, found.projections, found.sids_mm)],
        ground_truth_mm=None if study is None else study.ground_truth_mm,
        ground_truth_tree=None if study is None else study.ground_truth_tree,
        lesions=found.lesions, title=title, subtitle=_score_lines(scores) if isinstance(scores, dict) else ())
    for note in found.notes:
        print(f"angiohull view: note: {note}", file=sys.stderr)
    if not args.quiet:
        layers = ["surface" if mesh is not None else "points"]
        if found.tree is not None:
            layers.append(f"{found.tree.n_branches} branches")
        if study is not None and (study.ground_truth_mm is not None or study.ground_truth_tree is not None):
            layers.append("ground truth and error")
        if found.lesions:
            layers.append(f"{len(found.lesions)} lesion{'s' if len(found.lesions) != 1 else ''}")
        layers.append(f"{len(found.names)} view{'s' if len(found.names) != 1 else ''}")
        print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB: {', '.join(layers)})")
    if args.open:
        import webbrowser

        if not webbrowser.open(path.resolve().as_uri()):
            print(f"angiohull view: note: no web browser could be started here; open {path} yourself", file=sys.stderr)
    return 0


# -- DICOM input and segmentation: dicom-info, segment, study-from-dicom ------------------------
_FULL: str | None = None  # the command whose options build_parser builds completely (None: all)


def _complete(name: str) -> bool:
    """Whether build_parser builds command ``name``'s options that need heavy imports."""
    return _FULL is None or _FULL == name


def _add_segmentation_options(parser: argparse.ArgumentParser, command: str) -> None:
    """One option per field of SegmentationParameters (defaults shown; see angiohull.segmentation)."""
    if not _complete(command):
        return
    from dataclasses import fields

    from .segmentation import SegmentationParameters

    group = parser.add_argument_group("segmentation parameters (angiohull.segmentation.SegmentationParameters)")
    default = SegmentationParameters()
    for item in fields(SegmentationParameters):
        flag = "--" + item.name.replace("_", "-")
        value = getattr(default, item.name)
        text = f"{item.metadata['help']} (default {value if not isinstance(value, tuple) else ','.join(f'{v:g}' for v in value)})"
        text = text.replace("%", "%%")  # argparse formats help texts with %: a bare % (e.g. "percentile, %") breaks --help
        if isinstance(value, bool):
            group.add_argument(flag, dest=f"seg_{item.name}", action=argparse.BooleanOptionalAction, default=None, help=text)
        elif isinstance(value, tuple):
            group.add_argument(flag, dest=f"seg_{item.name}", type=_float_list, default=None, metavar="S1,S2,...", help=text)
        elif item.name in ("vessels", "method"):
            choices = ("dark", "bright") if item.name == "vessels" else ("sato", "frangi")
            group.add_argument(flag, dest=f"seg_{item.name}", choices=choices, default=None, help=text)
        else:
            group.add_argument(flag, dest=f"seg_{item.name}", type=type(value), default=None, metavar="N", help=text)


def _float_list(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, e.g. 1.5,2.5,4, got {text!r}") from None


def _segmentation_parameters(args):
    from .segmentation import SegmentationParameters

    prefix = "seg_"
    overrides = {key[len(prefix):]: value for key, value in vars(args).items() if key.startswith(prefix) and value is not None}
    return SegmentationParameters().replace(overrides)


def _add_dicom_commands(sub) -> None:
    p = sub.add_parser("dicom-info", help="show the geometry angiohull reads from XA DICOM files",
                       description="One line per file (and per frame where the geometry changes, or with --frames): "
                                   "modality, frames, C-arm angles, SID, SOD, pixel spacing and where it came from.")
    p.add_argument("files", type=Path, nargs="+", metavar="FILE", help="XA DICOM files")
    p.add_argument("--frames", action="store_true", help="one line per frame, even when all frames share one geometry")

    p = sub.add_parser("segment", help="segment the vessels of a raw angiogram into a binary mask",
                       description="Segment the vessels of one frame of an XA DICOM file (or of a PNG/TIFF/NPY image) "
                                   "and write the mask (PNG/TIFF/NPY by extension).")
    p.add_argument("input", type=Path, metavar="INPUT", help="XA DICOM file, or a grey-scale PNG/TIFF/NPY image")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="MASK", help="the mask to write (.png, .tif, .npy)")
    p.add_argument("--overwrite", action="store_true", help="replace MASK if it exists (refused otherwise)")
    p.add_argument("--frame", type=int, default=None, metavar="N",
                   help="frame index from 0 (default: the frame with the most contrast, or the end-diastolic frame nearest to it)")
    _add_segmentation_options(p, "segment")

    p = sub.add_parser("study-from-dicom", help="build a study folder from XA runs",
                       description="Write a study folder (study.yaml) with one view per XA file, geometry from the "
                                   "headers; with --segment the masks are segmented now, otherwise the views name the "
                                   "DICOM image and are segmented when the study is loaded.")
    p.add_argument("files", type=Path, nargs="+", metavar="FILE", help="XA DICOM files")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="STUDY_DIR", help="the study folder to write")
    p.add_argument("--overwrite", action="store_true", help="replace what STUDY_DIR holds (refused otherwise)")
    p.add_argument("--segment", action="store_true", help="segment now and write masks/<name>.png")
    frames = p.add_mutually_exclusive_group()
    frames.add_argument("--frame", type=int, default=None, metavar="N", help="use frame N (from 0) of every file "
                        "(default: chosen automatically per file and written as frame:)")
    frames.add_argument("--all-frames", action="store_true", help="one view per frame (e.g. a rotational run)")
    p.add_argument("--reference", action="store_true",
                   help="refer to the files where they are (relative paths) instead of copying them into STUDY_DIR/dicom/")
    _add_segmentation_options(p, "study-from-dicom")


def _format_spacing(frame) -> str:
    return f"{frame.pixel_spacing_mm[0]:g} x {frame.pixel_spacing_mm[1]:g} mm"


def _cmd_dicom_info(args) -> int:
    from .dicom import read_xa_header

    status = 0
    for path in args.files:
        try:
            with warnings.catch_warnings():  # the line itself says where the spacing came from
                warnings.simplefilter("ignore", DicomGeometryWarning)
                header = read_xa_header(path)
        except AngiohullError as error:
            print(f"angiohull dicom-info: error: {error}", file=sys.stderr)
            status = 2
            continue
        first = header.frames[0]
        rows, cols = header.image_shape
        ecg = (f", end-diastolic frames {list(header.end_diastolic_frames)} (from {header.ecg_source})"
               if header.end_diastolic_frames else "")
        kind = header.modality if header.sop_class == "XA" else f"{header.modality} ({header.sop_class})"
        line = f"{path}: {kind}, {header.n_frames} frame{'s' if header.n_frames != 1 else ''}, {rows}x{cols}"
        if header.varying_geometry:
            print(f"{line}, geometry varies by frame (angles from {header.angle_source}){ecg}")
        else:
            print(f"{line}, primary {first.primary_deg:g} secondary {first.secondary_deg:g} ({first.clinical}), "
                  f"SID {first.sid_mm:g} mm, SOD {first.sod_mm:g} mm, spacing {_format_spacing(first)} "
                  f"(from {header.spacing_source}){ecg}")
        if header.varying_geometry or args.frames:
            for frame in header.frames:
                print(f"{path} frame {frame.frame}: primary {frame.primary_deg:g} secondary {frame.secondary_deg:g} "
                      f"({frame.clinical}), SID {frame.sid_mm:g} mm, SOD {frame.sod_mm:g} mm, spacing {_format_spacing(frame)}")
    return status


def _cmd_segment(args) -> int:
    from . import io
    from .dicom import read_xa_view
    from .errors import SegmentationError
    from .segmentation import flat_image_message, segment_vessels
    from .workflow import check_output_file, output_file

    params = _segmentation_parameters(args)
    # refused before the work: an existing file without --overwrite, the input itself, a folder
    check_output_file(args.output, inputs=[args.input], overwrite=args.overwrite, what="the mask")
    if args.input.suffix.lower() in io.IMAGE_SUFFIXES:
        if args.frame is not None:
            raise AngiohullError(f"{args.input}: --frame is only used with a DICOM file")
        image, where = io.read_image(args.input), str(args.input)
    else:
        view = read_xa_view(args.input, args.frame, parameters=params)
        image, where = view.image, f"{args.input} frame {view.frame} ({view.selection.reason}; {view.carm.clinical_name()})"
    try:
        mask = segment_vessels(image, params)
    except SegmentationError as exc:  # an image it cannot segment (too small, not finite)
        raise AngiohullError(f"{where}: {exc}") from None
    if not mask.any():
        flat = flat_image_message(image)  # where thresholds cannot help
        advice = "" if flat else (" (try a lower --high-threshold or --seed-snr, or --vessels bright for an inverted "
                                  "display)")
        raise AngiohullError(f"{where}: {flat or 'the segmentation found no vessel'}; nothing written{advice}")
    with output_file(args.output, inputs=[args.input], overwrite=args.overwrite, what="the mask") as partial:
        io.write_mask(partial, mask)
    print(f"{where}: {int(mask.sum())} vessel pixels of {mask.size}; wrote {args.output}")
    return 0


def _cmd_study_from_dicom(args) -> int:
    from .study import study_from_dicom
    from .workflow import output_folder

    with output_folder(args.output, inputs=args.files, overwrite=args.overwrite, what="the study") as staged:
        yaml_path, views = study_from_dicom(args.files, staged.path, segment=args.segment, frame=args.frame,
                                            all_frames=args.all_frames, copy=not args.reference,
                                            parameters=_segmentation_parameters(args))
        yaml_path = staged.final(yaml_path)
    for view in views:
        pixels = f", {view.mask_pixels} vessel pixels" if view.mask_pixels is not None else ""
        print(f"{view.name}: {view.source_file} frame {view.frame} ({view.selection}), {view.carm.clinical_name()}{pixels}")
    print(f"wrote {yaml_path} ({len(views)} view{'s' if len(views) != 1 else ''})")
    return 0


_COMMANDS = {"reconstruct": _cmd_reconstruct, "evaluate": _cmd_evaluate, "demo": _cmd_demo, "synth": _cmd_synth,
             "qca": _cmd_qca, "dicom-info": _cmd_dicom_info, "segment": _cmd_segment, "study-from-dicom": _cmd_study_from_dicom}


class _WarningPrinter:
    """angiohull's own warnings as one line on stderr, each message once (others keep Python's format)."""

    def __init__(self):
        self.seen: set[str] = set()
        self.python = warnings.showwarning

    def __call__(self, message, category, filename, lineno, file=None, line=None) -> None:
        if not issubclass(category, (DicomGeometryWarning, TreeWarning, AgreementWarning, InputWarning)):
            self.python(message, category, filename, lineno, file, line)
        elif str(message) not in self.seen:
            self.seen.add(str(message))
            print(f"angiohull: warning: {message}", file=sys.stderr)


# -- experiments and reports (self-contained block) -------------------------------------------------
def _add_experiment_parsers(sub) -> None:
    if _complete("experiment"):
        from .experiments.config import shipped_config_names

        names = ", ".join(shipped_config_names())
    else:
        names = "see angiohull experiment --help"
    p = sub.add_parser("experiment", help="run one of the paper's experiments (or your own config), resumably",
                       description="Run every case of an experiment configuration and write one row per case to "
                                   "RUN_DIR/rows.csv as it finishes; running the same command again resumes. "
                                   f"CONFIG is a YAML file, a shipped name ({names}) or 'all' (every shipped "
                                   "experiment, each into RUN_DIR/NAME/).")
    p.add_argument("config", metavar="CONFIG", help="YAML file, shipped experiment name, or 'all'")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="RUN_DIR", help="run directory (resumed if it exists)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local worker processes (default: the usable CPUs; 1 runs in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster, e.g. tcp://host:8786 (needs pip install 'angiohull[cluster]')")
    p.add_argument("--quick", action="store_true",
                   help="scale every count down (config's quick.fraction, small floors) keeping each table and plot")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress, only the final summary")

    p = sub.add_parser("report", help="tables, t-tests and figures of experiment runs, beside the paper's numbers",
                       description="Write report.md, report.json and figures/*.png for one or more run directories "
                                   "(or folders of run directories); every number is recomputed from the rows.")
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="run directory, or a folder of them")
    p.add_argument("-o", "--output", type=Path, default=Path("angiohull-report"), metavar="OUT_DIR",
                   help="output folder (default ./angiohull-report)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a non-empty OUT_DIR (a folder holding only an earlier report is replaced without it)")


def _cmd_experiment(args) -> int:
    from .experiments.config import load_config, shipped_config_names
    from .experiments.runner import run_experiment

    if args.workers is not None and args.workers < 1:
        raise AngiohullError(f"--workers must be >= 1, got {args.workers}")
    if args.config == "all":
        jobs = [(load_config(name, quick=args.quick), args.output / name) for name in shipped_config_names()]
    else:
        jobs = [(load_config(args.config, quick=args.quick), args.output)]
    stream = None if args.quiet else sys.stderr
    summaries = []
    try:
        for config, run_dir in jobs:
            summaries.append(run_experiment(config, run_dir, workers=args.workers, scheduler=args.scheduler,
                                            stream=stream))
    except KeyboardInterrupt:
        print(f"angiohull experiment: interrupted; finished rows are kept in {run_dir / 'rows.csv'}; run the same "
              f"command again to resume", file=sys.stderr)
        return 130
    if args.quiet:  # otherwise run_experiment has printed each summary on stderr already
        for summary in summaries:
            print(summary.text())
    if len(summaries) > 1:
        for s in summaries:
            print(f"{s.name:<18} {s.done:>6}/{s.total:<6} cases  {s.failures:>4} failed  wall time {s.wall_s:8.1f} s")
        total = sum(s.wall_s for s in summaries)
        print(f"{len(summaries)} experiments, {sum(s.done_now for s in summaries)} cases run now, "
              f"{sum(s.failures for s in summaries)} failed, wall time {total / 60:.1f} min")
    return 0


REPORT_OUTPUTS = ("report.md", "report.json", "figures")
"""What `angiohull report` writes: a folder holding only these is an earlier report, which a new one replaces."""


def _cmd_report(args) -> int:
    from .experiments.report import build_report
    from .workflow import folder_holds_only, output_folder

    with output_folder(args.output, inputs=args.runs, overwrite=args.overwrite, what="the report",
                       replaceable=lambda folder: folder_holds_only(folder, REPORT_OUTPUTS)) as staged:
        path = staged.final(build_report(args.runs, staged.path))
    print(f"wrote {path} (and report.json, figures/ beside it)")
    return 0


_COMMANDS.update({"experiment": _cmd_experiment, "report": _cmd_report})
_COMMANDS["view"] = _cmd_view


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``angiohull`` command; returns the exit status (0 ok, 2 bad input)."""
    # The numerical work is many (N, 3) x (3, 3) products, which a multi-threaded BLAS makes several
    # times slower (measured: 0.26 s against 0.034 s for a million points on 2 busy cores); set
    # before NumPy is first imported, unless the user chose otherwise.
    for variable in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(variable, "1")
    arguments = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in arguments if not a.startswith("-")), "")  # top-level options have no values
    parser = build_parser(command)
    args = parser.parse_args(arguments)
    from . import compiled

    previous = None  # ANGIOHULL_COMPILED, where set, decides; else what pays for this command
    if not compiled.chosen_by_environment():
        previous = compiled.set_enabled(_kernels_pay(args), why_off="a small job: the command line runs the NumPy "
                                        "code where loading numba costs more than it saves; ANGIOHULL_COMPILED=1 "
                                        "runs it anyway")
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _WarningPrinter()
            warnings.simplefilter("always", DicomGeometryWarning)  # the printer shows each message once
            warnings.simplefilter("always", TreeWarning)
            warnings.simplefilter("always", AgreementWarning)
            warnings.simplefilter("always", InputWarning)
            return _COMMANDS[args.command](args)
    except AngiohullError as error:
        print(f"angiohull {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # output folders are written all or nothing: nothing half-written is left
        print(f"angiohull {args.command}: interrupted; nothing of this run was written", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            compiled.set_enabled(previous)


KERNELS_FROM_RESOLUTION = 512
"""From this lattice resolution K on, the command line uses numba's compiled kernels (where numba is
installed and ``ANGIOHULL_COMPILED`` is unset) for a single reconstruction."""


def _kernels_pay(args) -> bool:
    """Whether numba's compiled kernels pay for themselves in this command: loading them costs about
    0.4 s per process (and a compile, once per installation), one reconstruction at K = 100 saves
    about 15 ms; experiments, calibration, fine lattices and the tree method save more than that
    (docs/engines.md): 14-32 % of the tree method's time with two views. Not the demo's three
    views: the tree method's demo took 4.2-4.6 s with the kernels loaded and 4.0-4.5 s without them
    (2026-12-07, 2 cores), and its first run would compile them (25 s, once)."""
    tree = args.command in ("reconstruct", "evaluate") and _chosen_method(args) == "tree"
    return (tree or args.command == "experiment" or bool(getattr(args, "calibrate", False))
            or (getattr(args, "resolution", None) or 0) >= KERNELS_FROM_RESOLUTION)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
