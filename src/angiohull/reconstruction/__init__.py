"""Visual-hull reconstruction from binary masks and projections (arrays in, arrays out).

The single entry point is :func:`reconstruct`. Nothing in this package reads or writes files.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .. import _validation as _v
from .. import options
from ..errors import EmptyHullError, ReconstructionError
from ..geometry import Projection, cube_half_edge_mm
from ..tree import VesselTree
from .centerlines import extract_centerlines, skeletonise
from .cube import MAX_DENSE_RESOLUTION, Lattice
from .engines import ENGINES, CarveOutcome
from . import hierarchical  # noqa: F401  (registers the lookup and octree engines)
from .gpu import CUDA_ENGINES, carve_cuda
from .refine import (REFINED, clean_mask, refine_hull, with_small_holes_filled, without_salt,
                     without_small_components)
from .vessel_tree import TreeBuild, checked_occupancy, hull_tree

__all__ = [
    "reconstruct",
    "view_order_agreement",
    "ReconstructionResult",
    "Lattice",
    "ENGINES",
    "CarveOutcome",
    "extract_centerlines",
    "skeletonise",
    "DEFAULT_RESOLUTION",
    "DEFAULT_THRESHOLD_PX",
    "AUTO_ENGINE",
    "ENGINE_CHOICES",
    "PRESETS",
    "METHODS",
    "MAX_DENSE_RESOLUTION",
    "MAX_THRESHOLD_PX",
    "check_threshold_px",
    "hull_tree",
    "TreeBuild",
]

# names and defaults, defined in angiohull.options (importable without NumPy, for the command line)
DEFAULT_RESOLUTION = options.DEFAULT_RESOLUTION
DEFAULT_THRESHOLD_PX = options.DEFAULT_THRESHOLD_PX
AUTO_ENGINE = options.AUTO_ENGINE
ENGINE_CHOICES = options.ENGINE_CHOICES
PRESETS = options.PRESETS
METHODS = options.METHODS
MAX_THRESHOLD_PX = 32.0
"""Largest distance threshold accepted, pixels. Vessels in an angiogram are 2-20 px wide, so a
point farther than this from every vessel pixel is not near a vessel; and the exact engines read
every pixel within the threshold of each point, a work that grows with its square (at K = 100 on
the demo: 0.8 s at 16 px, 8 s at 32 px, 135 s at 64 px; 300 px ran for hours, 1e5 px asked for
149 GiB)."""


def check_threshold_px(value: object, name: str = "threshold_px") -> float:
    """``value`` as a float if it is a finite number in (0, :data:`MAX_THRESHOLD_PX`], else a
    :class:`ReconstructionError` naming ``name``, the value, the bound and why."""
    threshold = _v.positive_finite(value, name, error=ReconstructionError)
    if threshold > MAX_THRESHOLD_PX:
        raise ReconstructionError(
            f"{name} must be at most {MAX_THRESHOLD_PX:g} px, got {value!r}: vessels are 2-20 px wide, so a point "
            f"farther than {MAX_THRESHOLD_PX:g} px from every vessel pixel is not near a vessel, and the carving's "
            f"work grows with the threshold's square (the paper uses 1 px)")
    return threshold


@dataclass(frozen=True)
class ReconstructionResult:
    """Output of :func:`reconstruct`."""

    vessel_points_mm: np.ndarray  # (N, 3) kept lattice points, mm
    centerline_points_mm: np.ndarray | None  # (M, 3) centerline points, mm; None when not requested
    lattice: Lattice  # the cube of interest that was carved
    engine: str  # name of the carving engine
    device: str  # "cpu" or "cuda"
    threshold_px: float  # distance threshold, px (strict)
    view_names: tuple[str, ...]  # names of the views, as given
    survivors_per_view: tuple[int, ...]  # points alive after each view, in the order applied (min_views: kept points each view supports)
    view_order: tuple[int, ...]  # indices of the views in the order the engine applied them
    min_views: int | None = None  # robust carving: views that must keep a point (None: all, the paper)
    preset: str = "paper"  # "paper" (as published) or "refined" (see reconstruction.refine)
    # seconds per stage: cube, carve, refine, centerlines, tree, reconstruction; checks (reconstruct's warn)
    timings_s: dict[str, float] = field(default_factory=dict)
    tree: VesselTree | None = None  # the vessel tree (centerlines with radii); None when not requested or not built
    tree_build: TreeBuild | None = None  # how the tree was built (skeleton parts, views' coverage, timings)
    tree_error: str | None = None  # why no tree could be built, when one was requested
    method: str = "hull"  # "hull" (the paper's visual hull) or "tree" (reconstruction.model)
    model_build: object | None = None  # the tree method's record (reconstruction.model.ModelBuild)

    @property
    def lattice_spacing_mm(self) -> float:
        """Distance between neighbouring lattice points, mm."""
        return self.lattice.spacing_mm

    @property
    def time_s(self) -> float:
        """Time of the vessel reconstruction alone (cube of interest + carving, + refinement with the
        refined preset), seconds."""
        return self.timings_s["reconstruction"]


def _as_list(views, what: str) -> list:
    """``views`` (any iterable, one item per view: a generator has no len()) as a list; a single
    projection or mask given alone is said to be so."""
    if isinstance(views, Projection) or (isinstance(views, np.ndarray) and views.ndim == 2 and views.dtype != object):
        raise ReconstructionError(f"{what} must be a sequence with one item per view, got a single "
                                  f"{type(views).__name__}; wrap it in a list")
    try:
        return list(views)
    except TypeError:
        raise ReconstructionError(f"{what} must be a sequence with one item per view, got "
                                  f"{type(views).__name__}") from None


def _check_inputs(projections: Sequence[Projection], masks: Sequence[np.ndarray],
                  view_names: Sequence[str] | None) -> tuple[list[np.ndarray], tuple[str, ...]]:
    if len(projections) == 0:
        raise ReconstructionError("reconstruction needs at least one view, got none")
    if len(masks) != len(projections):
        raise ReconstructionError(f"got {len(projections)} projections but {len(masks)} masks; give one mask per view")
    names = tuple(view_names) if view_names is not None else tuple(f"view{i}" for i in range(len(projections)))
    if len(names) != len(projections):
        raise ReconstructionError(f"got {len(names)} view names for {len(projections)} views")
    checked = []
    for i, (projection, mask, name) in enumerate(zip(projections, masks, names)):
        if not isinstance(projection, Projection):
            raise ReconstructionError(f"view {i} ({name!r}): expected a Projection, got {type(projection).__name__}")
        array = np.asarray(mask)
        if array.ndim != 2:
            raise ReconstructionError(f"view {i} ({name!r}): mask must be a 2D (rows, cols) array, got shape {array.shape}")
        if array.shape != projection.image_shape:
            raise ReconstructionError(
                f"view {i} ({name!r}): mask shape {array.shape} differs from the projection's image shape "
                f"{projection.image_shape} (rows, cols)"
            )
        if not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
            raise ReconstructionError(f"view {i} ({name!r}): mask must be numeric or bool (nonzero = vessel), "
                                      f"got dtype {array.dtype}")
        if np.issubdtype(array.dtype, np.inexact) and not np.isfinite(array).all():
            raise ReconstructionError(f"view {i} ({name!r}): mask holds {int((~np.isfinite(array)).sum())} non-finite "
                                      f"values (NaN or infinity); give a binary mask (nonzero = vessel)")
        array = array.astype(bool, copy=False)
        if not array.any():
            raise ReconstructionError(f"view {i} ({name!r}): mask is empty (no vessel pixel); nothing can be reconstructed")
        checked.append(array)
    return checked, names


def _checked_carving(threshold_px: float, engine: str, device: str) -> tuple[float, str]:
    """The threshold and the engine's name (``auto`` resolved), or a :class:`ReconstructionError`
    naming the bad option."""
    threshold = check_threshold_px(threshold_px)
    if engine not in ENGINE_CHOICES:
        raise ReconstructionError(f"unknown engine {engine!r}; choose one of {list(ENGINE_CHOICES)}")
    engine = AUTO_ENGINE if engine == "auto" else engine
    if device not in ("cpu", "cuda"):
        raise ReconstructionError(f"unknown device {device!r}; choose 'cpu' or 'cuda'")
    if device == "cuda" and engine not in CUDA_ENGINES:
        raise ReconstructionError(f"engine {engine!r} runs on the CPU only; with device='cuda' use one of {list(CUDA_ENGINES)}")
    return threshold, engine


_COARSE_LATTICE_MM = 2.0  # an empty hull's error names the lattice when its points lie farther apart than this


def _empty_hull_error(outcome: CarveOutcome, names: tuple[str, ...], lattice: Lattice) -> EmptyHullError:
    order = outcome.order if outcome.order is not None else tuple(range(len(names)))
    counts = (lattice.n_points,) + outcome.survivors_per_view
    step = next(i for i, n in enumerate(outcome.survivors_per_view) if n == 0)
    view = order[step]
    applied = ", ".join(f"{names[i]}: {n}" for i, n in zip(order, outcome.survivors_per_view))
    coarse = (f" The lattice is coarse: its points lie {lattice.spacing_mm:.1f} mm apart (resolution "
              f"{lattice.resolution}), and a vessel a millimetre or two wide falls between them; a finer "
              f"resolution keeps it." if lattice.spacing_mm > _COARSE_LATTICE_MM else "")
    return EmptyHullError(
        f"the visual hull is empty: view {view} ({names[view]!r}) removed the last {counts[step]} points "
        f"(survivors after each view, in the order applied: {applied}). The views do not agree on any "
        f"point: check the calibration (angles, SID/SOD, pixel spacing, image shifts) and that the masks "
        f"show the same vessels; a larger threshold_px tolerates small misalignments.{coarse}",
        view_index=view, view_name=names[view], points_before=counts[step],
    )


def reconstruct(projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                resolution: int | None = None, threshold_px: float = DEFAULT_THRESHOLD_PX,
                engine: str = "auto", centerlines: bool = True, view_names: Sequence[str] | None = None,
                half_edge_mm: float | None = None, allow_empty: bool = False, device: str = "cpu",
                min_views: int | None = None, preset: str | None = None, tree: bool = True, method: str | None = None,
                progress: Callable[[str], None] | None = None, warn: bool = True) -> ReconstructionResult:
    """Reconstruct the vessels from the views: the tree method by default (``method``), or the
    visual hull of the masks (the paper's method) with, optionally, its centerline points and tree.

    Parameters
    ----------
    projections : sequence of Projection
        One per view, applied in this order.
    masks : sequence of (rows, cols) arrays
        Nonzero = vessel (bool or numeric, every value finite: NaN or infinity is refused, as
        :func:`angiohull.io.read_mask` refuses it in a file); shape must equal the projection's
        ``image_shape``.
    resolution : int, optional, keyword-only
        K, lattice points per axis of the cube of interest (default: the preset's, 100 for
        ``"paper"`` as in the paper, 256 for ``"refined"`` and the tree method).
    threshold_px : float, keyword-only
        A point survives a view when its projection is strictly closer than this to a mask pixel
        centre (default 1.0; at most :data:`MAX_THRESHOLD_PX`).
    engine : str, keyword-only
        ``"auto"`` (default: the fastest exact engine, :data:`AUTO_ENGINE`), ``"kdtree"`` (the
        paper's reference), ``"lookup"`` or ``"octree"``; all keep exactly the same points.
    centerlines : bool, keyword-only
        Also extract centerline points (Guo–Hall skeletons).
    view_names : sequence of str, optional
        Used in messages and the result.
    half_edge_mm : float, optional
        Override of the cube's half-edge R (default: from the views, docs/conventions.md step 2).
    allow_empty : bool, keyword-only
        Return an empty result instead of raising :class:`EmptyHullError`.
    device : {"cpu", "cuda"}, keyword-only
        Where the ``lookup`` / ``octree`` engines run; ``"cuda"`` needs CuPy and a CUDA GPU
        (``pip install 'angiohull[gpu]'``) and keeps exactly the CPU's points. It pays from about
        K = 512 on (see docs/engines.md).
    min_views : int, optional, keyword-only
        Robust carving (beyond the paper): keep a point when at least this many views keep it, so
        that a view with a false-negative segmentation or a missing segment does not carve the
        vessel away. Default None: every view must keep it (the paper's rule). A hull option:
        given without ``method``, it picks the hull.
    preset : {"paper", "refined"}, optional, keyword-only
        How the hull is carved (a hull option: given without ``method``, it picks the hull).
        ``"paper"`` (the hull's default): the method as published. ``"refined"`` (beyond the paper,
        see :mod:`.refine`): specks removed from the masks, a finer lattice, small disconnected
        parts dropped and the hull trimmed to the vessel radii the views show.
    method : {"hull", "tree"}, optional, keyword-only
        ``"tree"`` (the default when no hull option is given, :func:`angiohull.options.chosen_method`;
        beyond the paper, :mod:`.model`): the hull of the views is carved on the lattice (default
        K = 256), then the vessel tree is built from centerline correspondences across the views
        (with three views or more, from the refined hull's skeleton) and tubes fitted to the masks;
        the vessel points are the lattice points inside those tubes, the centerline points the
        tree's. Needs two views or more; ``preset`` (but ``"paper"``), ``min_views`` and ``tree``
        do not apply (the tree is the result). ``"hull"``: the visual hull of ``preset``, the
        paper's method (the default until 2026-12-07; docs/results/tree-method.md compares them).
    progress : callable, optional, keyword-only
        Called with a line per stage of the tree method.
    tree : bool, keyword-only
        Also build the vessel tree (:func:`.vessel_tree.hull_tree`: the hull's skeleton, centres
        and radii fitted to the views; ``result.tree``). When no tree can be built (a hull too
        small for a skeleton), ``result.tree`` is None and ``result.tree_error`` says why. The
        hull's option: ``tree=False`` without ``method`` picks the hull (the tree method's result
        is its tree).
    warn : bool, keyword-only
        Check the inputs first and give a warning for each problem found (:mod:`.checks`; default
        True): a mask that is mostly vessel, one view, views that look along nearly one line (under
        25 degrees), views that disagree (the paper's hull of all views covers under 95 % of a
        view's mask: a geometry off by pixels, or masks of other vessels) and, with two views,
        masks whose epipolar planes agree only with one view moved by 2 px or more (a geometry
        off by pixels, which the hull's coverage hardly sees with two views) and vessel cut off
        by an image's edge. The agreement checks carve a hull and bin the masks' epipolar planes
        (0.08-0.13 s for two 512 x 512 views, 2026-12-07; ``timings_s["checks"]``, not in ``"total"``).
        ``warn=False`` skips them (experiments that mean such inputs, timing benchmarks).

    Returns
    -------
    ReconstructionResult

    Warns
    -----
    angiohull.errors.InputWarning, angiohull.errors.AgreementWarning
        With ``warn``, for each problem the checks find (each says what and what to do).
    """
    projections, masks = _as_list(projections, "projections"), _as_list(masks, "masks")
    if progress is not None and not callable(progress):
        raise ReconstructionError(f"progress must be a function of one str (or None), got {type(progress).__name__}")
    if view_names is not None:
        names_given = view_names if isinstance(view_names, (str, bytes)) else list(view_names)
        if isinstance(names_given, (str, bytes)) or not all(isinstance(name, str) for name in names_given):
            raise ReconstructionError(f"view_names must be a sequence of str, one per view, got {view_names!r}")
        view_names = names_given
    checked_masks, names = _check_inputs(projections, masks, view_names)
    method = options.chosen_method(method, preset, min_views, tree)
    preset = "paper" if preset is None else preset
    if method not in METHODS:
        raise ReconstructionError(f"unknown method {method!r}; choose one of {list(METHODS)}")
    checks_s = _warn_about_inputs(projections, checked_masks, names, threshold_px, method) if warn else None
    if method == "tree":
        result = _reconstruct_tree(projections, checked_masks, names, resolution=resolution, threshold_px=threshold_px,
                                   engine=engine, centerlines=centerlines, half_edge_mm=half_edge_mm, device=device,
                                   min_views=min_views, preset=preset, progress=progress, allow_empty=allow_empty)
    else:
        result = _reconstruct_hull(projections, checked_masks, names, resolution=resolution,
                                   threshold_px=threshold_px, engine=engine, centerlines=centerlines,
                                   half_edge_mm=half_edge_mm, device=device, min_views=min_views, preset=preset,
                                   tree=tree, allow_empty=allow_empty)
    if checks_s is not None:
        result.timings_s["checks"] = checks_s
    return result


def view_order_agreement(projections: Sequence[Projection], masks: Sequence[np.ndarray],
                         result: ReconstructionResult) -> tuple[float, float | None]:
    """Two views: how well the tree method's own trees agree with the masks as given (from
    ``result``, their reconstruction with ``method="tree"``) and with the two masks swapped between
    the views (each read with the other view's projection; built here as ``result`` was: its
    lattice, threshold, engine and device), as
    :attr:`~.model.ModelBuild.mask_agreement` gives it: the mean Dice over the views of a tree's
    silhouettes and the masks, the best over its matchings, before the hypotheses of a wrong pairing
    (which the swapped build skips: they come after this agreement, so the two compare alike).

    Two views' masks of one tree cover nearly the same epipolar planes either way round, so the
    input checks miss most swaps (docs/tree-method.md, "A geometry off by pixels"); paired, the views
    the right way round agreed better in 173 of 180 generated cases (benchmarks/view_order.py,
    2026-12-07; :data:`.checks.VIEW_ORDER_MARGIN` has the trade-off).
    ``swapped`` is None where no tree can be built with the masks swapped. The time of a second
    reconstruction without its hypotheses (0.95-1.21 s on four generated trees, two 512 x 512
    views, this 2-core machine). With three views two masks swapped make the views disagree (the
    input checks warned on 60 of 60 generated cases, 2026-12-07).

    Raises
    ------
    ReconstructionError
        Unless two views and a tree-method ``result`` of them are given.
    """
    from dataclasses import replace

    from .model import MODEL_SETTINGS

    projections, masks = _as_list(projections, "projections"), _as_list(masks, "masks")
    if len(projections) != 2:
        raise ReconstructionError(f"the view-order check compares two views' masks swapped, got {len(projections)} "
                                  f"views (with three, two masks swapped make the views disagree: the input checks "
                                  f"warned on 60 of 60 generated cases)")
    build = getattr(result, "model_build", None)
    if getattr(result, "method", None) != "tree" or build is None or not build.mask_agreement:
        raise ReconstructionError("the view-order check needs the tree method's result of the two views "
                                  "(reconstruct(..., method='tree'))")
    checked, names = _check_inputs(projections, masks, result.view_names)
    try:
        swapped = _reconstruct_tree(projections, [checked[1], checked[0]], names, resolution=result.lattice.resolution,
                                    threshold_px=result.threshold_px, engine=result.engine, centerlines=False,
                                    half_edge_mm=result.lattice.half_edge_mm, device=result.device, min_views=None,
                                    preset="paper", progress=None,
                                    settings=replace(MODEL_SETTINGS, hypotheses=0, slide=None))
    except ReconstructionError:
        return float(max(build.mask_agreement)), None
    return float(max(build.mask_agreement)), float(max(swapped.model_build.mask_agreement))


def _warn_about_inputs(projections: Sequence[Projection], masks: list[np.ndarray], names: tuple[str, ...],
                       threshold_px: float, method: str) -> float:
    """Give the warnings of :func:`.checks.input_warnings` (to the caller of :func:`reconstruct`);
    returns the seconds they took. (The tree method refuses one view with an error of its own.)"""
    from .checks import input_warnings

    if method == "tree" and len(projections) < 2:
        return 0.0
    start = time.perf_counter()
    for category, message in input_warnings(projections, masks, names, threshold_px=check_threshold_px(threshold_px)):
        warnings.warn(message, category, stacklevel=3)
    return time.perf_counter() - start


def _reconstruct_hull(projections: Sequence[Projection], checked_masks: list[np.ndarray], names: tuple[str, ...], *,
                      resolution: int | None, threshold_px: float, engine: str, centerlines: bool,
                      half_edge_mm: float | None, device: str, min_views: int | None, preset: str, tree: bool,
                      allow_empty: bool) -> ReconstructionResult:
    """``reconstruct(method="hull")`` (see :func:`reconstruct`)."""
    if preset not in PRESETS:
        raise ReconstructionError(f"unknown preset {preset!r}; choose one of {list(PRESETS)}")
    if resolution is None:
        resolution = DEFAULT_RESOLUTION if preset == "paper" else REFINED.resolution
    if preset == "refined":
        checked_masks = [clean_mask(without_salt(m, REFINED.speck_px, REFINED.salt_pieces_per_px,
                                                 REFINED.salt_min_pieces, REFINED.pinhole_px),
                                    REFINED.min_neighbours, REFINED.fill_neighbours) for m in checked_masks]
        empty = [names[i] for i, m in enumerate(checked_masks) if not m.any()]
        if empty:
            raise ReconstructionError(f"view {empty[0]!r}: the refined preset's speck removal leaves the mask empty "
                                      f"(only isolated pixels); use preset='paper'")
    threshold, engine = _checked_carving(threshold_px, engine, device)
    if min_views is not None:
        need = _v.positive_int(min_views, "min_views", error=ReconstructionError)
        if need > len(checked_masks):
            raise ReconstructionError(f"min_views must be between 1 and the number of views ({len(checked_masks)}), got {need}")
        min_views = None if need == len(checked_masks) else need
    timings: dict[str, float] = {}

    start = time.perf_counter()
    radius = cube_half_edge_mm(projections) if half_edge_mm is None else half_edge_mm
    lattice = Lattice(radius, resolution)
    timings["cube"] = time.perf_counter() - start

    start = time.perf_counter()
    if device == "cuda":
        outcome = carve_cuda(engine, lattice, list(projections), checked_masks, threshold_px=threshold,
                             min_views=min_views)
    else:
        outcome = ENGINES[engine](lattice, list(projections), checked_masks, threshold_px=threshold,
                                  min_views=min_views)
    timings["carve"] = time.perf_counter() - start
    points = outcome.points_mm
    carved = points
    if preset == "refined":
        start = time.perf_counter()
        points, _ = refine_hull(points, lattice, projections, checked_masks, REFINED)
        timings["refine"] = time.perf_counter() - start
    timings["reconstruction"] = timings["cube"] + timings["carve"] + timings.get("refine", 0.0)
    if len(points) == 0 and not allow_empty:
        if min_views is not None:
            raise EmptyHullError(f"the visual hull is empty: no lattice point is kept by {min_views} of the "
                                 f"{len(names)} views; check the calibration and the masks",
                                 view_index=-1, view_name="", points_before=lattice.n_points)
        raise _empty_hull_error(outcome, names, lattice)

    centerline_points = None
    if centerlines:
        start = time.perf_counter()
        centerline_points = extract_centerlines(points, projections, checked_masks)
        timings["centerlines"] = time.perf_counter() - start
    vessel_tree, build, tree_error = None, None, None
    if tree and len(projections) < 2:  # (its skeleton would be the cone's: hundreds of branches, and a minute)
        tree_error = ("one view: its visual hull is the view's whole cone of rays, which holds no depth; a vessel "
                      "tree needs two views or more")
    elif tree and len(points):
        start = time.perf_counter()
        try:
            vessel_tree, build = hull_tree(points, lattice, projections, checked_masks,
                                           support_points_mm=carved if preset == "refined" else None)
        except ReconstructionError as exc:
            tree_error = str(exc)
        timings["tree"] = time.perf_counter() - start
    elif tree:
        tree_error = "the hull is empty"
    timings["total"] = sum(v for k, v in timings.items() if k != "reconstruction")
    return ReconstructionResult(
        vessel_points_mm=points,
        centerline_points_mm=centerline_points,
        lattice=lattice,
        engine=engine,
        device=device,
        threshold_px=threshold,
        view_names=names,
        survivors_per_view=outcome.survivors_per_view,
        view_order=outcome.order if outcome.order is not None else tuple(range(len(names))),
        min_views=min_views,
        preset=preset,
        timings_s=timings,
        tree=vessel_tree,
        tree_build=build,
        tree_error=tree_error,
    )


_TREE_METHOD_HINT = (" (the tree method, which needs vessels in the masks and a lattice fine enough for them; "
                     "method 'hull' carves the visual hull instead)")


_DEEP_HULL_DEG = 30.0  # views nearer than this to looking along one line carve a deep hull (_deep_hull_hint)


def _deep_hull_hint(projections: Sequence[Projection]) -> str:
    """What a hull too large for a vessel tree may owe to the views rather than to the masks: where
    every pair of views looks within :data:`_DEEP_HULL_DEG` of one line, each vessel's hull runs
    deep along the rays (two views of a wide vessel nearly opposite each other). Empty otherwise."""
    from .model import _from_one_line_deg

    nearest = _from_one_line_deg(projections)
    if nearest >= _DEEP_HULL_DEG:
        return ""
    return (f"; or is it the views? every pair of them looks within {nearest:.1f} degrees of one line, where each "
            f"vessel's hull runs deep along the rays (views {_DEEP_HULL_DEG:g} degrees or more from one line carve a "
            f"smaller one)")


def _reconstruct_tree(projections: Sequence[Projection], masks: list[np.ndarray], names: tuple[str, ...], *,
                      resolution: int | None, threshold_px: float, engine: str, centerlines: bool,
                      half_edge_mm: float | None, device: str, min_views: int | None, preset: str,
                      progress: Callable[[str], None] | None, allow_empty: bool = False,
                      settings=None) -> ReconstructionResult:
    """``reconstruct(method="tree")`` (see :func:`reconstruct`); ``settings``: the
    :class:`~.model.ModelSettings` (None: :func:`~.model.model_tree`'s default)."""
    from .model import MODEL_SETTINGS, model_tree

    if len(projections) < 2:
        raise ReconstructionError(f"method 'tree' matches centerlines across views and needs two views or more, "
                                  f"got {len(projections)}; use method='hull' (--method hull)")
    if min_views is not None:
        raise ReconstructionError("min_views applies to method 'hull' only; the tree method reads every view")
    if preset != "paper":
        raise ReconstructionError(f"preset {preset!r} applies to method 'hull' only; leave the preset at 'paper' "
                                  f"with method 'tree'")
    threshold, engine = _checked_carving(threshold_px, engine, device)
    timings: dict[str, float] = {}
    # specks (a noisy segmentation's salt): no other view matches them, and the hull they carve slows
    # every bridge search (docs/tree-method.md, step 1). Two views: a mask's small pieces go before
    # anything reads it. Three or more: a salted mask is read without them throughout; otherwise the
    # support hull the bridges search is carved without them (the refined hull that starts the tree
    # removes specks its own way)
    speckless = [without_small_components(m, MODEL_SETTINGS.speck_px) for m in masks]
    empty = [names[i] for i, m in enumerate(speckless) if not m.any()]
    if empty and not allow_empty:
        raise ReconstructionError(f"view {empty[0]!r}: the mask holds no piece of {MODEL_SETTINGS.speck_px} pixels "
                                  f"or more (only specks); the tree method needs the vessels")
    if len(projections) == 2:  # ... and its pinholes are filled (pepper breaks a skeleton into loops; step 1)
        masks = [with_small_holes_filled(m, MODEL_SETTINGS.pinhole_px, MODEL_SETTINGS.pepper_holes_per_px,
                                         MODEL_SETTINGS.pepper_min_holes) for m in speckless]
    else:  # a salted mask (many specks, few pinholes: docs/tree-method.md) is read without its specks throughout
        masks = [without_salt(m, MODEL_SETTINGS.speck_px, MODEL_SETTINGS.salt_pieces_per_px,
                              MODEL_SETTINGS.salt_min_pieces, MODEL_SETTINGS.pinhole_px) for m in masks]
    start = time.perf_counter()
    lattice = Lattice(cube_half_edge_mm(projections) if half_edge_mm is None else half_edge_mm,
                      REFINED.resolution if resolution is None else resolution)
    timings["cube"] = time.perf_counter() - start
    def carved(views_masks: list[np.ndarray]) -> CarveOutcome:
        if device == "cuda":
            return carve_cuda(engine, lattice, list(projections), views_masks, threshold_px=threshold, min_views=None)
        return ENGINES[engine](lattice, list(projections), views_masks, threshold_px=threshold, min_views=None)

    start = time.perf_counter()
    outcome = carved(masks)
    support = outcome.points_mm
    if len(projections) > 2 and any(not np.array_equal(a, b) for a, b in zip(masks, speckless)):
        support = carved(speckless).points_mm
    timings["carve"] = time.perf_counter() - start
    order = outcome.order if outcome.order is not None else tuple(range(len(names)))
    if len(outcome.points_mm) == 0:
        if not allow_empty:
            raise _empty_hull_error(outcome, names, lattice)
        timings["reconstruction"] = timings["total"] = sum(timings.values())
        return ReconstructionResult(vessel_points_mm=outcome.points_mm, centerline_points_mm=None, lattice=lattice,
                                    engine=engine, device=device, threshold_px=threshold, view_names=names,
                                    survivors_per_view=outcome.survivors_per_view, view_order=order, preset=preset,
                                    timings_s=timings, tree_error="the hull is empty", method="tree")
    if len(outcome.points_mm) > MODEL_SETTINGS.tree.max_voxels:  # a hull no vessel tree fills: said now, not
        try:  # after minutes of 2D centerlines and matchings through masks that are not vessel masks
            checked_occupancy(outcome.points_mm, lattice, MODEL_SETTINGS.tree)
        except ReconstructionError as exc:
            raise ReconstructionError(f"{exc}{_deep_hull_hint(projections)}{_TREE_METHOD_HINT}") from None
    initial = None
    if len(projections) >= 3:
        # three views or more: the refined hull is no longer ambiguous, and its skeleton starts the tree
        start = time.perf_counter()
        cleaned = [clean_mask(m, REFINED.min_neighbours, REFINED.fill_neighbours) for m in masks]
        if all(m.any() for m in cleaned):
            initial, _ = refine_hull(outcome.points_mm, lattice, projections, cleaned, REFINED)
            masks = cleaned
        timings["refine"] = time.perf_counter() - start
        if progress:
            progress(f"{len(projections)} views: the refined hull ({0 if initial is None else len(initial)} points) "
                     f"starts the tree")
    try:
        points, vessel_tree, build = model_tree(projections, masks, lattice, support_points_mm=support,
                                                initial_points_mm=initial if initial is not None and len(initial)
                                                else None, progress=progress,
                                                **({} if settings is None else {"settings": settings}))
    except ReconstructionError as exc:  # the tree method is the default: say what else there is
        if type(exc) is not ReconstructionError:
            raise
        raise ReconstructionError(f"{exc}{_TREE_METHOD_HINT}") from None
    timings.update({f"tree_{k}": v for k, v in build.timings_s.items()})
    timings["reconstruction"] = sum(timings.values())
    timings["total"] = timings["reconstruction"]
    return ReconstructionResult(
        vessel_points_mm=points,
        centerline_points_mm=vessel_tree.points()[0] if centerlines else None,
        lattice=lattice, engine=engine, device=device, threshold_px=threshold, view_names=names,
        survivors_per_view=outcome.survivors_per_view, view_order=order,
        preset=preset, timings_s=timings, tree=vessel_tree, tree_build=build.tree_build, method="tree",
        model_build=build,
    )
