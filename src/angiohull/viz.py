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
from matplotlib.patches import Patch, Rectangle

from . import _validation as _v
from .errors import AngiohullError

__all__ = ["OVERLAY_COLOURS", "overlay_rgb", "reconstruction_figure", "qca_profiles_figure", "qca_view_map_figure"]

#: RGB colour (uint8) of each overlay class.
OVERLAY_COLOURS: dict[str, tuple[int, int, int]] = {
    "background": (0, 0, 0),
    "both": (235, 235, 235),  # in the mask and in the re-projection: agreement
    "missed": (213, 94, 0),  # mask only: vessel the reconstruction does not cover
    "spurious": (86, 180, 233),  # re-projection only: reconstruction outside the vessel
}

_OVERLAY_LABELS = {"both": "both", "missed": "mask only (missed)", "spurious": "reprojection only (spurious)"}

#: Above this many vessel points the projections draw an evenly strided subset (drawing cost).
_MAX_DRAWN_POINTS = 200_000
_CENTERLINE_COLOUR = "#d62728"
_POINT_CMAP = "viridis"
_VIEWS_PER_ROW = 4
_FIGURE_WIDTH_IN = 13.0
_VIEW_PANEL_WIDTH_IN = 3.15  # width of one of four view panels in a row, in inches
_VIEW_DECORATION_IN = 0.95  # title above and three-line colour legend below a view panel

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


def _draw_plane(fig: Any, ax: Any, plane: tuple, vessel: np.ndarray, centerline: np.ndarray | None,
                low: np.ndarray, high: np.ndarray, with_legend: bool) -> None:
    h, v, d, panel_title, nearer_is_larger = plane
    handles = []
    if len(vessel):
        # Far points first, so that the points nearer to the viewer are drawn on top.
        order = np.argsort(vessel[:, d], kind="stable")
        if not nearer_is_larger:
            order = order[::-1]
        pts = vessel[order]
        sc = ax.scatter(pts[:, h], pts[:, v], s=_marker_size(len(vessel)), c=pts[:, d], cmap=_POINT_CMAP,
                        vmin=low[d], vmax=high[d], linewidths=0, label="vessel", zorder=2)
        handles.append(sc)
        cbar = fig.colorbar(sc, ax=ax, shrink=0.8, aspect=30, pad=0.02)
        cbar.set_label(f"depth: {_AXIS_LABELS[d]} (mm)", fontsize=7)
        cbar.ax.tick_params(labelsize=6)
    else:
        ax.text(0.5, 0.5, "empty reconstruction\n(0 vessel points)", transform=ax.transAxes, ha="center",
                va="center", fontsize=10, color="0.25", zorder=4,
                bbox=dict(boxstyle="round,pad=0.4", facecolor="white", edgecolor="0.6", alpha=0.9))
    if centerline is not None and len(centerline):
        handles.append(ax.scatter(centerline[:, h], centerline[:, v], s=max(_marker_size(len(centerline)), 2.0),
                                  c=_CENTERLINE_COLOUR, linewidths=0, label="centerline", zorder=3))
    ax.set_xlim(low[h], high[h])
    if v == 1:  # axial: anterior at the top, as seen from the feet
        ax.set_ylim(high[v], low[v])
    else:
        ax.set_ylim(low[v], high[v])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(_HORIZONTAL_LABELS[h], fontsize=8)
    ax.set_ylabel(_VERTICAL_LABELS[v], fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title(panel_title, fontsize=9)
    ax.grid(True, linewidth=0.3, alpha=0.5)
    if with_legend and len(handles) > 1:
        legend = ax.legend(handles=handles, loc="upper right", fontsize=6, framealpha=0.8,
                           handletextpad=0.3, borderpad=0.3)
        legend_handles = getattr(legend, "legend_handles", None)
        if legend_handles is None:  # Matplotlib < 3.7
            legend_handles = legend.legendHandles
        for handle in legend_handles:
            handle.set_sizes([16.0])


def _draw_view(ax: Any, mask: np.ndarray, reprojection: np.ndarray, name: str, score: float | None) -> None:
    ax.imshow(overlay_rgb(mask, reprojection), interpolation="nearest")
    ax.set_axis_off()
    label = name
    if score is not None:
        label += f" — Dice {score:.1f}%" if math.isfinite(score) else " — Dice n/a"
    ax.set_title(label, fontsize=9)
    counts = {
        "both": int(np.count_nonzero(mask & reprojection)),
        "missed": int(np.count_nonzero(mask & ~reprojection)),
        "spurious": int(np.count_nonzero(~mask & reprojection)),
    }
    handles = [
        Patch(facecolor=np.asarray(OVERLAY_COLOURS[key]) / 255.0, edgecolor="0.4", linewidth=0.5,
              label=f"{_OVERLAY_LABELS[key]}: {counts[key]}")
        for key in ("both", "missed", "spurious")
    ]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=1, fontsize=6,
              frameon=False, handlelength=1.0, handleheight=0.8, handletextpad=0.4, borderaxespad=0.2,
              labelspacing=0.2, title_fontsize=6)


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
    dpi: int = 110,
) -> Path:
    """Write a PNG summarising a reconstruction and return its path.

    Layout: the top row shows the vessel point cloud projected orthographically on the three
    anatomical planes (LPS millimetres): frontal (x vs z, seen from anterior, so the patient's
    left is on the viewer's right), lateral (y vs z, seen from the patient's left) and axial (x vs
    y, seen from the feet, anterior up). Points are coloured by their coordinate along the dropped
    (depth) axis and drawn far-to-near; centerline points are drawn on top in red. With a ground
    truth, a second row shows the ground truth in the same three planes, on the same axes. The rows below hold one panel per view (up to four
    per row) with :func:`overlay_rgb` of the view's mask and the reconstruction's re-projection,
    titled with the view name and, when given, its score.

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
        a mask and its re-projection differ in shape, or ``dpi`` is not a positive number.
    """
    vessel = _points(vessel_points_mm, "vessel_points_mm")
    centerline = None if centerline_points_mm is None else _points(centerline_points_mm, "centerline_points_mm")
    ground_truth = None if ground_truth_mm is None else _points(ground_truth_mm, "ground_truth_mm")

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
    if len(set(lengths.values())) > 1:
        detail = ", ".join(f"{key}: {value}" for key, value in lengths.items())
        raise AngiohullError(f"need one entry per view in each per-view sequence, got {detail}")
    views = []
    for i, (mask, reproj) in enumerate(zip(mask_list, reproj_list)):
        mask_b = _image(mask, f"masks[{i}]")
        reproj_b = _image(reproj, f"reprojections[{i}]")
        if mask_b.shape != reproj_b.shape:
            raise AngiohullError(
                f"view {i} ({name_list[i]!r}): mask shape {mask_b.shape} differs from reprojection shape {reproj_b.shape}"
            )
        views.append((mask_b, reproj_b))
    if isinstance(dpi, (bool, np.bool_)):
        raise AngiohullError(f"dpi must be a positive number, got {dpi!r}")
    try:
        dpi_value = float(dpi)
    except (TypeError, ValueError):
        raise AngiohullError(f"dpi must be a positive number, got {dpi!r}") from None
    if not math.isfinite(dpi_value) or dpi_value <= 0:
        raise AngiohullError(f"dpi must be a positive number, got {dpi!r}")

    # Drawing a million markers is slow and indistinguishable from a strided subset.
    drawn = vessel
    if len(vessel) > _MAX_DRAWN_POINTS:
        drawn = vessel[np.linspace(0, len(vessel) - 1, _MAX_DRAWN_POINTS).astype(np.int64)]
    low, high = _limits([vessel] + [layer for layer in (centerline, ground_truth) if layer is not None])

    n_views = len(views)
    view_rows = math.ceil(n_views / _VIEWS_PER_ROW)
    # Each view row is as tall as its tallest image at the panel width (capped), plus room for the
    # title above and the colour legend below: constrained layout cannot shrink a fixed-aspect
    # image to make room for decorations on its own.
    row_heights = []
    for row in range(view_rows):
        in_row = views[row * _VIEWS_PER_ROW:(row + 1) * _VIEWS_PER_ROW]
        aspect = max(mask.shape[0] / mask.shape[1] for mask, _ in in_row)
        row_heights.append(min(max(_VIEW_PANEL_WIDTH_IN * aspect, 1.2), 3.6) + _VIEW_DECORATION_IN)
    top_height = 4.2 if ground_truth is None else 8.0
    fig = Figure(figsize=(_FIGURE_WIDTH_IN, top_height + sum(row_heights) + 0.6), dpi=dpi_value,
                 layout="constrained")
    FigureCanvasAgg(fig)
    try:
        # Sub-figures keep the constrained layouts of the rows independent: a single grid whose
        # columns the top panels and the view panels split differently collapses.
        if view_rows:
            top, bottom = fig.subfigures(2, 1, height_ratios=[top_height, sum(row_heights)])
        else:
            top, bottom = fig, None
        if ground_truth is None:
            plane_axes = top.subplots(1, len(_PLANES))
            for k, (ax, plane) in enumerate(zip(plane_axes, _PLANES)):
                _draw_plane(top, ax, plane, drawn, centerline, low, high, with_legend=(k == 0))
        else:
            # The ground truth beside the reconstruction: one row each, same planes, same axes.
            rec_fig, gt_fig = top.subfigures(2, 1)
            rec_fig.suptitle("reconstruction", fontsize=10)
            gt_fig.suptitle("ground truth", fontsize=10)
            gt_drawn = ground_truth
            if len(ground_truth) > _MAX_DRAWN_POINTS:
                gt_drawn = ground_truth[np.linspace(0, len(ground_truth) - 1, _MAX_DRAWN_POINTS).astype(np.int64)]
            for sub, cloud, line in ((rec_fig, drawn, centerline), (gt_fig, gt_drawn, None)):
                axes = sub.subplots(1, len(_PLANES))
                for k, (ax, plane) in enumerate(zip(axes, _PLANES)):
                    _draw_plane(sub, ax, plane, cloud, line, low, high, with_legend=(k == 0))

        row_figs = [] if bottom is None else list(np.atleast_1d(bottom.subfigures(view_rows, 1, height_ratios=row_heights)))
        for row, row_fig in enumerate(row_figs):
            in_row = list(range(row * _VIEWS_PER_ROW, min(n_views, (row + 1) * _VIEWS_PER_ROW)))
            if len(in_row) < _VIEWS_PER_ROW:  # centre a short row between two blank margins
                pad = (_VIEWS_PER_ROW - len(in_row)) / 2.0
                row_fig = row_fig.subfigures(1, 3, width_ratios=[pad, len(in_row), pad])[1]
            view_axes = np.atleast_1d(row_fig.subplots(1, len(in_row)))
            for ax, i in zip(view_axes, in_row):
                score = None if score_list is None else score_list[i]
                _draw_view(ax, views[i][0], views[i][1], name_list[i], score)

        heading = title if title is not None else "angiohull reconstruction"
        counts = f"{len(vessel):,} vessel points"
        if len(drawn) < len(vessel):
            counts += f" ({len(drawn):,} drawn)"
        if centerline is not None:
            counts += f" · {len(centerline):,} centerline points"
        if ground_truth is not None:
            counts += f" · {len(ground_truth):,} ground-truth points"
        counts += f" · {n_views} view{'s' if n_views != 1 else ''}"
        fig.suptitle(f"{heading}\n{counts}", fontsize=12)

        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, format="png", dpi=dpi_value, facecolor="white")
    finally:
        fig.clear()
    return out


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
    if not analysed.all():
        ax.scatter(arc[~analysed], diameter[~analysed], s=6, color="0.6", linewidths=0, zorder=2,
                   label="not analysed (inside the parent)")
    reference = np.where(analysed, p.reference_mm(), np.nan)
    ax.plot(arc, reference, color="0.15", linestyle="--", linewidth=1.0, label="reference", zorder=4)
    top = float(np.nanmax(np.concatenate([diameter, reference[np.isfinite(reference)]])))
    ax.set_ylim(0.0, 1.25 * top if top > 0 else 1.0)
    ax.set_xlim(float(arc[0]), float(arc[-1]))
    span = float(arc[-1] - arc[0])
    for k, lesion in enumerate(p.lesions):
        # the label under the lesion, kept clear of the panel's sides
        x_text = float(np.clip(0.5 * (lesion.start_mm + lesion.end_mm), arc[0] + 0.17 * span, arc[-1] - 0.17 * span))
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
    lumen (not analysed) in grey, the reference taper dashed, and each lesion's span shaded, its
    minimal lumen diameter marked and labelled with %DS, MLD and length.

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
