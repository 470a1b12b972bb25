"""The Markdown report of one or more runs: tables beside the paper's numbers, t-tests, figures.

Everything is recomputed from the runs' rows (``rows.csv``, read with :func:`~.runner.load_run`);
the only numbers that are not are the paper's, from :data:`~.paper.PAPER_RESULTS`. The same
numbers go to ``report.json`` (machine-readable) and ``report.md``; figures go to ``figures/``.

Layouts, chosen from the design:

* ``trees`` without a sweep (``general``, ``general_clinical``): one row per tortuosity level and
  one for all trees; the paper's Table 1 or 2 beside the mean of all trees; Student's and Welch's
  t-tests between the levels on the configured metric (Table 3); box plots per level.
* ``trees`` with a sweep, ``n_views`` and ``angles``: the metrics against the swept value, the
  number of views or the smallest singular value of the angle matrix, per value (at most 20 distinct
  values) or in equal-width bins; mean ± standard deviation bands; Spearman's correlation.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from .. import __version__
from ..errors import AngiohullError
from .config import TREE_METRICS, NViewsDesign, TreesDesign
from .figures import METRIC_LABELS, curve_figure, group_figure
from .paper import PAPER_CITATION, PAPER_RESULTS
from .runner import CONFIG_FILE, RunData, load_run
from .stats import Summary, bin_edges, spearman, summarise, ttest

__all__ = ["find_runs", "analyse_run", "build_report", "render_markdown"]

_MAX_DISCRETE = 20
_X_LABELS = {"shift_px": "shift |t| of view 0 (px)", "factor": "scale factor of view 0", "angle_deg": "rotation (deg)",
             "p": "probability p", "count": "count", "n_views": "number of views N",
             "sigma_min": "smallest singular value of the angle matrix"}


def find_runs(paths: Sequence[str | Path]) -> list[Path]:
    """Run directories among ``paths``: each one itself, or the run directories directly inside it."""
    found: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise AngiohullError(f"{path}: not found; expected a run directory (with {CONFIG_FILE}) or a folder of "
                                 f"run directories")
        if (path / CONFIG_FILE).is_file():
            found.append(path)
            continue
        children = sorted(p for p in path.iterdir() if (p / CONFIG_FILE).is_file()) if path.is_dir() else []
        if not children:
            raise AngiohullError(f"{path}: neither a run directory (with {CONFIG_FILE}) nor a folder of run directories")
        found.extend(children)
    return found


def _column(rows: Sequence[dict[str, Any]], name: str) -> np.ndarray:
    return np.array([float(r[name]) for r in rows], dtype=np.float64)


def _x_column(data: RunData) -> Optional[str]:
    design = data.config.design
    if isinstance(design, TreesDesign):
        if design.sweep is None:
            return None
        return {"translate": "shift_px", "scale": "factor", "rotate": "angle_deg", "fp": "p", "fn": "p"}.get(
            design.sweep.corruption, "count")
    return "n_views" if isinstance(design, NViewsDesign) else "sigma_min"


def _groups_by_x(rows: Sequence[dict[str, Any]], column: str, bins: int) -> tuple[list[dict[str, Any]], Optional[list[float]]]:
    x = _column(rows, column)
    distinct = sorted(set(x[np.isfinite(x)].tolist()))
    if len(distinct) <= _MAX_DISCRETE:
        return [{"label": f"{v:g}", "x": v, "index": np.flatnonzero(x == v)} for v in distinct], None
    edges = bin_edges(x, bins)
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    groups = []
    for b in range(bins):
        index = np.flatnonzero(which == b)
        closing = "]" if b == bins - 1 else ")"
        groups.append({"label": f"[{edges[b]:.3g}, {edges[b + 1]:.3g}{closing}", "x": float(0.5 * (edges[b] + edges[b + 1])),
                       "index": index})
    return groups, [float(e) for e in edges]


def analyse_run(data: RunData) -> dict[str, Any]:
    """Every number of a run's part of the report (JSON-able)."""
    config = data.config
    rows = data.rows
    metrics = list(config.metrics)
    record = data.record
    invocations = record.get("invocations", [])
    statuses: dict[str, int] = {}
    for row in rows:
        statuses[row["status"]] = statuses.get(row["status"], 0) + 1
    out: dict[str, Any] = {
        "name": config.name, "mode": config.mode, "description": config.description, "paper_ref": config.paper,
        "design": config.design.type, "engine": config.reconstruction.engine,
        "resolution": config.reconstruction.resolution, "threshold_px": config.reconstruction.threshold_px,
        "preset": config.reconstruction.preset, "method": config.reconstruction.method,
        "calibrate": config.reconstruction.calibrate,
        "calibrate_scale": config.reconstruction.calibrate_scale,
        "min_views": config.reconstruction.min_views,
        "rasteriser": config.generator.rasteriser, "cases_total": data.total, "cases_done": len(rows),
        "status_counts": statuses, "metrics": metrics,
        "wall_s": float(sum(i.get("wall_s", 0.0) for i in invocations)),
        "executors": sorted({i.get("executor", "") for i in invocations if i.get("cases_run")}),
        "angiohull_version": record.get("angiohull_version"),
        "reasons": sorted({r["reason"] for r in rows if r["status"] != "ok" and r["reason"]})[:5],
        "timing": {"case_s": summarise(_column(rows, "case_s")).to_dict() if rows else None,
                   "time_s": summarise(_column(rows, "time_s")).to_dict() if rows and "time_s" in metrics else None},
    }
    values = {m: _column(rows, m) for m in metrics}
    column = _x_column(data)
    if column is None:
        levels = list(config.design.tortuosity)
        labels = np.array([r["tortuosity"] for r in rows])
        groups = [{"label": level, "index": np.flatnonzero(labels == level)} for level in levels]
        if len(levels) > 1:
            groups.append({"label": "all", "index": np.arange(len(rows))})
        out["layout"] = "groups"
        out["x"] = None
    else:
        groups, edges = _groups_by_x(rows, column, config.report.bins)
        out["layout"] = "curve"
        out["x"] = {"column": column, "label": _X_LABELS.get(column, column), "edges": edges,
                    "values": _column(rows, column).tolist()}
        out["correlation"] = {m: dict(zip(("rho", "p", "n"), spearman(_column(rows, column), values[m])))
                              for m in metrics}
    out["groups"] = [{"label": g["label"], "x": g.get("x"), "n_cases": int(len(g["index"])),
                      "summaries": {m: summarise(values[m][g["index"]]).to_dict() for m in metrics}}
                     for g in groups]
    if config.report.ttest is not None:
        metric = config.report.ttest
        levels = list(config.design.tortuosity)
        labels = np.array([r["tortuosity"] for r in rows])
        pairs = [(a, b) for i, a in enumerate(levels) for b in levels[i + 1:]]
        out["ttests"] = {"metric": metric, "tests": [
            ttest(a, values[metric][labels == a], b, values[metric][labels == b]).to_dict() for a, b in pairs]}
    if config.report.paper is not None:
        paper = PAPER_RESULTS[config.report.paper]
        overall = {m: summarise(values[m]) for m in metrics}
        comparison = []
        for metric in ("dice3d", "iou3d", "chamfer_mm", "dice2d_paper"):
            if metric not in metrics:
                continue
            ours: Summary = overall[metric]
            comparison.append({"metric": metric, "paper": paper[metric], "mean": ours.mean, "std": ours.std,
                               "ci_low": ours.ci_low, "ci_high": ours.ci_high, "difference": ours.mean - paper[metric],
                               "paper_in_ci": bool(ours.ci_low <= paper[metric] <= ours.ci_high)})
        out["paper"] = {"table": config.report.paper, "source": paper["source"], "rows": comparison}
    if isinstance(config.design, TreesDesign) and config.design.sweep is not None and config.design.sweep.corruption == "translate":
        out["translation_vectors"] = {"tx_px": _column(rows, "tx_px").tolist(), "ty_px": _column(rows, "ty_px").tolist()}
    out["_values"] = {m: values[m].tolist() for m in metrics}
    out["_group_index"] = [g["index"].tolist() for g in groups]
    return out


# -- formatting ---------------------------------------------------------------------------------------
def _fmt(metric: str, value: Optional[float]) -> str:
    if value is None or not math.isfinite(value):
        return "n/a"
    if metric in ("chamfer_mm", "time_s", "case_s"):
        return f"{value:.4f}"
    if metric in TREE_METRICS:  # millimetres and shares in [0, 1]
        return f"{value:.3f}"
    return f"{value:.2f}"


def _fmt_p(p: Optional[float]) -> str:
    if p is None or not math.isfinite(p):
        return "n/a"
    return f"{p:.3g}" if p >= 1e-3 else f"{p:.2e}"


def _cell(metric: str, s: dict[str, Any]) -> str:
    if s["n"] == 0:
        return "n/a"
    text = f"{_fmt(metric, s['mean'])} ± {_fmt(metric, s['std'])}"
    if math.isfinite(s["ci_low"]):
        text += f" ({_fmt(metric, s['ci_low'])}–{_fmt(metric, s['ci_high'])})"
    return text


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60} min {seconds % 60:02d} s" if seconds >= 60 else f"{seconds} s"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def render_markdown(analyses: Sequence[dict[str, Any]], figures: dict[str, str]) -> str:
    """The report's Markdown text (figures given as paths relative to the report)."""
    lines = [
        "# angiohull experiments report", "",
        f"Generated by angiohull {__version__} from {len(analyses)} run(s). Every number is computed from the "
        f"runs' rows (`rows.csv`); the paper's values ({PAPER_CITATION}) are the only transcribed numbers. Cells: "
        f"mean ± sample standard deviation (95 % confidence interval of the mean, Student's t). Percentages for "
        f"Dice and IoU, millimetres for the Chamfer distance, seconds for times. Undefined values (the Chamfer "
        f"distance of an empty reconstruction, failed cases) are left out; `n` counts the values used.", "",
        "## Runs", "",
    ]
    run_rows = []
    for a in analyses:
        counts = ", ".join(f"{n} {s}" for s, n in sorted(a["status_counts"].items()))
        timing = a["timing"]["time_s"]
        run_rows.append([a["name"], a["mode"], f"{a['cases_done']}/{a['cases_total']}", counts or "-",
                         f"{a['engine']}, K={a['resolution'] or 'preset default'}, {a['threshold_px']:g} px, "
                         f"{a.get('preset', 'paper')}{', tree method' if a.get('method') == 'tree' else ''}{', calibrated' if a.get('calibrate') or a.get('calibrate_scale') else ''}"
                         f"{' (scales too)' if a.get('calibrate_scale') else ''}"
                         f"{', min_views ' + str(a['min_views']) if a.get('min_views') else ''}", _duration(a["wall_s"]),
                         "; ".join(a["executors"]) or "-",
                         _fmt("time_s", timing["mean"]) if timing else "n/a"])
    lines += _table(["experiment", "mode", "cases", "status", "reconstruction", "wall time", "run on",
                     "mean reconstruction time (s)"], run_rows)
    lines.append("")
    for a in analyses:
        lines += _run_section(a, figures.get(a["name"]))
    return "\n".join(lines).rstrip() + "\n"


def _run_section(a: dict[str, Any], figure: Optional[str]) -> list[str]:
    metrics = a["metrics"]
    lines = [f"## {a['name']}", "", f"{a['description']}" + (f" — paper: {a['paper_ref']}." if a["paper_ref"] else "."),
             ""]
    if a["mode"] == "quick":
        lines += ["*Quick run (`--quick`): the experiment's shape at a fraction of its size; not comparable "
                  "with the paper.*", ""]
    if a["cases_done"] < a["cases_total"]:
        lines += [f"*Incomplete: {a['cases_done']} of {a['cases_total']} cases finished.*", ""]
    first = "tortuosity" if a["layout"] == "groups" else a["x"]["label"]
    body = [[g["label"], str(g["n_cases"])] + [_cell(m, g["summaries"][m]) for m in metrics] for g in a["groups"]]
    lines += _table([first, "cases"] + [METRIC_LABELS[m] for m in metrics], body)
    lines.append("")
    if "paper" in a:
        paper = a["paper"]
        lines += [f"### Against the paper ({paper['source']})", ""]
        body = [[METRIC_LABELS[r["metric"]], _fmt(r["metric"], r["paper"]), _fmt(r["metric"], r["mean"]),
                 f"{_fmt(r['metric'], r['ci_low'])}–{_fmt(r['metric'], r['ci_high'])}",
                 ("+" if r["difference"] >= 0 else "") + _fmt(r["metric"], r["difference"]),
                 "yes" if r["paper_in_ci"] else "no"] for r in paper["rows"]]
        lines += _table(["metric", "paper", "ours", "ours, 95 % CI", "ours − paper", "paper inside our CI"], body)
        lines.append("")
    if "ttests" in a:
        metric = a["ttests"]["metric"]
        published = PAPER_RESULTS["table3"]["p_values"]
        lines += [f"### t-tests on {METRIC_LABELS[metric]} between tortuosity groups (paper Table 3)", "",
                  "Two-sided, independent samples: Student's (pooled variance, as `scipy.stats.ttest_ind`'s default) "
                  "and Welch's.", ""]
        body = []
        for t in a["ttests"]["tests"]:
            paper_p = "not transcribed" if published is None else _fmt_p(published.get(f"{t['group_a']} vs {t['group_b']}"))
            body.append([f"{t['group_a']} vs {t['group_b']}", f"{t['n_a']} / {t['n_b']}", _fmt(metric, t["mean_a"]),
                         _fmt(metric, t["mean_b"]), f"{t['t']:.3f}" if math.isfinite(t["t"]) else "n/a",
                         _fmt_p(t["p_student"]), _fmt_p(t["p_welch"]), paper_p])
        lines += _table(["groups", "n", "mean A", "mean B", "t", "p (Student)", "p (Welch)", "paper p"], body)
        lines.append("")
    if "correlation" in a:
        body = [[METRIC_LABELS[m], f"{c['rho']:.3f}" if math.isfinite(c["rho"]) else "n/a", _fmt_p(c["p"]), str(c["n"])]
                for m, c in a["correlation"].items()]
        lines += [f"Spearman's rank correlation with {a['x']['label']}:", ""]
        lines += _table(["metric", "rho", "p", "n"], body)
        lines.append("")
    if a["reasons"]:
        lines += ["Reasons given by cases that are not `ok` (first five distinct):", ""]
        lines += [f"- {reason}" for reason in a["reasons"]]
        lines.append("")
    if figure:
        lines += [f"![{a['name']}]({figure})", ""]
    return lines


def figure_title(a: dict[str, Any]) -> str:
    """A figure's title: the experiment and its description; for a quick run, the cases it ran, the
    description being the full experiment's (its counts are not this run's)."""
    if a.get("mode") == "quick":
        return (f"{a['name']}: quick run, {a['cases_done']} of {a['cases_total']} cases (the full experiment: "
                f"{a['description']})")
    return f"{a['name']}: {a['description']}"


def _draw(a: dict[str, Any], path: Path) -> Path:
    metrics = a["metrics"]
    values = {m: np.asarray(a["_values"][m], dtype=float) for m in metrics}
    title = figure_title(a)
    summaries = {m: [Summary(**g["summaries"][m]) for g in a["groups"]] for m in metrics}
    if a["layout"] == "groups":
        per_group = {m: [values[m][idx][np.isfinite(values[m][idx])] for idx in a["_group_index"]] for m in metrics}
        paper = None
        if "paper" in a:
            paper = {r["metric"]: r["paper"] for r in a["paper"]["rows"]}
        return group_figure(path, title, [g["label"] for g in a["groups"]], per_group, summaries, paper)
    scatter = None
    if "translation_vectors" in a and "dice3d" in metrics:
        scatter = (a["translation_vectors"]["tx_px"], a["translation_vectors"]["ty_px"], values["dice3d"], "Dice3D (%)")
    return curve_figure(path, title, a["x"]["label"], a["x"]["values"], values, [g["x"] for g in a["groups"]],
                        summaries, scatter_xy=scatter)


def build_report(run_dirs: Sequence[str | Path], out_dir: str | Path) -> Path:
    """Write ``report.md``, ``report.json`` and ``figures/*.png`` for the runs into ``out_dir``.

    Returns the path of ``report.md``.
    """
    from .rows import write_atomic

    runs = [load_run(path) for path in find_runs(run_dirs)]
    names = [r.config.name for r in runs]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        listed = "; ".join(f"{n}: {', '.join(str(r.run_dir) for r in runs if r.config.name == n)}" for n in duplicates)
        raise AngiohullError(f"two runs of the same experiment ({listed}); report them separately")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    analyses = [analyse_run(run) for run in runs]
    figures = {}
    for a in analyses:
        if a["cases_done"]:
            _draw(a, out / "figures" / f"{a['name']}.png")
            figures[a["name"]] = f"figures/{a['name']}.png"
    public = [{k: v for k, v in a.items() if not k.startswith("_")} for a in analyses]
    document = {"angiohull_version": __version__, "paper": PAPER_RESULTS, "runs": public}
    write_atomic(out / "report.json", json.dumps(_json_safe(document), indent=1, allow_nan=False) + "\n")
    return write_atomic(out / "report.md", render_markdown(analyses, figures))


def _json_safe(value: Any) -> Any:
    """Plain JSON data: numpy scalars to Python numbers, nan and infinities to None."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json_safe(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value
