"""An experiment as a list of cases, and one case as one row of results.

:func:`expand_cases` turns a validated :class:`~angiohull.experiments.config.ExperimentConfig` into
case parameter records (plain JSON-able dicts, written to ``RUN_DIR/cases.jsonl``); :func:`run_case`
turns one record into one row (a dict with the columns of :func:`row_columns`). ``run_case`` is a
pure function of its record: the runner may call it in any process, thread or Dask worker, in any
order, and gets the same row (up to the timings ``time_s`` and ``case_s``).

Seeds
-----
Every seed derives from the configuration's ``seed`` S through ``numpy.random.SeedSequence``
(:func:`derive_seed`): tree ``i`` of tortuosity level L of kind K has seed
``derive_seed(S, 1, K, L, i)``, the same in every design, so experiments with the same S use the
same trees. A tree seed plays the role of ``angiohull synth --seed``: the tree and the corruption
draws of a ``trees`` case are exactly those of
``make_case(SynthOptions(..., corruptions=..., seed=tree_seed))`` (tested), so any case can be
replayed from its row. Random view directions (stream 2), N-view selections (3), sweep values
(4) and view triplets (5) have streams of their own.

Random view directions are uniform on the sphere: ``z = 2 u1 - 1``, ``phi = 2 pi u2`` give the
detector direction ``d = (sqrt(1 - z^2) cos phi, sqrt(1 - z^2) sin phi, z)``, which the conventions'
``d = (sin a cos b, -cos a cos b, sin b)`` turns into ``secondary b = asin(z)`` in [-90, 90] and
``primary a = atan2(d_x, -d_y)`` in (-180, 180].

Worker caches
-------------
A tree's surface points (the ground truth and the paper rasteriser's splat points) cost most of a
case, and the ``n_views`` design uses the same 1000 views for all its cases. Each worker process
keeps the last few trees and up to a few thousand rendered masks (bit-packed) in memory, keyed by
everything they depend on, so a view is rendered once per worker. Caching never changes a result.
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence

import numpy as np

from ..errors import AngiohullError
from ..geometry import CArmGeometry, Projection, format_clinical_angles
from ..metrics import dice2d_paper, dice2d_plain, scores_3d
from ..reconstruction import reconstruct
from ..reconstruction.calibration import calibrate_shifts
from ..synthetic.case import GT_SURFACE_SPACING_MM, fit_problem
from ..synthetic.corruptions import CorruptionSpec, apply_all, draw_corruptions
from ..synthetic.render import PAPER_SURFACE_SPACING_MM, render_mask
from ..synthetic.tree import TORTUOSITY_LEVELS, TREE_KINDS, build_tree, draw_tree_params
from ..synthetic.views import parse_views
from ..tree import VesselTree
from .config import TREE_METRICS, AnglesDesign, ExperimentConfig, NViewsDesign, TreesDesign, grid_values
from .rows import STATUSES

__all__ = [
    "derive_seed", "tree_seed", "sphere_directions", "direction_angles", "angle_matrix_sigma_min",
    "sweep_values", "expand_cases", "row_columns", "run_case", "case_inputs", "CaseInputs", "STATUSES",
    "clear_caches",
]

TREE_STREAM, DIRECTION_STREAM, SELECTION_STREAM, SWEEP_STREAM, TRIPLET_STREAM = 1, 2, 3, 4, 5

"""``ok``; ``empty``: the visual hull is empty (Dice 0, Chamfer nan); ``failed``: the case could not be
built or reconstructed (metrics nan, reason given); ``error``: an unexpected exception (metrics nan)."""

_SWEEP_COLUMNS = {"translate": ("tx_px", "ty_px", "shift_px"), "scale": ("factor",), "rotate": ("angle_deg",),
                  "fp": ("p",), "fn": ("p",), "missing": ("count",), "blob": ("count",), "catheter": ("count",)}


# -- seeds and directions -------------------------------------------------------------------------
def derive_seed(config_seed: int, *keys: int) -> int:
    """A 63-bit seed from ``SeedSequence([config_seed, *keys])`` (distinct keys: independent streams)."""
    state = np.random.SeedSequence([int(config_seed), *(int(k) for k in keys)]).generate_state(1, np.uint64)[0]
    return int(state >> np.uint64(1))


def tree_seed(config_seed: int, kind: str, tortuosity: str, index: int) -> int:
    """Seed of tree ``index`` of a kind and level (the ``--seed`` of ``angiohull synth`` that draws it)."""
    return derive_seed(config_seed, TREE_STREAM, TREE_KINDS.index(kind), TORTUOSITY_LEVELS.index(tortuosity), index)


def sphere_directions(count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` unit vectors uniform on the sphere, (count, 3); row k depends only on the k-th draw pair."""
    u = rng.random((count, 2))
    z = 2.0 * u[:, 0] - 1.0
    phi = 2.0 * math.pi * u[:, 1]
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def direction_angles(direction: Sequence[float]) -> tuple[float, float]:
    """``(primary_deg, secondary_deg)`` of a detector direction ``d`` (docs/conventions.md convention)."""
    x, y, z = (float(c) for c in direction)
    secondary = math.degrees(math.asin(max(-1.0, min(1.0, z))))
    primary = math.degrees(math.atan2(x, -y))
    return (180.0 if primary == -180.0 else primary), secondary


def _detector_direction(primary_deg: float, secondary_deg: float) -> np.ndarray:
    a, b = math.radians(primary_deg), math.radians(secondary_deg)
    return np.array([math.sin(a) * math.cos(b), -math.cos(a) * math.cos(b), math.sin(b)])


def angle_matrix_sigma_min(angles_deg: Sequence[tuple[float, float]]) -> float:
    """Smallest singular value of the matrix whose rows are the unit viewing directions of the views."""
    matrix = np.stack([_detector_direction(p, s) for p, s in angles_deg])
    return float(np.linalg.svd(matrix, compute_uv=False).min())


def _min_line_angle_deg(angles_deg: Sequence[tuple[float, float]]) -> float:
    """Smallest angle between the viewing lines of any two views, degrees in [0, 90]."""
    dirs = [_detector_direction(p, s) for p, s in angles_deg]
    best = 90.0
    for i in range(len(dirs)):
        for j in range(i + 1, len(dirs)):
            best = min(best, math.degrees(math.acos(min(1.0, abs(float(dirs[i] @ dirs[j]))))))
    return best


def sweep_values(config: ExperimentConfig) -> list[Any]:
    """The values of the design's sweep, in case order (floats, or (tx, ty) pairs); ``[None]`` without one."""
    design = config.design
    if not isinstance(design, TreesDesign) or design.sweep is None:
        return [None]
    sweep = design.sweep
    values = sweep.values
    if values.list is not None:
        return [tuple(float(x) for x in v) if isinstance(v, tuple) else float(v) for v in values.list]
    if values.grid is not None:
        return grid_values(values.grid)
    rng = np.random.default_rng(derive_seed(config.seed, SWEEP_STREAM))
    low, high, count = values.uniform.low, values.uniform.high, values.uniform.count
    if sweep.corruption == "translate":
        draws = rng.uniform(low, high, size=(count, 2))
        return [(float(tx), float(ty)) for tx, ty in draws]
    return [float(v) for v in rng.uniform(low, high, size=count)]


# -- expansion --------------------------------------------------------------------------------------
def _sweep_fields(kind: str, value: Any) -> dict[str, Any]:
    if kind == "translate":
        tx, ty = value
        return {"tx_px": tx, "ty_px": ty, "shift_px": math.hypot(tx, ty)}
    if kind in ("missing", "blob", "catheter"):
        return {"count": int(value)}
    return {_SWEEP_COLUMNS[kind][0]: float(value)}


def expand_cases(config: ExperimentConfig) -> list[dict[str, Any]]:
    """Every case of an experiment as a parameter record (``case_id`` = position in the list).

    Cases of one tree are adjacent (tree-major order), so a worker's tree cache is reused.
    """
    generator = config.generator
    common = {
        "experiment": config.name,
        "design": config.design.type,
        "kind": generator.kind,
        "generator": {"rasteriser": generator.rasteriser, "sid_mm": generator.sid_mm, "sod_mm": generator.sod_mm,
                      "pixel_mm": generator.pixel_mm, "size": generator.size},
        "reconstruction": config.reconstruction.model_dump(mode="json"),
        "metrics": list(config.metrics),
    }
    fixed = [spec.to_dict() for spec in generator.corruption_specs()]
    design = config.design
    cases: list[dict[str, Any]] = []

    def add(tortuosity: str, tree_index: int, views: list[tuple[str, float, float]], *, corruptions=(),
            columns: Optional[dict[str, Any]] = None, view_ids: Optional[list[int]] = None, require_fit: bool,
            sweep: Optional[str] = None) -> None:
        cases.append({
            "case_id": len(cases), **common, "tortuosity": tortuosity, "tree_index": tree_index,
            "tree_seed": tree_seed(config.seed, generator.kind, tortuosity, tree_index),
            "views": [[name, float(p), float(s)] for name, p, s in views], "view_ids": view_ids,
            "corruptions": [*fixed, *corruptions], "sweep": sweep, "columns": dict(columns or {}),
            "require_fit": require_fit,
        })

    if isinstance(design, TreesDesign):
        views = parse_views(design.views)
        values = sweep_values(config)
        sweep = design.sweep
        n = design.trees
        for level in design.tortuosity:
            if sweep is None or design.paired_trees:
                order = [(i, j) for i in range(n) for j in range(len(values))]
            else:
                order = [(j * n + i, j) for j in range(len(values)) for i in range(n)]
            for tree_index, j in order:
                if sweep is None:
                    add(level, tree_index, views, require_fit=True)
                else:
                    value = values[j]
                    add(level, tree_index, views, corruptions=[sweep.spec(value).to_dict()],
                        columns=_sweep_fields(sweep.corruption, value), require_fit=True, sweep=sweep.corruption)
    elif isinstance(design, NViewsDesign):
        rng = np.random.default_rng(derive_seed(config.seed, DIRECTION_STREAM))
        table = [direction_angles(d) for d in sphere_directions(design.directions, rng)]
        for n_views in design.n_views.values():
            for selection in range(design.selections):
                pick = np.random.default_rng(derive_seed(config.seed, SELECTION_STREAM, n_views, selection))
                ids = sorted(int(i) for i in pick.choice(design.directions, size=n_views, replace=False))
                add(design.tortuosity, design.tree_index, [(f"d{i}", *table[i]) for i in ids], view_ids=ids,
                    require_fit=False)
    elif isinstance(design, AnglesDesign):
        for triplet in range(design.triplets):
            rng = np.random.default_rng(derive_seed(config.seed, TRIPLET_STREAM, triplet))
            angles = [direction_angles(d) for d in sphere_directions(3, rng)]
            add(design.tortuosity, 0 if design.same_tree else triplet,
                [(f"v{k}", p, s) for k, (p, s) in enumerate(angles)],
                columns={"sigma_min": angle_matrix_sigma_min(angles), "min_angle_deg": _min_line_angle_deg(angles)},
                require_fit=False)
    else:  # pragma: no cover - the config's union has three members
        raise AngiohullError(f"unknown design {design!r}")
    return cases


def row_columns(config: ExperimentConfig) -> list[str]:
    """The columns of the rows of an experiment, in file order."""
    columns = ["case_id", "tortuosity", "tree_index", "tree_seed", "n_views", "views"]
    design = config.design
    if isinstance(design, TreesDesign) and design.sweep is not None:
        columns += ["corruption", *_SWEEP_COLUMNS[design.sweep.corruption]]
    elif isinstance(design, NViewsDesign):
        columns += ["view_ids"]
    elif isinstance(design, AnglesDesign):
        columns += ["sigma_min", "min_angle_deg"]
    columns += [m for m in config.metrics if m != "time_s"]
    columns += ["n_points", "gt_outside_fraction", "status", "reason"]
    if "time_s" in config.metrics:
        columns += ["time_s"]
    return columns + ["case_s"]


# -- worker caches ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class _TreeAssets:
    phantom: Any  # TubePhantom
    ground_truth_mm: np.ndarray  # surface points, GT_SURFACE_SPACING_MM apart (as make_case)
    splat_mm: Optional[np.ndarray]  # the paper rasteriser's surface points, or None
    true_tree: VesselTree  # the generator's tree (centerlines with radii)


class _LRU:
    """A small thread-safe least-recently-used cache (values computed outside the lock)."""

    def __init__(self, size: int):
        self.size = size
        self.items: OrderedDict = OrderedDict()
        self.lock = threading.Lock()
        self.hits = self.misses = 0

    def get(self, key, make: Callable[[], Any]):
        with self.lock:
            if key in self.items:
                self.items.move_to_end(key)
                self.hits += 1
                return self.items[key]
            self.misses += 1
        value = make()
        with self.lock:
            self.items[key] = value
            self.items.move_to_end(key)
            while len(self.items) > self.size:
                self.items.popitem(last=False)
        return value

    def clear(self) -> None:
        with self.lock:
            self.items.clear()
            self.hits = self.misses = 0


_TREES = _LRU(8)
_MASKS = _LRU(4096)  # 4096 bit-packed 512x512 masks = 128 MiB at most


def clear_caches() -> None:
    """Empty this process's tree and mask caches (tests; results never depend on them)."""
    _TREES.clear()
    _MASKS.clear()


def _tree_assets(kind: str, tortuosity: str, seed: int, rasteriser: str) -> _TreeAssets:
    def make() -> _TreeAssets:
        tree_stream = np.random.SeedSequence(seed).spawn(2)[0]  # make_case's convention
        params = draw_tree_params(kind, tortuosity, np.random.default_rng(tree_stream))
        tree = build_tree(params.model_copy(update={"seed": seed}))
        splat = tree.phantom.surface_points_mm(PAPER_SURFACE_SPACING_MM) if rasteriser == "paper" else None
        return _TreeAssets(tree.phantom, tree.phantom.surface_points_mm(GT_SURFACE_SPACING_MM), splat,
                           tree.vessel_tree())

    return _TREES.get((kind, tortuosity, seed, rasteriser), make)


def _clean_mask(tree_key: tuple, assets: _TreeAssets, carm: CArmGeometry, rasteriser: str) -> np.ndarray:
    key = (tree_key, rasteriser, carm.primary_deg, carm.secondary_deg, carm.sid_mm, carm.sod_mm,
           carm.pixel_spacing_mm, carm.image_shape)

    def make():
        mask = render_mask(assets.phantom, carm.projection(), rasteriser, surface_points_mm=assets.splat_mm)
        return np.packbits(mask), mask.shape

    packed, shape = _MASKS.get(key, make)
    return np.unpackbits(packed, count=shape[0] * shape[1]).reshape(shape).astype(bool)


# -- one case ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CaseInputs:
    """What a case reconstructs and scores."""

    names: tuple[str, ...]
    carms: tuple[CArmGeometry, ...]
    projections: tuple[Projection, ...]
    clean_masks: tuple[np.ndarray, ...]
    masks: tuple[np.ndarray, ...]  # after the corruptions
    ground_truth_mm: np.ndarray
    corruptions: tuple[tuple[Any, ...], ...]  # per view, the records applied
    true_tree: Optional[VesselTree] = None  # the generator's tree


def case_inputs(params: dict[str, Any]) -> CaseInputs:
    """Build (or take from this worker's caches) the tree, render the views, draw and apply the corruptions."""
    g = params["generator"]
    kind, tortuosity, seed = params["kind"], params["tortuosity"], int(params["tree_seed"])
    assets = _tree_assets(kind, tortuosity, seed, g["rasteriser"])
    names, carms = [], []
    for name, primary, secondary in params["views"]:
        names.append(name)
        carms.append(CArmGeometry(primary_deg=primary, secondary_deg=secondary, sid_mm=g["sid_mm"], sod_mm=g["sod_mm"],
                                  pixel_spacing_mm=(g["pixel_mm"], g["pixel_mm"]), image_shape=(g["size"], g["size"])))
    tree_key = (kind, tortuosity, seed)
    clean = [_clean_mask(tree_key, assets, carm, g["rasteriser"]) for carm in carms]
    specs = [CorruptionSpec.from_dict(c) for c in params["corruptions"]]
    corruption_stream = np.random.SeedSequence(seed).spawn(2)[1]  # make_case's convention
    records = draw_corruptions(specs, clean, np.random.default_rng(corruption_stream)) if specs else [[] for _ in clean]
    masks = [apply_all(mask, recs) if recs else mask for mask, recs in zip(clean, records)]
    return CaseInputs(tuple(names), tuple(carms), tuple(c.projection() for c in carms), tuple(clean), tuple(masks),
                      assets.ground_truth_mm, tuple(tuple(r) for r in records), assets.true_tree)


def _fit_problem(ground_truth: np.ndarray, projections: Sequence[Projection]) -> tuple[Optional[str], float]:
    """(make_case's objection to the tree, or None; fraction of GT points outside some view's image)."""
    problem, outside = fit_problem(ground_truth, projections)
    return problem, float(outside.mean()) if len(outside) else 0.0


def _base_row(params: dict[str, Any]) -> dict[str, Any]:
    row = {
        "case_id": params["case_id"], "tortuosity": params["tortuosity"], "tree_index": params["tree_index"],
        "tree_seed": params["tree_seed"], "n_views": len(params["views"]),
        "views": ";".join(format_clinical_angles(p, s) for _, p, s in params["views"]),
    }
    if params.get("view_ids") is not None:
        row["view_ids"] = ";".join(str(i) for i in params["view_ids"])
    if params.get("sweep") is not None:
        row["corruption"] = params["sweep"]
    row.update(params["columns"])
    for metric in params["metrics"]:
        row[metric] = math.nan
    row.update({"n_points": 0, "gt_outside_fraction": math.nan, "status": "ok", "reason": ""})
    return row


def run_case(params: dict[str, Any]) -> dict[str, Any]:
    """Generate, reconstruct and score one case; never raises for a case-level problem.

    Returns
    -------
    dict
        The row: the case's parameters that vary (tree, views, sweep value), the metrics in percent
        and mm, ``n_points``, ``gt_outside_fraction``, ``status`` (:data:`STATUSES`), ``reason``
        (empty when ``ok``), ``time_s`` (reconstruction alone, when asked for) and ``case_s`` (the
        whole case: generation, reconstruction, metrics).
    """
    start = time.perf_counter()
    row = _base_row(params)
    try:
        _score_case(params, row)
    except AngiohullError as exc:
        row["status"], row["reason"] = "failed", _one_line(str(exc))
    except Exception as exc:  # noqa: BLE001 - a case must become a row, whatever happened
        row["status"], row["reason"] = "error", _one_line(f"{type(exc).__name__}: {exc}")
    if row["status"] in ("failed", "error"):
        for metric in params["metrics"]:
            row[metric] = math.nan
    row["case_s"] = time.perf_counter() - start
    return row


def _one_line(text: str, limit: int = 300) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _score_case(params: dict[str, Any], row: dict[str, Any]) -> None:
    inputs = case_inputs(params)
    problem, outside = _fit_problem(inputs.ground_truth_mm, inputs.projections)
    row["gt_outside_fraction"] = outside
    if problem is not None and params["require_fit"]:
        raise AngiohullError(problem)
    for name, mask in zip(inputs.names, inputs.masks):
        if not mask.any():
            raise AngiohullError(f"view {name}: the corruptions erased every vessel pixel")
    options = params["reconstruction"]
    tree_metrics = [m for m in params["metrics"] if m in TREE_METRICS]
    projections = list(inputs.projections)
    if options.get("calibrate"):
        projections = calibrate_shifts(projections, list(inputs.masks), threshold_px=options["threshold_px"],
                                       estimate_scale=bool(options.get("calibrate_scale"))).corrected(projections)
    result = reconstruct(projections, list(inputs.masks), resolution=options["resolution"],
                         threshold_px=options["threshold_px"], engine=options["engine"], centerlines=False,
                         view_names=inputs.names, allow_empty=True, preset=options.get("preset", "paper"),
                         min_views=options.get("min_views"), tree=bool(tree_metrics),
                         method=options.get("method", "hull"), warn=False)  # the design means its views
    points = result.vessel_points_mm
    metrics = params["metrics"]
    row["n_points"] = int(len(points))
    if len(points) == 0:
        step = next((i for i, n in enumerate(result.survivors_per_view) if n == 0), None)
        row["status"] = "empty"
        if step is None:
            row["reason"] = "empty reconstruction after the refined preset's filtering or k-of-N carving"
        else:
            view = result.view_order[step]
            row["reason"] = f"empty visual hull: view {view} ({inputs.names[view]}) removed the last points"
    if {"dice3d", "iou3d", "chamfer_mm"} & set(metrics):
        s3 = scores_3d(points, inputs.ground_truth_mm)
        for name in ("dice3d", "iou3d", "chamfer_mm"):
            if name in metrics:
                row[name] = getattr(s3, name)
    if "dice2d_paper" in metrics:
        spacing = params["generator"]["pixel_mm"]
        row["dice2d_paper"] = float(np.mean(dice2d_paper(points, projections, inputs.masks,
                                                         detector_spacings_mm=[spacing] * len(inputs.masks))))
    if "dice2d" in metrics:
        row["dice2d"] = float(np.mean(dice2d_plain(points, projections, inputs.masks,
                                                   cell_mm=result.lattice_spacing_mm)))
    if "time_s" in metrics:
        row["time_s"] = result.time_s
    if tree_metrics and result.tree is not None:
        from ..metrics.tree import tree_scores

        scores = tree_scores(result.tree, inputs.true_tree).as_dict()
        for name in tree_metrics:
            row[name] = scores[name]
    elif tree_metrics and result.tree_error and row["status"] == "ok":
        row["reason"] = _one_line(f"no vessel tree: {result.tree_error}")
