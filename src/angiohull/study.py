"""The study folder (docs/conventions.md, "Study folder"): ``study.yaml``, masks and optional ground truth.

A study is a folder with a ``study.yaml``::

    angiohull: 1                      # format version
    views:
      - name: RAO30_CRA30             # optional, defaults to the mask's stem
        mask: masks/view0.png         # PNG/TIFF/NPY; nonzero = vessel; shape = (rows, cols)
        carm: {primary_deg: -30, secondary_deg: 30, sid_mm: 1200, sod_mm: 800,
               pixel_spacing_mm: [0.35, 0.35]}
      - mask: masks/view1.png
        projection_matrix: [[...], [...], [...]]   # 3x4
      - image: dicom/run3.dcm         # a raw angiogram (DICOM or PNG/TIFF/NPY), segmented on loading
        dicom: dicom/run3.dcm         # geometry from the XA header
        frame: 12                     # optional frame index (from 0); default: chosen automatically
        segmentation: {high_threshold: 0.25}   # optional overrides of SegmentationParameters
    ground_truth: gt.npy              # optional: (N, 3) points in mm (.npy or .ply)
    ground_truth_tree: gt_centerlines.npz   # optional: the true vessel tree (.npz, .npy or .json)
    allow_outside_paths: false        # optional: true to read files outside the folder

Each view has exactly one geometry source (``carm``, ``projection_matrix`` or ``dicom``) and
exactly one of ``mask`` (a binary vessel mask) and ``image`` (segmented with
:func:`angiohull.segmentation.segment_vessels_detailed`; the view keeps the flattened attenuation
too, ``View.attenuation``, on which ``reconstruct --qca`` measures lesions). Paths are relative to the folder. :func:`load_study` checks everything and reports every problem
it finds in one :class:`~angiohull.errors.StudyError`, one line per problem, each line
``<path to study.yaml>: <field>: <what was expected, what was received>``.
"""

from __future__ import annotations

import math
import os
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Iterable, Optional, Sequence, Union

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from . import _validation as _v
from . import dicom, exports, io
from .errors import DicomError, GeometryError, InputWarning, SegmentationError, StudyError
from ._models import find_model, short_repr
from ._yaml import read_yaml_file
from .geometry import CArmGeometry, Projection
from .segmentation import SegmentationParameters, flat_image_message, segment_vessels, segment_vessels_detailed
from .tree import VesselTree

__all__ = ["View", "Study", "load_study", "save_study", "study_from_dicom", "DicomViewSummary", "FORMAT_VERSION",
           "STUDY_FILE"]

#: Version of the ``study.yaml`` format this module reads and writes (the ``angiohull:`` key).
FORMAT_VERSION = 1
#: File name of the study description inside a study folder.
STUDY_FILE = "study.yaml"

_SOURCES = ("carm", "projection_matrix", "dicom")
_MASK_FORMATS = {"png": ".png", "tif": ".tif", "tiff": ".tiff", "npy": ".npy"}
_GROUND_TRUTH_FILE = "gt.npy"


# -- in-memory study ------------------------------------------------------------------------
def _readonly_bool(array: np.ndarray) -> np.ndarray:
    return _v.readonly_copy(np.asarray(array) != 0, dtype=bool)


@dataclass(frozen=True, eq=False)
class View:
    """One X-ray view: its vessel mask and acquisition geometry.

    Parameters
    ----------
    name : str
        Unique name of the view within its study (also the mask's file stem when saved).
    mask : array_like of bool, shape (rows, cols)
        Vessel mask, nonzero = vessel; stored as a read-only bool copy. Its shape is the
        detector's (rows, cols) and must equal ``projection.image_shape``.
    projection : Projection
        The view's 3x4 projection (mm -> pixel, ``u`` = column, ``v`` = row).
    carm : CArmGeometry or None
        The C-arm pose the projection was computed from, or None when the view was given as a
        matrix. When given, ``projection`` must be exactly ``carm.projection()``.
    source : {"carm", "projection_matrix", "dicom"} or None
        Where the geometry came from; None infers it from ``carm`` ("carm" or
        "projection_matrix"). A "dicom" view has the ``carm`` read from ``dicom_path``.
    mask_path : Path or None
        The file the mask was read from, if any (None when it was segmented from an image).
    dicom_path : Path or None
        The XA file the geometry was read from (``source == "dicom"`` only).
    frame : int or None
        The frame (from 0) of ``dicom_path`` whose geometry is used, or None when every frame
        has the same geometry and none was named.
    image_path : Path or None
        The raw image the mask was segmented from, if any.
    attenuation : ndarray of float64 or None
        For a view segmented from its image: the flattened attenuation the segmentation computed,
        unclipped (:attr:`angiohull.segmentation.SegmentationResult.lumen_attenuation`, the mask's shape), on which
        the quantitative analysis measures lesions (``reconstruct --qca``); None otherwise.

    Raises
    ------
    StudyError
        If the fields are inconsistent (shapes, source, carm vs projection).
    """

    name: str
    mask: np.ndarray
    projection: Projection
    carm: Optional[CArmGeometry] = None
    source: Optional[str] = None
    mask_path: Optional[Path] = None
    dicom_path: Optional[Path] = None
    frame: Optional[int] = None
    image_path: Optional[Path] = None
    attenuation: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise StudyError(f"view name must be a non-empty string, got {self.name!r}")
        where = f"view {self.name!r}"
        mask = np.asarray(self.mask)
        if mask.ndim != 2 or mask.dtype.kind not in "biuf":
            raise StudyError(f"{where}: mask must be a 2D (rows, cols) numeric array, got shape {mask.shape}, dtype {mask.dtype}")
        if not isinstance(self.projection, Projection):
            raise StudyError(f"{where}: projection must be a Projection, got {type(self.projection).__name__}")
        if mask.shape != self.projection.image_shape:
            raise StudyError(f"{where}: mask shape {mask.shape} differs from the projection's image_shape {self.projection.image_shape}")
        source = self.source if self.source is not None else ("carm" if self.carm is not None else "projection_matrix")
        self._check_source(source, where)
        object.__setattr__(self, "mask", _readonly_bool(mask))
        object.__setattr__(self, "source", source)
        if self.attenuation is not None:
            attenuation = np.array(self.attenuation, dtype=np.float64)
            if attenuation.shape != mask.shape:
                raise StudyError(f"{where}: attenuation shape {attenuation.shape} differs from the mask's {mask.shape}")
            attenuation.setflags(write=False)
            object.__setattr__(self, "attenuation", attenuation)
        for name in ("mask_path", "dicom_path", "image_path"):
            value = getattr(self, name)
            object.__setattr__(self, name, None if value is None else Path(value))

    def _check_source(self, source: str, where: str) -> None:
        if source not in ("carm", "projection_matrix", "dicom"):
            raise StudyError(f"{where}: source must be 'carm', 'projection_matrix' or 'dicom', got {source!r}")
        needs_carm = source in ("carm", "dicom")
        if needs_carm != (self.carm is not None):
            raise StudyError(f"{where}: source {source!r} needs carm {'given' if needs_carm else 'None'}, got {self.carm!r}")
        if (source == "dicom") != (self.dicom_path is not None):
            raise StudyError(f"{where}: dicom_path is given exactly for source 'dicom', got source {source!r} and "
                             f"dicom_path {self.dicom_path!r}")
        if self.frame is not None and (source != "dicom" or isinstance(self.frame, bool) or not isinstance(self.frame, int)
                                       or self.frame < 0):
            raise StudyError(f"{where}: frame must be an index >= 0 of a 'dicom' view's file, got frame {self.frame!r} "
                             f"with source {source!r}")
        if self.carm is not None:
            if not isinstance(self.carm, CArmGeometry):
                raise StudyError(f"{where}: carm must be a CArmGeometry, got {type(self.carm).__name__}")
            if not np.array_equal(self.carm.projection().matrix, self.projection.matrix):
                raise StudyError(f"{where}: projection is not carm.projection(); build the view with View.from_carm")

    @classmethod
    def from_carm(cls, name: str, mask: Any, carm: CArmGeometry, *, mask_path: Optional[Path] = None) -> "View":
        """A view whose projection is ``carm.projection()``; ``carm.image_shape`` must be the mask's."""
        return cls(name=name, mask=mask, projection=carm.projection(), carm=carm, source="carm", mask_path=mask_path)

    @classmethod
    def from_dicom(cls, name: str, mask: Any, dicom_path: Union[str, Path], frame: Optional[int] = None, *,
                   mask_path: Optional[Path] = None, image_path: Optional[Path] = None) -> "View":
        """A view whose geometry is read from an XA file's header (one frame, or the run's only geometry).

        Raises
        ------
        DicomError
            If the file cannot be read (see :func:`angiohull.dicom.read_xa_header`), the frame does
            not exist or is needed (a rotational run), or the header's matrix size differs from
            the mask's shape.
        """
        header = dicom.read_xa_header(dicom_path)
        carm = header.geometry(frame)
        if carm.image_shape != np.shape(mask):
            raise DicomError(f"{dicom_path}: the image is {carm.image_shape[0]} x {carm.image_shape[1]} pixels (Rows, Columns) "
                             f"but view {name!r}'s mask is {np.shape(mask)}; the mask must have the detector's shape")
        return cls(name=name, mask=mask, projection=carm.projection(), carm=carm, source="dicom", mask_path=mask_path,
                   dicom_path=Path(dicom_path), frame=None if frame is None else int(frame), image_path=image_path)

    @classmethod
    def from_matrix(cls, name: str, mask: Any, matrix: Any, *, mask_path: Optional[Path] = None) -> "View":
        """A view given by a 3x4 projection matrix; the image shape is the mask's shape."""
        shape = np.shape(mask)
        try:
            projection = Projection(matrix, shape)  # type: ignore[arg-type]
        except GeometryError as exc:
            raise StudyError(f"view {name!r}: {exc}") from None
        return cls(name=name, mask=mask, projection=projection, source="projection_matrix", mask_path=mask_path)


@dataclass(frozen=True, eq=False)
class Study:
    """A set of views and, optionally, the ground truth they were made from.

    Parameters
    ----------
    root : Path or None
        The study folder, when the study was read from one.
    views : tuple of View
        At least one view, with unique names.
    ground_truth_mm : ndarray of float64, shape (N, 3), or None
        Ground-truth points in mm (world frame of docs/conventions.md), stored read-only.
    ground_truth_path : Path or None
        The file the ground truth was read from.
    ground_truth_tree : VesselTree or None
        The true vessel tree (centerlines with radii), when the study has one.
    ground_truth_tree_path : Path or None
        The file it was read from.
    """

    root: Optional[Path]
    views: tuple[View, ...]
    ground_truth_mm: Optional[np.ndarray] = None
    ground_truth_path: Optional[Path] = None
    ground_truth_tree: Optional[VesselTree] = None
    ground_truth_tree_path: Optional[Path] = None

    def __post_init__(self) -> None:
        views = tuple(self.views)
        _check_views(views, "study")
        object.__setattr__(self, "views", views)
        if self.ground_truth_mm is not None:
            points = _points(self.ground_truth_mm, "study: ground_truth_mm")
            points.setflags(write=False)
            object.__setattr__(self, "ground_truth_mm", points)
        if self.ground_truth_tree is not None and not isinstance(self.ground_truth_tree, VesselTree):
            raise StudyError(f"study: ground_truth_tree must be a VesselTree, got {type(self.ground_truth_tree).__name__}")

    @property
    def projections(self) -> tuple[Projection, ...]:
        """The views' projections, in order."""
        return tuple(view.projection for view in self.views)

    @property
    def masks(self) -> tuple[np.ndarray, ...]:
        """The views' bool masks (rows, cols), in order."""
        return tuple(view.mask for view in self.views)

    @property
    def names(self) -> tuple[str, ...]:
        """The views' names, in order."""
        return tuple(view.name for view in self.views)


def _check_views(views: Sequence[Any], where: str) -> None:
    if not views:
        raise StudyError(f"{where}: needs at least one view, got none")
    for index, view in enumerate(views):
        if not isinstance(view, View):
            raise StudyError(f"{where}: views[{index}] must be a View, got {type(view).__name__}")
    names = [view.name for view in views]
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise StudyError(f"{where}: view names must be unique, got duplicates {duplicates}")


def _points(points: Any, where: str) -> np.ndarray:
    array = np.array(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise StudyError(f"{where}: expected an (N, 3) array of x, y, z in mm, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise StudyError(f"{where}: contains non-finite values (nan or inf); expected finite mm")
    return array


# -- study.yaml schema ----------------------------------------------------------------------
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


_Pair = Annotated[list[float], Field(min_length=2, max_length=2)]
_Text = Annotated[str, Field(min_length=1)]


class _CArmEntry(_Strict):
    primary_deg: float  # LAO +, RAO -
    secondary_deg: float  # CRA +, CAU -
    sid_mm: float
    sod_mm: float
    pixel_spacing_mm: _Pair  # [row, col] at the detector
    principal_offset_px: Optional[_Pair] = None  # [du, dv]


class _ViewEntry(_Strict):
    name: Optional[_Text] = None
    mask: Optional[_Text] = None
    carm: Optional[_CArmEntry] = None
    projection_matrix: Optional[list[list[float]]] = None
    dicom: Optional[_Text] = None
    frame: Optional[Annotated[int, Field(ge=0)]] = None  # frame index from 0
    image: Optional[_Text] = None  # a raw angiogram (DICOM, PNG, TIFF or NPY) to segment
    segmentation: Optional[dict[str, Any]] = None  # overrides of SegmentationParameters

    @field_validator("projection_matrix")
    @classmethod
    def _three_by_four(cls, rows: Optional[list[list[float]]]) -> Optional[list[list[float]]]:
        if rows is None:
            return rows
        lengths = [len(row) for row in rows]
        if lengths != [4, 4, 4]:
            raise ValueError(f"expected a 3x4 matrix (3 rows of 4 numbers), got {len(rows)} rows of lengths {lengths}")
        if not all(math.isfinite(value) for row in rows for value in row):
            raise ValueError(f"expected 12 finite numbers, got non-finite values (nan or inf): {rows}")
        problem = _isocentre_behind(rows[2][3])
        if problem:
            raise ValueError(problem)
        return rows

    @model_validator(mode="after")
    def _one_source(self) -> "_ViewEntry":
        given = [key for key in _SOURCES if getattr(self, key) is not None]
        if len(given) != 1:
            found = "no geometry source" if not given else f"{len(given)} geometry sources ({', '.join(given)})"
            raise ValueError(f"view {self.resolved_name!r} has {found}; give exactly one of carm:, projection_matrix:, dicom:")
        if (self.mask is None) == (self.image is None):
            found = "neither mask: nor image:" if self.mask is None else "both mask: and image:"
            raise ValueError(f"view {self.resolved_name!r} has {found}; give exactly one of mask: (a binary vessel mask) "
                             "or image: (a raw angiogram, DICOM or PNG/TIFF/NPY, to segment)")
        if self.frame is not None and self.dicom is None and self.image is None:
            raise ValueError(f"view {self.resolved_name!r}: frame: is only used with dicom: or a DICOM image:, got frame: {self.frame}")
        if self.segmentation is not None and self.image is None:
            raise ValueError(f"view {self.resolved_name!r}: segmentation: is only used with image: (a mask: is not segmented), "
                             f"got segmentation: {self.segmentation}")
        return self

    @property
    def resolved_name(self) -> str:
        if self.name is not None:
            return self.name
        for path in (self.mask, self.image, self.dicom):
            if path is not None:
                return Path(path).stem
        return "?"


class _StudyFile(_Strict):
    angiohull: int
    views: Annotated[list[_ViewEntry], Field(min_length=1)]
    ground_truth: Optional[_Text] = None
    ground_truth_tree: Optional[_Text] = None
    allow_outside_paths: bool = False  # read files outside the study folder (off: a study is a folder)

    @field_validator("angiohull")
    @classmethod
    def _version(cls, value: int) -> int:
        if value != FORMAT_VERSION:
            raise ValueError(
                f"unsupported study format version {value}; this version of angiohull reads "
                f"version {FORMAT_VERSION} (write 'angiohull: {FORMAT_VERSION}', or use a newer angiohull)"
            )
        return value

    @field_validator("views")
    @classmethod
    def _unique_names(cls, views: list[_ViewEntry]) -> list[_ViewEntry]:
        where: dict[str, list[int]] = {}
        for index, view in enumerate(views):
            where.setdefault(view.resolved_name, []).append(index)
        clashes = [f"{name!r} is used by views {indices}" for name, indices in where.items() if len(indices) > 1]
        if clashes:
            raise ValueError(
                "view names must be unique: " + "; ".join(clashes)
                + " (a name defaults to the mask file's stem; give name: to tell them apart)"
            )
        return views


# -- error messages -------------------------------------------------------------------------
def _format_loc(loc: Iterable[Union[str, int]]) -> str:
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


def _model_at(loc: Sequence[Union[str, int]]) -> Optional[type[BaseModel]]:
    """The schema model that holds the keys at ``loc`` (list indices are skipped)."""
    model: Optional[type[BaseModel]] = _StudyFile
    for part in loc:
        if isinstance(part, str) and model is not None:
            field = model.model_fields.get(part)
            model = None if field is None else find_model(field.annotation)
    return model


def _received(value: Any) -> str:
    hint = ""
    if isinstance(value, str):
        try:
            number = yaml.safe_dump(float(value)).splitlines()[0]
            hint = f" (YAML read this as text; write the number as {number})"
        except ValueError:
            pass
    return f"got {short_repr(value)} ({type(value).__name__}){hint}"


def _pydantic_problem(error: Any) -> tuple[str, str]:
    """``(field, message)`` for one pydantic error."""
    loc, kind = tuple(error["loc"]), error["type"]
    if kind in ("extra_forbidden", "invalid_key"):
        model = _model_at(loc[:-1])
        allowed = "allowed keys here: " + (", ".join(model.model_fields) if model is not None else "?")
        if kind == "extra_forbidden":
            return _format_loc(loc), f"unknown key; {allowed}"
        return _format_loc(loc[:-1]) or "(top level)", f"key {loc[-1]!r} is not text; {allowed}"
    if kind in ("model_type", "dict_type"):
        model = _model_at(loc)
        keys = ", ".join(model.model_fields) if model is not None else "?"
        return _format_loc(loc), f"expected a mapping with keys from: {keys}; {_received(error['input'])}"
    if kind == "missing":
        return _format_loc(loc), "required key is missing"
    if kind == "value_error":
        return _format_loc(loc), str(error["ctx"]["error"])
    return _format_loc(loc), f"{error['msg']}, {_received(error['input'])}"


class _Problem(Exception):
    """One problem with a field of study.yaml (collected, then raised as one StudyError)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field, self.message = field, message


def _raise_problems(yaml_path: Path, problems: Sequence[tuple[str, str]]) -> None:
    if problems:
        raise StudyError("\n".join(f"{yaml_path}: {field}: {message}" for field, message in problems))


# -- loading --------------------------------------------------------------------------------
def _study_file(folder: Union[str, Path]) -> Path:
    path = Path(folder)
    yaml_path = path / STUDY_FILE if path.is_dir() else path
    if not yaml_path.is_file():
        raise StudyError(
            f"{yaml_path}: study file not found; expected a study folder containing {STUDY_FILE} "
            f"(or the path to the {STUDY_FILE} itself)"
        )
    return yaml_path


def _parse_yaml(yaml_path: Path) -> dict[str, Any]:
    data = read_yaml_file(yaml_path, error=StudyError, what="the study file")
    if not isinstance(data, dict):
        got = "an empty file" if data is None else f"a {type(data).__name__}"
        raise StudyError(
            f"{yaml_path}: expected a YAML mapping with keys angiohull, views and optionally "
            f"ground_truth, got {got}"
        )
    return data


def _validate(yaml_path: Path, data: dict[str, Any]) -> _StudyFile:
    try:
        return _StudyFile.model_validate(data)
    except ValidationError as exc:
        _raise_problems(yaml_path, [_pydantic_problem(error) for error in exc.errors(include_url=False)])
        raise  # unreachable: a ValidationError always has at least one error


def _geometry(entry: _ViewEntry, shape: tuple[int, int], field: str) -> tuple[Projection, Optional[CArmGeometry]]:
    try:
        if entry.carm is None:
            return Projection(np.array(entry.projection_matrix, dtype=np.float64), shape), None
        carm = CArmGeometry(
            primary_deg=entry.carm.primary_deg,
            secondary_deg=entry.carm.secondary_deg,
            sid_mm=entry.carm.sid_mm,
            sod_mm=entry.carm.sod_mm,
            pixel_spacing_mm=tuple(entry.carm.pixel_spacing_mm),
            image_shape=shape,
            principal_offset_px=tuple(entry.carm.principal_offset_px or (0.0, 0.0)),
        )
        return carm.projection(), carm
    except GeometryError as exc:
        raise _Problem(field, str(exc)) from None


def _read_view_mask(entry: _ViewEntry, root: Path, name: str, where: str, header: Optional[dicom.XAHeader] = None
                    ) -> tuple[np.ndarray, Optional[int], Optional[np.ndarray]]:
    """The view's mask (read, or segmented from its image), the DICOM frame the image came from and
    the segmentation's flattened attenuation (None for a mask).

    ``header`` is the geometry's XA header, reused when the image is the same file.
    """
    if entry.mask is not None:
        mask_path = root / entry.mask
        try:
            mask = io.read_mask(mask_path)
        except StudyError as exc:
            raise _Problem(f"{where}.mask", f"view {name!r}: {exc}") from None
        if not mask.any():
            raise _Problem(
                f"{where}.mask",
                f"view {name!r}: {mask_path}: the mask has no vessel pixel (all {mask.shape[0]}x{mask.shape[1]} "
                "pixels are zero); expected nonzero vessel pixels",
            )
        return mask, None, None
    try:
        params = SegmentationParameters().replace(entry.segmentation or {})
    except SegmentationError as exc:
        raise _Problem(f"{where}.segmentation", f"view {name!r}: {exc}") from None
    image_path = root / str(entry.image)
    frame_used = None
    try:
        if image_path.suffix.lower() in io.IMAGE_SUFFIXES:
            if entry.frame is not None and entry.dicom is None:
                raise _Problem(f"{where}.frame", f"view {name!r}: frame: is only used with dicom: or a DICOM image:, "
                                                 f"but {image_path.name} is not a DICOM file")
            image = io.read_image(image_path)
        else:
            same = header is not None and _same_file(header.path, image_path)
            xa = dicom.read_xa_view(image_path, _image_frame(entry, root, image_path), parameters=params,
                                    header=header if same else None)
            image, frame_used = xa.image, xa.frame
    except StudyError as exc:  # DicomError is a StudyError
        raise _Problem(f"{where}.image", f"view {name!r}: {exc}") from None
    try:
        segmented = segment_vessels_detailed(image, params)
    except SegmentationError as exc:  # an image it cannot segment (too small, not finite)
        raise _Problem(f"{where}.image", f"view {name!r}: {image_path}: {exc}") from None
    mask = segmented.mask
    if not mask.any():
        raise _Problem(
            f"{where}.image",
            f"view {name!r}: {image_path}: " + (
                flat_image_message(image) or "the segmentation found no vessel; check the image, or lower "
                "segmentation: {high_threshold: ..., seed_snr: ...} (see angiohull.segmentation.SegmentationParameters)"),
        )
    return mask, frame_used, segmented.lumen_attenuation


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve()
    except OSError:  # pragma: no cover - unresolvable paths
        return a == b


def _image_frame(entry: _ViewEntry, root: Path, image_path: Path) -> Optional[int]:
    """The frame of a DICOM image: ``frame:`` when it belongs to that file, else automatic (None)."""
    if entry.frame is None:
        return None
    if entry.dicom is None or _same_file(root / entry.dicom, image_path):
        return entry.frame
    return None  # frame: names the geometry's frame in another file


def _dicom_header(entry: _ViewEntry, root: Path, where: str, name: str) -> dicom.XAHeader:
    try:
        return dicom.read_xa_header(root / str(entry.dicom))
    except DicomError as exc:
        raise _Problem(f"{where}.dicom", f"view {name!r}: {exc}") from None


def _dicom_geometry(entry: _ViewEntry, root: Path, header: dicom.XAHeader, shape: tuple[int, int], frame_used: Optional[int],
                    where: str, name: str) -> tuple[CArmGeometry, Path, Optional[int]]:
    """Geometry from ``dicom:``; the image's frame when the image is the same file and no frame: is given."""
    path = root / str(entry.dicom)
    frame = entry.frame
    if frame is None and frame_used is not None and entry.image is not None and _same_file(path, root / entry.image):
        frame = frame_used
    try:
        carm = header.geometry(frame)
    except DicomError as exc:  # a frame that does not exist, or none given for a rotational run
        raise _Problem(f"{where}.frame" if entry.frame is not None else f"{where}.dicom", f"view {name!r}: {exc}") from None
    if carm.image_shape != shape:
        raise _Problem(f"{where}.dicom", f"view {name!r}: {path}: the image is {carm.image_shape[0]} x {carm.image_shape[1]} "
                                         f"pixels (Rows, Columns) but the mask is {shape[0]} x {shape[1]}; the mask must have "
                                         "the detector's shape")
    return carm, path, frame


def _load_view(index: int, entry: _ViewEntry, root: Path) -> View:
    name, where = entry.resolved_name, f"views[{index}]"
    header = None if entry.dicom is None else _dicom_header(entry, root, where, name)
    mask, frame_used, attenuation = _read_view_mask(entry, root, name, where, header)
    mask_path = None if entry.mask is None else root / entry.mask
    image_path = None if entry.image is None else root / entry.image
    if entry.dicom is not None:
        carm, dicom_path, frame = _dicom_geometry(entry, root, header, mask.shape, frame_used, where, name)
        return View(name=name, mask=mask, projection=carm.projection(), carm=carm, source="dicom", mask_path=mask_path,
                    dicom_path=dicom_path, frame=frame, image_path=image_path, attenuation=attenuation)
    source = "carm" if entry.carm is not None else "projection_matrix"
    projection, carm = _geometry(entry, mask.shape, f"{where}.{source}")
    return View(name=name, mask=mask, projection=projection, carm=carm, source=source, mask_path=mask_path,
                image_path=image_path, attenuation=attenuation)


_PATH_FIELDS = ("mask", "image", "dicom")


def _outside(relative: str, root: Path, field: str) -> Optional[tuple[str, str]]:
    """``(field, message)`` when ``root / relative`` lies outside the study folder (``..``, an
    absolute path, or a symbolic link that leads out), else None."""
    folder = Path(os.path.realpath(root))
    target = Path(os.path.realpath(root / relative))
    if target == folder or folder in target.parents:
        return None
    how = "is an absolute path" if Path(relative).is_absolute() else "leads out of the study folder"
    return field, (f"{relative!r} {how} ({target}); a study's files stay inside its folder ({folder}): move the "
                   f"file in, or add 'allow_outside_paths: true' to study.yaml to read files elsewhere")


def _outside_paths(entries: "_StudyFile", root: Path) -> list[tuple[str, str]]:
    """Every path of the study file that lies outside the study folder (none with allow_outside_paths)."""
    if entries.allow_outside_paths:
        return []
    found = []
    for index, view in enumerate(entries.views):
        for key in _PATH_FIELDS:
            relative = getattr(view, key)
            if relative is not None:
                problem = _outside(relative, root, f"views[{index}].{key}")
                if problem is not None:
                    found.append(problem)
    for key in ("ground_truth", "ground_truth_tree"):
        relative = getattr(entries, key)
        if relative is not None:
            problem = _outside(relative, root, key)
            if problem is not None:
                found.append(problem)
    return found


def _load_ground_truth(relative: str, root: Path) -> tuple[np.ndarray, Path]:
    path = root / relative
    try:
        points = io.read_points(path)
    except StudyError as exc:
        raise _Problem("ground_truth", str(exc)) from None
    if len(points) == 0:
        raise _Problem("ground_truth", f"{path}: holds no points; the scores against the truth are undefined without "
                                       f"any: give the true points, or remove ground_truth: from study.yaml")
    return points, path


def _load_ground_truth_tree(relative: str, root: Path) -> tuple[VesselTree, Path]:
    path = root / relative
    try:
        return exports.read_true_tree(path), path
    except StudyError as exc:
        raise _Problem("ground_truth_tree", str(exc)) from None


def load_study(folder: Union[str, Path]) -> Study:
    """Read and check a study folder.

    Parameters
    ----------
    folder : str or Path
        The study folder, or the path to its ``study.yaml``. Paths inside are relative to the
        folder that holds the YAML file.

    Returns
    -------
    Study
        Views in file order, each with a bool mask (rows, cols) and its projection (for ``carm:``
        views built with ``image_shape = mask.shape``), and the ground truth (N, 3) in mm if given.

    Raises
    ------
    StudyError
        One error listing every problem found, one line each, as
        ``<path to study.yaml>: <field, e.g. views[1].carm.sid_mm>: <expected, received>``:
        unreadable or malformed YAML, unknown or missing keys, wrong types, a format version other
        than 1, zero or two geometry sources in a view, zero or two of mask/image, duplicate view
        names, missing, unreadable or empty masks, an image whose segmentation finds no vessel or
        bad segmentation overrides, an unusable DICOM file (named tag), invalid C-arm parameters
        or matrices, and an unreadable or empty ground truth or true tree; a path (``mask:``, ``image:``,
        ``dicom:``, ``ground_truth:``, ``ground_truth_tree:``) that leads outside the study folder
        (``../x``, an absolute path, a symbolic link out), unless the file sets
        ``allow_outside_paths: true``.

    Warns
    -----
    DicomGeometryWarning
        When a DICOM file's pixel spacing is derived from a fallback tag.
    InputWarning
        For a mask (read or segmented) with fewer than :data:`MIN_MASK_SIDE_PX` rows or columns,
        or more than :data:`MAX_VESSEL_SHARE` of its pixels vessel (probably inverted), and for
        DICOM headers that are legal but suspicious (see :func:`angiohull.dicom.read_xa_header`).
    """
    yaml_path = _study_file(folder)
    entries = _validate(yaml_path, _parse_yaml(yaml_path))
    root = yaml_path.parent
    _raise_problems(yaml_path, _outside_paths(entries, root))  # before any of them is read
    views: list[View] = []
    problems: list[tuple[str, str]] = []
    ground_truth, ground_truth_path = None, None
    for index, entry in enumerate(entries.views):
        try:
            views.append(_load_view(index, entry, root))
        except _Problem as problem:
            problems.append((problem.field, problem.message))
    if entries.ground_truth is not None:
        try:
            ground_truth, ground_truth_path = _load_ground_truth(entries.ground_truth, root)
        except _Problem as problem:
            problems.append((problem.field, problem.message))
    tree, tree_path = None, None
    if entries.ground_truth_tree is not None:
        try:
            tree, tree_path = _load_ground_truth_tree(entries.ground_truth_tree, root)
        except _Problem as problem:
            problems.append((problem.field, problem.message))
    _raise_problems(yaml_path, problems)
    for index, (entry, view) in enumerate(zip(entries.views, views)):
        _warn_if_suspicious(yaml_path, f"views[{index}].{'mask' if entry.mask is not None else 'image'}", view)
    return Study(root=root, views=tuple(views), ground_truth_mm=ground_truth, ground_truth_path=ground_truth_path,
                 ground_truth_tree=tree, ground_truth_tree_path=tree_path)


MIN_MASK_SIDE_PX = _v.MIN_MASK_SIDE_PX
"""A mask with fewer rows or columns than this cannot show a vessel with background beside it."""
MAX_VESSEL_SHARE = _v.MAX_VESSEL_SHARE
"""A vessel mask covering more than this share of its image is probably inverted (vessels cover a few percent)."""


def _warn_if_suspicious(yaml_path: Path, field: str, view: View) -> None:
    """An :class:`~angiohull.errors.InputWarning` for a mask that is legal but probably not meant."""
    rows, cols = view.mask.shape
    source = view.mask_path if view.mask_path is not None else view.image_path
    where = f"{yaml_path}: {field}: view {view.name!r}" + (f" ({source})" if source is not None else "")
    if min(rows, cols) < MIN_MASK_SIDE_PX:
        warnings.warn(f"{where}: the mask is only {rows} x {cols} pixels, too small to show a vessel and the background "
                      f"beside it; is it the right file?", InputWarning, stacklevel=3)
    problem = _v.vessel_share_problem(view.mask)
    if problem:
        warnings.warn(f"{where}: {problem}", InputWarning, stacklevel=3)


# -- saving ---------------------------------------------------------------------------------
def _carm_entry(carm: CArmGeometry) -> dict[str, Any]:
    entry: dict[str, Any] = {
        "primary_deg": float(carm.primary_deg),
        "secondary_deg": float(carm.secondary_deg),
        "sid_mm": float(carm.sid_mm),
        "sod_mm": float(carm.sod_mm),
        "pixel_spacing_mm": [float(value) for value in carm.pixel_spacing_mm],
    }
    if any(value != 0.0 for value in carm.principal_offset_px):
        entry["principal_offset_px"] = [float(value) for value in carm.principal_offset_px]
    return entry


def _relative(path: Path, folder: Path) -> str:
    """``path`` relative to ``folder`` (POSIX separators), or absolute when there is no relative path."""
    try:
        return Path(os.path.relpath(path.resolve(), folder.resolve())).as_posix()
    except ValueError:  # e.g. another drive on Windows
        return str(path.resolve())


def _isocentre_behind(depth: float) -> str | None:
    """What is wrong with a projection matrix whose isocentre depth ``P[2, 3]`` (the w of the world
    origin, where the cube of interest is centred) is negative: it lies behind the source. None
    otherwise (0 is the degenerate matrices' error, given where the matrix is read)."""
    if depth >= 0:
        return None
    return (f"the isocentre (the world origin, where the cube of interest is centred) has depth w = {depth:g} < 0, "
            f"behind the source; w > 0 in front (DESIGN: P maps [X, Y, Z, 1] to [u w, v w, w]); a matrix of the "
            f"opposite sign projects the same pixels: multiply it by -1")


def _view_entry(view: View, mask_file: str, folder: Path) -> dict[str, Any]:
    entry: dict[str, Any] = {"name": view.name, "mask": mask_file}
    if view.source == "dicom":
        entry["dicom"] = _relative(Path(view.dicom_path), folder)
        if view.frame is not None:
            entry["frame"] = int(view.frame)
    elif view.carm is not None:
        entry["carm"] = _carm_entry(view.carm)
    else:  # tolist() gives Python floats, which PyYAML writes with repr: exact round trip
        problem = _isocentre_behind(float(view.projection.matrix[2, 3]))
        if problem:  # (the study could not be loaded back)
            raise StudyError(f"{folder}: view {view.name!r}: {problem}")
        entry["projection_matrix"] = view.projection.matrix.tolist()
    return entry


def _check_file_name(name: str, where: str) -> None:
    if name in (".", "..") or Path(name).name != name or "\\" in name:
        raise StudyError(f"{where}: view name {name!r} cannot be a file name; use a name without path separators")


def save_study(
    folder: Union[str, Path],
    views: Iterable[View],
    *,
    ground_truth_mm: Optional[Any] = None,
    mask_format: str = "png",
    ground_truth_tree_file: Optional[str] = None,
) -> Path:
    """Write a study folder that :func:`load_study` reads back exactly.

    Parameters
    ----------
    folder : str or Path
        The study folder; created if missing. An existing ``study.yaml``, masks of the same names
        and ``gt.npy`` are overwritten.
    views : iterable of View
        At least one, with unique names usable as file names. ``carm`` views are written as
        ``carm:`` (plain floats), ``dicom`` views as ``dicom:`` (the file's path relative to the
        folder) and ``frame:``, the others as ``projection_matrix:`` (every float at full
        precision). Masks (also those segmented from images) are written to ``masks/`` and must
        contain at least one vessel pixel.
    ground_truth_mm : array_like, shape (N, 3), optional
        Ground-truth points in mm, written to ``gt.npy``.
    mask_format : {"png", "tiff", "tif", "npy"}
        Format of ``masks/<name>.<ext>``.
    ground_truth_tree_file : str, optional
        A file holding the true vessel tree, relative to the folder (e.g. ``gt_centerlines.npz``,
        which the caller writes): recorded as ``ground_truth_tree:``.

    Returns
    -------
    Path
        The written ``study.yaml``.

    Raises
    ------
    StudyError
        For bad arguments (no views, duplicate or unusable names, empty masks, bad ground truth,
        unknown mask format) or a file that cannot be written.
    """
    folder = Path(folder)
    views = tuple(views)
    _check_views(views, f"{folder}: save_study")
    suffix = _MASK_FORMATS.get(mask_format)
    if suffix is None:
        raise StudyError(f"{folder}: mask_format must be one of {sorted(_MASK_FORMATS)}, got {mask_format!r}")
    for view in views:
        _check_file_name(view.name, f"{folder}: save_study")
        if not view.mask.any():
            raise StudyError(f"{folder}: save_study: view {view.name!r} has an empty mask (no vessel pixel)")
    points = None if ground_truth_mm is None else _points(ground_truth_mm, f"{folder}: ground_truth_mm")
    try:
        (folder / "masks").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StudyError(f"{folder}: cannot create the study folder ({exc})") from None
    document: dict[str, Any] = {"angiohull": FORMAT_VERSION, "views": []}
    for view in views:
        mask_file = f"masks/{view.name}{suffix}"
        io.write_mask(folder / mask_file, view.mask)
        document["views"].append(_view_entry(view, mask_file, folder))
    if points is not None:
        _save_points(folder / _GROUND_TRUTH_FILE, points)
        document["ground_truth"] = _GROUND_TRUTH_FILE
    if ground_truth_tree_file is not None:
        document["ground_truth_tree"] = str(ground_truth_tree_file)
    if any("dicom" in entry and _outside(entry["dicom"], folder, "dicom") is not None for entry in document["views"]):
        document["allow_outside_paths"] = True  # a dicom: view refers to its file where it is
    return _write_yaml(folder / STUDY_FILE, document)


def _save_points(path: Path, points: np.ndarray) -> None:
    try:
        with open(path, "wb") as handle:
            np.save(handle, points, allow_pickle=False)
    except OSError as exc:
        raise StudyError(f"{path}: cannot write the ground truth ({exc})") from None


def _write_yaml(yaml_path: Path, document: dict[str, Any]) -> Path:
    text = "# angiohull study (docs/conventions.md, 'Study folder'); paths are relative to this folder\n"
    text += yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=4096)
    try:
        yaml_path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise StudyError(f"{yaml_path}: cannot write the study file ({exc})") from None
    return yaml_path


# -- building a study from XA runs ----------------------------------------------------------
@dataclass(frozen=True)
class DicomViewSummary:
    """One view written by :func:`study_from_dicom`."""

    name: str  # the view's name in study.yaml
    source_file: Path  # the XA file it came from
    frame: int  # the frame used, from 0
    selection: str  # how the frame was chosen
    carm: CArmGeometry  # its geometry
    mask_pixels: Optional[int]  # vessel pixels of the segmented mask, None when not segmented yet


def _segmentation_overrides(params: SegmentationParameters) -> dict[str, Any]:
    """The fields of ``params`` that differ from the defaults, as YAML-friendly values."""
    default = SegmentationParameters()
    changed = {}
    for name in SegmentationParameters.field_names():
        value = getattr(params, name)
        if value != getattr(default, name):
            changed[name] = list(value) if isinstance(value, tuple) else value
    return changed


def _unique(stem: str, taken: set[str]) -> str:
    name, k = stem, 2
    while name in taken:
        name, k = f"{stem}_{k}", k + 1
    taken.add(name)
    return name


def study_from_dicom(
    files: Sequence[Union[str, Path]],
    folder: Union[str, Path],
    *,
    segment: bool = False,
    frame: Optional[int] = None,
    all_frames: bool = False,
    copy: bool = True,
    parameters: Optional[SegmentationParameters] = None,
) -> tuple[Path, list[DicomViewSummary]]:
    """Write a study folder whose views come from XA runs (geometry from the headers).

    Parameters
    ----------
    files : sequence of str or Path
        XA DICOM files, one or more views each.
    folder : str or Path
        The study folder (created; an existing ``study.yaml`` and files of the same names are
        overwritten).
    segment : bool
        Segment now and write ``masks/<name>.png`` (views get ``mask:``); otherwise views get
        ``image:`` and are segmented each time the study is loaded.
    frame : int, optional
        Use this frame (from 0) of every file. Default: one frame per file, chosen automatically
        (:func:`angiohull.dicom.select_frame`) and written as ``frame:`` so that the study is
        reproducible.
    all_frames : bool
        One view per frame (e.g. a rotational run), named ``<stem>_f<frame>``.
    copy : bool
        Copy the files into ``<folder>/dicom/`` (a self-contained study); otherwise refer to
        them by their path relative to the folder.
    parameters : SegmentationParameters, optional
        Segmentation (and frame scoring) parameters; non-default ones are written to each
        ``image:`` view's ``segmentation:``.

    Returns
    -------
    (Path, list of DicomViewSummary)
        The written ``study.yaml`` and one summary per view.

    Raises
    ------
    StudyError
        No files, ``frame`` together with ``all_frames``, a file that cannot be used
        (:class:`~angiohull.errors.DicomError`), a segmentation that finds no vessel, or a file
        that cannot be written.
    """
    files = [Path(f) for f in files]
    folder = Path(folder)
    if not files:
        raise StudyError(f"{folder}: study_from_dicom needs at least one DICOM file, got none")
    if frame is not None and all_frames:
        raise StudyError(f"{folder}: give either a frame or all_frames, not both")
    params = SegmentationParameters() if parameters is None else parameters
    overrides = _segmentation_overrides(params)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for sub, wanted in (("masks", segment), ("dicom", copy)):
            if wanted:
                (folder / sub).mkdir(exist_ok=True)
    except OSError as exc:
        raise StudyError(f"{folder}: cannot create the study folder ({exc})") from None
    taken: set[str] = set()
    document: dict[str, Any] = {"angiohull": FORMAT_VERSION, "views": []}
    summaries: list[DicomViewSummary] = []
    seen_images: dict[str, Path] = {}  # SOP Instance UID -> the first file that holds it
    for path in files:
        header = dicom.read_xa_header(path)
        if header.sop_instance_uid and header.sop_instance_uid in seen_images:
            warnings.warn(f"{path}: the same image as {seen_images[header.sop_instance_uid]} (SOP Instance UID "
                          f"{header.sop_instance_uid}): both become views, which look along one line; give each run "
                          f"once", InputWarning, stacklevel=2)
        seen_images.setdefault(header.sop_instance_uid, path)
        stem = _unique(path.stem if path.suffix.lower() in (".dcm", ".dicom") else path.name, taken)
        if copy:
            target = folder / "dicom" / f"{stem}.dcm"
            try:
                if not (target.exists() and _same_file(target, path)):
                    shutil.copyfile(path, target)
            except OSError as exc:
                raise StudyError(f"{target}: cannot copy {path} into the study ({exc})") from None
            reference = f"dicom/{stem}.dcm"
        else:
            reference = _relative(path, folder)
        images: dict[int, np.ndarray] = {}
        if all_frames:
            chosen = [(i, f"frame {i} of {header.n_frames} (all frames)") for i in range(header.n_frames)]
            if segment:
                images = dict(enumerate(dicom.read_xa_frames(path, header)))
        elif frame is not None:
            index = header.check_frame(frame)
            chosen = [(index, f"frame {index} as requested")]
        else:
            view = dicom.read_xa_view(path, None, parameters=params, header=header)
            chosen = [(view.frame, view.selection.reason)]
            images = {view.frame: view.image}
        for index, reason in chosen:
            name = stem if len(chosen) == 1 else _unique(f"{stem}_f{index:03d}", taken)
            entry: dict[str, Any] = {"name": name}
            pixels = None
            if segment:
                image = images[index] if index in images else dicom.read_xa_frame(path, index, header)
                mask = segment_vessels(image, params)
                if not mask.any():
                    raise StudyError(f"{path}: frame {index}: the segmentation found no vessel; check the run, or lower the "
                                     "segmentation's high_threshold / seed_snr")
                io.write_mask(folder / "masks" / f"{name}.png", mask)
                entry["mask"] = f"masks/{name}.png"
                pixels = int(np.count_nonzero(mask))
            else:
                entry["image"] = reference
                if overrides:
                    entry["segmentation"] = dict(overrides)
            entry["dicom"] = reference
            entry["frame"] = int(index)
            document["views"].append(entry)
            summaries.append(DicomViewSummary(name, path, int(index), reason, header.frames[index].carm(), pixels))
    if not copy and any(_outside(entry["dicom"], folder, "dicom") is not None for entry in document["views"]):
        document["allow_outside_paths"] = True  # --reference: the runs stay where they are, on purpose
    return _write_yaml(folder / STUDY_FILE, document), summaries
