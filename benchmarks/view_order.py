"""The view-order check (``reconstruct --check-view-order``): how well the tree method's trees tell
two views' masks the right way round from the masks swapped between the views.

For each generated tree (RCA and left, ``--trees`` each, from ``--first-tree`` on, tortuosity in
turn, seeds as benchmarks/tree_method.py draws them) in each two-view setup of that benchmark (the
two clinical views with exact masks and with segmented angiograms, random pairs 30-150 degrees
apart with exact masks), the tree method reconstructs the views with their own masks and
:func:`angiohull.reconstruction.view_order_agreement` builds the tree again with the two masks
swapped. The check's two agreements are the same numbers whichever way round the masks are given
(tests/test_tree_method.py), so one case gives both answers: a false warning where the swapped
masks agree better than the right ones, a missed swap where they do not agree worse. It also counts
how often the input checks (:func:`angiohull.reconstruction.checks.input_warnings`) warn of the
swapped masks, for comparison.

    OPENBLAS_NUM_THREADS=1 python benchmarks/view_order.py [--trees 30] [--first-tree 0] [--workers 2] \\
        [--rows FILE.json]

It prints a markdown table: per setup the cases where the right masks agree better, the margin
(right less swapped), how often the input checks warn of the swap, and the check's time; then, for
a warning only where the swap agrees better by more than a margin, the false warnings (right masks)
and the swaps caught (by the check, and by it or the input checks together).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

SETUPS = ("2 clinical views, exact masks", "2 clinical views, segmented angiograms",
          "2 random views 30-150 degrees apart, exact masks")


def _run(task: tuple[str, int, str]) -> dict:
    from tree_method import SETUPS as VIEWS, _case  # beside this script

    from angiohull.reconstruction import reconstruct, view_order_agreement
    from angiohull.reconstruction.checks import input_warnings

    kind, index, setup = task
    seed, case = _case(kind, index, setup)
    projections, masks = [v.projection for v in case.views], [v.mask for v in case.views]
    if VIEWS[setup][1] == "segmented":
        from angiohull.segmentation import segment_vessels
        from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram

        masks = [segment_vessels(render_angiogram(case.tree.phantom, v.carm, seed * 10 + i,
                                                  AngiogramParameters(collimator_px=8)).image)
                 for i, v in enumerate(case.views)]
    start = time.perf_counter()
    result = reconstruct(projections, masks, method="tree", centerlines=False, warn=False)
    middle = time.perf_counter()
    right, swapped = view_order_agreement(projections, masks, result)
    check_s = time.perf_counter() - middle
    return {"kind": kind, "index": index, "seed": seed, "setup": setup, "right": right, "swapped": swapped,
            "reconstruct_s": middle - start, "check_s": check_s,
            "inputs_warn_swapped": bool(input_warnings(projections, masks[::-1], ["0", "1"]))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=30, help="trees of each kind (default 30)")
    parser.add_argument("--first-tree", type=int, default=0, help="index of the first tree (default 0)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rows", default=None, metavar="FILE", help="also write every case's numbers here (JSON)")
    args = parser.parse_args()
    if args.trees < 1 or args.first_tree < 0 or args.workers < 1:
        parser.error("--trees and --workers must be at least 1, --first-tree at least 0")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    tasks = [(kind, i, setup) for setup in SETUPS for i in range(args.first_tree, args.first_tree + args.trees)
             for kind in ("rca", "left")]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = []
        for k, row in enumerate(pool.map(_run, tasks)):
            rows.append(row)
            print(f"[{time.perf_counter() - start:6.0f} s] case {k + 1}/{len(tasks)}", file=sys.stderr, flush=True)
    print(f"# The view-order check, trees {args.first_tree}-{args.first_tree + args.trees - 1} of each kind "
          f"({time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, {time.perf_counter() - start:.0f} s)\n")
    print("| setup | cases | right agrees better (no false warning, swap caught) | no tree swapped | margin: min / "
          "median / max | input checks warn of the swap | check time: median / max (s) |")
    print("|---|---|---|---|---|---|---|")
    for setup in SETUPS + ("all",):
        mine = [r for r in rows if setup in ("all", r["setup"])]
        built = [r for r in mine if r["swapped"] is not None]
        margin = np.array([r["right"] - r["swapped"] for r in built])
        times = np.array([r["check_s"] for r in mine])
        better = int(np.count_nonzero(margin > 0))
        print(f"| {setup} | {len(mine)} | {better} of {len(built)} | {len(mine) - len(built)} | "
              f"{margin.min():+.4f} / {np.median(margin):+.4f} / {margin.max():+.4f} | "
              f"{sum(r['inputs_warn_swapped'] for r in mine)} of {len(mine)} | "
              f"{np.median(times):.2f} / {times.max():.2f} |")
    built = [r for r in rows if r["swapped"] is not None]
    print("\n| warn where the swap agrees better by more than | false warnings (right masks) | swaps caught by the "
          "check | caught by the check or the input checks |")
    print("|---|---|---|---|")
    for margin in (0.0, 0.002, 0.005, 0.01, 0.015):
        false = sum(r["swapped"] - r["right"] > margin for r in built)
        caught = [r["right"] - r["swapped"] > margin for r in built]
        either = sum(c or r["inputs_warn_swapped"] for c, r in zip(caught, built))
        print(f"| {margin:g} | {false} of {len(built)} | {sum(caught)} of {len(built)} | {either} of {len(built)} |")
    if args.rows:
        with open(args.rows, "w", encoding="utf-8") as out:
            json.dump(rows, out, indent=0)
    worst = sorted((r for r in rows if r["swapped"] is not None), key=lambda r: r["right"] - r["swapped"])[:5]
    print("\nNarrowest margins: " + "; ".join(f"{r['kind']} {r['seed']} ({r['setup']}) {r['right']:.4f} / "
                                              f"{r['swapped']:.4f}" for r in worst))


if __name__ == "__main__":
    main()
