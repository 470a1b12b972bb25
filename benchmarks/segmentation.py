"""Vessel segmentation on synthetic angiograms: Dice against the true mask, and time per image.

Run from the repository root (after `pip install .`):

    OPENBLAS_NUM_THREADS=1 python benchmarks/segmentation.py [--seeds 2]

Images: synthetic coronary trees (per seed and view, an RCA or left tree of each tortuosity level in
turn, angiohull.synthetic.generate_tree) rendered by angiohull.synthetic.angiogram (Beer-Lambert attenuation of the
exact chord through the tubes, smooth body texture, quantum and electronic noise, detector blur) in
six views -- the three demo views (RAO 30 CRA 30, LAO 60 CRA 30, RAO 30 CAU 30) and LAO 75 CAU 20,
RAO 55 CRA 10, LAO 20 CRA 40 -- 512 x 512 pixels of 0.35 mm, SID 1200 mm, SOD 800 mm, one image per
view and seed. Renderer settings: the defaults with an 8-pixel collimator ("default"), and
variations that make the task harder. Segmentation: the default SegmentationParameters (Sato, its
edge at the blurred round vessel's level, edge_profile 0.5 and edge_blur_px 0.6, read on the
attenuation less its local background with its floor in the noise left there, gaps bridged up to
20 px, narrow vessels widened to their densitometric radius), Sato with the edge floor in the
image's global noise (edge_local_noise false, edge_blur_px 0: the masks before commit 9e18419),
Sato without the densitometric widening (density_radius_px 0), Sato without the local background
under the vessels (local_background_px 0, edge_blur_px 0: the masks before commit ee611be), Sato
without bridging (bridge_px 0), Sato with the noise-level edge alone (edge_profile 0, the floor in
the global noise: the default before 2026-12-03 but for the local background and bridging), Sato
with the relative edge alone (edge_fraction 0.2), and Frangi. Prints mean and minimum Dice per
setting and the mean time of segment_vessels per image.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from angiohull.geometry import CArmGeometry
from angiohull.segmentation import SegmentationParameters, segment_vessels
from angiohull.synthetic import TORTUOSITY_LEVELS, demo_views, generate_tree
from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram

SETTINGS = {
    "default (collimator 8 px)": AngiogramParameters(collimator_px=8),
    "no collimator": AngiogramParameters(),
    "low dose (1000 quanta/px)": AngiogramParameters(collimator_px=8, photons_per_pixel=1000.0),
    "strong texture (0.3)": AngiogramParameters(collimator_px=8, background_texture=0.3),
    "faint contrast (0.12 /mm)": AngiogramParameters(collimator_px=8, vessel_attenuation_per_mm=0.12),
}
_BEFORE_LOCAL_NOISE = {"edge_local_noise": False, "edge_blur_px": 0.0}  # the masks before commit 9e18419
METHODS = {"sato (default)": SegmentationParameters(),
           "sato, edge floor in the global noise (edge_local_noise false, edge_blur_px 0)":
               SegmentationParameters(**_BEFORE_LOCAL_NOISE),
           "sato, no densitometric width (density_radius_px 0)": SegmentationParameters(density_radius_px=0.0),
           "sato, no local background (local_background_px 0, edge_blur_px 0)":
               SegmentationParameters(local_background_px=0.0, edge_blur_px=0.0),
           "sato, no bridging (bridge_px 0)": SegmentationParameters(bridge_px=0.0),
           "sato, noise edge only (edge_profile 0, edge floor in the global noise)":
               SegmentationParameters(edge_profile=0.0, **_BEFORE_LOCAL_NOISE),
           "sato, edge_fraction 0.2": SegmentationParameters(edge_profile=0.0, edge_fraction=0.2),
           "frangi": SegmentationParameters(method="frangi")}


def views():
    extra = [(75.0, -20.0), (-55.0, 10.0), (20.0, 40.0)]
    return [carm for _, carm in demo_views()] + [CArmGeometry(a, b, 1200.0, 800.0, (0.35, 0.35), (512, 512)) for a, b in extra]


def dice(a, b):
    return 2.0 * np.count_nonzero(a & b) / (np.count_nonzero(a) + np.count_nonzero(b))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="images per view and setting (default 2)")
    args = parser.parse_args()
    kinds = [(kind, level) for kind in ("rca", "left") for level in TORTUOSITY_LEVELS]
    print(f"# Python {platform.python_version()}, {platform.machine()}, {args.seeds} seed(s) x {len(views())} views per row")
    print("| renderer setting | segmentation | mean Dice | min Dice | time per image (s) |")
    print("|---|---|---|---|---|")
    for setting, render_params in SETTINGS.items():
        images = []
        for seed in range(args.seeds):
            for i, carm in enumerate(views()):
                kind, level = kinds[(seed * len(views()) + i) % len(kinds)]
                tree = generate_tree(kind, level, 1000 * seed + i)
                images.append(render_angiogram(tree.phantom, carm, 1000 * seed + i, render_params))
        for method, seg_params in METHODS.items():
            scores, times = [], []
            for image in images:
                start = time.perf_counter()
                mask = segment_vessels(image.image, seg_params)
                times.append(time.perf_counter() - start)
                scores.append(dice(mask, image.mask))
            print(f"| {setting} | {method} | {np.mean(scores):.3f} | {np.min(scores):.3f} | {np.mean(times):.2f} |", flush=True)


if __name__ == "__main__":
    main()
