"""Generated RCA trees under the paper's protocol vs the authors' own synthetic data.

For each tortuosity level, N generated RCA trees (seeds 0..N-1 of that level) are rendered with the
paper's rasteriser in the paper's perpendicular (and clinical) views, carved at K = 100 with a
1 px threshold and scored as in the paper (3 mm voxels). The same is done for the 48 studies of
``../shared/benchmarks/peer-synthetic`` when present. Prints a Markdown table of means and standard
deviations, the tortuosity index per level, and writes a gallery figure of the trees.

    python benchmarks/synthetic_band.py [--trees 30] [--engine kdtree] [--figure docs/synthetic-trees.png]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from angiohull.metrics import scores_3d  # noqa: E402
from angiohull.reconstruction import reconstruct  # noqa: E402
from angiohull.study import load_study  # noqa: E402
from angiohull.synthetic import TORTUOSITY_LEVELS, SynthOptions, make_case  # noqa: E402
from angiohull.synthetic.tree import TORTUOSITY_BANDS  # noqa: E402

SHARED = Path(os.environ.get("ANGIOHULL_SHARED", Path(__file__).resolve().parents[2] / "shared"))


def _score(projections, masks, ground_truth, engine):
    result = reconstruct(projections, masks, method="hull", engine=engine, centerlines=False, allow_empty=True,
                         warn=False)
    s = scores_3d(result.vessel_points_mm, ground_truth)
    return s.dice3d, s.iou3d, s.chamfer_mm, result.time_s


def _row(label, values):
    v = np.array(values, dtype=float)
    return (f"| {label} | {len(v)} | {np.mean(v[:, 0]):.1f} ± {np.std(v[:, 0]):.1f} | {np.mean(v[:, 1]):.1f} ± "
            f"{np.std(v[:, 1]):.1f} | {np.nanmean(v[:, 2]):.3f} ± {np.nanstd(v[:, 2]):.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=30, help="trees per tortuosity level (default 30)")
    parser.add_argument("--engine", default="kdtree", help="carving engine (default kdtree, the reference)")
    parser.add_argument("--figure", type=Path, default=None, help="write a gallery of generated trees here")
    args = parser.parse_args()

    header = "| data | cases | Dice3D % | IoU3D % | Chamfer mm |\n|---|---|---|---|---|"
    for views in ("perpendicular", "clinical"):
        print(f"\n### {views} views, paper rasteriser, K = 100, threshold 1 px, engine {args.engine}\n")
        print(header)
        pooled, start = [], time.perf_counter()
        for level in TORTUOSITY_LEVELS:
            values = []
            for seed in range(args.trees):
                case = make_case(SynthOptions(kind="rca", tortuosity=level, views=views, rasteriser="paper", seed=seed))
                values.append(_score([v.projection for v in case.views], [v.mask for v in case.views],
                                     case.surface_points_mm, args.engine))
            pooled += values
            print(_row(f"generated RCA, {level}", values))
        print(_row("generated RCA, all", pooled))
        peer_dir = SHARED / "benchmarks" / "peer-synthetic"
        if peer_dir.is_dir():
            peer = []
            for folder in sorted(peer_dir.glob(f"{views}_*")):
                study = load_study(folder)
                peer.append(_score(study.projections, study.masks, study.ground_truth_mm, args.engine))
            print(_row("authors' peer-synthetic", peer))
        print(f"\n({time.perf_counter() - start:.0f} s)")

    print("\n### Tortuosity index (rad/cm) of the generated trees\n")
    print("| kind | level | band | min | median | max |\n|---|---|---|---|---|---|")
    for kind in ("rca", "left"):
        for level in TORTUOSITY_LEVELS:
            index = [make_case(SynthOptions(kind=kind, tortuosity=level, seed=s, views="AP")).tree.tortuosity_index()
                     for s in range(args.trees)]
            low, high = TORTUOSITY_BANDS[level]
            print(f"| {kind} | {level} | [{low}, {high}] | {min(index):.2f} | {np.median(index):.2f} | {max(index):.2f} |")

    if args.figure is not None:
        _gallery(args.figure)
        print(f"\nwrote {args.figure}")


def _gallery(path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    views = ("RAO 30", "LAO 45", "RAO 30 CRA 30", "LAO 60 CRA 30")
    rows = [("rca", level) for level in TORTUOSITY_LEVELS] + [("left", "moderate")]
    fig = Figure(figsize=(2.2 * len(views), 2.35 * len(rows)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(rows), len(views))
    for i, (kind, level) in enumerate(rows):
        case = make_case(SynthOptions(kind=kind, tortuosity=level, seed=1, views="; ".join(views)))
        for j, view in enumerate(case.views):
            ax = axes[i, j]
            ax.imshow(~view.mask[48:464, 48:464], cmap="gray", interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(views[j], fontsize=9)
            if j == 0:
                ax.set_ylabel(f"{kind} {level}\nindex {case.tree.tortuosity_index():.2f}", fontsize=8)
    fig.suptitle("angiohull synth: exact masks of generated trees (seed 1)", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)


if __name__ == "__main__":
    main()
