"""Calibration robustness: one view moved by 5-40 px, calibrated, against the clean score.

For every case, one view (drawn at random) has its mask content moved by a random 5-40 px in a
random direction, unknown to the method: a generated tree is rendered anew in the moved view (its
exact silhouette), the authors' masks, which cannot be rendered again, are moved by whole pixels
(resampling a binary mask by a fraction of a pixel changes its edge, a corruption of its own).
The case is reconstructed from the clean masks, from the moved ones as they are, and from the
moved ones after ``calibrate_shifts`` (default settings), with both presets; Dice3D against the truth. A case *loses* when its calibrated Dice3D is more than
``--bar`` (3) points below its clean Dice3D. The calibration's own verdict is recorded beside it:
its outcome (improved / unchanged / reverted), the agreement of the views after it (per-view mask
coverage, :func:`angiohull.reconstruction.calibration.view_coverage`), the silhouette fit's outline
RMS, and whether the command line would warn (:func:`angiohull.workflow.agreement_warning` or a
reverted calibration, or an ambiguous one: another view moved instead explains the masks as well).
The report counts the cases that lose without a warning (the bar: none).

Cases (the same defaults for all):

* ``--trees`` generated trees (RCA and left in turn, tortuosity simple / moderate / tortuous in turn,
  perpendicular and clinical views in turn), exact masks;
* the authors' 48 studies (``../shared/benchmarks/peer-synthetic``, when present).

    OPENBLAS_NUM_THREADS=1 python benchmarks/calibration_robustness.py [--trees 200] [--workers 2] \\
        [--output docs/results/calibration-robustness.md]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _versions import library_versions  # noqa: E402  (benchmarks/_versions.py, beside this script)

SHARED = Path(os.environ.get("ANGIOHULL_SHARED", Path(__file__).resolve().parents[2] / "shared"))
LEVELS = ("simple", "moderate", "tortuous")
PRESETS = ("paper", "refined")


def _generated(index: int):
    """(name, projections, masks, truth, render) of generated tree ``index``; ``render(projection)``
    is the exact mask of the tree in any view."""
    from angiohull.errors import AngiohullError
    from angiohull.synthetic import SynthOptions, make_case

    kind = ("rca", "left")[index % 2]
    views = ("perpendicular", "clinical")[(index // 2) % 2]
    for attempt in range(10):
        seed = 23_000 + index + 1000 * attempt
        try:
            case = make_case(SynthOptions(kind=kind, tortuosity=LEVELS[index % 3], views=views, seed=seed))
        except AngiohullError:
            continue
        return (f"{kind}-{views}-{LEVELS[index % 3]}-{seed}", [v.projection for v in case.views],
                [v.mask for v in case.views], case.surface_points_mm, case.tree.phantom.silhouette)
    raise RuntimeError(f"no tree for index {index}")


def _peer(folder: str):
    from angiohull.study import load_study

    study = load_study(folder)
    return Path(folder).name, list(study.projections), list(study.masks), study.ground_truth_mm, None


def _moved_by_whole_pixels(mask: np.ndarray, du: int, dv: int) -> np.ndarray:
    """The mask's content moved by ``(du, dv)`` whole pixels (+du to larger columns), exactly; what
    moves past the edge is lost, what comes in is background."""
    out = np.zeros_like(mask)
    rows, cols = mask.shape
    out[max(dv, 0):rows + min(dv, 0), max(du, 0):cols + min(du, 0)] = \
        mask[max(-dv, 0):rows + min(-dv, 0), max(-du, 0):cols + min(-du, 0)]
    return out


def _run(task: tuple[str, object, int]) -> dict:
    from angiohull.metrics import scores_3d
    from angiohull.reconstruction import reconstruct
    from angiohull.reconstruction.calibration import calibrate_shifts, shift_projection
    from angiohull.workflow import agreement_warning, ambiguity_warning

    source, key, seed = task
    name, projections, masks, truth, render = _generated(key) if source == "generated" else _peer(key)
    rng = np.random.default_rng(seed)
    view = int(rng.integers(len(masks)))
    length, angle = float(rng.uniform(5.0, 40.0)), float(rng.uniform(0.0, 2.0 * np.pi))
    shift = (length * np.cos(angle), length * np.sin(angle))
    moved = list(masks)
    # the moved view as its detector would have imaged it: a generated tree is rendered anew in the
    # moved view (any fraction of a pixel); the authors' masks, which cannot be, move by whole pixels
    # (resampling a binary mask by a fraction of a pixel changes its edge: a corruption of its own)
    if render is not None:
        moved[view] = render(shift_projection(projections[view], *shift))
    else:
        shift = (float(round(shift[0])), float(round(shift[1])))
        length = float(np.hypot(*shift))
        moved[view] = _moved_by_whole_pixels(masks[view], int(shift[0]), int(shift[1]))

    def dice(projs, ms, preset):
        points = reconstruct(projs, ms, preset=preset, centerlines=False, tree=False, allow_empty=True,
                             warn=False).vessel_points_mm
        return scores_3d(points, truth).dice3d if len(points) else 0.0

    start = time.perf_counter()
    calibration = calibrate_shifts(projections, moved)
    seconds = time.perf_counter() - start
    corrected = calibration.corrected(projections)
    names = [f"view{i}" for i in range(len(masks))]
    warning = (agreement_warning(dict(zip(names, calibration.coverage_after)), calibrated=True)
               or ambiguity_warning(calibration, names))
    row = {"source": source, "case": name, "views": len(masks), "moved_view": view, "shift_px": list(shift),
           "shift_length_px": length, "found_px": list(calibration.shifts_px[view]),
           "calibration_s": seconds, "outcome": calibration.outcome,
           "coverage_before": list(calibration.coverage_before), "coverage_after": list(calibration.coverage_after),
           "silhouette_fit": calibration.silhouette_fit,
           "ambiguous_with": [list(a[:1]) + list(a[1]) + list(a[2:]) for a in calibration.ambiguous_with],
           "warns": bool(warning) or calibration.outcome.startswith("reverted")}
    # the exact correction of the same masks: what the move itself costs (vessel moved past the
    # image's edge), whatever the calibration
    exact = [shift_projection(p, *shift) if v == view else p for v, p in enumerate(projections)]
    for preset in PRESETS:
        row[f"{preset}_clean"] = dice(projections, masks, preset)
        row[f"{preset}_moved"] = dice(projections, moved, preset)
        row[f"{preset}_calibrated"] = dice(corrected, moved, preset)
        row[f"{preset}_exact_correction"] = dice(exact, moved, preset)
    return row


def _summary(rows: list[dict], bar: float) -> list[str]:
    lines = ["| cases | preset | median loss (clean - calibrated), points | loses > %g | of them warned | warned, no loss | "
             "reverted | calibration s (median, max) | loses > %g against the exact correction | of them warned |" % (bar, bar),
             "|---|---|---|---|---|---|---|---|---|---|"]
    for source in ("generated", "authors", "all"):
        chosen = [r for r in rows if source == "all" or r["source"] == source]
        if not chosen:
            continue
        seconds = [r["calibration_s"] for r in chosen]
        for preset in PRESETS:
            loss = np.array([r[f"{preset}_clean"] - r[f"{preset}_calibrated"] for r in chosen])
            warns = np.array([r["warns"] for r in chosen])
            loses = loss > bar
            against_exact = np.array([r[f"{preset}_exact_correction"] - r[f"{preset}_calibrated"] for r in chosen]) > bar
            lines.append(f"| {source} ({len(chosen)}) | {preset} | {np.median(loss):.2f} | {int(loses.sum())} | "
                         f"{int((loses & warns).sum())} | {int((~loses & warns).sum())} | "
                         f"{sum(r['outcome'].startswith('reverted') for r in chosen)} | "
                         f"{np.median(seconds):.1f}, {max(seconds):.1f} | {int(against_exact.sum())} | "
                         f"{int((against_exact & warns).sum())} |")
    lines += ["", "Cases that lose more than %g points unwarned (Dice3D %%: clean, moved, calibrated, the exact "
              "correction of the same moved masks):" % bar, ""]
    silent = [(r, preset) for r in rows for preset in PRESETS
              if r[f"{preset}_clean"] - r[f"{preset}_calibrated"] > bar and not r["warns"]]
    lines += [f"- {r['case']} ({preset}), view {r['moved_view']} moved by ({r['shift_px'][0]:+.1f}, "
              f"{r['shift_px'][1]:+.1f}) px, found ({r['found_px'][0]:+.1f}, {r['found_px'][1]:+.1f}): "
              f"{r[f'{preset}_clean']:.1f}, {r[f'{preset}_moved']:.1f}, {r[f'{preset}_calibrated']:.1f}, "
              f"{r[f'{preset}_exact_correction']:.1f}" for r, preset in silent] or ["- none"]
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trees", type=int, default=200, help="generated trees (default 200)")
    parser.add_argument("--authors", type=int, default=48, help="how many of the authors' 48 studies (default all)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--bar", type=float, default=3.0, help="Dice3D points a case may lose (default 3)")
    parser.add_argument("--output", type=Path, default=None, help="Markdown report (the rows go beside it, .json)")
    args = parser.parse_args(argv)
    tasks = [("generated", i, 10_000 + i) for i in range(args.trees)]
    peer = SHARED / "benchmarks" / "peer-synthetic"
    if peer.is_dir():
        folders = sorted(str(p) for p in peer.iterdir() if (p / "study.yaml").is_file())[:args.authors]
        tasks += [("authors", f, 20_000 + i) for i, f in enumerate(folders)]
    else:
        print(f"(the authors' studies are not at {peer}; generated trees only)", file=sys.stderr)
    start = time.perf_counter()
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(_run, tasks):
            rows.append(row)
            print(f"[{time.perf_counter() - start:7.1f} s] {row['case']:<40} moved {row['shift_length_px']:5.1f} px: "
                  f"refined {row['refined_clean']:.1f} -> {row['refined_moved']:.1f} -> {row['refined_calibrated']:.1f}, "
                  f"calibration {row['calibration_s']:.1f} s, {row['outcome'].split(':')[0]}"
                  f"{', WARNS' if row['warns'] else ''}", file=sys.stderr, flush=True)
    header = [f"# Calibration robustness: one view moved by 5-40 px",
              "",
              f"`python benchmarks/calibration_robustness.py --trees {args.trees} --workers {args.workers}`, "
              f"{datetime.date.today().isoformat()}, {platform.machine()}, {os.cpu_count()} CPUs, {library_versions()}, "
              f"{time.perf_counter() - start:.0f} s wall. A case loses when its calibrated Dice3D is more than "
              f"{args.bar:g} points below its clean Dice3D (and, in the last two columns, below the Dice3D of the "
              f"moved masks with the exact inverse shift: what moves past an image's edge is lost whatever the "
              f"calibration). The moved view is the image its detector would give: a generated tree rendered "
              f"anew in the moved view, the authors' masks moved by whole pixels (a binary mask resampled by a "
              f"fraction of a pixel changes its edge). 'warned' counts the cases where the command line warns "
              f"(views still disagreeing after calibration, a reverted calibration, or an ambiguous one: "
              f"another view's correction explains the masks as well).", ""]
    text = "\n".join(header + _summary(rows, args.bar)) + "\n"
    print(text)
    if args.output is not None:
        args.output.write_text(text)
        args.output.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
