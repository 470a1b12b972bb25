"""End to end on real angiograms: three GE XA runs of a static phantom -> masks -> 3D -> figure.

Run from the repository root (after `pip install .`), with the project's shared data beside the
checkout (../shared) or ANGIOHULL_SHARED pointing at it:

    python examples/ge_phantom.py [-o ge-phantom-example] [--data DIR] [--figure docs/dicom-phantom.png]

It runs the command line exactly as a user would (the commands are printed first):

    angiohull dicom-info IM1.dcm IM2.dcm IM5.dcm
    angiohull study-from-dicom IM1.dcm IM2.dcm IM5.dcm -o OUT/study --segment --overwrite
    angiohull reconstruct OUT/study -o OUT/reconstruction --method hull --overwrite

(the paper's visual hull: how much of each mask it keeps shows whether the views agree; docs/dicom.md
gives the tree method's numbers beside it) then prints, per view, the plain reprojection Dice2D of report.json with the mask pixels the
reconstruction covers and the reprojected pixels that fall on the mask, and draws a figure: each
chosen frame with its segmentation, and each mask against the reconstruction's reprojection.

The header geometry of these files disagrees between views by tens of pixels (see
../shared/data/ge-xa-phantom/README.md and docs/dicom.md); nothing here corrects it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from angiohull.cli import main as angiohull
from angiohull.dicom import read_xa_frame
from angiohull.errors import DicomGeometryWarning
from angiohull.io import read_points
from angiohull.rasterise import cell_silhouette
from angiohull.study import load_study

FILES = ("IM1.dcm", "IM2.dcm", "IM5.dcm")


def default_data() -> Path:
    shared = os.environ.get("ANGIOHULL_SHARED")
    root = Path(shared) if shared else Path(__file__).resolve().parents[2] / "shared"
    return root / "data" / "ge-xa-phantom"


def run(argv: list[str]) -> None:
    print("$ angiohull " + " ".join(argv), flush=True)
    status = angiohull(argv)
    if status != 0:
        sys.exit(status)


def figure(path: Path, study, frames, silhouettes, scores) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(study.views)
    fig, axes = plt.subplots(2, n, figsize=(3.4 * n, 7.0), constrained_layout=True)
    for k, (view, frame, silhouette) in enumerate(zip(study.views, frames, silhouettes)):
        top, bottom = axes[0, k], axes[1, k]
        top.imshow(frame, cmap="gray", interpolation="nearest")
        overlay = np.zeros((*view.mask.shape, 4))
        overlay[view.mask] = (1.0, 0.25, 0.1, 0.55)
        top.imshow(overlay, interpolation="nearest")
        top.set_title(f"{view.name} frame {view.frame}: {view.carm.clinical_name()}\nSID {view.carm.sid_mm:g} mm, "
                      f"segmentation {int(view.mask.sum())} px", fontsize=9)
        rgb = np.zeros((*view.mask.shape, 3))
        rgb[view.mask & silhouette] = (0.92, 0.92, 0.92)
        rgb[view.mask & ~silhouette] = (0.85, 0.37, 0.0)
        rgb[~view.mask & silhouette] = (0.35, 0.7, 0.9)
        bottom.imshow(rgb, interpolation="nearest")
        bottom.set_title(f"mask vs reprojection: Dice2D {scores[k]:.1f} %\n(white both, orange missed, blue spurious)", fontsize=9)
        for ax in (top, bottom):
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle("GE XA phantom: DICOM -> segmentation -> visual hull with the header geometry (uncalibrated)", fontsize=10)
    fig.savefig(path, dpi=72)
    plt.close(fig)
    from PIL import Image

    with Image.open(path) as image:  # 96 colours keep the PNG small
        image.convert("RGB").quantize(96).save(path, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=Path("ge-phantom-example"), help="output folder")
    parser.add_argument("--data", type=Path, default=default_data(), help="folder with IM1.dcm, IM2.dcm, IM5.dcm")
    parser.add_argument("--figure", type=Path, default=None, help="where to write the summary figure (default OUT/summary.png)")
    args = parser.parse_args()
    files = [str(args.data / name) for name in FILES]
    missing = [f for f in files if not Path(f).is_file()]
    if missing:
        sys.exit(f"missing input files {missing}; pass --data or set ANGIOHULL_SHARED")
    out = args.output
    run(["dicom-info", *files])
    # --overwrite: the example owns its output folder, so a second run replaces the first one's results
    run(["study-from-dicom", *files, "-o", str(out / "study"), "--segment", "--overwrite"])
    run(["reconstruct", str(out / "study"), "-o", str(out / "reconstruction"), "--method", "hull", "--overwrite"])

    report = json.loads((out / "reconstruction" / "report.json").read_text())
    warnings.simplefilter("ignore", DicomGeometryWarning)  # the commands above have shown them
    study = load_study(out / "study")
    points = read_points(out / "reconstruction" / "vessel.ply")
    spacing = report["cube_of_interest"]["lattice_spacing_mm"]
    silhouettes = [cell_silhouette(points, view.projection, spacing) for view in study.views]
    print(f"\n{len(points)} vessel points at K={report['cube_of_interest']['resolution']} "
          f"(lattice {spacing:.2f} mm); carving {report['timings_s']['carve']:.3f} s")
    print("| view | frame | angles | Dice2D (plain) | mask covered | reprojection on the mask |")
    print("|---|---|---|---|---|---|")
    scores = []
    for view, silhouette, entry in zip(study.views, silhouettes, report["views"]):
        both = np.count_nonzero(view.mask & silhouette)
        scores.append(entry["dice2d_reprojection"])
        print(f"| {view.name} | {view.frame} | {view.carm.clinical_name()} | {entry['dice2d_reprojection']:.1f} % | "
              f"{100 * both / view.mask.sum():.0f} % | {100 * both / max(silhouette.sum(), 1):.0f} % |")
    frames = [read_xa_frame(view.dicom_path, view.frame) for view in study.views]
    target = args.figure if args.figure is not None else out / "summary.png"
    figure(target, study, frames, silhouettes, scores)
    print(f"\nfigure: {target}; the reconstruction's own figure: {out / 'reconstruction' / 'figure.png'}")


if __name__ == "__main__":
    main()
