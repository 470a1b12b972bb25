"""A synthetic study: a drawn tree, its masks in chosen views, corruptions, and the ground truth.

:func:`make_case` does the work in memory (seeded, replayable); :func:`write_case` writes a study
folder (docs/conventions.md format) plus the ground truth and the records that replay it:

=======================  ==========================================================================
``study.yaml``, masks/   the study, as any other (views as ``carm:``), ``ground_truth: gt.npy``,
                         ``ground_truth_tree: gt_centerlines.npz``
``gt.npy``               points on the tube surface, mm (the paper's ground truth after voxelising)
``gt_lumen.npy``         grid points (0.5 mm) inside the lumen, mm
``gt_centerlines.npz``   per branch an (M, 4) array ``x, y, z, radius`` (mm) under its name, plus
                         ``branch_names``, ``parents`` (-1 for a root) and ``origin_vertices``
``tree.json``            the :class:`~angiohull.synthetic.tree.TreeParams` record
``synthetic.json``       the options, the seed, the views, every corruption record with the number of
                         pixels it changed, and measured facts of the tree (lengths, tortuosity)
=======================  ==========================================================================
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from .. import __version__
from .. import _validation as _v
from ..errors import AngiohullError
from ..geometry import CArmGeometry, Projection, cube_half_edge_mm
from ..study import View, save_study
from .corruptions import CorruptionSpec, apply_all, corruption_from_dict, draw_corruptions, parse_corruption
from .render import PAPER_SURFACE_SPACING_MM, RASTERISERS, render_mask
from .tree import TORTUOSITY_LEVELS, TREE_KINDS, CoronaryTree, TreeParams, build_tree, draw_tree_params
from .views import carm_views

__all__ = ["SynthOptions", "SyntheticCase", "make_case", "write_case", "read_case_record", "replay_case", "fit_problem",
           "GT_SURFACE_SPACING_MM", "GT_LUMEN_SPACING_MM", "MAX_DETECTOR_PX"]

GT_SURFACE_SPACING_MM = 0.3
"""Spacing of the ground-truth surface points (``gt.npy``), mm: ten per 3 mm voxel edge."""
GT_LUMEN_SPACING_MM = 0.5
"""Grid step of the ground-truth lumen points (``gt_lumen.npy``), mm."""
MAX_DETECTOR_PX = 8192
"""Largest detector (rows = columns) of a synthetic study: flat-panel detectors have 1024-2048
pixels a side, and an 8192 x 8192 mask already takes 64 MiB per view (100000 asked for 9.3 GiB)."""


@dataclass(frozen=True)
class SynthOptions:
    """Everything ``angiohull synth`` asks for (defaults: the paper's geometry, clinical views)."""

    kind: str = "rca"  # "rca" or "left"
    tortuosity: str = "moderate"  # "simple", "moderate" or "tortuous"
    views: str | tuple[str, ...] = "clinical"  # "perpendicular", "clinical", or clinical angle strings
    sid_mm: float = 1200.0
    sod_mm: float = 800.0
    pixel_mm: float = 0.35  # detector pixel spacing (square pixels)
    size: int = 512  # detector rows = cols
    rasteriser: str = "exact"  # "exact" silhouette or the paper's "paper" rasteriser
    corruptions: tuple[CorruptionSpec, ...] = ()
    seed: Optional[int] = None  # None: fresh entropy, recorded so the case can be replayed

    def __post_init__(self) -> None:
        if self.kind not in TREE_KINDS:
            raise AngiohullError(f"tree must be one of {', '.join(TREE_KINDS)}, got {self.kind!r}")
        if self.tortuosity not in TORTUOSITY_LEVELS:
            raise AngiohullError(f"tortuosity must be one of {', '.join(TORTUOSITY_LEVELS)}, got {self.tortuosity!r}")
        if self.rasteriser not in RASTERISERS:
            raise AngiohullError(f"rasteriser must be one of {', '.join(RASTERISERS)}, got {self.rasteriser!r}")
        for name in ("sid_mm", "sod_mm", "pixel_mm"):
            object.__setattr__(self, name, _v.positive_finite(getattr(self, name), name))
        object.__setattr__(self, "size", _v.positive_int(self.size, "size"))
        if self.size > MAX_DETECTOR_PX:
            raise AngiohullError(f"size (detector rows = columns, --size) must be at most {MAX_DETECTOR_PX} pixels, got "
                                 f"{self.size}: real detectors have 1024-2048, and each view's mask takes size**2 "
                                 f"bytes ({self.size ** 2 / 2 ** 30:.1f} GiB here)")
        if self.sod_mm >= self.sid_mm:
            raise AngiohullError(f"sod_mm must be smaller than sid_mm, got sod_mm={self.sod_mm} >= sid_mm={self.sid_mm}")
        specs = tuple(parse_corruption(c) if isinstance(c, str) else c for c in self.corruptions)
        for spec in specs:
            if not isinstance(spec, CorruptionSpec):
                raise AngiohullError(f"corruptions must be CorruptionSpec or 'kind=values' strings, got {spec!r}")
        object.__setattr__(self, "corruptions", specs)
        if self.seed is not None:
            if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
                raise AngiohullError(f"seed must be a non-negative integer, got {self.seed!r}")
            object.__setattr__(self, "seed", int(self.seed))
        self.geometries()  # validate the views now

    def geometries(self) -> list[tuple[str, CArmGeometry]]:
        return carm_views(self.views, sid_mm=self.sid_mm, sod_mm=self.sod_mm, pixel_mm=self.pixel_mm, size=self.size)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "tortuosity": self.tortuosity,
                "views": self.views if isinstance(self.views, str) else list(self.views),
                "sid_mm": self.sid_mm, "sod_mm": self.sod_mm, "pixel_mm": self.pixel_mm, "size": self.size,
                "rasteriser": self.rasteriser,
                "corruptions": [c.to_dict() for c in self.corruptions],
                "seed": self.seed}


@dataclass(frozen=True, eq=False)
class SyntheticCase:
    """One generated study in memory."""

    options: SynthOptions
    seed: int  # the seed actually used (options.seed, or the drawn one)
    tree: CoronaryTree
    views: tuple[View, ...]  # with the corrupted masks
    clean_masks: tuple[np.ndarray, ...]  # before corruption
    corruptions: tuple[tuple[Any, ...], ...]  # per view, the records applied in order
    changed_pixels: tuple[tuple[int, ...], ...]  # per view and record, pixels it changed
    surface_points_mm: np.ndarray = field(repr=False)  # ground truth, GT_SURFACE_SPACING_MM apart

    def record(self) -> dict[str, Any]:
        """The JSON document ``synthetic.json``."""
        return {
            "angiohull_synthetic": 1,
            "angiohull_version": __version__,
            "seed": self.seed,
            "options": self.options.to_dict(),
            "views": [{"name": v.name, "primary_deg": v.carm.primary_deg, "secondary_deg": v.carm.secondary_deg,
                       "clinical": v.carm.clinical_name(), "vessel_pixels": int(v.mask.sum()),
                       "clean_vessel_pixels": int(m.sum())}
                      for v, m in zip(self.views, self.clean_masks)],
            "corruptions": [{"view": v.name, "records": [c.to_dict() for c in records], "changed_pixels": list(changed)}
                            for v, records, changed in zip(self.views, self.corruptions, self.changed_pixels)],
            "ground_truth": {"surface_spacing_mm": GT_SURFACE_SPACING_MM, "lumen_spacing_mm": GT_LUMEN_SPACING_MM,
                             "n_surface_points": int(len(self.surface_points_mm))},
            "tree": self.tree.summary(),
        }


def fit_problem(surface_mm: np.ndarray, projections: Sequence[Projection],
                names: Sequence[str] | None = None) -> tuple[str | None, np.ndarray]:
    """Whether a tree fits the views: inside the cube of interest and inside every view's image.

    Returns
    -------
    problem : str or None
        Why it does not fit (the cube, else the first view an image point falls outside of), or None.
    outside : (N,) bool array
        Surface points that project outside some view's image.
    """
    names = list(names) if names is not None else [f"view{i}" for i in range(len(projections))]
    outside = np.zeros(len(surface_mm), dtype=bool)
    problem = None
    for name, projection in zip(names, projections):
        uv = projection.project(surface_mm)
        rows, cols = projection.image_shape
        here = (uv[:, 0] < 0) | (uv[:, 0] > cols - 1) | (uv[:, 1] < 0) | (uv[:, 1] > rows - 1)
        if problem is None and here.any():
            problem = (f"view {name}: {int(here.sum())} surface point(s) of the tree project outside the "
                       f"{rows}x{cols} image; use a larger detector (--size, --pixel-mm)")
        outside |= here
    half = cube_half_edge_mm(projections)
    reach = float(np.abs(surface_mm).max()) if len(surface_mm) else 0.0
    if reach >= half:
        problem = (f"the tree reaches {reach:.1f} mm from the isocentre but the cube of interest of these views is "
                   f"only ±{half:.1f} mm; use a larger detector (--size, --pixel-mm) or a smaller magnification "
                   f"(--sid-mm/--sod-mm)")
    return problem, outside


def _clean_masks(tree: CoronaryTree, options: SynthOptions,
                 geometries: Sequence[tuple[str, CArmGeometry]]) -> list[np.ndarray]:
    """The tree's masks in the views, before any corruption."""
    splat = tree.phantom.surface_points_mm(PAPER_SURFACE_SPACING_MM) if options.rasteriser == "paper" else None
    return [render_mask(tree.phantom, g.projection(), options.rasteriser, surface_points_mm=splat) for _, g in geometries]


def make_case(options: SynthOptions = SynthOptions(), *, tree_params: TreeParams | None = None) -> SyntheticCase:
    """Draw (or take) a tree, render its masks, draw and apply the corruptions.

    Parameters
    ----------
    options : SynthOptions
    tree_params : TreeParams, optional
        Use this tree instead of drawing one (its kind and tortuosity win over the options').

    Returns
    -------
    SyntheticCase

    Notes
    -----
    Randomness: ``SeedSequence(seed).spawn(2)`` gives one stream for the tree and one for the
    corruptions, so adding a corruption never changes the tree of a seed.
    """
    seed = options.seed if options.seed is not None else int(np.random.SeedSequence().generate_state(1, np.uint64)[0] >> 1)
    tree_seq, corruption_seq = np.random.SeedSequence(seed).spawn(2)
    if tree_params is None:
        tree_params = draw_tree_params(options.kind, options.tortuosity, np.random.default_rng(tree_seq))
        tree_params = tree_params.model_copy(update={"seed": seed})
    tree = build_tree(tree_params)
    geometries = options.geometries()
    surface = tree.phantom.surface_points_mm(GT_SURFACE_SPACING_MM)
    problem, _ = fit_problem(surface, [g.projection() for _, g in geometries], [name for name, _ in geometries])
    if problem is not None:
        raise AngiohullError(problem)
    clean = _clean_masks(tree, options, geometries)
    records = draw_corruptions(options.corruptions, clean, np.random.default_rng(corruption_seq))
    views, changed = [], []
    for (name, geometry), mask, view_records in zip(geometries, clean, records):
        current, counts = mask, []
        for record in view_records:
            after = record.apply(current)
            counts.append(int(np.count_nonzero(after != current)))
            current = after
        changed.append(tuple(counts))
        if not mask.any():  # before any corruption: the detector is too coarse (or small) for the vessels
            rows, cols = geometry.image_shape
            raise AngiohullError(f"view {name}: the tree draws no vessel pixel on a detector of {rows} x {cols} pixels "
                                 f"of {geometry.pixel_spacing_mm[0]:g} x {geometry.pixel_spacing_mm[1]:g} mm: use "
                                 f"smaller pixels or more of them")
        if not current.any():
            raise AngiohullError(f"view {name}: the corruptions erased all {int(np.count_nonzero(mask))} vessel pixels; "
                                 f"every view needs some left: use fewer or milder corruptions (e.g. a smaller N in "
                                 f"missing=N, or a smaller p in fn=P)")
        views.append(View.from_carm(name, current, geometry))
    return SyntheticCase(options, seed, tree, tuple(views), tuple(clean), tuple(tuple(r) for r in records),
                         tuple(changed), surface)


def write_case(folder: str | Path, case: SyntheticCase) -> Path:
    """Write the study folder of a case (see the module docstring); returns the ``study.yaml`` path."""
    folder = Path(folder)
    yaml_path = save_study(folder, case.views, ground_truth_mm=case.surface_points_mm,
                           ground_truth_tree_file="gt_centerlines.npz")
    np.save(folder / "gt_lumen.npy", case.tree.phantom.lumen_points_mm(GT_LUMEN_SPACING_MM), allow_pickle=False)
    centerlines = case.tree.centerlines()
    np.savez(folder / "gt_centerlines.npz", branch_names=np.array([b.name for b in case.tree.branches]),
             parents=np.array([-1 if b.parent is None else b.parent for b in case.tree.branches]),
             origin_vertices=np.array([-1 if b.origin_vertex is None else b.origin_vertex for b in case.tree.branches]),
             **centerlines)
    (folder / "tree.json").write_text(case.tree.params.to_json() + "\n", encoding="utf-8")
    (folder / "synthetic.json").write_text(json.dumps(case.record(), indent=1) + "\n", encoding="utf-8")
    return yaml_path


def read_case_record(folder: str | Path) -> tuple[TreeParams, dict[str, Any]]:
    """The tree record and ``synthetic.json`` of a written case."""
    folder = Path(folder)
    try:
        tree_text = (folder / "tree.json").read_text(encoding="utf-8")
        record = json.loads((folder / "synthetic.json").read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise AngiohullError(f"{folder}: not a synthetic case folder ({exc})") from None
    return TreeParams.from_json(tree_text, str(folder / "tree.json")), record


def replay_case(folder: str | Path) -> SyntheticCase:
    """Rebuild a written case from its records alone (tree record + corruption records), no RNG.

    The masks of the returned case equal the ones on disk; this is how any case is replayed.
    """
    params, record = read_case_record(folder)
    opts = record["options"]
    specs = tuple(CorruptionSpec.from_dict(c) for c in opts["corruptions"])
    options = SynthOptions(kind=opts["kind"], tortuosity=opts["tortuosity"],
                           views=opts["views"] if isinstance(opts["views"], str) else tuple(opts["views"]),
                           sid_mm=opts["sid_mm"], sod_mm=opts["sod_mm"], pixel_mm=opts["pixel_mm"], size=opts["size"],
                           rasteriser=opts["rasteriser"], corruptions=specs, seed=record["seed"])
    tree = build_tree(params)
    geometries = options.geometries()
    clean = _clean_masks(tree, options, geometries)
    per_view = [[corruption_from_dict(c) for c in entry["records"]] for entry in record["corruptions"]]
    views = [View.from_carm(name, apply_all(mask, recs), g) for (name, g), mask, recs in zip(geometries, clean, per_view)]
    changed = tuple(tuple(entry["changed_pixels"]) for entry in record["corruptions"])
    return SyntheticCase(options, record["seed"], tree, tuple(views), tuple(clean), tuple(tuple(r) for r in per_view),
                         changed, tree.phantom.surface_points_mm(GT_SURFACE_SPACING_MM))
