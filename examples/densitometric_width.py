"""A stenosis in a rendered angiogram, segmented with and without the densitometric width: a figure.

Run from the repository root (after `pip install .`):

    python examples/densitometric_width.py [--figure docs/densitometric-width.png]

The tree is the QCA benchmark's RCA tree 19 (benchmarks/qca.py: generator seed 17703, moderate
tortuosity), whose RCA has a 46 % stenosis 112.9 mm from the ostium; the view is the benchmark's
first (RAO 30 CRA 30), rendered as the benchmark renders it (texture, noise, blur, an 8 px
collimator). The figure shows the angiogram around the stenosis, the segmented mask without the
widening (`density_radius_px` 0) and with it (the default) against the true silhouette, and the
mask's width across the vessel along its true centreline against the true projected diameter.
It prints the mean width error over the lesion for both.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import ndimage as ndi

from angiohull.segmentation import SegmentationParameters, segment_vessels
from angiohull.synthetic import SynthOptions, draw_tree_params, make_case
from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram

SEED, KIND, LEVEL = 17703, "rca", "moderate"
VIEWS = ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30")
BRANCH, CENTRE_MM, HALF_SPAN_MM = "RCA", 112.9, 12.0


def widths_px(mask: np.ndarray, uv: np.ndarray, normals: np.ndarray, reach_px: float = 12.0) -> np.ndarray:
    """The run of ``mask`` across each point (px, pixel-centre rule): along the normal, 0.1 px steps,
    the contiguous run through the sample nearest the point (0 where there is none within 2 px)."""
    q = np.arange(-reach_px, reach_px + 1e-9, 0.1)
    cols = uv[:, 0, None] + q[None, :] * normals[:, 0, None]
    rows = uv[:, 1, None] + q[None, :] * normals[:, 1, None]
    inside = ndi.map_coordinates(mask.astype(float), [rows.ravel(), cols.ravel()], order=0).reshape(rows.shape) > 0.5
    middle = len(q) // 2
    out = np.zeros(len(uv))
    for i, row in enumerate(inside):
        near = np.flatnonzero(row[middle - 20:middle + 21])
        if len(near) == 0:
            continue
        j = middle - 20 + near[np.argmin(np.abs(near - 20))]
        lo, hi = j, j
        while lo > 0 and row[lo - 1]:
            lo -= 1
        while hi < len(row) - 1 and row[hi + 1]:
            hi += 1
        out[i] = (hi - lo + 1) * 0.1
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", default="densitometric-width.png", help="PNG to write")
    args = parser.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    case = make_case(SynthOptions(kind=KIND, tortuosity=LEVEL, views=VIEWS, seed=SEED),
                     tree_params=draw_tree_params(KIND, LEVEL, SEED))
    view = case.views[0]
    image = render_angiogram(case.tree.phantom, view.carm, SEED * 10, AngiogramParameters(collimator_px=8)).image
    plain = segment_vessels(image, SegmentationParameters(density_radius_px=0.0))
    widened = segment_vessels(image)

    branch = next(b for b in case.tree.branches if b.name == BRANCH)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(branch.centerline_mm, axis=0), axis=1))])
    near = np.abs(arc - CENTRE_MM) <= HALF_SPAN_MM
    points, radius, along = branch.centerline_mm[near], branch.radius_mm[near], arc[near] - CENTRE_MM
    projection = view.carm.projection()
    uv = projection.project(points)
    tangent = np.gradient(uv, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normals = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    true_px = 2.0 * radius * max(projection.focal_lengths_px) / projection.depth_mm(points)
    w_plain, w_widened = widths_px(plain, uv, normals), widths_px(widened, uv, normals)
    lesion = np.abs(along) <= 4.0
    for name, w in (("without the widening", w_plain), ("with it (default)", w_widened)):
        print(f"{name}: mask width minus true diameter over the lesion's middle 8 mm, mean "
              f"{np.mean(w[lesion] - true_px[lesion]):+.2f} px (absolute {np.mean(np.abs(w[lesion] - true_px[lesion])):.2f} px)")

    c = np.round(uv[len(uv) // 2]).astype(int)
    half = 32
    box = (slice(c[1] - half, c[1] + half), slice(c[0] - half, c[0] + half))
    fig = plt.figure(figsize=(12, 7.5))
    grid = fig.add_gridspec(2, 3, height_ratios=[1.15, 1.0])
    truth = view.mask[box]
    outline = truth & ~ndi.binary_erosion(truth)
    panels = (("angiogram (RAO 30 CRA 30)", None), ("mask, density_radius_px 0", plain), ("mask, default", widened))
    for k, (title, mask) in enumerate(panels):
        ax = fig.add_subplot(grid[0, k])
        ax.imshow(image[box], cmap="gray")
        if mask is not None:
            overlay = np.zeros(truth.shape + (4,))
            overlay[mask[box]] = (0.1, 0.8, 0.2, 0.45)
            overlay[outline] = (1.0, 0.2, 0.2, 0.9)
            ax.imshow(overlay)
        ax.plot(uv[:, 0] - box[1].start, uv[:, 1] - box[0].start, "y-", lw=0.7)
        ax.set_xlim(-0.5, 2 * half - 0.5)
        ax.set_ylim(2 * half - 0.5, -0.5)
        ax.set_title(title + ("" if mask is None else "\n(green: mask, red: true outline)"), fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    ax = fig.add_subplot(grid[1, :])
    ax.plot(along, true_px, "k-", lw=2, label="true projected diameter")
    ax.plot(along, w_plain, "o", ms=3, color="tab:orange", label="mask width, density_radius_px 0")
    ax.plot(along, w_widened, "o", ms=3, color="tab:green", label="mask width, default (densitometric)")
    ax.set_xlabel(f"arc length from the stenosis's centre along the {BRANCH}, mm")
    ax.set_ylabel("width across the vessel, px")
    ax.legend(fontsize=9)
    ax.grid(alpha=0.3)
    severity = next(st.severity for st in branch.stenoses if abs(st.centre_mm - CENTRE_MM) < 1.0)
    fig.suptitle(f"A {100 * severity:.0f} % stenosis of a rendered angiogram (QCA benchmark, RCA tree 19)", fontsize=11)
    fig.tight_layout()
    fig.savefig(args.figure, dpi=90)
    print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
