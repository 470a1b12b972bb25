"""Quantitative coronary analysis of reconstructions against the generator's truth (issue 22).

Runs, with the same defaults for every case (:class:`angiohull.qca.QcaSettings()`):

* ``--trees`` RCA and ``--trees`` left generated trees (tortuosity simple / moderate / tortuous in
  turn) that carry 1 to 3 stenoses of 30-80 % (the generator draws 0-2 per main vessel and 0-1 per
  side branch; seeds whose tree has none or more than 3 are passed over, and counted);
* reconstructed with the refined preset from 3 clinical views (RAO 30 CRA 30, LAO 60 CRA 30,
  RAO 30 CAU 30) and from 2 (the first two), each from the exact masks and from segmented
  angiograms (rendered with :func:`angiohull.synthetic.angiogram.render_angiogram`, collimator
  8 px, seeded; segmented by :func:`angiohull.segmentation.segment_vessels` with its defaults);
  every case also with the tree method (``method="tree"``, docs/tree-method.md), built for two
  views and the default method since 2026-12-07 (with three views it fits the refined hull's
  tree and takes its lumen from the fitted tubes);
* :func:`angiohull.qca.analyse_tree` on each reconstructed tree, compared with the truth:

  - every true stenosis: its MLD point (the true centerline point of least radius inside the
    window), MLD, reference diameter (the generator's taper there) and %DS, and the lesion length
    the module's definition gives for the window (:func:`angiohull.qca.window_lesion_length_mm`);
    a reported lesion is matched one to one to the nearest true one whose MLD point lies within
    5 mm of its own; the errors are reported minus true; an unmatched reported lesion is false;
  - every true branch: the length of the reconstructed tree's path between its points nearest
    to the true branch's first and last points, against the true branch's length, and where along
    it the error lies (its first and last 8 mm, and between);
  - every true bifurcation matched (5 mm, one to one) to a reconstructed one: the true arms are
    paired one to one with the reconstructed arms whose chords (the stretch each direction is
    measured over) lie nearest theirs (least total distance of both chord ends, at most 10 mm
    apart), and the proximal and distal angles of each side branch are compared; a true angle
    whose bifurcation was not found, or whose arms found no partner with a direction, counts as
    not measured.

Writes a Markdown report (``--output``) and the raw rows beside it (``.json``), and prints both.

    OPENBLAS_NUM_THREADS=1 python benchmarks/qca.py [--trees 30] [--workers 2] \\
        [--output docs/results/qca.md]
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _versions import library_versions  # noqa: E402  (benchmarks/_versions.py, beside this script)

LEVELS = ("simple", "moderate", "tortuous")
VIEWS3 = ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30")
# (views, masks, method, where lesions' MLD is read: "tree" = the tree's profile, "images" = measured again on the
# angiograms, analyse_tree(..., attenuation=); the "images" setups reuse their "tree" twin's reconstruction)
SETUPS = (("3 views", "masks", "hull", "tree"), ("3 views", "segmented", "hull", "tree"),
          ("3 views", "segmented", "hull", "images"), ("2 views", "masks", "hull", "tree"),
          ("2 views", "segmented", "hull", "tree"), ("2 views", "masks", "tree", "tree"),
          ("2 views", "segmented", "tree", "tree"), ("2 views", "segmented", "tree", "images"),
          ("3 views", "masks", "tree", "tree"), ("3 views", "segmented", "tree", "tree"),
          ("3 views", "segmented", "tree", "images"))
MATCH_MM = 5.0
END_MM = 8.0  # a branch length's error is split into its first and last END_MM and the rest between
CAAS = {  # CAAS 3D bifurcation QCA on phantoms (EuroIntervention 2012), error mean +- sd
    "mld_mm": (0.013, 0.131), "reference_diameter_mm": (-0.052, 0.039), "diameter_stenosis_pct": (-1.08, 5.13),
    "bifurcation_angle_deg": (-1.3, 5.0), "length_mm": (0.15, 0.26)}


def _seed(kind: str, index: int) -> int:
    return (17_000 if kind == "rca" else 18_000) + 37 * index


def _tree_params(kind: str, index: int):
    """The record of tree ``index``: the first seed from its base on whose tree the generator
    puts 1 to 3 stenoses; returns (seed, params, seeds passed over)."""
    from angiohull.errors import AngiohullError
    from angiohull.synthetic import draw_tree_params

    passed = 0
    for attempt in range(200):
        seed = _seed(kind, index) + attempt
        try:
            params = draw_tree_params(kind, LEVELS[index % 3], seed)
        except AngiohullError:
            passed += 1
            continue
        count = sum(len(b.stenoses) for b in params.branches)
        if 1 <= count <= 3:
            return seed, params, passed
        passed += 1
    raise RuntimeError(f"no {kind} tree with 1-3 stenoses from seed {_seed(kind, index)}")


def _true_lesions(tree) -> list[dict]:
    from angiohull.qca import window_lesion_length_mm

    out = []
    for bi, b in enumerate(tree.branches):
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(b.centerline_mm, axis=0), axis=1))])
        for s in b.stenoses:
            inside = np.flatnonzero(np.abs(arc - s.centre_mm) <= 0.5 * s.length_mm)
            k = int(inside[np.argmin(b.radius_mm[inside])])
            mld, ref = 2.0 * float(b.radius_mm[k]), 2.0 * float(b.reference_radius_mm[k])
            out.append({"branch": bi, "name": b.name, "severity": s.severity, "profile": s.profile,
                        "extent_mm": s.length_mm, "point_mm": b.centerline_mm[k].tolist(), "mld_mm": mld,
                        "reference_diameter_mm": ref, "diameter_stenosis_pct": 100.0 * (1.0 - mld / ref),
                        "lesion_length_mm": window_lesion_length_mm(s.profile, s.length_mm)})
    return out


def _match(true_points: np.ndarray, rec_points: np.ndarray, limit: float) -> list[tuple[int, int, float]]:
    """One-to-one pairs (true, rec, distance) within ``limit``, nearest first (greedy)."""
    if len(true_points) == 0 or len(rec_points) == 0:
        return []
    dist = np.linalg.norm(true_points[:, None, :] - rec_points[None, :, :], axis=2)
    pairs, used_t, used_r = [], set(), set()
    for flat in np.argsort(dist, axis=None):
        i, j = np.unravel_index(flat, dist.shape)
        if dist[i, j] > limit:
            break
        if i in used_t or j in used_r:
            continue
        used_t.add(i)
        used_r.add(j)
        pairs.append((int(i), int(j), float(dist[i, j])))
    return pairs


def _tree_graph(tree):
    """Points of the tree and a sparse graph of its polylines and connectors (edge = mm)."""
    from scipy.sparse import coo_matrix

    points, _, index = tree.points()
    offsets = np.concatenate([[0], np.cumsum([b.n_points for b in tree.branches])])
    rows, cols, weights = [], [], []
    for bi, b in enumerate(tree.branches):
        i = np.arange(offsets[bi], offsets[bi + 1] - 1)
        rows.append(i)
        cols.append(i + 1)
        weights.append(np.linalg.norm(points[i + 1] - points[i], axis=1))
        if b.parent is not None:
            p = offsets[b.parent] + b.parent_point
            rows.append(np.array([p]))
            cols.append(np.array([offsets[bi]]))
            weights.append(np.array([max(float(np.linalg.norm(points[p] - points[offsets[bi]])), 1e-9)]))
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    n = len(points)
    return points, coo_matrix((np.concatenate([w, w]), (np.concatenate([r, c]), np.concatenate([c, r]))), (n, n)).tocsr()


def _branch_lengths(truth, rec) -> list[dict]:
    """Per true branch: the reconstructed tree's path length between its points nearest to the true
    branch's first and last points, and where the error lies along it: the path's part up to its
    point nearest to the true point ``END_MM`` from the start, its part from there to its point
    nearest to the true point ``END_MM`` before the tip, and the rest (each minus its true length;
    ``END_MM`` is a third of shorter branches)."""
    from scipy.sparse.csgraph import dijkstra
    from scipy.spatial import cKDTree

    points, graph = _tree_graph(rec)
    kd = cKDTree(points)
    out = []
    for b in truth.branches:
        _, (i, j) = kd.query(b.points_mm[[0, -1]])
        distance, predecessor = dijkstra(graph, indices=int(i), return_predecessors=True)
        path = [int(j)]
        while path[-1] != int(i):
            path.append(int(predecessor[path[-1]]))
        p = points[path[::-1]]
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        arc, true_length = b.arc_length_mm, b.length_mm
        end = min(END_MM, true_length / 3.0)
        marks = [int(np.argmin(np.linalg.norm(p - np.array([np.interp(s, arc, b.points_mm[:, k]) for k in range(3)]),
                                              axis=1))) for s in (end, true_length - end)]
        out.append({"name": b.name, "true_mm": true_length, "measured_mm": float(distance[int(j)]),
                    "start_error_mm": float(along[marks[0]] - end),
                    "inner_error_mm": float(along[marks[1]] - along[marks[0]] - (true_length - 2 * end)),
                    "tip_error_mm": float(along[-1] - along[marks[1]] - end)})
    return out


def _angle(a, b) -> float:
    if a is None or b is None:
        return math.nan
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


def _paired_arms(true_arms, rec_arms) -> dict[int, int]:
    """True arm -> reconstructed arm, one to one: least total distance between their chords' ends
    (:attr:`angiohull.qca.bifurcations.Arm.near_mm`, ``far_mm``), pairs within ``2 * MATCH_MM``."""
    from scipy.optimize import linear_sum_assignment

    cost = np.full((len(true_arms), len(rec_arms)), 1e6)
    for i, t in enumerate(true_arms):
        for j, r in enumerate(rec_arms):
            if t.near_mm is not None and r.near_mm is not None:
                cost[i, j] = (np.linalg.norm(np.subtract(t.near_mm, r.near_mm))
                              + np.linalg.norm(np.subtract(t.far_mm, r.far_mm)))
    rows, cols = linear_sum_assignment(cost)
    return {int(i): int(j) for i, j in zip(rows, cols) if cost[i, j] <= 2.0 * MATCH_MM}


def _bifurcation_angles(truth_qca, rec_qca) -> list[dict]:
    t_pos = np.array([b.position_mm for b in truth_qca.bifurcations]).reshape(-1, 3)
    r_pos = np.array([b.position_mm for b in rec_qca.bifurcations]).reshape(-1, 3)
    out = []
    matched = {ti: (ri, dist) for ti, ri, dist in _match(t_pos, r_pos, MATCH_MM)}
    for ti, tb in enumerate(truth_qca.bifurcations):
        roles = {a.role: k for k, a in enumerate(tb.arms) if a.role != "side"}
        if ti in matched:
            ri, dist = matched[ti]
            rb = rec_qca.bifurcations[ri]
            pairs = _paired_arms(tb.arms, rb.arms)
        else:
            rb, dist, pairs = None, math.nan, {}
        for k, side in enumerate(tb.arms):
            if side.role != "side":
                continue
            for kind, other_role in (("distal", "distal main"), ("proximal", "proximal main")):
                if other_role not in roles:
                    continue
                true_angle = _angle(tb.arms[roles[other_role]].direction, side.direction)
                if not math.isfinite(true_angle):
                    continue
                o, s = pairs.get(roles[other_role]), pairs.get(k)
                rec_angle = math.nan if o is None or s is None else _angle(rb.arms[o].direction, rb.arms[s].direction)
                out.append({"kind": kind, "true_deg": true_angle, "measured_deg": rec_angle, "distance_mm": dist})
    return out


def _label(n_views: str, source: str, method: str, mld: str = "tree") -> str:
    """A setup's column: the refined hull unless the tree method is named; MLD from the angiograms
    where said."""
    return (f"{n_views}, {source}" + (", tree method" if method == "tree" else "")
            + (", MLD from the angiograms" if mld == "images" else ""))


def _views(setup_views: str, case):
    return case.views if setup_views == "3 views" else case.views[:2]


def _run_tree(task: tuple[str, int, float]) -> list[dict]:
    from angiohull.geometry import cube_half_edge_mm
    from angiohull.qca import QcaSettings, analyse_tree
    from angiohull.reconstruction import reconstruct
    from angiohull.segmentation import segment_vessels_detailed
    from angiohull.synthetic import SynthOptions, make_case
    from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram

    kind, index, cube_scale = task
    seed, params, passed = _tree_params(kind, index)
    case = make_case(SynthOptions(kind=kind, tortuosity=LEVELS[index % 3], views=VIEWS3, seed=seed),
                     tree_params=params)
    truth = case.tree.vessel_tree()
    settings = QcaSettings(lesion_views=False)
    truth_qca = analyse_tree(truth, settings=settings)
    true_lesions = _true_lesions(case.tree)
    segmentations = [segment_vessels_detailed(render_angiogram(case.tree.phantom, v.carm, seed * 10 + i,
                                                               AngiogramParameters(collimator_px=8)).image)
                     for i, v in enumerate(case.views)]
    segmented = [s.mask for s in segmentations]
    rows = []
    built: dict[tuple[str, str, str], tuple] = {}  # a reconstruction, shared by the MLD variants of a setup
    for n_views, source, method, mld in SETUPS:
        views = _views(n_views, case)
        masks = [v.mask for v in views] if source == "masks" else segmented[:len(views)]
        projections = [v.carm.projection() for v in views]
        row = {"kind": kind, "index": index, "seed": seed, "seeds_passed": passed, "views": n_views,
               "source": source, "method": method, "mld": mld, "true_lesions": true_lesions}
        half_edge = None if cube_scale == 1.0 else cube_scale * cube_half_edge_mm(projections)
        key = (n_views, source, method)
        if key not in built:
            t0 = time.perf_counter()
            try:
                result = (reconstruct(projections, masks, preset="refined", half_edge_mm=half_edge, warn=False)
                          if method == "hull" else
                          reconstruct(projections, masks, method="tree", centerlines=False, half_edge_mm=half_edge,
                                      warn=False))
                built[key] = (result, None, time.perf_counter() - t0)
            except Exception as exc:  # noqa: BLE001 - a failed case is a row, not a crash
                built[key] = (None, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)
        result, failure, reconstruct_s = built[key]
        if failure is not None:
            rows.append({**row, "error": failure})
            continue
        if result.tree is None:
            rows.append({**row, "error": f"no tree: {result.tree_error}"})
            continue
        t1 = time.perf_counter()
        try:
            qca = (analyse_tree(result.tree, settings=settings) if mld == "tree" else
                   analyse_tree(result.tree, projections, settings=settings,
                                attenuation=[s.lumen_attenuation for s in segmentations[:len(views)]]))
        except Exception as exc:  # noqa: BLE001 - a failed analysis is a row (and counted), not a crash
            rows.append({**row, "error": f"analysis: {type(exc).__name__}: {exc}"})
            continue
        t2 = time.perf_counter()
        found = [{"branch": les.branch, "point_mm": list(les.mld_point_mm), "mld_mm": les.mld_mm,
                  "reference_diameter_mm": les.reference_diameter_mm,
                  "diameter_stenosis_pct": les.diameter_stenosis_pct, "lesion_length_mm": les.length_mm}
                 for les in qca.lesions]
        pairs = _match(np.array([t["point_mm"] for t in true_lesions]).reshape(-1, 3),
                       np.array([f["point_mm"] for f in found]).reshape(-1, 3), MATCH_MM)
        rows.append({**row, "found_lesions": found, "pairs": pairs,
                     "branch_lengths": _branch_lengths(truth, result.tree),
                     "angles": _bifurcation_angles(truth_qca, qca),
                     "reconstruct_s": reconstruct_s, "qca_s": t2 - t1})
    return rows


def _stats(values) -> dict:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return {"n": 0, "mean": math.nan, "sd": math.nan, "mae": math.nan}
    return {"n": int(v.size), "mean": float(v.mean()), "sd": float(v.std(ddof=1)) if v.size > 1 else 0.0,
            "mae": float(np.abs(v).mean())}


def summarise(rows: list[dict]) -> dict:
    out = {}
    for n_views, source, method, mld in SETUPS:
        same = [r for r in rows if r["views"] == n_views and r["source"] == source and r.get("method", "hull") == method
                and r.get("mld", "tree") == mld]
        sel = [r for r in same if "error" not in r]
        errors = [r for r in same if "error" in r]
        diffs = {k: [] for k in ("diameter_stenosis_pct", "mld_mm", "reference_diameter_mm", "lesion_length_mm")}
        sev50 = found50 = 0
        false_all = false50 = 0
        missed = []
        for r in sel:
            matched_t = {p[0]: p[1] for p in r["pairs"]}
            matched_r = {p[1] for p in r["pairs"]}
            for ti, t in enumerate(r["true_lesions"]):
                if t["diameter_stenosis_pct"] >= 50.0:
                    sev50 += 1
                    if ti in matched_t:
                        found50 += 1
                    else:
                        missed.append(f"{r['kind']}{r['index']}:{t['name']}:{t['diameter_stenosis_pct']:.0f}%")
                if ti in matched_t:
                    f = r["found_lesions"][matched_t[ti]]
                    for k in diffs:
                        diffs[k].append(f[k] - t[k])
            for j, f in enumerate(r["found_lesions"]):
                if j not in matched_r:
                    false_all += 1
                    false50 += f["diameter_stenosis_pct"] >= 50.0
        lengths = [b for r in sel for b in r["branch_lengths"]]
        length_err = [b["measured_mm"] - b["true_mm"] for b in lengths]
        within = [abs(b["measured_mm"] - b["true_mm"]) <= max(0.01 * b["true_mm"], 1.0) for b in lengths]
        angles = [a for r in sel for a in r["angles"]]
        n_true = sum(len(r["true_lesions"]) for r in sel)
        out[_label(n_views, source, method, mld)] = {
            "trees": len(sel), "failed": len(errors), "true_lesions": n_true,
            "matched_lesions": sum(len(r["pairs"]) for r in sel),
            **{k: _stats(v) for k, v in diffs.items()},
            "sensitivity_50": found50 / sev50 if sev50 else math.nan, "lesions_50": sev50, "missed_50": missed,
            "false_per_tree": false_all / len(sel) if sel else math.nan,
            "false_50_per_tree": false50 / len(sel) if sel else math.nan,
            "branch_length_mm": _stats(length_err),
            "branch_length_abs_pct": _stats([100.0 * abs(b["measured_mm"] - b["true_mm"]) / b["true_mm"] for b in lengths]),
            "branch_length_within": float(np.mean(within)) if within else math.nan, "branches": len(lengths),
            **{f"branch_length_{part}_error_mm": {"median": float(np.median([b[f"{part}_error_mm"] for b in lengths])),
                                                   "mae": float(np.mean([abs(b[f"{part}_error_mm"]) for b in lengths]))}
               if lengths else {"median": math.nan, "mae": math.nan} for part in ("start", "inner", "tip")},
            "distal_angle_deg": _stats([a["measured_deg"] - a["true_deg"] for a in angles if a["kind"] == "distal"]),
            "proximal_angle_deg": _stats([a["measured_deg"] - a["true_deg"] for a in angles if a["kind"] == "proximal"]),
            "angles_within_5": float(np.mean([abs(a["measured_deg"] - a["true_deg"]) <= 5.0 for a in angles
                                              if math.isfinite(a["measured_deg"])])) if angles else math.nan,
            "angles_measured": sum(math.isfinite(a["measured_deg"]) for a in angles), "angles_true": len(angles),
            "reconstruct_s": float(np.median([r["reconstruct_s"] for r in sel])) if sel else math.nan,
            "qca_s": float(np.median([r["qca_s"] for r in sel])) if sel else math.nan,
        }
    return out


def _ms(s: dict, digits: int = 2) -> str:
    if s["n"] == 0:
        return "-"
    return f"{s['mean']:+.{digits}f} ± {s['sd']:.{digits}f}"


def markdown(summary: dict, meta: dict) -> str:
    keys = list(summary)
    lines = [f"# Quantitative coronary analysis against the truth ({meta['date']})", "",
             f"Made by `OPENBLAS_NUM_THREADS=1 python benchmarks/qca.py --trees {meta['trees']} --workers "
             f"{meta['workers']}" + (f" --cube-scale {meta['cube_scale']:g}" if meta.get("cube_scale", 1.0) != 1.0 else "")
             + f"` at commit {meta['commit']} on {meta['machine']}, Python {meta['python']} "
             f"({meta.get('libraries', 'libraries not recorded')}), in "
             f"{meta['wall_s']:.0f} s. {2 * meta['trees']} generated trees ({meta['trees']} RCA, {meta['trees']} "
             f"left) with 1-3 stenoses of 30-80 %, {meta['true_lesions']} stenoses in all, {meta['lesions_50']} of them "
             f">= 50 %; refined preset (the columns marked tree method: `method=\"tree\"`); the default `QcaSettings()`. Errors are measured minus true, mean ± sd. "
             f"Seeds passed over for having no stenosis or more than 3: {meta['seeds_passed']}.", "",
             "| quantity | target (3 views) | " + " | ".join(keys) + " | CAAS 3D (phantom) |",
             "|---|---|" + "---|" * len(keys) + "---|"]

    def row(label, target, cells, caas="-"):
        lines.append(f"| {label} | {target} | " + " | ".join(cells) + f" | {caas} |")

    row("trees (failed)", "", [f"{summary[k]['trees']} ({summary[k]['failed']})" for k in keys])
    row("stenoses matched / true", "", [f"{summary[k]['matched_lesions']} / {summary[k]['true_lesions']}" for k in keys])
    row("%DS error (points)", "0 ± 5", [_ms(summary[k]["diameter_stenosis_pct"], 1) for k in keys], "-1.08 ± 5.13")
    row("MLD error (mm)", "0 ± 0.15", [_ms(summary[k]["mld_mm"], 3) for k in keys], "+0.013 ± 0.131")
    row("reference diameter error (mm)", "0 ± 0.1", [_ms(summary[k]["reference_diameter_mm"], 3) for k in keys],
        "-0.052 ± 0.039")
    row("lesion length error (mm)", "within 1.5", [_ms(summary[k]["lesion_length_mm"], 2) + f" (MAE {summary[k]['lesion_length_mm']['mae']:.2f})"
                                                   for k in keys], "+0.15 ± 0.26 (length)")
    row("sensitivity, stenoses >= 50 %", ">= 0.90", [f"{summary[k]['sensitivity_50']:.3f} ({summary[k]['lesions_50']})" for k in keys])
    row("false lesions per tree (>= 20 % / >= 50 %)", "<= 0.5",
        [f"{summary[k]['false_per_tree']:.2f} / {summary[k]['false_50_per_tree']:.2f}" for k in keys])
    row("branch length error (mm)", "", [_ms(summary[k]["branch_length_mm"], 2) for k in keys])
    row("branch length within 1 % or 1 mm", "all", [f"{summary[k]['branch_length_within']:.3f} of {summary[k]['branches']}"
                                                     for k in keys])
    row(f"branch length error: first {END_MM:g} mm / between / last {END_MM:g} mm, median (MAE) (mm)", "",
        [" / ".join(f"{summary[k][f'branch_length_{part}_error_mm']['median']:+.2f} "
                    f"({summary[k][f'branch_length_{part}_error_mm']['mae']:.2f})" for part in ("start", "inner", "tip"))
         for k in keys])
    row("distal (bifurcation) angle error (deg)", "within 5", [_ms(summary[k]["distal_angle_deg"], 1) + f" (MAE {summary[k]['distal_angle_deg']['mae']:.1f}, n {summary[k]['distal_angle_deg']['n']})"
                                                             for k in keys], "-1.3 ± 5.0")
    row("proximal angle error (deg)", "within 5", [_ms(summary[k]["proximal_angle_deg"], 1) + f" (MAE {summary[k]['proximal_angle_deg']['mae']:.1f})"
                                                  for k in keys])
    row("angles within 5 deg", "", [f"{summary[k]['angles_within_5']:.3f}" for k in keys])
    row("angles measured / true", "", [f"{summary[k]['angles_measured']} / {summary[k]['angles_true']}" for k in keys])
    row("reconstruction / QCA time, median (s)", "", [f"{summary[k]['reconstruct_s']:.2f} / {summary[k]['qca_s']:.3f}" for k in keys])
    lines += ["", "Missed stenoses >= 50 % (tree:branch:true %DS):", ""]
    for k in keys:
        lines.append(f"- {k}: {', '.join(summary[k]['missed_50']) or 'none'}")
    return "\n".join(lines) + "\n"


def _rounded(value, digits: int = 5):
    """Floats to ``digits`` decimals (the raw rows stay small enough to commit)."""
    if isinstance(value, float):
        return round(value, digits) if math.isfinite(value) else value
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(v, digits) for v in value]
    return value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", type=int, default=30, help="trees of each kind (default 30)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--output", type=Path, default=Path("docs/results/qca.md"))
    parser.add_argument("--cube-scale", type=float, default=1.0, metavar="S",
                        help="reconstruct on the cube of interest's half-edge S times the views' own (default 1): the "
                             "same views on another lattice, to measure how far the results move when nothing but the "
                             "lattice does (docs/qca.md)")
    args = parser.parse_args()
    if not 0.5 <= args.cube_scale <= 2.0:
        parser.error(f"--cube-scale must lie within [0.5, 2] (the cube must hold the vessels), got {args.cube_scale}")
    tasks = [(kind, i, args.cube_scale) for i in range(args.trees) for kind in ("rca", "left")]
    t0 = time.perf_counter()
    rows: list[dict] = []
    with ProcessPoolExecutor(args.workers) as pool:
        for k, result in enumerate(pool.map(_run_tree, tasks)):
            rows.extend(result)
            print(f"[{time.perf_counter() - t0:6.0f} s] tree {k + 1}/{len(tasks)}", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    summary = summarise(rows)
    first = [r for r in rows if r["views"] == "3 views" and r["source"] == "masks" and r["method"] == "hull"
             and r["mld"] == "tree"]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).resolve().parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    meta = {"date": datetime.date.today().isoformat(), "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            "commit": commit, "python": platform.python_version(), "libraries": library_versions(),
            "trees": args.trees, "workers": args.workers, "cube_scale": args.cube_scale, "wall_s": wall,
            "true_lesions": sum(len(r["true_lesions"]) for r in first),
            "lesions_50": sum(t["diameter_stenosis_pct"] >= 50 for r in first for t in r["true_lesions"]),
            "seeds_passed": sum(r["seeds_passed"] for r in first)}
    text = markdown(summary, meta)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text)
    args.output.with_suffix(".json").write_text(json.dumps(_rounded({"meta": meta, "summary": summary, "rows": rows}),
                                                           separators=(",", ":"), allow_nan=True))
    print(text)


if __name__ == "__main__":
    main()
