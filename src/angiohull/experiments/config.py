"""Experiment configurations: YAML files validated with pydantic, before any work starts.

A configuration names everything a run needs: the generator settings (tree kind, rasteriser, C-arm
geometry, fixed corruptions), the *design* (which trees, which views, which corruption sweep), the
reconstruction options (engine, K, threshold) and the metrics. Every case derives its seeds from
``seed`` (see :mod:`angiohull.experiments.cases`), so a configuration is one reproducible study.

Three designs:

``trees``
    ``trees`` synthetic trees per tortuosity level (and per sweep value) seen in a fixed view set,
    optionally with a corruption swept over values (``sweep``). The paper's ``general``,
    ``general_clinical``, ``translation``, ``scaling``, ``false_positives`` and ``false_negatives``.
``n_views``
    One tree, ``directions`` view directions drawn uniformly on the sphere, and for each N in
    ``n_views`` ``selections`` random subsets of N of them (paper Figure 2).
``angles``
    ``triplets`` random triplets of view directions (uniform on the sphere), one tree each; the
    metrics against the smallest singular value of the 3x3 matrix of the viewing directions.

Errors name the file and the field: ``general.yaml: design.trees: got -5 (int); expected a value
greater than or equal to 1``. The shipped configurations live in ``configs/`` (package data);
:func:`load_config` accepts a path or a shipped name.
"""

from __future__ import annotations

import math
import warnings
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

import numpy as np
from pydantic import (BaseModel, ConfigDict, Field, ValidationError, ValidatorFunctionWrapHandler, WrapValidator,
                      field_validator, model_validator)
from pydantic_core import PydanticCustomError

from .._yaml import load_yaml
from ..errors import AngiohullError, InputWarning
from .._models import find_model, short_repr
from ..synthetic.corruptions import CORRUPTION_KINDS, CorruptionSpec, parse_corruption
from ..synthetic.views import parse_views

__all__ = [
    "ConfigError", "ExperimentConfig", "GeneratorSettings", "ReconstructionSettings", "TreesDesign", "NViewsDesign",
    "AnglesDesign", "Sweep", "SweepValues", "METRICS", "TREE_METRICS", "CONFIG_FORMAT", "load_config", "shipped_config_names",
    "shipped_config_path", "config_from_dict", "config_to_dict", "MAX_CASES",
]

CONFIG_FORMAT = 1
"""Value of the ``angiohull_experiment`` key of every configuration file."""

TREE_METRICS: tuple[str, ...] = ("centerline_mean_mm", "centerline_p95_mm", "ot1mm", "cldice", "radius_mae_mm",
                                  "radius_bias_mm", "branch_recall", "branch_precision", "bifurcation_error_mm")
"""Tree scores a configuration may ask for (:func:`angiohull.metrics.tree.tree_scores`; shares in [0, 1]):
the case then builds the reconstruction's vessel tree and scores it against the generator's."""

METRICS: tuple[str, ...] = ("dice3d", "iou3d", "chamfer_mm", "dice2d_paper", "dice2d", "time_s", *TREE_METRICS)
"""Metric names a configuration may ask for (docs/conventions.md, "Metrics"); ``time_s`` is the reconstruction alone."""

Metric = Literal["dice3d", "iou3d", "chamfer_mm", "dice2d_paper", "dice2d", "time_s", "centerline_mean_mm",
                 "centerline_p95_mm", "ot1mm", "cldice", "radius_mae_mm", "radius_bias_mm", "branch_recall",
                 "branch_precision", "bifurcation_error_mm"]
Level = Literal["simple", "moderate", "tortuous"]

MAX_CASES = 1_000_000
"""Most cases an experiment may have."""

_QUICK_MIN_TREES = 2  # trees per group: two, so a standard deviation exists
_QUICK_MIN_VALUES = 3  # sweep values: three, so a curve keeps its shape
_QUICK_MIN_SELECTIONS = 2
_QUICK_MIN_TRIPLETS = 5


class ConfigError(AngiohullError):
    """An experiment configuration is invalid; the message names the file and the field."""


def _problem(field: str, message: str) -> PydanticCustomError:
    """A validation error about ``field`` (relative to the model that raises it)."""
    return PydanticCustomError("field_problem", "{message}", {"field": field, "message": message})


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _one_of(expected: str) -> WrapValidator:
    """Validate a union with its own types, but say a value that none of its forms takes in one line of
    plain words: pydantic reports one error per form, each under its internal type's name (e.g.
    ``views.tuple[constrained-int, ...]: expected a valid tuple``)."""

    def validate(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
        try:
            return handler(value)
        except ValidationError:
            raise ValueError(f"{_got(value)}; expected {expected}") from None

    return WrapValidator(validate)


def _finite(value: float, name: str) -> float:
    if not math.isfinite(value):
        raise ValueError(f"expected a finite number, got {value!r}")
    return value


class GeneratorSettings(_Model):
    """How each synthetic case is generated (the paper's geometry by default)."""

    kind: Literal["rca", "left"] = Field("rca", description="right coronary tree or left tree")
    rasteriser: Literal["exact", "paper"] = Field("paper", description="the paper's rasteriser or the exact silhouette")
    sid_mm: float = Field(1200.0, gt=0, description="source-to-detector distance, mm")
    sod_mm: float = Field(800.0, gt=0, description="source-to-isocentre distance, mm")
    pixel_mm: float = Field(0.35, gt=0, description="detector pixel spacing, mm")
    size: int = Field(512, ge=16, le=8192, description="detector rows = columns")
    corruptions: tuple[str, ...] = Field((), description="fixed corruptions of every case, KIND=VALUES[@VIEWS]")

    @field_validator("sid_mm", "sod_mm", "pixel_mm")
    @classmethod
    def _finite_numbers(cls, value: float, info) -> float:
        return _finite(value, info.field_name)

    @field_validator("corruptions")
    @classmethod
    def _parse_corruptions(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for index, text in enumerate(value):
            try:
                parse_corruption(text)
            except AngiohullError as exc:
                raise _problem(f"[{index}]", f"{exc}; got {text!r}") from None
        return value

    @model_validator(mode="after")
    def _sod_below_sid(self) -> "GeneratorSettings":
        if self.sod_mm >= self.sid_mm:
            raise _problem("sod_mm", f"got {self.sod_mm}; expected a value smaller than sid_mm ({self.sid_mm}): "
                                     f"the isocentre lies between source and detector")
        return self

    def corruption_specs(self) -> tuple[CorruptionSpec, ...]:
        return tuple(parse_corruption(text) for text in self.corruptions)


class ReconstructionSettings(_Model):
    """Options of :func:`angiohull.reconstruct` (the paper's by default; ``octree`` keeps the kdtree's points)."""

    engine: Literal["octree", "kdtree", "lookup", "auto"] = "octree"
    resolution: Optional[int] = Field(None, ge=2, le=1024,
                                      description="K, lattice points per axis (default: the preset's, 100 or 256)")
    threshold_px: float = Field(1.0, gt=0, description="strict distance threshold, px")
    preset: Literal["paper", "refined"] = Field("paper", description="the method as published, or refined (beyond the paper)")
    method: Literal["hull", "tree"] = Field("hull", description="hull (the paper's visual hull, see preset; the "
                                                               "paper's experiments keep it by default) or tree "
                                                               "(centerline correspondences, tubes; 2+ views; "
                                                               "reconstruct's default)")
    calibrate: bool = Field(False, description="estimate per-view image shifts first (beyond the paper)")
    calibrate_scale: bool = Field(False, description="also per-view image scales (implies calibrate; 3+ views)")
    min_views: Optional[int] = Field(None, ge=1, description="robust carving: views that must keep a point (default all)")

    @field_validator("threshold_px")
    @classmethod
    def _finite_threshold(cls, value: float) -> float:
        from ..reconstruction import check_threshold_px

        _finite(value, "threshold_px")
        try:
            return check_threshold_px(value, "threshold_px")
        except AngiohullError as exc:
            raise ValueError(str(exc).removeprefix("threshold_px ")) from None

    @model_validator(mode="after")
    def _tree_method_has_no_hull_options(self) -> "ReconstructionSettings":
        if self.method == "tree" and (self.preset != "paper" or self.min_views is not None):
            raise ValueError("method 'tree' has no preset or min_views (they choose how the hull is carved); "
                             "leave preset at 'paper' and min_views unset")
        return self

    @model_validator(mode="before")
    @classmethod
    def _scales_imply_calibrate(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("calibrate_scale") and not data.get("calibrate"):
            data = {**data, "calibrate": True}
        return data


class GridValues(_Model):
    """``count`` evenly spaced values from ``start`` to ``stop`` (``stop`` included iff ``endpoint``)."""

    start: float
    stop: float
    count: int = Field(ge=1, le=100_000)
    endpoint: bool = True

    @model_validator(mode="after")
    def _ordered(self) -> "GridValues":
        if not (math.isfinite(self.start) and math.isfinite(self.stop)):
            raise _problem("start", f"expected finite bounds, got start={self.start}, stop={self.stop}")
        if self.count > 1 and not self.start < self.stop:
            raise _problem("stop", f"got {self.stop}; expected a value greater than start ({self.start})")
        return self


class UniformValues(_Model):
    """``count`` values drawn uniformly from ``[low, high)`` (for ``translate``: each of tx, ty)."""

    low: float
    high: float
    count: int = Field(ge=1, le=100_000)

    @model_validator(mode="after")
    def _ordered(self) -> "UniformValues":
        if not (math.isfinite(self.low) and math.isfinite(self.high)):
            raise _problem("low", f"expected finite bounds, got low={self.low}, high={self.high}")
        if not self.low < self.high:
            raise _problem("high", f"got {self.high}; expected a value greater than low ({self.low})")
        return self


class SweepValues(_Model):
    """Exactly one of ``grid``, ``uniform`` or ``list``."""

    grid: Optional[GridValues] = None
    uniform: Optional[UniformValues] = None
    list: Optional[tuple[Annotated[Union[float, tuple[float, float]],
                                   _one_of("a number, or a [tx, ty] pair of numbers (translate)")], ...]] = Field(
        None, min_length=1)

    @model_validator(mode="after")
    def _exactly_one(self) -> "SweepValues":
        given = [name for name in ("grid", "uniform", "list") if getattr(self, name) is not None]
        if len(given) != 1:
            raise _problem("", f"got {', '.join(given) or 'none'}; expected exactly one of grid, uniform, list")
        return self

    def count(self) -> int:
        if self.grid is not None:
            return self.grid.count
        if self.uniform is not None:
            return self.uniform.count
        return len(self.list)


class Sweep(_Model):
    """A corruption applied with one value per case, over a set of values."""

    corruption: Literal[CORRUPTION_KINDS] = Field(description="translate, scale, rotate, fp, fn, missing, blob, catheter")  # type: ignore[valid-type]
    values: SweepValues
    views: Annotated[Union[Literal["all"], Annotated[tuple[Annotated[int, Field(ge=0)], ...], Field(min_length=1)], None],
                     _one_of("'all', or a list of view indices (whole numbers from 0; at least one), e.g. [0] or "
                             "[0, 2]")] = Field(
        None, description="views it corrupts (default: view 0 for translate/scale/rotate, all views otherwise)")

    @model_validator(mode="after")
    def _values_fit_the_kind(self) -> "Sweep":
        kind, values = self.corruption, self.values

        def check(field: str, value: Any) -> None:
            try:
                CorruptionSpec(kind, value if kind == "translate" else (value,))
            except AngiohullError as exc:
                raise _problem(field, f"{exc}") from None

        if kind == "translate":
            if values.grid is not None:
                raise _problem("values.grid", "translate takes 'uniform' (tx and ty each in [low, high)) or a "
                                              "'list' of [tx, ty] pairs, not a grid")
            for index, value in enumerate(values.list or ()):
                if not isinstance(value, tuple):
                    raise _problem(f"values.list[{index}]", f"got {value!r}; expected a [tx, ty] pair")
                check(f"values.list[{index}]", value)
            return self
        for index, value in enumerate(values.list or ()):
            if isinstance(value, tuple):
                raise _problem(f"values.list[{index}]", f"got {list(value)!r}; expected a single number")
            check(f"values.list[{index}]", value)
        whole = kind in ("missing", "blob", "catheter")
        if values.grid is not None:
            check("values.grid.start", values.grid.start)
            check("values.grid.stop", values.grid.stop)
            if whole and not all(v.is_integer() for v in grid_values(values.grid)):
                raise _problem("values.grid", f"{kind} counts are whole numbers; this grid has fractions")
        if values.uniform is not None:
            if whole:
                raise _problem("values.uniform", f"{kind} counts are whole numbers: use a grid or a list")
            check("values.uniform.low", values.uniform.low)
            # [low, high): high itself is never drawn, the numbers just below it are
            check("values.uniform.high", math.nextafter(values.uniform.high, -math.inf))
        return self

    def spec(self, value: Any) -> CorruptionSpec:
        values = tuple(value) if self.corruption == "translate" else (float(value),)
        return CorruptionSpec(self.corruption, values, self.views)


def grid_values(grid: GridValues) -> list[float]:
    """The values of a grid (``numpy.linspace``)."""
    return [float(v) for v in np.linspace(grid.start, grid.stop, grid.count, endpoint=grid.endpoint)]


def _check_views(value: Union[str, tuple[str, ...]]) -> Union[str, tuple[str, ...]]:
    try:
        parse_views(value)
    except AngiohullError as exc:
        raise ValueError(str(exc).removeprefix("views: ")) from None
    return value


def _each_once(what: str):
    """A validator that rejects a tuple naming some ``what`` twice."""

    def check(value: tuple[str, ...]) -> tuple[str, ...]:
        if len(set(value)) != len(value):
            raise ValueError(f"expected each {what} once, got {list(value)}")
        return value

    return check


class TreesDesign(_Model):
    """``trees`` trees per tortuosity level (and per sweep value), in a fixed set of views."""

    type: Literal["trees"]
    tortuosity: tuple[Level, ...] = Field(min_length=1, description="one group of trees per level")
    trees: int = Field(ge=1, le=1_000_000, description="trees per level and per sweep value")
    views: Annotated[Union[str, tuple[str, ...]],
                     _one_of("'perpendicular', 'clinical', clinical angle strings separated by ';' (e.g. 'RAO 30 CRA "
                             "30; LAO 60 CRA 30'), or a list of such strings")] = Field(
        description="'perpendicular', 'clinical' or clinical angle strings")
    sweep: Optional[Sweep] = None
    paired_trees: bool = Field(True, description="with a sweep: the same trees at every value (else new trees per value)")

    _views = field_validator("views")(_check_views)

    _unique_levels = field_validator("tortuosity")(_each_once("level"))

    @model_validator(mode="after")
    def _sweep_views_exist(self) -> "TreesDesign":
        n_views = len(parse_views(self.views))
        if self.sweep is not None and isinstance(self.sweep.views, tuple):
            bad = [i for i in self.sweep.views if i >= n_views]
            if bad:
                raise _problem("sweep.views", f"got view index {bad[0]}; expected an index below {n_views} "
                                              f"(the design has {n_views} views)")
        return self


class IntRange(_Model):
    """Whole numbers from ``min`` to ``max``, both included."""

    min: int = Field(ge=1)
    max: int = Field(ge=1)

    @model_validator(mode="after")
    def _ordered(self) -> "IntRange":
        if self.max < self.min:
            raise _problem("max", f"got {self.max}; expected a value >= min ({self.min})")
        return self

    def values(self) -> list[int]:
        return list(range(self.min, self.max + 1))


class NViewsDesign(_Model):
    """One tree; ``directions`` random view directions; for each N, ``selections`` random N-subsets."""

    type: Literal["n_views"]
    tortuosity: Level = "moderate"
    tree_index: int = Field(0, ge=0, description="which tree of the level (tree i is the same tree in every design)")
    directions: int = Field(ge=1, le=100_000, description="view directions drawn uniformly on the sphere")
    n_views: IntRange
    selections: int = Field(ge=1, le=1_000_000, description="random subsets per N")

    @model_validator(mode="after")
    def _enough_directions(self) -> "NViewsDesign":
        if self.n_views.max > self.directions:
            raise _problem("n_views.max", f"got {self.n_views.max}; expected at most directions ({self.directions}): "
                                          f"a selection takes distinct directions")
        few = [n for n in self.n_views.values() if math.comb(self.directions, n) < self.selections]
        if few:  # (random selections may repeat anyway; here some must)
            n = few[0]
            warnings.warn(f"design: {self.directions} directions hold only {math.comb(self.directions, n)} distinct "
                          f"selections of {n} views, fewer than the {self.selections} selections asked for"
                          f"{f' (and so for N = {few[1:]})' if len(few) > 1 else ''}: some cases repeat one another, "
                          f"and the statistics count them as independent", InputWarning, stacklevel=2)
        return self


class AnglesDesign(_Model):
    """``triplets`` random triplets of view directions, each seen on its own tree (or one tree)."""

    type: Literal["angles"]
    tortuosity: Level = "moderate"
    triplets: int = Field(ge=1, le=1_000_000)
    same_tree: bool = Field(False, description="one tree for every triplet (else tree i for triplet i)")


Design = Annotated[Union[TreesDesign, NViewsDesign, AnglesDesign], Field(discriminator="type")]


class ReportSettings(_Model):
    """What the report adds for this experiment."""

    paper: Optional[Literal["table1", "table2"]] = Field(None, description="the paper's table to set beside ours")
    ttest: Optional[Metric] = Field(None, description="t-tests between the tortuosity groups on this metric (Table 3)")
    bins: int = Field(10, ge=2, le=1000, description="bins of a continuous x axis (shift, factor, singular value)")


class QuickSettings(_Model):
    """How ``--quick`` scales the run down: every count times ``fraction``, with small floors."""

    fraction: float = Field(0.025, gt=0, le=1)


class ExperimentConfig(_Model):
    """One experiment of the paper (or your own), as read from its YAML file."""

    angiohull_experiment: Literal[1] = Field(description="format version of the file")
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9_\-]*$", max_length=64)
    description: str = ""
    paper: str = Field("", description="what of the paper it reproduces, e.g. 'Table 1, Figure 3'")
    seed: int = Field(ge=0, le=2 ** 63 - 1, description="every case's seeds derive from it")
    mode: Literal["full", "quick"] = Field("full", description="'quick' once --quick has scaled the counts down")
    generator: GeneratorSettings = GeneratorSettings()
    design: Design
    reconstruction: ReconstructionSettings = ReconstructionSettings()
    metrics: tuple[Metric, ...] = Field(min_length=1)
    report: ReportSettings = ReportSettings()
    quick: QuickSettings = QuickSettings()

    _unique_metrics = field_validator("metrics")(_each_once("metric"))

    def case_count(self) -> int:
        """How many cases the design expands to (without building them)."""
        design = self.design
        if isinstance(design, TreesDesign):
            values = design.sweep.values.count() if design.sweep is not None else 1
            return len(design.tortuosity) * design.trees * values
        if isinstance(design, NViewsDesign):
            return (design.n_views.max - design.n_views.min + 1) * design.selections
        return design.triplets

    def fewest_views(self) -> int:
        """The fewest views any case of the design has."""
        design = self.design
        if isinstance(design, TreesDesign):
            return len(parse_views(design.views))
        if isinstance(design, NViewsDesign):
            return design.n_views.min
        return 3

    @model_validator(mode="after")
    def _within_bounds(self) -> "ExperimentConfig":
        count = self.case_count()
        if count > MAX_CASES:
            raise _problem("design", f"expands to {count:,} cases; expected at most {MAX_CASES:,} (a million cases "
                                     f"take weeks on a workstation, and their records alone gigabytes): lower "
                                     f"trees, selections, triplets or the sweep's count")
        fewest = self.fewest_views()
        if self.reconstruction.calibrate_scale and fewest < 3:
            raise _problem("reconstruction.calibrate_scale", f"needs three views or more in every case; this design's "
                                                             f"smallest case has {fewest}")
        for index, spec in enumerate(self.generator.corruption_specs()):
            views = spec.views if isinstance(spec.views, tuple) else ()
            if any(i >= fewest for i in views):
                raise _problem(f"generator.corruptions[{index}]", f"got view index {max(views)}; expected an index "
                                                                  f"below {fewest}, the views of this design's smallest "
                                                                  f"case")
        need = self.reconstruction.min_views
        if need is not None and need > self.fewest_views():
            raise _problem("reconstruction.min_views", f"got {need}; expected at most {self.fewest_views()}, the "
                                                       f"number of views of {'every' if isinstance(self.design, TreesDesign) else 'the smallest'} "
                                                       f"case of this design (a point kept by {need} views needs {need} views)")
        return self

    @model_validator(mode="after")
    def _report_fits_design(self) -> "ExperimentConfig":
        if self.report.ttest is not None:
            if not isinstance(self.design, TreesDesign) or len(self.design.tortuosity) < 2:
                raise _problem("report.ttest", "t-tests compare tortuosity groups; expected a 'trees' design with "
                                               "at least two tortuosity levels")
            if self.report.ttest not in self.metrics:
                raise _problem("report.ttest", f"got {self.report.ttest!r}; expected one of the metrics {list(self.metrics)}")
        if self.report.paper is not None and not isinstance(self.design, TreesDesign):
            raise _problem("report.paper", "the paper's Tables 1 and 2 are 'trees' designs without a sweep")
        return self

    # -- quick ------------------------------------------------------------------------------------
    def quick_version(self) -> "ExperimentConfig":
        """The same experiment with every count scaled by ``quick.fraction`` (floors keep each table and plot)."""
        if self.mode == "quick":
            return self
        f = self.quick.fraction

        def scaled(n: int, floor: int) -> int:
            return min(n, max(floor, math.ceil(n * f)))

        design = self.design
        if isinstance(design, TreesDesign):
            update: dict[str, Any] = {"trees": scaled(design.trees, _QUICK_MIN_TREES)}
            if design.sweep is not None:
                values = design.sweep.values
                count = scaled(values.count(), _QUICK_MIN_VALUES)
                if values.grid is not None:
                    new_values = values.model_copy(update={"grid": values.grid.model_copy(update={"count": count})})
                elif values.uniform is not None:
                    new_values = values.model_copy(update={"uniform": values.uniform.model_copy(update={"count": count})})
                else:
                    keep = sorted(set(np.linspace(0, len(values.list) - 1, count).round().astype(int).tolist()))
                    new_values = values.model_copy(update={"list": tuple(values.list[i] for i in keep)})
                update["sweep"] = design.sweep.model_copy(update={"values": new_values})
            design = design.model_copy(update=update)
        elif isinstance(design, NViewsDesign):
            directions = min(design.directions, max(design.n_views.max, math.ceil(design.directions * f)))
            design = design.model_copy(update={"directions": directions,
                                               "selections": scaled(design.selections, _QUICK_MIN_SELECTIONS)})
        else:
            design = design.model_copy(update={"triplets": scaled(design.triplets, _QUICK_MIN_TRIPLETS)})
        # model_copy skips validation: round-trip through a dict so the result is checked like a file
        data = config_to_dict(self)
        data["mode"] = "quick"
        data["design"] = design.model_dump(mode="json")
        return config_from_dict(data, "quick version")


# -- loading and errors ---------------------------------------------------------------------------
def _format_loc(loc) -> str:
    text = ""
    for index, part in enumerate(loc):
        if isinstance(part, int):
            text += f"[{part}]"
        elif index == 1 and loc[0] == "design" and part in ("trees", "n_views", "angles"):
            continue  # the discriminated union's tag is not a key of the file
        elif str(part).startswith(("function-", "tagged-union", "literal[")):
            continue
        elif str(part).startswith("["):
            text += str(part)
        else:
            text += f".{part}" if text else str(part)
    return text or "(top level)"


def _got(value: Any) -> str:
    return f"got {short_repr(value)} ({type(value).__name__})"


def _model_at(loc) -> Optional[type[BaseModel]]:
    """The model that holds the keys at ``loc`` (list indices skipped; ``design``'s tag picks the design)."""
    designs = {"trees": TreesDesign, "n_views": NViewsDesign, "angles": AnglesDesign}
    model: Optional[type[BaseModel]] = ExperimentConfig
    parts = list(loc)
    i = 0
    while i < len(parts):
        part = parts[i]
        if isinstance(part, str) and model is not None:
            if model is ExperimentConfig and part == "design":
                model = designs.get(parts[i + 1]) if i + 1 < len(parts) else None
                i += 2
                continue
            field = model.model_fields.get(part)
            model = None if field is None else find_model(field.annotation)
        i += 1
    return model


def _describe(error: dict) -> tuple[str, str]:
    """``(field, message)`` for one pydantic error."""
    loc, kind = tuple(error["loc"]), error["type"]
    field = _format_loc(loc)
    if kind == "extra_forbidden":
        model = _model_at(loc[:-1])
        allowed = ", ".join(model.model_fields) if model is not None else "?"
        return field, f"unknown key; expected one of: {allowed}"
    if kind == "missing":
        return field, "required key is missing"
    if kind == "field_problem":
        sub = error["ctx"]["field"]
        if sub.startswith("["):
            field += sub
        elif sub:
            field = sub if field == "(top level)" else f"{field}.{sub}"
        return field, error["ctx"]["message"]
    if kind == "union_tag_invalid":
        return f"{field}.type", f"{_got(error['input'].get('type') if isinstance(error['input'], dict) else error['input'])}; " \
                                f"expected one of {error['ctx']['expected_tags']}"
    if kind == "union_tag_not_found":
        return f"{field}.type", "required key is missing; expected one of 'trees', 'n_views', 'angles'"
    if kind == "value_error":
        return field, f"{error['ctx']['error']}"
    if kind == "tuple_type":  # (a YAML list; tuple is Python's word)
        return field, f"{_got(error.get('input'))}; expected a list"
    if kind == "too_short" and error["ctx"].get("field_type") in ("Tuple", "List"):
        return field, f"{_got(error.get('input'))}; expected a list of at least {error['ctx']['min_length']} item(s)"
    message = error["msg"]
    if message.startswith("Input should be "):
        rest = message[len("Input should be "):]
        if rest.startswith(("greater", "less")):
            rest = "a value " + rest
        message = "expected " + rest
    received = error.get("input")
    return field, f"{_got(received)}; {message}"


def config_from_dict(data: Any, where: str = "experiment config") -> ExperimentConfig:
    """Validate a configuration given as a dict; raises :class:`ConfigError` naming ``where`` and each bad field."""
    if not isinstance(data, dict):
        got = "an empty document" if data is None else f"a {type(data).__name__}"
        raise ConfigError(f"{where}: expected a mapping with keys {', '.join(ExperimentConfig.model_fields)}; got {got}")
    try:
        return ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        problems = []
        errors = exc.errors(include_url=False)
        for error in errors:
            loc = tuple(error["loc"])
            if error["type"] == "too_short" and any(len(o["loc"]) > len(loc) and tuple(o["loc"][:len(loc)]) == loc
                                                    for o in errors):
                continue  # a list whose items failed is 'too short' too (pydantic counts the items that passed)
            field, message = _describe(error)
            line = f"{where}: {field}: {message}"
            if line not in problems:
                problems.append(line)
        raise ConfigError("\n".join(problems)) from None


def config_to_dict(config: ExperimentConfig) -> dict[str, Any]:
    """The configuration as plain YAML/JSON data (what RUN_DIR/config.yaml holds)."""
    return config.model_dump(mode="json", exclude_none=True)


def _configs_dir():
    return resources.files("angiohull.experiments").joinpath("configs")


def shipped_config_names() -> list[str]:
    """Names of the configurations shipped with the package (the paper's experiments)."""
    return sorted(entry.name[:-5] for entry in _configs_dir().iterdir() if entry.name.endswith(".yaml"))


def shipped_config_path(name: str):
    """The shipped file of a configuration name (a :mod:`importlib.resources` traversable)."""
    entry = _configs_dir().joinpath(f"{name}.yaml")
    if not entry.is_file():
        raise ConfigError(f"no shipped experiment named {name!r}; expected a YAML file or one of: "
                          f"{', '.join(shipped_config_names())}")
    return entry


def load_config(source: Union[str, Path], *, quick: bool = False) -> ExperimentConfig:
    """Read and validate a configuration.

    Parameters
    ----------
    source : str or Path
        A YAML file, or the name of a shipped configuration (:func:`shipped_config_names`).
    quick : bool, keyword-only
        Return :meth:`ExperimentConfig.quick_version`.

    Raises
    ------
    ConfigError
        Unreadable file, invalid YAML, or a field that fails validation (each one named).
    """
    path = Path(source)
    if path.suffix in (".yaml", ".yml") or path.exists() or "/" in str(source):
        where = str(path)
        try:
            text = path.read_bytes()
        except OSError as exc:
            raise ConfigError(f"{where}: cannot read the experiment config ({exc.strerror or exc}); expected a YAML "
                              f"file or one of the shipped names: {', '.join(shipped_config_names())}") from None
    else:
        entry = shipped_config_path(str(source))
        where = f"{source}.yaml (shipped)"
        text = entry.read_bytes()
    data = load_yaml(text, where, error=ConfigError)
    config = config_from_dict(data, where)
    return config.quick_version() if quick else config
