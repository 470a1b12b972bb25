"""The tree method against the visual hull (issue 21): generated trees in two and three views.

Runs, with the same defaults for every case: generated RCA and left trees (``--trees`` each,
tortuosity simple / moderate / tortuous in turn), exact masks, in

* two clinical views, RAO 30 CAU 25 with LAO 45 CRA 20;
* the paper's three clinical views (RAO 30 CRA 30, LAO 60 CRA 30, RAO 30 CAU 30);

and reconstructs each with ``hull`` (paper preset, K = 100), ``hull`` (refined preset, K = 256)
and ``tree`` (K = 256): Dice3D, Chamfer, the tree scores of
:func:`angiohull.metrics.tree.tree_scores` (centerline mean distance, Ot(1 mm) both ways, radius
MAE, branch recall and precision) and the reconstruction time.

    OPENBLAS_NUM_THREADS=1 python benchmarks/tree_method.py [--trees 30] [--workers 2] \\
        [--output docs/results/tree-method.md]
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

LEVELS = ("simple", "moderate", "tortuous")
SETUPS = {"2 views": ("RAO 30 CAU 25", "LAO 45 CRA 20"), "3 views": ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30")}
METHODS = (("hull", "paper"), ("hull", "refined"), ("tree", "paper"))
KEYS = ("centerline_mean_mm", "ot1mm", "ot1mm_reverse", "radius_mae_mm", "branch_recall", "branch_precision")


def _case(kind: str, index: int, views):
    from angiohull.errors import AngiohullError
    from angiohull.synthetic import SynthOptions, make_case

    for attempt in range(10):
        seed = (7_000 if kind == "rca" else 8_000) + index + 1000 * attempt
        try:
            return seed, make_case(SynthOptions(kind=kind, tortuosity=LEVELS[index % 3], views=views, seed=seed))
        except AngiohullError:
            continue
    raise RuntimeError(f"no {kind} tree for index {index}")


def _run(task: tuple[str, int, str]) -> list[dict]:
    from angiohull.metrics import scores_3d
    from angiohull.metrics.tree import tree_scores
    from angiohull.reconstruction import reconstruct

    kind, index, setup = task
    seed, case = _case(kind, index, SETUPS[setup])
    truth = case.tree.vessel_tree()
    projections, masks = [v.projection for v in case.views], [v.mask for v in case.views]
    rows = []
    for method, preset in METHODS:
        row = {"kind": kind, "index": index, "seed": seed, "setup": setup, "method": method, "preset": preset}
        start = time.perf_counter()
        try:
            result = reconstruct(projections, masks, method=method, preset=preset, centerlines=False)
        except Exception as exc:  # noqa: BLE001 - a failed case is a row
            rows.append({**row, "error": f"{type(exc).__name__}: {exc}"})
            continue
        row["time_s"] = time.perf_counter() - start
        s3 = scores_3d(result.vessel_points_mm, case.surface_points_mm)
        row.update({"dice3d": s3.dice3d, "chamfer_mm": s3.chamfer_mm})
        if result.tree is not None:
            scores = tree_scores(result.tree, truth).as_dict()
            row.update({k: scores[k] for k in KEYS})
        rows.append(row)
    return rows


def _fmt(values) -> str:
    values = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    if len(values) == 0:
        return "-"
    return f"{values.mean():.3f} ± {values.std():.3f} ({np.median(values):.3f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=30, help="generated trees per kind (default 30)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--output", type=Path, default=None, help="Markdown report to write (and .json beside it)")
    args = parser.parse_args()
    start = time.perf_counter()
    tasks = [(kind, i, setup) for setup in SETUPS for kind in ("rca", "left") for i in range(args.trees)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = [r for chunk in pool.map(_run, tasks) for r in chunk]
    elapsed = time.perf_counter() - start
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    lines = [f"# Results: the tree method against the visual hull", "",
             f"Produced by `OPENBLAS_NUM_THREADS=1 python benchmarks/tree_method.py --trees {args.trees} "
             f"--workers {args.workers}` on {datetime.date.today()}, commit {commit}, {platform.machine()} with "
             f"{os.cpu_count()} cores, Python {platform.python_version()}, in {elapsed:.0f} s. Exact masks; the same "
             f"defaults for every case; mean ± sd (median).", ""]
    for setup in SETUPS:
        lines += [f"## {setup}: {', '.join(SETUPS[setup])}", "",
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
    failures = [f"{r['setup']} {r['kind']} {r['seed']} {r['method']}: {r['error']}" for r in rows if "error" in r]
    if failures:
        lines += ["Failed cases:", ""] + [f"- {f}" for f in failures] + [""]
    text = "\n".join(lines)
    print(text)
    if args.output is not None:
        args.output.write_text(text + "\n", encoding="utf-8")
        args.output.with_suffix(".json").write_text(json.dumps(rows, indent=1, default=float) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
