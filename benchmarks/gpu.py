"""CPU octree engine vs its CUDA path (CuPy) on the demo phantom: median carving time per K.

Run from the repository root (after `pip install .` and CuPy for your CUDA, e.g. cupy-cuda12x):

    OPENBLAS_NUM_THREADS=1 python benchmarks/gpu.py [--repeats 5] [--resolutions 100 200 512 1024]

Each time is the median of --repeats runs after one warm-up run (which also compiles the CuPy
kernels); the GPU clock stops after `cupy.cuda.Device().synchronize()`. Both paths must keep the
same points; the script checks it and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np

from angiohull.geometry import cube_half_edge_mm
from angiohull.reconstruction import ENGINES, Lattice
from angiohull.reconstruction.gpu import carve_cuda, cuda_available
from angiohull.synthetic import demo_phantom, demo_views


def median_time(run, repeats, sync=lambda: None):
    outcome = run()  # warm-up
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        sync()
        times.append(time.perf_counter() - start)
    return statistics.median(times), outcome


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--resolutions", type=int, nargs="+", default=[100, 200, 512, 1024])
    parser.add_argument("--threshold", type=float, default=1.0)
    args = parser.parse_args(argv)
    if not cuda_available():
        raise SystemExit("no CUDA device usable through CuPy: install CuPy for your CUDA (pip install 'angiohull[gpu]')")
    import cupy

    sync = cupy.cuda.Device().synchronize
    name = cupy.cuda.runtime.getDeviceProperties(cupy.cuda.Device().id)["name"]
    name = name.decode() if isinstance(name, bytes) else name
    phantom = demo_phantom()
    projections = [carm.projection() for _, carm in demo_views()]
    masks = [phantom.silhouette(p) for p in projections]
    radius = cube_half_edge_mm(projections)
    print(f"# GPU {name}, CuPy {cupy.__version__}; CPU {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, NumPy {np.__version__}; demo phantom, {len(projections)} views, "
          f"threshold {args.threshold} px, median of {args.repeats} runs after a warm-up")
    print("\n| K | kept points | CPU octree (s) | CUDA octree (s) | speed-up |")
    print("|---|---|---|---|---|")
    for k in args.resolutions:
        lattice = Lattice(radius, k)
        t_cpu, cpu = median_time(lambda: ENGINES["octree"](lattice, projections, masks, threshold_px=args.threshold),
                                 args.repeats)
        t_gpu, gpu = median_time(lambda: carve_cuda("octree", lattice, projections, masks, threshold_px=args.threshold),
                                 args.repeats, sync)
        if not np.array_equal(cpu.points_mm, gpu.points_mm):
            raise SystemExit(f"K={k}: the CUDA path kept different points ({len(gpu.points_mm)} vs {len(cpu.points_mm)})")
        print(f"| {k} | {len(cpu.points_mm)} | {t_cpu:.4f} | {t_gpu:.4f} | {t_cpu / t_gpu:.2f}x |", flush=True)


if __name__ == "__main__":
    main()
