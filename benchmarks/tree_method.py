"""The tree method against the visual hull (issue 21): generated trees in two and three views.

Runs, with the same defaults for every case: generated RCA and left trees (``--trees`` each,
tortuosity simple / moderate / tortuous in turn) in

* two clinical views, RAO 30 CAU 25 with LAO 45 CRA 20: exact masks, the paper's rasteriser, and
  angiograms rendered by :func:`angiohull.synthetic.angiogram.render_angiogram` (collimator 8 px,
  seeded) and segmented by :func:`angiohull.segmentation.segment_vessels` (its defaults);
* two random views per tree, 30-150 degrees apart (primary within +-60, secondary within +-30
  degrees, seeded), exact masks;
* the paper's three clinical views (RAO 30 CRA 30, LAO 60 CRA 30, RAO 30 CAU 30) and six views
  (those, LAO 45 CAU 30, AP, LAO 90), exact masks;

the XCAT vessel (``../shared/data/xcat-single-vessel``, when present: every pair of its 19 views
30 degrees apart or more; its true centerline has no radii, so the centerline scores only, also
after the best common translation of the truth, as in benchmarks/vessel_tree.py) and the authors'
48 studies (``../shared/benchmarks/peer-synthetic``, when present: their masks and views, Dice3D and
Chamfer against their ``gt.npy``; with their matrices as given and moved by -0.5 px, see
:func:`_peer`). Each is reconstructed with ``hull`` (paper preset, K = 100), ``hull`` (refined
preset, K = 256) and ``tree`` (K = 256): Dice3D, Chamfer, the
tree scores of :func:`angiohull.metrics.tree.tree_scores` (centerline mean distance, Ot(1 mm)
both ways, radius MAE, branch recall and precision) and the reconstruction time; for the tree
method on generated trees also where its Dice3D goes (:func:`_dice_split`: far phantom and missing
voxels, and what the true tree itself scores through the same lumen points). The time section
times two 512 x 512 views in one process: three trees, medians of ``--repeats`` runs, stage by
stage; then one run of each of the first ``--timing-trees`` trees of each kind, for how the time
spreads over trees and how much of it the hypotheses of a wrong pairing take.

    OPENBLAS_NUM_THREADS=1 python benchmarks/tree_method.py [--trees 30] [--workers 2] \\
        [--output docs/results/tree-method.md]
    OPENBLAS_NUM_THREADS=1 python benchmarks/tree_method.py --timing-only [--timing-trees 10] \\
        [--output docs/results/tree-method-timing.md]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _versions import library_versions  # noqa: E402  (benchmarks/_versions.py, beside this script)

LEVELS = ("simple", "moderate", "tortuous")
TWO = ("RAO 30 CAU 25", "LAO 45 CRA 20")
THREE = ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30")
SETUPS = {  # name: (views, masks)
    "2 clinical views, exact masks": (TWO, "exact"),
    "2 clinical views, the paper's rasteriser": (TWO, "paper"),
    "2 clinical views, segmented angiograms": (TWO, "segmented"),
    "2 random views 30-150 degrees apart, exact masks": ("random", "exact"),
    "3 clinical views, exact masks": (THREE, "exact"),
    "6 views, exact masks": (THREE + ("LAO 45 CAU 30", "AP", "LAO 90"), "exact"),
}
SHARED = Path(os.environ.get("ANGIOHULL_SHARED", Path(__file__).resolve().parents[2] / "shared"))
METHODS = (("hull", "paper"), ("hull", "refined"), ("tree", "paper"))
KEYS = ("centerline_mean_mm", "ot1mm", "ot1mm_reverse", "radius_mae_mm", "branch_recall", "branch_precision")


def _random_pair(seed: int) -> tuple[str, str]:
    """Two C-arm poses 30-150 degrees apart (angle between the beams), drawn from the seed."""
    from angiohull.geometry import CArmGeometry, format_clinical_angles

    rng = np.random.default_rng(seed)
    while True:
        angles = [(rng.uniform(-60, 60), rng.uniform(-30, 30)) for _ in range(2)]
        d = [CArmGeometry(a, b, 1200.0, 800.0, (0.35, 0.35), (512, 512)).detector_direction() for a, b in angles]
        between = np.degrees(np.arccos(np.clip(np.dot(d[0], d[1]), -1, 1)))
        if 30 <= between <= 150:
            return tuple(format_clinical_angles(round(a), round(b)) for a, b in angles)


def _case(kind: str, index: int, setup: str):
    from angiohull.errors import AngiohullError
    from angiohull.synthetic import SynthOptions, make_case

    views, source = SETUPS[setup]
    for attempt in range(10):
        seed = (7_000 if kind == "rca" else 8_000) + index + 1000 * attempt
        chosen = _random_pair(seed) if views == "random" else views
        try:
            return seed, make_case(SynthOptions(kind=kind, tortuosity=LEVELS[index % 3], views=chosen, seed=seed,
                                                rasteriser="paper" if source == "paper" else "exact"))
        except AngiohullError:
            continue
    raise RuntimeError(f"no {kind} tree for index {index}")


def _run(task: tuple[str, int, str, float]) -> list[dict]:
    kind, index, setup, cube_scale = task
    seed, case = _case(kind, index, setup)
    truth = case.tree.vessel_tree()
    projections, masks = [v.projection for v in case.views], [v.mask for v in case.views]
    if SETUPS[setup][1] == "segmented":
        from angiohull.segmentation import segment_vessels
        from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram

        masks = [segment_vessels(render_angiogram(case.tree.phantom, v.carm, seed * 10 + i,
                                                  AngiogramParameters(collimator_px=8)).image)
                 for i, v in enumerate(case.views)]
    row = {"kind": kind, "index": index, "seed": seed, "setup": setup,
           "views": [v.carm.clinical_name() for v in case.views]}
    return _methods(row, projections, masks, case.surface_points_mm, truth, cube_scale)


def _methods(row: dict, projections, masks, truth_points_mm: np.ndarray, truth_tree=None,
             cube_scale: float = 1.0) -> list[dict]:
    """One row per method: ``row`` plus the method, its time, Dice3D and Chamfer against
    ``truth_points_mm``, the tree scores against ``truth_tree`` when given, or the error. With
    ``cube_scale`` the cube of interest's half-edge is that many times the views' own."""
    from angiohull.geometry import cube_half_edge_mm
    from angiohull.metrics import scores_3d
    from angiohull.metrics.tree import tree_scores
    from angiohull.reconstruction import reconstruct

    half_edge = None if cube_scale == 1.0 else cube_scale * cube_half_edge_mm(projections)
    rows = []
    for method, preset in METHODS:
        out = {**row, "method": method, "preset": preset}
        start = time.perf_counter()
        try:
            result = reconstruct(projections, masks, method=method, preset=preset, centerlines=False,
                                 half_edge_mm=half_edge, warn=False)
        except Exception as exc:  # noqa: BLE001 - a failed case is a row
            rows.append({**out, "error": f"{type(exc).__name__}: {exc}"})
            continue
        out["time_s"] = time.perf_counter() - start
        s3 = scores_3d(result.vessel_points_mm, truth_points_mm)
        out.update({"dice3d": s3.dice3d, "chamfer_mm": s3.chamfer_mm})
        if truth_tree is not None and result.tree is not None:
            scores = tree_scores(result.tree, truth_tree).as_dict()
            out.update({k: scores[k] for k in KEYS})
            if method == "tree":
                out.update(_dice_split(result, truth_tree, truth_points_mm))
        rows.append(out)
    return rows


def _dice_split(result, truth_tree, truth_points_mm: np.ndarray) -> dict:
    """Where the tree method's Dice3D goes: the true tree's own lumen points on the same lattice
    (the same tubes, margin and voxels: what a perfect tree scores), and the Dice3D with the far
    voxels set right: the reconstruction's voxels whose centre lies more than a voxel (3 mm)
    outside the true tubes taken out (phantom vessel), the true voxels more than a voxel outside
    the reconstructed tubes put in (missing vessel), and both. Outside: the distance to the
    nearest point of the tree's centerline (0.5 mm apart) less that point's radius. What the far
    voxels leave between the Dice3D and the true tree's score is local (positions and radii near
    the truth)."""
    from scipy.spatial import cKDTree

    from angiohull.metrics import scores_3d
    from angiohull.metrics.paper import PAPER_VOXEL_MM, voxel_centres_mm, voxelise
    from angiohull.reconstruction.model import MODEL_SETTINGS, tree_lumen_points

    lattice = result.lattice
    perfect = tree_lumen_points(truth_tree, lattice, MODEL_SETTINGS.lumen_margin_steps * lattice.spacing_mm)
    ours, true = ({tuple(v) for v in voxelise(p)} for p in (result.vessel_points_mm, truth_points_mm))

    def far(voxels: set, tree) -> int:  # voxels whose centre lies more than a voxel outside the tree's tubes
        if not voxels:
            return 0
        points, radius, _ = tree.resampled(0.5).points()
        distance, nearest = cKDTree(points).query(voxel_centres_mm(np.array(sorted(voxels))))
        return int(np.count_nonzero(distance - radius[nearest] > PAPER_VOXEL_MM))

    common, phantom, missing = len(ours & true), far(ours - true, truth_tree), far(true - ours, result.tree)

    def dice(c: int, a: int) -> float:
        return 200.0 * c / (a + len(true))

    return {"dice3d_true_tree": scores_3d(perfect, truth_points_mm).dice3d,
            "dice3d_without_phantom": dice(common, len(ours) - phantom),
            "dice3d_with_missing": dice(common + missing, len(ours) + missing),
            "dice3d_both": dice(common + missing, len(ours) + missing - phantom)}


def _peer(folder: Path) -> list[dict]:
    """The three methods on one of the authors' studies: Dice3D and Chamfer against their gt.npy,
    with the matrices as given (``reading`` "as given") and moved by -0.5 px in u and v
    ("pixel areas"): the authors' rasteriser puts a point at (u, v) into pixel (floor v, floor u),
    so their pixel (r, c) covers [c, c + 1) x [r, r + 1) and its centre lies at (c + 0.5, r + 0.5),
    while the study format (and every method here) puts pixel centres at integer (u, v); their own
    carving compares with integer indices, so the paper's parity needs the matrices as given."""
    from angiohull.geometry import Projection
    from angiohull.study import load_study

    study = load_study(folder)
    row = {"study": folder.name, "views": folder.name.split("_")[0]}
    to_centres = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    moved = [Projection(to_centres @ p.matrix, p.image_shape) for p in study.projections]
    return (_methods({**row, "reading": "as given"}, study.projections, study.masks, study.ground_truth_mm)
            + _methods({**row, "reading": "pixel areas"}, moved, study.masks, study.ground_truth_mm))


def _xcat_pairs() -> list[tuple[int, int]]:
    """Every pair of the XCAT vessel's 19 views (10 degrees apart in turn) 30 degrees apart or more."""
    return [(i, j) for i in range(1, 20) for j in range(i + 3, 20)]


def _xcat(task: tuple) -> dict:
    """One method on one pair of the XCAT vessel's views (benchmarks/vessel_tree.py's scoring); a
    failure is a row."""
    import vessel_tree  # beside this script

    try:
        return vessel_tree._xcat(task)
    except Exception as exc:  # noqa: BLE001 - a failed case is a row
        pair, preset, method = task
        return {"views": list(pair), "preset": preset, "method": method, "tree_error": None,
                "error": f"{type(exc).__name__}: {exc}"}


def _xcat_section(rows: list[dict]) -> list[str]:
    import vessel_tree  # beside this script

    lines = ["## XCAT single vessel, every pair of views 30 degrees apart or more", "",
             "One thick vessel with a stenosis (``../shared/data/xcat-single-vessel``); its true centerline has no "
             "radii and lies off the middle of the imaged vessel by a constant vector (docs/results/vessel-tree.md), "
             "so the centerline scores are given as they are and after the best common translation of the truth. "
             "Mean ± sd (median); 960 x 960 images.", "",
             "| views | method | cases | centerline mean mm | Ot(1 mm) | Ot(1 mm) reverse | centerline mean after "
             "the translation mm | length / true length | time s | failed |",
             "|---|---|---|---|---|---|---|---|---|---|"]

    def gap(r: dict) -> float:
        return abs(vessel_tree.XCAT_ALPHA_DEG[r["views"][1]] - vessel_tree.XCAT_ALPHA_DEG[r["views"][0]])

    for low, high in ((30, 30), (40, 60), (70, 90), (100, 120), (130, 150), (160, 180), (30, 180)):
        label = f"{low}°" + (f"–{high}°" if high > low else "") + " apart"
        for method, preset in METHODS:
            sel = [r for r in rows if r["method"] == method and r["preset"] == preset and low <= gap(r) <= high]
            ok = [r for r in sel if r.get("centerline_mean_mm") is not None]
            name = f"{method} ({preset})" if method == "hull" else "tree"
            cells = [_fmt(r.get(k) for r in ok) for k in ("centerline_mean_mm", "ot1mm", "ot1mm_reverse",
                                                           "centerline_mean_translated_mm")]
            cells.append(_fmt(r["length_mm"] / r["true_length_mm"] for r in ok))
            cells.append(_fmt(r.get("time_s") for r in ok))
            lines.append(f"| {label} | {name} | {len(sel)} | " + " | ".join(cells) + f" | {len(sel) - len(ok)} |")
    return lines + [""]


def _timing(repeats: int) -> list[dict]:
    """Medians of ``repeats`` runs of the tree method (after a first one that imports what it uses)
    on three generated trees in the two clinical views, in this process, per stage."""
    from angiohull.reconstruction import reconstruct

    out = []
    for kind, index in (("rca", 0), ("left", 0), ("left", 1)):
        seed, case = _case(kind, index, "2 clinical views, exact masks")
        projections, masks = [v.projection for v in case.views], [v.mask for v in case.views]
        totals, stages = [], []
        for repeat in range(repeats + 1):
            start = time.perf_counter()
            result = reconstruct(projections, masks, method="tree", centerlines=False, warn=False)
            if repeat:
                totals.append(time.perf_counter() - start)
                stages.append(result.timings_s)
        out.append({"kind": kind, "seed": seed, "total_s": float(np.median(totals)),
                    "stages_s": {k: float(np.median([s[k] for s in stages])) for k in stages[0]
                                 if k not in ("reconstruction", "total")}})
    return out


def _timing_spread(trees: int) -> list[dict]:
    """One timed run of the tree method on each of the first ``trees`` generated trees of each kind
    in the two clinical views (exact masks), in this process after :func:`_timing` (whose first,
    untimed runs imported what the method uses): how the time spreads over trees, and how much of
    it the hypotheses of a wrong pairing take (a tree whose own trees agree less with the masks
    builds three or six more trees)."""
    from angiohull.reconstruction import reconstruct

    cases = []
    for kind in ("rca", "left"):
        for index in range(trees):
            seed, case = _case(kind, index, "2 clinical views, exact masks")
            cases.append((kind, seed, [v.projection for v in case.views], [v.mask for v in case.views]))
    out = []
    for kind, seed, projections, masks in cases:
        start = time.perf_counter()
        result = reconstruct(projections, masks, method="tree", centerlines=False, warn=False)
        out.append({"kind": kind, "seed": seed, "total_s": time.perf_counter() - start,
                    "hypotheses": len(result.model_build.hypotheses),
                    "hypotheses_s": result.timings_s.get("tree_hypotheses", 0.0)})
    return out


def _spread_lines(spread: list[dict], target_s: float = 2.0) -> list[str]:
    """The time section's spread over trees: quantiles, the share within ``target_s``, and the
    same by the number of hypotheses a tree built."""
    if not spread:
        return []
    totals = np.array([t["total_s"] for t in spread])
    lines = [f"One run per tree of the first {len(spread) // 2} trees of each kind (seeds 7000 and 8000 on), two "
             "clinical views, exact masks, in the same process after the cases above; seconds.", "",
             f"| trees | median | 75th percentile | 90th percentile | largest | within {target_s:g} s |",
             "|---|---|---|---|---|---|"]
    groups = [("all", totals)] + [(f"building {h} hypotheses", np.array([t["total_s"] for t in spread
                                                                         if t["hypotheses"] == h]))
                                  for h in sorted({t["hypotheses"] for t in spread})]
    for label, values in groups:
        lines.append(f"| {label} ({len(values)}) | {np.median(values):.2f} | {np.percentile(values, 75):.2f} | "
                     f"{np.percentile(values, 90):.2f} | {values.max():.2f} | {np.mean(values <= target_s):.0%} |")
    share = sum(t["hypotheses_s"] for t in spread) / max(float(totals.sum()), 1e-9)
    return lines + ["", f"The hypotheses took {share:.0%} of the time over these trees.", ""]


def _rounded(value, digits: int = 5):
    """Floats to ``digits`` decimals, so that the raw rows stay small enough to commit."""
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(v, digits) for v in value]
    return value


def _fmt(values) -> str:
    values = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    if len(values) == 0:
        return "-"
    return f"{values.mean():.3f} ± {values.std():.3f} ({np.median(values):.3f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=30, help="generated trees per kind (default 30)")
    parser.add_argument("--first-tree", type=int, default=0, metavar="N",
                        help="start at tree N of each kind (default 0; seeds 7000 + N and 8000 + N on): other trees "
                             "than the committed results' to check a change on, as a 60-tree mean is known to about "
                             "+- 0.7 Dice3D points")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--output", type=Path, default=None, help="Markdown report to write (and .json beside it)")
    parser.add_argument("--no-shared", action="store_true", help="skip the XCAT vessel and the authors' studies")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per case of the time section (default 5)")
    parser.add_argument("--timing-only", action="store_true", help="only the time section (no pool, no scores)")
    parser.add_argument("--timing-trees", type=int, default=10, metavar="N",
                        help="the time section's spread: one run of each of the first N trees of each kind (default "
                             "10; 0 leaves it out)")
    parser.add_argument("--setup", action="append", choices=list(SETUPS), default=None,
                        help="only this generated setup (repeatable): its section alone, without the authors' studies, "
                             "the XCAT vessel and the time section")
    parser.add_argument("--cube-scale", type=float, default=1.0, metavar="S",
                        help="the cube of interest's half-edge S times the views' own (default 1): the same views on "
                             "another lattice, to measure how far a setup's scores move when nothing but the lattice "
                             "does (docs/tree-method.md, \"Reproducibility\"); generated setups only, like --setup")
    args = parser.parse_args()
    if args.first_tree < 0 or args.trees < 0 or args.first_tree + args.trees > 1000:
        parser.error("--trees and --first-tree count from 0, and together stay within 1000 (the seeds of a kind's "
                     "trees are 1000 apart)")
    if not 0 <= args.timing_trees <= 1000:
        parser.error(f"--timing-trees counts trees of each kind, 0 to 1000, got {args.timing_trees}")
    if args.setup is not None and args.timing_only:
        parser.error("--setup and --timing-only exclude each other (a setup's section has no time section)")
    setups = list(SETUPS) if args.setup is None else args.setup
    if not 0.5 <= args.cube_scale <= 2.0:
        parser.error(f"--cube-scale must lie within [0.5, 2] (the cube must hold the vessels), got {args.cube_scale}")
    if args.cube_scale != 1.0 and args.timing_only:
        parser.error("--cube-scale and --timing-only exclude each other (the time section keeps the views' own cube)")
    restricted = args.setup is not None or args.cube_scale != 1.0
    if restricted:
        args.no_shared = True
    start = time.perf_counter()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    tasks = [] if args.timing_only else [(kind, i, setup, args.cube_scale) for setup in setups for kind in ("rca", "left")
                                         for i in range(args.first_tree, args.first_tree + args.trees)]
    peer_folder = SHARED / "benchmarks" / "peer-synthetic"
    studies = (sorted(peer_folder.glob("*_*_*")) if peer_folder.is_dir() and not (args.no_shared or args.timing_only)
               else [])
    xcat_tasks = ([(pair, preset, method) for pair in _xcat_pairs() for method, preset in METHODS]
                  if (SHARED / "data" / "xcat-single-vessel").is_dir() and not (args.no_shared or args.timing_only)
                  else [])
    with ProcessPoolExecutor(args.workers) as pool:
        rows = [r for chunk in pool.map(_run, tasks) for r in chunk]
        peer_rows = [r for chunk in pool.map(_peer, studies) for r in chunk]
        xcat_rows = list(pool.map(_xcat, xcat_tasks))
    rows = rows if rows else []
    load = os.getloadavg()[0]  # what else ran on the machine as the time section began
    timing = _timing(args.repeats) if not restricted else []
    spread = _timing_spread(args.timing_trees) if not restricted else []
    elapsed = time.perf_counter() - start
    command = "--timing-only" if args.timing_only else f"--trees {args.trees} --workers {args.workers}"
    command += f" --first-tree {args.first_tree}" if args.first_tree and not args.timing_only else ""
    command += "".join(f' --setup "{setup}"' for setup in args.setup or ())
    command += f" --cube-scale {args.cube_scale:g}" if args.cube_scale != 1.0 else ""
    command += f" --repeats {args.repeats}" if args.repeats != 5 and not restricted else ""
    command += f" --timing-trees {args.timing_trees}" if args.timing_trees != 10 and not restricted else ""
    lines = ["# Results: the tree method against the visual hull", "",
             f"Produced by `OPENBLAS_NUM_THREADS=1 python benchmarks/tree_method.py {command}` on {datetime.date.today()}, commit {commit}, {platform.machine()} with "
             f"{os.cpu_count()} cores, Python {platform.python_version()} ({library_versions()}), in {elapsed:.0f} s. The same "
             f"defaults for every case; mean ± sd (median).", ""]
    for setup in [] if args.timing_only else setups:
        views = SETUPS[setup][0]
        lines += [f"## {setup}" + ("" if views == "random" else f": {', '.join(views)}"), "",
                  "| trees | method | Dice3D % | Chamfer mm | centerline mean mm | Ot(1 mm) | Ot(1 mm) reverse | "
                  "radius MAE mm | branch recall | branch precision | time s | failed |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for kind in ("rca", "left", "all"):
            for method, preset in METHODS:
                sel = [r for r in rows if r["setup"] == setup and r["method"] == method and r["preset"] == preset
                       and (kind == "all" or r["kind"] == kind)]
                ok = [r for r in sel if "error" not in r]
                name = f"{method} ({preset})" if method == "hull" else "tree"
                cells = [_fmt(r.get(k) for r in ok) for k in ("dice3d", "chamfer_mm", *KEYS, "time_s")]
                lines.append(f"| {kind} ({len(sel)}) | {name} | " + " | ".join(cells) + f" | {len(sel) - len(ok)} |")
        lines.append("")
    split_rows = [r for r in rows if "dice3d_true_tree" in r]
    if split_rows:
        lines += ["## Where the tree method's Dice3D goes", "",
                  "Per setup, all trees: the tree method's Dice3D; with the far voxels set right (its voxels whose "
                  "centre lies more than a voxel, 3 mm, outside every true tube taken out: *phantom vessel*; the true "
                  "voxels more than a voxel outside every reconstructed tube put in: *missing vessel*); and the true "
                  "tree's own lumen points on the same lattice, with the same tubes and margin (what a perfect tree "
                  "scores). What the far voxels leave to the true tree's score is local: positions and radii near the "
                  "truth. Mean ± sd (median).", "",
                  "| setup | trees | Dice3D % | phantom out | missing in | both | the true tree |",
                  "|---|---|---|---|---|---|---|"]
        for setup in setups:
            sel = [r for r in split_rows if r["setup"] == setup]
            if sel:
                cells = [_fmt(r[k] for r in sel) for k in ("dice3d", "dice3d_without_phantom", "dice3d_with_missing",
                                                            "dice3d_both", "dice3d_true_tree")]
                lines.append(f"| {setup} | {len(sel)} | " + " | ".join(cells) + " |")
        lines.append("")
    if peer_rows:
        lines += ["## The authors' 48 studies (their masks and views, against their gt.npy)", "",
                  "Matrices *as given* (the paper's parity), and moved by -0.5 px in u and v so that the masks "
                  "read as the pixel areas the authors' rasteriser filled (*pixel areas*: it puts a point at (u, v) "
                  "into pixel (floor v, floor u), while pixel centres lie at integer (u, v) in the study format).", "",
                  "| views | matrices | method | Dice3D % | Chamfer mm | time s | failed |",
                  "|---|---|---|---|---|---|---|"]
        for views in ("perpendicular", "clinical", "all"):
            for reading in ("as given", "pixel areas"):
                for method, preset in METHODS:
                    sel = [r for r in peer_rows if r["method"] == method and r["preset"] == preset
                           and r["reading"] == reading and (views == "all" or r["views"] == views)]
                    ok = [r for r in sel if "error" not in r]
                    name = f"{method} ({preset})" if method == "hull" else "tree"
                    cells = [_fmt(r.get(k) for r in ok) for k in ("dice3d", "chamfer_mm", "time_s")]
                    lines.append(f"| {views} ({len(sel)}) | {reading} | {name} | " + " | ".join(cells)
                                 + f" | {len(sel) - len(ok)} |")
        lines.append("")
    if xcat_rows:
        lines += _xcat_section(xcat_rows)
    stage_names = list(timing[0]["stages_s"]) if timing else []
    lines += [] if not timing else ["## Time of the tree method, two 512 x 512 views", "",
              f"One process, medians of {args.repeats} runs per case after a first run (imports done); seconds. "
              f"Load average as it began: {load:.2f} on {os.cpu_count()} cores ("
              + ("above 1: other work shared the machine, and these are upper bounds" if load > 1.0 else
                 "below 1: the machine was otherwise idle") + ").", "",
              "| tree | total | " + " | ".join(stage_names) + " |", "|---|---|" + "---|" * len(stage_names)]
    for t in timing:
        lines.append(f"| {t['kind']} seed {t['seed']} | **{t['total_s']:.2f}** | "
                     + " | ".join(f"{t['stages_s'][k]:.2f}" for k in stage_names) + " |")
    if timing:
        lines.append("")
    lines += _spread_lines(spread)
    failures = [f"{r['setup']} {r['kind']} {r['seed']} {r['method']}: {r['error']}" for r in rows if "error" in r]
    failures += [f"authors' {r['study']} ({r['reading']}) {r['method']}: {r['error']}" for r in peer_rows if "error" in r]
    failures += [f"XCAT views {r['views']} {r['method']} ({r['preset']}): {r.get('error') or r['tree_error']}"
                 for r in xcat_rows if r.get("centerline_mean_mm") is None]
    if failures:
        lines += ["Failed cases:", ""] + [f"- {f}" for f in failures] + [""]
    text = "\n".join(lines)
    print(text)
    if args.output is not None:
        args.output.write_text(text + "\n", encoding="utf-8")
        raw = {"generated": rows, "authors": peer_rows, "xcat": xcat_rows, "timing": timing, "timing_spread": spread}
        args.output.with_suffix(".json").write_text(json.dumps(_rounded(raw), separators=(",", ":"), default=float) + "\n",
                                                    encoding="utf-8")


if __name__ == "__main__":
    main()
