"""Carving engines: time, peak memory and Dice3D per lattice resolution K.

Run from the repository root (after `pip install .`):

    OPENBLAS_NUM_THREADS=1 python benchmarks/engines.py [--repeats 5] [--cases 6] [--full]

Cases: studies of ../shared/benchmarks/peer-synthetic (when present) and generated cases (the demo
phantom in three clinical views and in three perpendicular views). For each K in 100, 200, 512
(and 1024 for the hierarchical engines) it prints the median time per engine over the cases (each
case timed as the median of --repeats runs), the ratio to kdtree at the same K and to kdtree at
K = 100 (both measured in this run), the peak memory of the carving (tracemalloc, NumPy buffers
included) and the mean Dice3D against the ground truth. kdtree above K = 200 takes minutes per
case; it runs there only with --full.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from angiohull.geometry import CArmGeometry, cube_half_edge_mm
from angiohull.metrics import dice3d
from angiohull.reconstruction import ENGINES, Lattice
from angiohull.study import load_study
from angiohull.synthetic import demo_phantom, demo_views

ENGINE_NAMES = ("kdtree", "lookup", "octree")
RESOLUTIONS = (100, 200, 512, 1024)


def peer_cases(limit):
    root = Path(__file__).resolve().parents[2] / "shared" / "benchmarks" / "peer-synthetic"
    if not root.is_dir():
        print(f"# {root} not found: generated cases only", file=sys.stderr)
        return []
    folders = sorted(p for p in root.iterdir() if (p / "study.yaml").is_file())
    step = max(1, len(folders) // max(limit, 1))
    cases = []
    for folder in folders[::step][:limit]:
        study = load_study(folder)
        cases.append((folder.name, list(study.projections), list(study.masks), study.ground_truth_mm))
    return cases


def generated_cases():
    phantom = demo_phantom()
    truth = phantom.surface_points_mm(0.5)
    clinical = [carm.projection() for _, carm in demo_views()]
    perpendicular = [CArmGeometry(a, b, 1200, 800, (0.35, 0.35), (512, 512)).projection()
                     for a, b in ((0, 0), (90, 0), (0, 89.9))]
    return [(f"phantom_{name}", views, [phantom.silhouette(p) for p in views], truth)
            for name, views in (("clinical", clinical), ("perpendicular", perpendicular))]


def measure(engine, lattice, projections, masks, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        outcome = ENGINES[engine](lattice, projections, masks, threshold_px=1.0)
        times.append(time.perf_counter() - start)
    tracemalloc.start()
    ENGINES[engine](lattice, projections, masks, threshold_px=1.0)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return statistics.median(times), peak, outcome.points_mm


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cases", type=int, default=6, help="peer-synthetic studies to use (spread over the set)")
    parser.add_argument("--full", action="store_true", help="also run kdtree at K >= 512 (slow)")
    args = parser.parse_args(argv)
    cases = peer_cases(args.cases) + generated_cases()
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
          f"NumPy {np.__version__}; {len(cases)} cases, median of {args.repeats} runs each; threshold 1 px")
    print(f"# cases: {', '.join(c[0] for c in cases)}")
    rows = {}
    for k in RESOLUTIONS:
        for engine in ENGINE_NAMES:
            if engine == "kdtree" and k > 200 and not args.full:
                continue
            if engine == "lookup" and k > 512:
                continue
            times, peaks, dices = [], [], []
            for name, projections, masks, truth in cases:
                lattice = Lattice(cube_half_edge_mm(projections), k)
                t, peak, points = measure(engine, lattice, projections, masks, args.repeats if k <= 512 else 1)
                times.append(t)
                peaks.append(peak)
                dices.append(dice3d(points, truth))
            rows[(engine, k)] = (statistics.median(times), max(peaks), float(np.mean(dices)))
            print(f"# done {engine} K={k}", file=sys.stderr, flush=True)
    base100 = rows[("kdtree", 100)][0]
    print("\n| engine | K | median time (s) | speed-up vs kdtree same K | speed-up vs kdtree K=100 | peak memory (MiB) | mean Dice3D (%) |")
    print("|---|---|---|---|---|---|---|")
    for (engine, k), (t, peak, dice) in sorted(rows.items(), key=lambda item: (item[0][1], ENGINE_NAMES.index(item[0][0]))):
        same = rows.get(("kdtree", k))
        ratio = f"{same[0] / t:.1f}x" if same else "n/a"
        print(f"| {engine} | {k} | {t:.4f} | {ratio} | {base100 / t:.1f}x | {peak / 2 ** 20:.0f} | {dice:.2f} |")


if __name__ == "__main__":
    main()
