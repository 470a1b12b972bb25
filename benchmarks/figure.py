"""Time figure.png (angiohull.viz.reconstruction_figure) on the demo study at several K (issue 24).

Reconstructs the demo study (written by `angiohull demo`) with the paper preset at each K, then
draws the figure ``--repeats`` times (with the ground truth, the centerline points and the three
views, as `angiohull demo` does) and prints the median wall and process CPU times. With
``--before COMMIT`` the viz.py of that commit (read with `git show`) is timed too, interleaved
with the current one, so both see the same load.

    OPENBLAS_NUM_THREADS=1 python benchmarks/figure.py angiohull-demo/study -k 100 256 512 [--before f06be18]
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from angiohull import viz, workflow
from angiohull.study import load_study


def module_at(commit: str):
    """angiohull/viz.py as it was at ``commit``, importable beside the current package."""
    root = Path(__file__).resolve().parents[1]
    source = subprocess.run(["git", "show", f"{commit}:src/angiohull/viz.py"], cwd=root, check=True,
                            capture_output=True, text=True).stdout
    spec = importlib.util.spec_from_loader("angiohull._viz_before", loader=None)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "angiohull"
    exec(compile(source, f"{commit}:viz.py", "exec"), module.__dict__)
    return module


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", type=Path)
    parser.add_argument("-k", type=int, nargs="+", default=[100, 256])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--before", default=None, metavar="COMMIT")
    args = parser.parse_args(argv)
    study = load_study(args.study)
    versions = [("after", viz)] + ([("before", module_at(args.before))] if args.before else [])
    out = Path(tempfile.mkdtemp(prefix="angiohull-figure-"))
    for k in args.k:
        result = workflow.reconstruct_study(study, workflow.ReconstructOptions(resolution=k, tree=False))
        silhouettes = workflow.view_silhouettes(study, result)
        times = {name: [] for name, _ in versions}
        for _ in range(args.repeats):
            for name, module in versions:
                kwargs = dict(vessel_points_mm=result.vessel_points_mm, masks=study.masks, reprojections=silhouettes,
                              view_names=study.names, centerline_points_mm=result.centerline_points_mm,
                              ground_truth_mm=study.ground_truth_mm, view_scores=[80.0] * len(study.views),
                              title=f"K={k}")
                if name == "after":
                    kwargs.update(scores=["Dice3D ...", "tree: ..."], lattice_spacing_mm=result.lattice_spacing_mm)
                wall, cpu = time.perf_counter(), time.process_time()
                module.reconstruction_figure(out / f"{name}_{k}.png", **kwargs)
                times[name].append((time.perf_counter() - wall, time.process_time() - cpu))
        text = ", ".join(f"{name} median {statistics.median(t[0] for t in ts):.2f} s wall, "
                         f"{statistics.median(t[1] for t in ts):.2f} s CPU" for name, ts in times.items())
        print(f"K={k} ({len(result.vessel_points_mm):,} points, {args.repeats} runs): {text}", flush=True)
    print(f"figures in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
