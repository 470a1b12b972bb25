"""PNG figures of the report, in the spirit of the paper's Figures 2-6.

Drawn on Matplotlib's Agg canvas without ``pyplot`` (as :mod:`angiohull.viz`): each figure is a
:class:`~matplotlib.figure.Figure` bound to its own :class:`FigureCanvasAgg`, so it is safe in
headless processes and test suites and never touches global state.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .stats import Summary

__all__ = ["METRIC_LABELS", "group_figure", "curve_figure"]

METRIC_LABELS = {
    "dice3d": "Dice3D (%)",
    "iou3d": "IoU3D (%)",
    "chamfer_mm": "Chamfer distance (mm)",
    "dice2d_paper": "Dice2D, paper protocol (%)",
    "dice2d": "Dice2D, plain (%)",
    "time_s": "reconstruction time (s)",
    "centerline_mean_mm": "centerline distance, mean (mm)",
    "centerline_p95_mm": "centerline distance, 95th percentile (mm)",
    "ot1mm": "Ot(1 mm), share of the true centerline",
    "cldice": "clDice",
    "radius_mae_mm": "radius error, mean absolute (mm)",
    "radius_bias_mm": "radius error, bias (mm)",
    "branch_recall": "branch recall",
    "branch_precision": "branch precision",
    "bifurcation_error_mm": "bifurcation position error (mm)",
}

_MEAN_COLOUR = "#0072B2"  # Okabe-Ito blue
_BAND_COLOUR = "#56B4E9"  # sky blue
_PAPER_COLOUR = "#D55E00"  # vermillion
_POINT_COLOUR = "#999999"
_DPI = 90


def _wrapped(title: str, width_in: float, fontsize: float = 11.0) -> str:
    """The title broken into lines that fit the figure's width (about 0.55 em per character), never cut."""
    import textwrap

    per_line = max(30, int(width_in * 72.0 / (0.55 * fontsize)))
    return "\n".join(textwrap.wrap(title, per_line, break_long_words=False, break_on_hyphens=False)) or title


def _grid(count: int) -> tuple[int, int]:
    cols = min(3, count)
    return (count + cols - 1) // cols, cols


def _save(figure: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(figure)
    figure.savefig(path, dpi=_DPI)
    return path


def group_figure(path: str | Path, title: str, groups: Sequence[str], values: dict[str, Sequence[Sequence[float]]],
                 summaries: dict[str, Sequence[Summary]], paper: Optional[dict[str, float]] = None) -> Path:
    """Box plots per group (one panel per metric) with the mean ± standard deviation and the paper's mean.

    ``values[metric][g]`` are the finite values of group ``g``; ``summaries[metric][g]`` their summary.
    """
    metrics = list(values)
    rows, cols = _grid(len(metrics))
    figure = Figure(figsize=(4.2 * cols, 3.4 * rows), layout="constrained")
    positions = np.arange(1, len(groups) + 1)
    for index, metric in enumerate(metrics):
        ax = figure.add_subplot(rows, cols, index + 1)
        data = [np.asarray(v, dtype=float) if len(v) else np.array([np.nan]) for v in values[metric]]
        ax.boxplot(data, positions=positions, widths=0.5, showfliers=True,
                   flierprops={"markersize": 2, "markeredgecolor": _POINT_COLOUR},
                   medianprops={"color": "black"})
        means = np.array([s.mean for s in summaries[metric]])
        stds = np.array([s.std for s in summaries[metric]])
        ax.errorbar(positions + 0.33, means, yerr=stds, fmt="o", color=_MEAN_COLOUR, capsize=3, markersize=4,
                    label="mean ± std")
        if paper and metric in paper:
            ax.axhline(paper[metric], color=_PAPER_COLOUR, linestyle="--", linewidth=1, label="paper (all trees)")
        ax.set_xticks(positions, list(groups))
        ax.set_ylabel(METRIC_LABELS.get(metric, metric))
        ax.grid(axis="y", alpha=0.3)
        if index == 0:
            ax.legend(fontsize=7, loc="best")
    figure.suptitle(_wrapped(title, figure.get_figwidth()), fontsize=11)
    return _save(figure, Path(path))


def curve_figure(path: str | Path, title: str, xlabel: str, x: Sequence[float], y: dict[str, Sequence[float]],
                 centres: Sequence[float], summaries: dict[str, Sequence[Summary]], *,
                 scatter_xy: Optional[tuple[Sequence[float], Sequence[float], Sequence[float], str]] = None,
                 log_y: Sequence[str] = ()) -> Path:
    """Metrics against a parameter: every case (grey), the mean per value or bin, and a ± std band.

    ``scatter_xy``: an extra panel ``(a, b, colour values, label)``, e.g. the translation vectors
    coloured by Dice3D.
    """
    metrics = list(y)
    panels = len(metrics) + (scatter_xy is not None)
    rows, cols = _grid(panels)
    figure = Figure(figsize=(4.2 * cols, 3.3 * rows), layout="constrained")
    xs = np.asarray(x, dtype=float)
    c = np.asarray(centres, dtype=float)
    for index, metric in enumerate(metrics):
        ax = figure.add_subplot(rows, cols, index + 1)
        ax.scatter(xs, np.asarray(y[metric], dtype=float), s=4, color=_POINT_COLOUR, alpha=0.35, linewidths=0,
                   label="cases")
        mean = np.array([s.mean for s in summaries[metric]])
        std = np.array([s.std for s in summaries[metric]])
        ok = np.isfinite(mean)
        band = ok & np.isfinite(std)
        ax.fill_between(c[band], (mean - std)[band], (mean + std)[band], color=_BAND_COLOUR, alpha=0.35,
                        linewidth=0, label="± std")
        ax.plot(c[ok], mean[ok], "-o", color=_MEAN_COLOUR, markersize=3, linewidth=1.5, label="mean")
        if metric in log_y:
            ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(METRIC_LABELS.get(metric, metric))
        ax.grid(alpha=0.3)
        if index == 0:
            ax.legend(fontsize=7, loc="best")
    if scatter_xy is not None:
        a, b, colour, label = scatter_xy
        ax = figure.add_subplot(rows, cols, panels)
        points = ax.scatter(np.asarray(a, float), np.asarray(b, float), c=np.asarray(colour, float), s=14,
                            cmap="viridis")
        figure.colorbar(points, ax=ax, label=label)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("tx (px)")
        ax.set_ylabel("ty (px)")
        ax.grid(alpha=0.3)
    figure.suptitle(_wrapped(title, figure.get_figwidth()), fontsize=11)
    return _save(figure, Path(path))
