"""Static figures of a reconstruction (PNG), drawn with Matplotlib's Agg canvas.

This module sits on top of the layer stack: only the CLI imports it, and it never touches
Matplotlib's global state (no ``pyplot``, no ``matplotlib.use``): every figure is a
:class:`matplotlib.figure.Figure` bound to its own :class:`FigureCanvasAgg`, so it is safe in
headless processes, threads and test suites.

Public functions
----------------
:func:`reconstruction_figure`
    One PNG that summarises a reconstruction: the point cloud projected on the three anatomical
    planes (top row, the ground truth in a second row when there is one) and, for every view, the input mask overlaid with the reconstruction's
    re-projected silhouette (bottom rows).
:func:`overlay_rgb`
    The colour-coded mask / re-projection comparison image used by the view panels.
:func:`qca_profiles_figure`
    The diameter profiles of a quantitative coronary analysis, one panel per branch: reference
    taper, lesions with their MLD, %DS and length.
:func:`qca_view_map_figure`
    A segment's view map: ``foreshortening x (1 - overlap)`` over the C-arm angles, with the
    foreshortening contours, the overlapped region and the best working view.

Colour code of the overlays (:data:`OVERLAY_COLOURS`, Okabe–Ito colours that stay distinct for
colour-blind readers): pixels in both the mask and the re-projection are light grey, mask-only
pixels (vessel the reconstruction missed) are vermillion, re-projection-only pixels (spurious
reconstruction) are sky blue, and pixels in neither are black.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import patheffects
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from matplotlib.patches import Patch, Rectangle

from . import _validation as _v
from .errors import AngiohullError

__all__ = ["OVERLAY_COLOURS", "overlay_rgb", "reconstruction_figure", "nearest_distance_mm", "splat_image",
           "qca_profiles_figure", "qca_view_map_figure"]

#: RGB colour (uint8) of each overlay class.
OVERLAY_COLOURS: dict[str, tuple[int, int, int]] = {
    "background": (0, 0, 0),
    "both": (235, 235, 235),  # in the mask and in the re-projection: agreement
    "missed": (213, 94, 0),  # mask only: vessel the reconstruction does not cover
    "spurious": (86, 180, 233),  # re-projection only: reconstruction outside the vessel
}

_OVERLAY_LABELS = {"both": "both", "missed": "mask only (missed)", "spurious": "reprojection only (spurious)"}

#: Above this many vessel (or ground-truth) points the projections draw an evenly spread subset.
_MAX_DRAWN_POINTS = 2_000_000
#: Above this many ground-truth points the truth row draws an evenly spread subset.
_MAX_DRAWN_TRUTH = 15_000
_CENTERLINE_COLOUR = "#d62728"  # on the depth colours (viridis has no red)
_CENTERLINE_ON_ERROR_COLOUR = "#111111"  # on the distance colours, whose far end is red
#: The distance colour scale runs from 0 to this (mm) or to the 95th percentile of the distances if larger.
ERROR_SCALE_FLOOR_MM = 3.0
_POINT_CMAP = "viridis"
_VIEWS_PER_ROW = 4
_FIGURE_WIDTH_IN = 13.0
_VIEW_PANEL_WIDTH_IN = 3.15  # width of one of four view panels in a row, in inches
_VIEW_DECORATION_IN = 0.75  # title above and the pixel counts below a row of view panels

# (horizontal axis, vertical axis, depth axis, panel title, nearer-to-viewer is larger depth?)
_AXIS_LABELS = ("x", "y", "z")
_PLANES = (
    (0, 2, 1, "Frontal (seen from anterior)", False),
    (1, 2, 0, "Lateral (seen from patient's left)", True),
    (0, 1, 2, "Axial (seen from feet)", False),
)
_HORIZONTAL_LABELS = {0: "x (mm, patient left →)", 1: "y (mm, posterior →)"}
_VERTICAL_LABELS = {2: "z (mm, head ↑)", 1: "y (mm, posterior ↓)"}


# --------------------------------------------------------------------------------------------------
# Validation helpers
# --------------------------------------------------------------------------------------------------


def _points(value: Any, name: str) -> np.ndarray:
    """Return ``value`` as a finite float64 (N, 3) array (an empty input gives (0, 3))."""
    if np.size(value) == 0:
        return np.empty((0, 3), dtype=np.float64)
    return _v.points_array(value, name)


def _image(value: Any, name: str) -> np.ndarray:
    """Return ``value`` as a 2-D bool array (nonzero = True)."""
    array = np.asarray(value)
    if array.ndim != 2:
        raise AngiohullError(f"{name} must be a 2-D (rows, cols) image, got shape {array.shape}")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise AngiohullError(f"{name} must not be empty, got shape {array.shape}")
    if array.dtype == bool:
        return array
    if not (np.issubdtype(array.dtype, np.number)):
        raise AngiohullError(f"{name} must be a boolean or numeric image, got dtype {array.dtype}")
    return array != 0


def _sequence(value: Any, name: str) -> list[Any]:
    if isinstance(value, (str, bytes)) or isinstance(value, np.ndarray) and value.ndim < 1:
        raise AngiohullError(f"{name} must be a sequence with one entry per view, got {type(value).__name__}")
    if isinstance(value, np.ndarray) and value.ndim == 2:
        # A single 2-D image is almost certainly a mistake (one view without the enclosing list).
        raise AngiohullError(f"{name} must be a sequence of 2-D images (one per view), got a single array of shape {value.shape}")
    try:
        return list(value)
    except TypeError:
        raise AngiohullError(f"{name} must be a sequence with one entry per view, got {type(value).__name__}") from None


# --------------------------------------------------------------------------------------------------
# Overlay
# --------------------------------------------------------------------------------------------------


def overlay_rgb(mask: Any, reprojection: Any) -> np.ndarray:
    """Colour-code the agreement between an input mask and the reconstruction's silhouette.

    Parameters
    ----------
    mask, reprojection : array_like, shape (rows, cols)
        Boolean images (nonzero counts as True) of the same shape: the view's input vessel mask
        and the reconstruction projected into that view.

    Returns
    -------
    numpy.ndarray, shape (rows, cols, 3), dtype uint8
        Each pixel takes the colour of its class in :data:`OVERLAY_COLOURS`: ``"both"`` (light
        grey), ``"missed"`` (mask only), ``"spurious"`` (re-projection only) or ``"background"``.

    Raises
    ------
    AngiohullError (a ValueError)
        If an input is not 2-D or the shapes differ.
    """
    mask_b = _image(mask, "mask")
    reproj_b = _image(reprojection, "reprojection")
    if mask_b.shape != reproj_b.shape:
        raise AngiohullError(
            f"mask and reprojection must have the same (rows, cols) shape, got {mask_b.shape} and {reproj_b.shape}"
        )
    rgb = np.empty(mask_b.shape + (3,), dtype=np.uint8)
    rgb[...] = OVERLAY_COLOURS["background"]
    rgb[mask_b & reproj_b] = OVERLAY_COLOURS["both"]
    rgb[mask_b & ~reproj_b] = OVERLAY_COLOURS["missed"]
    rgb[~mask_b & reproj_b] = OVERLAY_COLOURS["spurious"]
    return rgb


# --------------------------------------------------------------------------------------------------
# Figure
# --------------------------------------------------------------------------------------------------

# Fixed layout in inches (a constrained layout of this many panels costs seconds to solve).
_PLANE_AXES_IN = 2.9  # side of a plane panel's axes
_PLANE_LEFT_IN = 0.72  # room for the y label and ticks left of a plane panel
_PLANE_COLUMN_IN = (_FIGURE_WIDTH_IN - 0.25) / 3.0  # one of three plane columns
_PLANE_ROW_IN = _PLANE_AXES_IN + 0.95  # axes, x label below, panel title above
_ROW_HEADING_IN = 0.3  # "reconstruction" / "ground truth" above a row of planes
_COLOURBAR_GAP_IN, _COLOURBAR_WIDTH_IN = 0.1, 0.13
# distance to the other cloud: blue (near) through amber to red (far), each visible on white; the
# viewer uses the same three colours
ERROR_COLOURS = ("#2b5ba8", "#e6a100", "#b2182b")


def _marker_size(n: int) -> float:
    """Scatter marker area (points^2) that keeps dense clouds readable and sparse ones visible."""
    if n <= 0:
        return 4.0
    return float(np.clip(3000.0 / n, 0.3, 6.0))


def _limits(layers: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Common (low, high) per axis over all non-empty layers, padded, with a minimum extent."""
    present = [layer for layer in layers if len(layer)]
    if not present:
        return np.full(3, -1.0), np.full(3, 1.0)
    stacked = np.concatenate(present, axis=0)
    low, high = stacked.min(axis=0), stacked.max(axis=0)
    centre = (low + high) / 2.0
    half = np.maximum((high - low) / 2.0, 1.0) * 1.06
    return centre - half, centre + half


def _spacing_mm(points: np.ndarray) -> float:
    """Typical distance between neighbouring points (median nearest-neighbour distance of a sample)."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 1.0
    sample = points[even_indices(len(points), 2000)]
    distance = cKDTree(points).query(sample, k=2)[0][:, 1]
    positive = distance[distance > 0]
    return float(np.median(positive)) if positive.size else 1.0


def even_indices(n: int, limit: int) -> np.ndarray:
    """At most ``limit`` indices of ``n`` items, evenly spread and increasing (all when n <= limit)."""
    if n <= limit:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, limit).round().astype(np.int64))


def nearest_distance_mm(points_mm: Any, reference_mm: Any) -> np.ndarray:
    """Distance (mm) from each point to the nearest reference point (exact, a k-d tree); NaN for
    every point when the reference is empty."""
    from scipy.spatial import cKDTree

    points, reference = _points(points_mm, "points_mm"), _points(reference_mm, "reference_mm")
    if len(points) == 0:
        return np.empty(0)
    if len(reference) == 0:
        return np.full(len(points), np.nan)
    return cKDTree(reference, balanced_tree=False, compact_nodes=False).query(points, workers=-1)[0]


def splat_image(u_px: np.ndarray, v_px: np.ndarray, depth: np.ndarray, values: np.ndarray, shape: tuple[int, int],
                side_px: int) -> np.ndarray:
    """Rasterise points: each point a ``side_px`` square centred on pixel ``(u, v)`` (column, row from
    the top), the nearest point (largest ``depth``) winning each pixel; pixels no point covers are NaN.

    Returns
    -------
    (rows, cols) float64 image of ``values``.
    """
    rows, cols = shape
    image = np.full(rows * cols, np.nan)
    if len(u_px) == 0:
        return image.reshape(shape)
    order = np.argsort(-depth, kind="stable")  # rank 0 = the nearest point
    u0 = np.floor(u_px[order]).astype(np.int64) - (side_px - 1) // 2
    v0 = np.floor(v_px[order]).astype(np.int64) - (side_px - 1) // 2
    rank = np.arange(len(order))
    best = np.full(rows * cols, len(order))  # per pixel the least rank that covers it
    for dv in range(side_px):
        for du in range(side_px):
            u, v = u0 + du, v0 + dv
            inside = (u >= 0) & (u < cols) & (v >= 0) & (v < rows)
            np.minimum.at(best, v[inside] * cols + u[inside], rank[inside])
    covered = best < len(order)
    image[covered] = values[order][best[covered]]
    return image.reshape(shape)


def _panel_limits(low: np.ndarray, high: np.ndarray, h: int, v: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """Square data limits (the panels are square, one mm is as long on both axes)."""
    centre_h, centre_v = (low[h] + high[h]) / 2.0, (low[v] + high[v]) / 2.0
    half = max(high[h] - low[h], high[v] - low[v]) / 2.0
    return (centre_h - half, centre_h + half), (centre_v - half, centre_v + half)


def _draw_plane(ax: Any, plane: tuple, cloud: np.ndarray, values: np.ndarray | None, centerline: np.ndarray | None,
                low: np.ndarray, high: np.ndarray, *, cmap: Any, norm: Any, spacing_mm: float, size_px: int,
                centerline_colour: str, fill: float = 1.0) -> None:
    """One orthographic panel: ``cloud`` rasterised (coloured by ``values``, or by depth when None),
    the centerline points scattered on top."""
    h, v, d, panel_title, nearer_is_larger = plane
    (h0, h1), (v0, v1) = _panel_limits(low, high, h, v)
    axial = v == 1  # anterior at the top, as seen from the feet
    if len(cloud):
        scale = size_px / (h1 - h0)
        side = int(np.clip(math.ceil(fill * spacing_mm * scale - 1e-9), 1, 9))  # neighbours touch: no moire
        u = (cloud[:, h] - h0) * scale
        rows_px = (cloud[:, v] - v0) * scale if axial else (v1 - cloud[:, v]) * scale
        depth = cloud[:, d] if nearer_is_larger else -cloud[:, d]
        colour = cloud[:, d] if values is None else values
        image = splat_image(u, rows_px, depth, colour, (size_px, size_px), side)
        extent = (h0, h1, v1, v0) if axial else (h0, h1, v0, v1)
        # coloured here, once, as RGBA bytes (transparent where no point is): Matplotlib then only
        # copies pixels instead of resampling a masked float image
        rgba = cmap(norm(np.nan_to_num(image, nan=0.0)), bytes=True)
        rgba[np.isnan(image), 3] = 0
        ax.imshow(rgba, extent=extent, origin="upper", interpolation="none", zorder=2)
    else:
        ax.text(0.5, 0.5, "empty reconstruction\n(0 vessel points)", transform=ax.transAxes, ha="center",
                va="center", fontsize=10, color="0.25", zorder=4,
                bbox=dict(boxstyle="round,pad=0.4", facecolor="white", edgecolor="0.6", alpha=0.9))
    if centerline is not None and len(centerline):
        ax.scatter(centerline[:, h], centerline[:, v], s=max(_marker_size(len(centerline)), 2.0), c=centerline_colour,
                   marker="o", linewidths=0, zorder=3)
    ax.set_xlim(h0, h1)
    ax.set_ylim((v1, v0) if axial else (v0, v1))
    ax.set_xlabel(_HORIZONTAL_LABELS[h], fontsize=8)
    ax.set_ylabel(_VERTICAL_LABELS[v], fontsize=8)
    ax.xaxis.set_major_locator(MaxNLocator(4))  # few ticks: each is an object to lay out and draw
    ax.yaxis.set_major_locator(MaxNLocator(4))
    ax.tick_params(labelsize=7)
    # the panel title as figure text: an axes title is re-placed against the tick labels at every draw
    box = ax.get_position()
    ax.figure.text((box.x0 + box.x1) / 2.0, box.y1 + 0.004, panel_title, ha="center", va="bottom", fontsize=9)



def _colour_legend(ax: Any, cmap: Any, label: str, centerline: bool, count: int, centerline_colour: str) -> None:
    """The legend of a plane row: the points' marker in three colours of their colour map (as drawn:
    squares coloured by the bar beside the panels) and the centerline's red dot."""
    from matplotlib.legend_handler import HandlerTuple

    squares = tuple(Line2D([], [], linestyle="none", marker="s", markersize=5, markeredgewidth=0,
                           color=cmap(level)) for level in (0.15, 0.5, 0.85))
    handles, labels = [squares], [label]
    if centerline:
        handles.append(Line2D([], [], linestyle="none", marker="o", markersize=4, markeredgewidth=0,
                              color=centerline_colour))
        labels.append(f"centerline points ({count:,})")
    ax.legend(handles, labels, handler_map={tuple: HandlerTuple(ndivide=None, pad=0.0)}, loc="upper right",
              fontsize=6, framealpha=0.85, handlelength=2.4, borderpad=0.3, handletextpad=0.5)


def _grey(image: Any) -> np.ndarray:
    """A grey image scaled to [0, 1] between its 1st and 99th percentiles (the angiogram under a view)."""
    array = np.asarray(image, dtype=np.float64)
    if array.ndim == 3:  # colour: its mean
        array = array[..., :3].mean(axis=-1)
    low, high = np.nanpercentile(array, [1.0, 99.0])
    if not high > low:
        return np.zeros_like(array)
    return np.clip((array - low) / (high - low), 0.0, 1.0)


def view_rgb(mask: np.ndarray, reprojection: np.ndarray, image: np.ndarray | None = None) -> np.ndarray:
    """A view panel's picture, float RGB in [0, 1]: :func:`overlay_rgb` of the mask and the
    re-projection, or, with the view's angiogram ``image``, the angiogram in grey with the classes
    over it (agreement faint, alpha 0.35; missed and spurious pixels strong, alpha 0.85)."""
    if image is None:
        return overlay_rgb(mask, reprojection) / 255.0
    rgb = np.repeat(_grey(image)[..., None], 3, axis=2)
    for key, where, alpha in (("both", mask & reprojection, 0.35), ("missed", mask & ~reprojection, 0.85),
                              ("spurious", ~mask & reprojection, 0.85)):
        rgb[where] = (1.0 - alpha) * rgb[where] + alpha * (np.asarray(OVERLAY_COLOURS[key]) / 255.0)
    return rgb


def _view_row(fig: Any, axes_at: Any, views: list, names: list[str], scores: list, left_in: float, top_in: float,
              width_in: float, image_in: float) -> None:
    """One row of view panels as one image (the views side by side on white): the axes machinery of
    a panel per view costs more than all the pixels."""
    rows = max(v[0].shape[0] for v in views)
    cols = max(v[0].shape[1] for v in views)
    gap = max(2, cols // 25)
    canvas = np.ones((rows, len(views) * (cols + gap) - gap, 3))
    for j, (mask, reprojection, image) in enumerate(views):
        rgb = view_rgb(mask, reprojection, image)
        r0, c0 = (rows - rgb.shape[0]) // 2, j * (cols + gap) + (cols - rgb.shape[1]) // 2
        canvas[r0:r0 + rgb.shape[0], c0:c0 + rgb.shape[1]] = rgb
    ax = axes_at(left_in, top_in, width_in, image_in)
    ax.imshow((canvas * 255.0 + 0.5).astype(np.uint8), interpolation="antialiased", aspect="auto")
    ax.set_axis_off()
    slot_in = width_in * cols / canvas.shape[1]
    step_in = width_in * (cols + gap) / canvas.shape[1]
    fig_w, fig_h = fig.get_size_inches()
    for j, ((mask, reprojection, image), name, score) in enumerate(zip(views, names, scores)):
        centre = (left_in + j * step_in + slot_in / 2.0) / fig_w
        label = name
        if score is not None:
            label += f" — Dice {score:.1f}%" if math.isfinite(score) else " — Dice n/a"
        fig.text(centre, 1.0 - (top_in - 0.05) / fig_h, label, ha="center", va="bottom", fontsize=9)
        counts = (f"both {np.count_nonzero(mask & reprojection):,} · missed {np.count_nonzero(mask & ~reprojection):,}"
                  f" · spurious {np.count_nonzero(~mask & reprojection):,} px")
        fig.text(centre, 1.0 - (top_in + image_in + 0.04) / fig_h, counts, ha="center", va="top", fontsize=6.5,
                 color="0.2")


def _view_legend(fig: Any, top_in: float, with_angiogram: bool) -> None:
    handles = [Patch(facecolor=np.asarray(OVERLAY_COLOURS[key]) / 255.0, edgecolor="0.4", linewidth=0.5,
                     label=_OVERLAY_LABELS[key]) for key in ("both", "missed", "spurious")]
    if with_angiogram:
        handles.append(Patch(facecolor="0.45", edgecolor="0.4", linewidth=0.5, label="angiogram underneath"))
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 1.0 - top_in / fig.get_size_inches()[1]),
               ncol=len(handles), fontsize=7, frameon=False, handlelength=1.2, columnspacing=1.5)


def _lines(value: Any, name: str) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [value] if value else []
    try:
        return [str(line) for line in value if str(line)]
    except TypeError:
        raise AngiohullError(f"{name} must be a string or a sequence of strings, got {type(value).__name__}") from None


def reconstruction_figure(
    path: str | os.PathLike[str],
    *,
    vessel_points_mm: Any,
    masks: Sequence[Any],
    reprojections: Sequence[Any],
    view_names: Sequence[str],
    centerline_points_mm: Any = None,
    ground_truth_mm: Any = None,
    title: str | None = None,
    view_scores: Sequence[float] | None = None,
    scores: str | Sequence[str] | None = None,
    images: Sequence[Any] | None = None,
    lattice_spacing_mm: float | None = None,
    dpi: int = 110,
) -> Path:
    """Write a PNG summarising a reconstruction and return its path.

    Layout: the top row shows the vessel point cloud projected orthographically on the three
    anatomical planes (LPS millimetres): frontal (x vs z, seen from anterior, so the patient's
    left is on the viewer's right), lateral (y vs z, seen from the patient's left) and axial (x vs
    y, seen from the feet, anterior up). The cloud is rasterised (each point a small square, the
    nearest point winning each pixel), so drawing costs the same for a thousand points as for a
    million. Without a ground truth the points are coloured by their coordinate along the dropped
    (depth) axis; with one, by their distance to the nearest ground-truth point (mm, one colour bar
    for the figure), and a second row shows the ground truth on the same axes coloured by its
    distance to the nearest reconstructed point (so missed vessel shows dark). Centerline points are
    drawn on top in red. The rows below hold one panel per view (up to four per row) with
    :func:`overlay_rgb` of the view's mask and the reconstruction's re-projection, over the
    view's angiogram when ``images`` gives one, titled with the view name and its score.

    Parameters
    ----------
    path : str or path-like
        Where to write the PNG (parent folders are created). Written as PNG whatever the suffix.
    vessel_points_mm : array_like, shape (N, 3)
        The reconstructed vessel points. May be empty: the projection panels then say so.
    masks : sequence of array_like (rows, cols)
        The input masks, one per view (nonzero = vessel).
    reprojections : sequence of array_like (rows, cols)
        The reconstruction's silhouette in each view, same shapes as ``masks``.
    view_names : sequence of str
        One name per view.
    centerline_points_mm, ground_truth_mm : array_like, shape (M, 3), optional
        Centerline points and ground-truth points to draw with the cloud.
    title : str, optional
        Figure title (default "angiohull reconstruction"); a line with the counts follows it.
    view_scores : sequence of float, optional
        One score per view (plain 2-D Dice in percent), shown in the panel titles; a NaN or
        ``None`` entry shows as "n/a".
    scores : str or sequence of str, optional
        Lines of scores printed under the title (e.g. Dice3D, IoU3D, Chamfer, Dice2D, tree scores).
    images : sequence of array_like (rows, cols) or None, optional
        Per view, the grey angiogram the mask was segmented from (drawn under the overlay), or None.
    lattice_spacing_mm : float, optional
        Spacing of the vessel points (the lattice's), which sets the drawn square's size; default:
        the median nearest-neighbour distance.
    dpi : int
        Resolution of the PNG (the figure is 13 inches wide).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    AngiohullError (a ValueError)
        If the point arrays are not (N, 3) and finite, the per-view sequences differ in length,
        a mask and its re-projection (or angiogram) differ in shape, or ``dpi`` is not a positive number.
    """
    vessel = _points(vessel_points_mm, "vessel_points_mm")
    centerline = None if centerline_points_mm is None else _points(centerline_points_mm, "centerline_points_mm")
    ground_truth = None if ground_truth_mm is None else _points(ground_truth_mm, "ground_truth_mm")
    score_lines = _lines(scores, "scores")

    mask_list = _sequence(masks, "masks")
    reproj_list = _sequence(reprojections, "reprojections")
    if isinstance(view_names, (str, bytes)):
        raise AngiohullError("view_names must be a sequence of names (one per view), got a single string")
    name_list = [str(name) for name in _sequence(view_names, "view_names")]
    lengths = {"masks": len(mask_list), "reprojections": len(reproj_list), "view_names": len(name_list)}
    score_list: list[float | None] | None = None
    if view_scores is not None:
        raw_scores = _sequence(view_scores, "view_scores")
        lengths["view_scores"] = len(raw_scores)
        score_list = []
        for i, score in enumerate(raw_scores):
            if score is None:
                score_list.append(float("nan"))
                continue
            try:
                score_list.append(float(score))
            except (TypeError, ValueError):
                raise AngiohullError(f"view_scores[{i}] must be a number, got {score!r}") from None
    image_list: list[Any] = [None] * len(mask_list)
    if images is not None:
        image_list = list(_sequence(images, "images"))
        lengths["images"] = len(image_list)
    if len(set(lengths.values())) > 1:
        detail = ", ".join(f"{key}: {value}" for key, value in lengths.items())
        raise AngiohullError(f"need one entry per view in each per-view sequence, got {detail}")
    views = []
    for i, (mask, reproj, image) in enumerate(zip(mask_list, reproj_list, image_list)):
        mask_b = _image(mask, f"masks[{i}]")
        reproj_b = _image(reproj, f"reprojections[{i}]")
        if mask_b.shape != reproj_b.shape:
            raise AngiohullError(
                f"view {i} ({name_list[i]!r}): mask shape {mask_b.shape} differs from reprojection shape {reproj_b.shape}"
            )
        if image is not None:
            image = np.asarray(image)
            if image.shape[:2] != mask_b.shape or image.dtype.kind not in "biuf":
                raise AngiohullError(f"images[{i}] ({name_list[i]!r}) must be a numeric image of the mask's shape "
                                     f"{mask_b.shape}, got shape {image.shape}, dtype {image.dtype}")
        views.append((mask_b, reproj_b, image))
    dpi_value = _dpi(dpi)

    # Drawing is rasterised, but the nearest-neighbour queries and splats still grow with the count.
    drawn = vessel
    if len(vessel) > _MAX_DRAWN_POINTS:
        drawn = vessel[even_indices(len(vessel), _MAX_DRAWN_POINTS)]
    gt_drawn = ground_truth
    if ground_truth is not None and len(ground_truth) > _MAX_DRAWN_TRUTH:
        # a truth of surface points (0.3 mm apart for synth) is denser than the panels' pixels
        gt_drawn = ground_truth[even_indices(len(ground_truth), _MAX_DRAWN_TRUTH)]
    low, high = _limits([vessel] + [layer for layer in (centerline, ground_truth) if layer is not None])
    with_truth = ground_truth is not None and len(ground_truth) > 0

    import matplotlib

    from matplotlib.colors import Normalize

    if with_truth:
        from matplotlib.colors import LinearSegmentedColormap

        cmap = LinearSegmentedColormap.from_list("angiohull_error", ERROR_COLOURS)
        vessel_error = nearest_distance_mm(drawn, ground_truth)
        truth_error = nearest_distance_mm(gt_drawn, vessel) if len(vessel) else np.full(len(gt_drawn), np.nan)
        finite = np.concatenate([vessel_error, truth_error])
        finite = finite[np.isfinite(finite)]
        # at least the paper's 3 mm voxel: two clouds sampled differently are a lattice step apart
        # where they agree, and that should not look like an error
        top = float(max(ERROR_SCALE_FLOOR_MM, np.percentile(finite, 95))) if finite.size else ERROR_SCALE_FLOOR_MM
        error_norm = Normalize(0.0, top)
    else:
        cmap = matplotlib.colormaps[_POINT_CMAP]
    line_colour = _CENTERLINE_ON_ERROR_COLOUR if with_truth else _CENTERLINE_COLOUR
    spacing = float(lattice_spacing_mm) if lattice_spacing_mm and len(drawn) == len(vessel) else _spacing_mm(drawn)
    gt_spacing = _spacing_mm(gt_drawn) if with_truth else 1.0

    # -- the layout, in inches from the top --------------------------------------------------------------
    n_views = len(views)
    view_rows = math.ceil(n_views / _VIEWS_PER_ROW)
    image_heights = []
    for row in range(view_rows):
        in_row = views[row * _VIEWS_PER_ROW:(row + 1) * _VIEWS_PER_ROW]
        aspect = max(mask.shape[0] for mask, _, _ in in_row) / max(mask.shape[1] for mask, _, _ in in_row)
        image_heights.append(min(max(_VIEW_PANEL_WIDTH_IN * aspect, 1.2), 3.6))
    row_heights = [h + _VIEW_DECORATION_IN for h in image_heights]
    legend_in = 0.35 if view_rows else 0.0
    plane_rows = 2 if ground_truth is not None else 1
    title_in = 0.35 + 0.22 * (1 + len(score_lines))
    heading_in = _ROW_HEADING_IN if plane_rows == 2 else 0.0
    planes_in = plane_rows * (_PLANE_ROW_IN + heading_in)
    height = title_in + planes_in + sum(row_heights) + legend_in + 0.15
    width = _FIGURE_WIDTH_IN
    fig = Figure(figsize=(width, height), dpi=dpi_value)
    FigureCanvasAgg(fig)
    size_px = max(32, int(round(_PLANE_AXES_IN * dpi_value)))

    def axes_at(left_in: float, top_in: float, w_in: float, h_in: float) -> Any:
        return fig.add_axes((left_in / width, 1.0 - (top_in + h_in) / height, w_in / width, h_in / height))

    rows_spec = [("reconstruction", drawn, centerline, spacing)]
    if ground_truth is not None:
        rows_spec.append(("ground truth", gt_drawn, None, gt_spacing))
    top_in = title_in
    for r, (row_name, cloud, line, cloud_spacing) in enumerate(rows_spec):
        if plane_rows == 2:
            what = ("coloured by the distance to the nearest ground-truth point" if r == 0 else
                    "coloured by the distance to the nearest reconstructed point (missed vessel is red)")
            fig.text(0.5, 1.0 - (top_in + 0.18) / height, f"{row_name}, {what}" if with_truth else row_name,
                     ha="center", va="center", fontsize=10)
            top_in += heading_in
        values = None
        if with_truth:
            values = vessel_error if r == 0 else truth_error
        for k, plane in enumerate(_PLANES):
            left = k * _PLANE_COLUMN_IN + _PLANE_LEFT_IN
            ax = axes_at(left, top_in + 0.4, _PLANE_AXES_IN, _PLANE_AXES_IN)
            if values is None:  # depth colouring: each panel its own depth axis
                norm = Normalize(low[plane[2]], high[plane[2]])
            else:
                norm = error_norm
            _draw_plane(ax, plane, cloud, values, line, low, high, cmap=cmap, norm=norm,
                        spacing_mm=cloud_spacing, size_px=size_px, centerline_colour=line_colour,
                        fill=1.0 if r == 0 else 1.6)  # surface points lie irregularly: larger squares
            if values is None or (k == len(_PLANES) - 1 and r == 0):
                # depth: a bar per panel; distance: one bar beside both rows (one scale)
                bar_top = top_in + 0.4 + 0.1 * _PLANE_AXES_IN
                bar_h = 0.8 * _PLANE_AXES_IN if values is None else _PLANE_ROW_IN + heading_in + 0.8 * _PLANE_AXES_IN
                cax = axes_at(left + _PLANE_AXES_IN + _COLOURBAR_GAP_IN, bar_top, _COLOURBAR_WIDTH_IN, bar_h)
                from matplotlib.cm import ScalarMappable

                bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=cax,
                                   extend="max" if values is not None else "neither")
                bar.set_label("distance to the other cloud (mm)" if values is not None
                              else f"depth: {_AXIS_LABELS[plane[2]]} (mm)", fontsize=7)
                bar.ax.tick_params(labelsize=6)
                bar.locator = MaxNLocator(5)
                bar.update_ticks()
            if k == 0 and len(cloud):
                colour_what = "depth" if values is None else ("distance to truth" if r == 0 else
                                                              "distance to reconstruction")
                label = (f"vessel points ({len(vessel):,}), colour: {colour_what}" if r == 0 else
                         f"ground-truth points ({len(ground_truth):,}), colour: {colour_what}")
                _colour_legend(ax, cmap, label, r == 0 and line is not None and len(line) > 0,
                               0 if line is None else len(line), line_colour)
        top_in += _PLANE_ROW_IN

    for row in range(view_rows):
        in_row = list(range(row * _VIEWS_PER_ROW, min(n_views, (row + 1) * _VIEWS_PER_ROW)))
        panel_w = width / _VIEWS_PER_ROW
        first_left = (width - len(in_row) * panel_w) / 2.0  # a short row is centred
        _view_row(fig, axes_at, [views[i] for i in in_row], [name_list[i] for i in in_row],
                  [None if score_list is None else score_list[i] for i in in_row], first_left + 0.05,
                  top_in + 0.3, len(in_row) * panel_w - 0.1, image_heights[row])
        top_in += row_heights[row]
    if view_rows:
        _view_legend(fig, top_in - 0.2, any(view[2] is not None for view in views))

    heading = title if title is not None else "angiohull reconstruction"
    counts = f"{len(vessel):,} vessel points"
    if len(drawn) < len(vessel):
        counts += f" ({len(drawn):,} drawn)"
    if centerline is not None:
        counts += f" · {len(centerline):,} centerline points"
    if ground_truth is not None:
        counts += f" · {len(ground_truth):,} ground-truth points"
    counts += f" · {n_views} view{'s' if n_views != 1 else ''}"
    fig.text(0.5, 1.0 - 0.12 / height, heading, ha="center", va="top", fontsize=12)
    fig.text(0.5, 1.0 - 0.4 / height, "\n".join([counts, *score_lines]), ha="center", va="top", fontsize=9,
             linespacing=1.4)

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    # zlib level 3 instead of 6: a third of the encoding time for a file about 10 % larger
    fig.savefig(out, format="png", dpi=dpi_value, facecolor="white", pil_kwargs={"compress_level": 3})
    return out  # (a Figure without pyplot is freed with its last reference: no clear() needed)


# --------------------------------------------------------------------------------------------------
# Quantitative coronary analysis
# --------------------------------------------------------------------------------------------------

#: At most this many diameter-profile panels (the longest branches); the title counts the rest.
QCA_MAX_PANELS = 24
_QCA_COLUMNS = 4
_QCA_MIN_LENGTH_MM = 10.0
_LESION_COLOUR = "#d55e00"  # Okabe–Ito vermillion
_PROFILE_COLOUR = "#0072b2"  # Okabe–Ito blue


def _dpi(dpi: Any) -> float:
    if isinstance(dpi, (bool, np.bool_)):
        raise AngiohullError(f"dpi must be a positive number, got {dpi!r}")
    return _v.positive_finite(dpi, "dpi")


def _branch_label(index: int, name: str) -> str:
    return f"branch {index} ({name})" if name else f"branch {index}"


def _lesion_label(lesion: Any) -> str:
    return (f"%DS {lesion.diameter_stenosis_pct:.0f} %, MLD {lesion.mld_mm:.2f} mm, "
            f"{lesion.length_mm:.1f} mm")


def _save(fig: Figure, path: str | os.PathLike[str], dpi: float) -> Path:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png", dpi=dpi, facecolor="white")
    return out


def _draw_profile(ax: Any, branch: Any) -> None:
    p = branch.profile
    arc, diameter, analysed = p.arc_mm, p.diameter_mm, p.analysed
    ax.plot(arc, diameter, color="0.75", linewidth=0.8, zorder=1)  # the whole profile, faint
    shown = np.where(analysed, diameter, np.nan)  # the analysed run, in colour
    ax.plot(arc, shown, color=_PROFILE_COLOUR, linewidth=1.1, label="diameter", zorder=3)
    if p.smoothed_diameter_mm is not None and np.isfinite(p.smoothed_diameter_mm).any():
        ax.plot(arc, p.smoothed_diameter_mm, color="0.05", linewidth=0.6, alpha=0.8,
                label="smoothed along the vessel (lesions are found on it)", zorder=4)
    if not analysed.all():
        ax.scatter(arc[~analysed], diameter[~analysed], s=6, color="0.6", linewidths=0, zorder=2,
                   label="not analysed (inside the parent, or a stub)")
    reference = np.where(analysed, p.reference_mm(), np.nan)
    ax.plot(arc, reference, color="0.15", linestyle="--", linewidth=1.0, label="reference", zorder=4)
    top = float(np.nanmax(np.concatenate([diameter, reference[np.isfinite(reference)]])))
    ax.set_ylim(0.0, 1.25 * top if top > 0 else 1.0)
    ax.set_xlim(float(arc[0]), float(arc[-1]))
    span = float(arc[-1] - arc[0])
    for k, lesion in enumerate(p.lesions):
        # the label under the lesion, kept clear of the panel's sides: "%DS 85 %, MLD 0.36 mm, 1.0 mm"
        # at 6 pt is about 1.4 in wide, 0.23 of a 3.05 in panel either side of its centre
        x_text = float(np.clip(0.5 * (lesion.start_mm + lesion.end_mm), arc[0] + 0.24 * span, arc[-1] - 0.24 * span))
        ax.axvspan(lesion.start_mm, lesion.end_mm, color=_LESION_COLOUR, alpha=0.18, linewidth=0, zorder=0)
        ax.plot([lesion.mld_arc_mm], [lesion.mld_mm], marker="v", markersize=5, color=_LESION_COLOUR, zorder=5)
        ax.annotate(_lesion_label(lesion), xy=(lesion.mld_arc_mm, lesion.mld_mm),
                    xytext=(x_text, (0.04 + 0.09 * (k % 3)) * ax.get_ylim()[1]),
                    ha="center", va="bottom", fontsize=6, color="0.1", zorder=6,
                    bbox=dict(boxstyle="round,pad=0.2", facecolor="white", edgecolor=_LESION_COLOUR, alpha=0.85,
                              linewidth=0.5))
    ax.set_title(_branch_label(branch.index, branch.name), fontsize=9)
    ax.set_xlabel("arc length (mm)", fontsize=8)
    ax.set_ylabel("diameter (mm)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, linewidth=0.3, alpha=0.5)


def qca_profiles_figure(result: Any, path: str | os.PathLike[str], *, title: str | None = None,
                        dpi: int = 110) -> Path:
    """Write the diameter profiles of a quantitative coronary analysis as a PNG; return its path.

    One panel per branch that has a reference diameter and is at least 10 mm long (at most
    :data:`QCA_MAX_PANELS`, the longest, in tree order; the title says how many are left out),
    four to a row: the diameter (mm) against arc length (mm), the points inside the parent's
    lumen (not analysed) in grey, the diameter smoothed along the vessel that lesions are found on
    as a thin dark line, the reference taper dashed, and each lesion's span shaded, its minimal
    lumen diameter marked and labelled with %DS, MLD and length.

    Parameters
    ----------
    result : angiohull.qca.QcaResult
    path : str or path-like
        Where to write the PNG (parent folders are created).
    title : str, optional
        First line of the figure title (default "quantitative coronary analysis: diameter profiles").
    dpi : int

    Raises
    ------
    AngiohullError (a ValueError)
        If ``result`` is not a QcaResult or ``dpi`` is not a positive number.
    """
    from .qca import QcaResult

    if not isinstance(result, QcaResult):
        raise AngiohullError(f"result must be an angiohull.qca.QcaResult, got {type(result).__name__}")
    dpi_value = _dpi(dpi)
    eligible = [b for b in result.branches if b.profile.reference is not None and b.length_mm >= _QCA_MIN_LENGTH_MM]
    without = len(result.branches) - len(eligible)
    shown = sorted(sorted(eligible, key=lambda b: -b.length_mm)[:QCA_MAX_PANELS], key=lambda b: b.index)
    capped = len(eligible) - len(shown)
    n = len(shown)
    cols = max(1, min(_QCA_COLUMNS, n))
    rows = max(1, math.ceil(n / cols))
    # Fixed margins in inches instead of a constrained layout, which doubles the drawing time of
    # a grid of many panels: every panel 3.05 x 2.1 in, 0.6 in beside it for the tick labels and
    # 0.85 in above and below for its title and x label.
    panel_w, panel_h, gap_w, gap_h, top_in, bottom_in, left_in = 3.05, 2.1, 0.6, 0.85, 0.85, 0.5, 0.6
    width = left_in + cols * panel_w + (cols - 1) * gap_w + 0.2
    height = top_in + rows * panel_h + (rows - 1) * gap_h + bottom_in
    fig = Figure(figsize=(width, height), dpi=dpi_value)
    fig.subplots_adjust(left=left_in / width, right=1.0 - 0.2 / width, bottom=bottom_in / height,
                        top=1.0 - top_in / height, wspace=gap_w / panel_w, hspace=gap_h / panel_h)
    FigureCanvasAgg(fig)
    try:
        axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
        for ax, branch in zip(axes, shown):
            _draw_profile(ax, branch)
        for ax in axes[n:]:
            ax.set_axis_off()
        if n == 0:
            axes[0].text(0.5, 0.5, "no branch has a reference diameter\n(all shorter than the reference fit needs)",
                         transform=axes[0].transAxes, ha="center", va="center", fontsize=10, color="0.25")
        else:
            handles, labels = axes[0].get_legend_handles_labels()
            for ax in axes[1:n]:  # the "not analysed" entry may first appear in a later panel
                for h, lab in zip(*ax.get_legend_handles_labels()):
                    if lab not in labels:
                        handles.append(h)
                        labels.append(lab)
            if any(b.profile.lesions for b in shown):
                handles.append(Patch(facecolor=_LESION_COLOUR, alpha=0.18, label="lesion"))
                labels.append("lesion")
            axes[0].legend(handles, labels, loc="best", fontsize=6, framealpha=0.85, handlelength=1.5,
                           borderpad=0.3, labelspacing=0.25)
        n_lesions = len(result.lesions)
        heading = title if title is not None else "quantitative coronary analysis: diameter profiles"
        counts = (f"{len(result.branches)} branch{'es' if len(result.branches) != 1 else ''}, "
                  f"{n_lesions} lesion{'s' if n_lesions != 1 else ''}; {n} shown")
        left_out = []
        if capped:
            left_out.append(f"{capped} more left out (the {QCA_MAX_PANELS} longest shown)")
        if without:
            left_out.append(f"{without} without a reference diameter or shorter than {_QCA_MIN_LENGTH_MM:g} mm "
                            f"not shown")
        if left_out:
            counts += " · " + " · ".join(left_out)
        fig.suptitle(f"{heading}\n{counts}", fontsize=11)
        return _save(fig, path, dpi_value)
    finally:
        fig.clear()


def _format_mm(value: float) -> str:
    return f"{value:.1f}"


def qca_view_map_figure(view_map: Any, path: str | os.PathLike[str], title: str | None = None, *,
                        dpi: int = 110) -> Path:
    """Write a segment's view map (:class:`angiohull.qca.ViewMap`) as a PNG; return its path.

    The map of ``foreshortening x (1 - overlap)`` over the primary angle (x axis, RAO negative,
    LAO positive) and the secondary angle (y axis, CAU negative, CRA positive), with contour lines
    of the foreshortening at 0.7, 0.8 and 0.9 (those the map reaches), the views where part of the
    segment is overlapped hatched, and the best view marked with a star and its name.

    Parameters
    ----------
    view_map : angiohull.qca.ViewMap
    path : str or path-like
    title : str, optional
        Default: the branch and the arc-length range.
    dpi : int

    Raises
    ------
    AngiohullError (a ValueError)
        If ``view_map`` is not a ViewMap or ``dpi`` is not a positive number.
    """
    from .qca import ViewMap

    if not isinstance(view_map, ViewMap):
        raise AngiohullError(f"view_map must be an angiohull.qca.ViewMap, got {type(view_map).__name__}")
    dpi_value = _dpi(dpi)
    primary = np.asarray(view_map.primary_deg, dtype=np.float64)
    secondary = np.asarray(view_map.secondary_deg, dtype=np.float64)
    fs = np.asarray(view_map.foreshortening, dtype=np.float64)
    overlap = np.asarray(view_map.overlap, dtype=np.float64)
    score = fs * (1.0 - overlap)
    width = float(np.ptp(primary)) if primary.size > 1 else 1.0
    height = float(np.ptp(secondary)) if secondary.size > 1 else 1.0
    # the map drawn at equal degrees per inch on both axes, plus room for the colour bar, labels and title
    axes_width = 6.4 if width >= height else float(np.clip(5.0 * width / max(height, 1e-9), 2.5, 6.4))
    axes_height = float(np.clip(axes_width * height / max(width, 1e-9), 1.5, 5.5))
    fig = Figure(figsize=(axes_width + 2.1, axes_height + 1.7), dpi=dpi_value, layout="constrained")
    FigureCanvasAgg(fig)
    try:
        ax = fig.subplots()
        mesh = ax.pcolormesh(primary, secondary, score, shading="nearest", cmap=_POINT_CMAP, vmin=0.0, vmax=1.0)
        cbar = fig.colorbar(mesh, ax=ax, shrink=0.9, pad=0.02)
        cbar.set_label("foreshortening × (1 − overlap)", fontsize=8)
        cbar.ax.tick_params(labelsize=7)
        handles = []
        grid = primary.size > 1 and secondary.size > 1
        if grid:
            low, high = float(np.nanmin(fs)), float(np.nanmax(fs))
            levels = [level for level in (0.7, 0.8, 0.9) if low < level < high]
            if levels:
                stroke = [patheffects.withStroke(linewidth=2.0, foreground="0.15")]
                lines = ax.contour(primary, secondary, fs, levels=levels, colors="white", linewidths=0.9)
                lines.set(path_effects=stroke)
                ax.clabel(lines, fmt="%.1f", fontsize=7)
                handles.append(Line2D([], [], color="white", linewidth=0.9, path_effects=stroke,
                                      label="foreshortening " + ", ".join(f"{level:.1f}" for level in levels)))
            covered = overlap > 0
            if covered.any():
                if covered.all():
                    ax.add_patch(Rectangle((0, 0), 1, 1, transform=ax.transAxes, facecolor="none",
                                           edgecolor="0.1", hatch="//", linewidth=0.0))
                else:
                    ax.contourf(primary, secondary, covered.astype(float), levels=[0.5, 1.5], colors="none",
                                hatches=["//"])
                    ax.contour(primary, secondary, covered.astype(float), levels=[0.5], colors="0.1", linewidths=0.7)
                handles.append(Patch(facecolor="none", edgecolor="0.1", hatch="//", label="part overlapped"))
        ax.plot([view_map.best_primary_deg], [view_map.best_secondary_deg], marker="*", markersize=15,
                color="white", markeredgecolor="black", linestyle="none", zorder=5)
        # the label towards the middle of the map, so that it stays inside the axes
        right = view_map.best_primary_deg > 0.5 * (primary[0] + primary[-1])
        upper = view_map.best_secondary_deg > 0.5 * (secondary[0] + secondary[-1])
        ax.annotate(view_map.best_name, xy=(view_map.best_primary_deg, view_map.best_secondary_deg),
                    xytext=(-9 if right else 9, -9 if upper else 9), textcoords="offset points",
                    ha="right" if right else "left", va="top" if upper else "bottom", annotation_clip=False,
                    fontsize=8, fontweight="bold", zorder=6,
                    bbox=dict(boxstyle="round,pad=0.25", facecolor="white", edgecolor="0.3", alpha=0.85))
        handles.append(Line2D([], [], marker="*", markersize=10, color="white", markeredgecolor="black",
                              linestyle="none", label=f"best: {view_map.best_name}"))
        ax.legend(handles=handles, loc="lower left", fontsize=7, framealpha=0.85)
        ax.set_xlabel("RAO ← primary angle (deg) → LAO", fontsize=8)
        ax.set_ylabel("CAU ← secondary angle (deg) → CRA", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_aspect("equal", adjustable="box")
        heading = title if title is not None else (
            f"view map: branch {view_map.branch}, arc {_format_mm(view_map.start_mm)}-{_format_mm(view_map.end_mm)} mm")
        fs_best, ov_best = view_map.best_foreshortening, view_map.best_overlap
        ax.set_title(f"{heading}\nbest view {view_map.best_name}: foreshortening {fs_best:.2f}, overlap "
                     f"{100.0 * ov_best:.0f} %", fontsize=9)
        return _save(fig, path, dpi_value)
    finally:
        fig.clear()
