"""Corruptions of vessel masks: each draws its parameters first, records them, then applies them.

A *corruption* (:class:`Translate`, :class:`Scale`, :class:`Rotate`, :class:`FalsePositives`,
:class:`FalseNegatives`, :class:`MissingSegment`, :class:`SpuriousBlob`, :class:`CatheterStroke`) is a
frozen record whose :meth:`apply` is a pure function of the record and the mask: replaying the
record gives the same image. A :class:`CorruptionSpec` says what to draw (``translate=10,0``,
``fp=0.01``, ``missing=2``, ...) and on which views; :func:`draw_corruptions` turns it into records
with a numpy Generator, looking at the mask where the corruption depends on it (a missing segment is
cut where there is vessel).

Pixel conventions (docs/conventions.md): pixel ``(row, col)`` has its centre at ``(u, v) = (col, row)``.
Geometric corruptions map the image content by an affine map ``x' = A (x - c) + c + t`` about the
image centre ``c = ((cols - 1) / 2, (rows - 1) / 2)`` in ``(u, v)``; each output pixel takes the
input pixel nearest to its pre-image (outside the input: background), so integer translations are
exact shifts.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Optional, Sequence

import numpy as np
from scipy import ndimage as ndi
from skimage.morphology import thin

from ..errors import AngiohullError

__all__ = [
    "Translate", "Scale", "Rotate", "FalsePositives", "FalseNegatives", "MissingSegment", "SpuriousBlob",
    "CatheterStroke", "CorruptionSpec", "CORRUPTION_KINDS", "parse_corruption", "draw_corruptions",
    "corruption_from_dict", "apply_all",
]


def _affine(mask: np.ndarray, linear: np.ndarray, shift_uv: tuple[float, float]) -> np.ndarray:
    """Nearest-neighbour warp of a bool mask by ``x' = linear (x - c) + c + shift`` (x in (u, v))."""
    rows, cols = mask.shape
    centre = np.array([(cols - 1) / 2.0, (rows - 1) / 2.0])
    inverse = np.linalg.inv(linear)
    vv, uu = np.mgrid[0:rows, 0:cols]
    out_uv = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    src = (out_uv - centre - np.asarray(shift_uv)) @ inverse.T + centre
    # Round half away from zero would bias; floor(x + 0.5) rounds halves up, consistently.
    cu = np.floor(src[:, 0] + 0.5).astype(np.int64)
    rv = np.floor(src[:, 1] + 0.5).astype(np.int64)
    ok = (cu >= 0) & (cu < cols) & (rv >= 0) & (rv < rows)
    out = np.zeros(rows * cols, dtype=bool)
    out[ok] = mask[rv[ok], cu[ok]]
    return out.reshape(rows, cols)


@dataclass(frozen=True)
class _Corruption:
    kind: ClassVar[str] = ""

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        for key, value in data.items():
            if isinstance(value, tuple):
                data[key] = [list(v) if isinstance(v, tuple) else v for v in value]
        return {"kind": self.kind, **data}

    def apply(self, mask: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass(frozen=True)
class Translate(_Corruption):
    """Shift the image content by ``(tx_px, ty_px)``: +tx to larger columns, +ty to larger rows."""

    kind: ClassVar[str] = "translate"
    tx_px: float
    ty_px: float

    def apply(self, mask: np.ndarray) -> np.ndarray:
        return _affine(mask, np.eye(2), (self.tx_px, self.ty_px))


@dataclass(frozen=True)
class Scale(_Corruption):
    """Scale the image content by ``factor`` about the image centre."""

    kind: ClassVar[str] = "scale"
    factor: float

    def apply(self, mask: np.ndarray) -> np.ndarray:
        return _affine(mask, self.factor * np.eye(2), (0.0, 0.0))


@dataclass(frozen=True)
class Rotate(_Corruption):
    """Rotate the image content by ``angle_deg`` about the image centre (clockwise as displayed, rows down)."""

    kind: ClassVar[str] = "rotate"
    angle_deg: float

    def apply(self, mask: np.ndarray) -> np.ndarray:
        a = math.radians(self.angle_deg)
        return _affine(mask, np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]), (0.0, 0.0))


def _flips(shape: tuple[int, int], p: float, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random(shape) < p


@dataclass(frozen=True)
class FalsePositives(_Corruption):
    """Each background pixel becomes vessel with probability ``p`` (pattern: ``default_rng(seed).random(shape) < p``)."""

    kind: ClassVar[str] = "fp"
    p: float
    seed: int

    def apply(self, mask: np.ndarray) -> np.ndarray:
        return mask | _flips(mask.shape, self.p, self.seed)


@dataclass(frozen=True)
class FalseNegatives(_Corruption):
    """Each vessel pixel becomes background with probability ``p`` (same pattern rule as FalsePositives)."""

    kind: ClassVar[str] = "fn"
    p: float
    seed: int

    def apply(self, mask: np.ndarray) -> np.ndarray:
        return mask & ~_flips(mask.shape, self.p, self.seed)


def _disk(shape: tuple[int, int], centre_rc: Sequence[float], radius: float) -> np.ndarray:
    rr, cc = np.ogrid[0:shape[0], 0:shape[1]]
    return (rr - centre_rc[0]) ** 2 + (cc - centre_rc[1]) ** 2 <= radius * radius


@dataclass(frozen=True)
class MissingSegment(_Corruption):
    """A gap in a vessel: every pixel within ``radius_px`` of ``centre_rc`` (a centreline pixel) is erased."""

    kind: ClassVar[str] = "missing"
    centre_rc: tuple[float, float]
    radius_px: float

    def apply(self, mask: np.ndarray) -> np.ndarray:
        return mask & ~_disk(mask.shape, self.centre_rc, self.radius_px)


@dataclass(frozen=True)
class SpuriousBlob(_Corruption):
    """A spurious filled ellipse (semi-axes ``axes_px`` along/across ``angle_deg`` from the column axis)."""

    kind: ClassVar[str] = "blob"
    centre_rc: tuple[float, float]
    axes_px: tuple[float, float]
    angle_deg: float

    def apply(self, mask: np.ndarray) -> np.ndarray:
        rr, cc = np.mgrid[0:mask.shape[0], 0:mask.shape[1]]
        a = math.radians(self.angle_deg)
        dr, dc = rr - self.centre_rc[0], cc - self.centre_rc[1]
        along = dc * math.cos(a) + dr * math.sin(a)
        across = -dc * math.sin(a) + dr * math.cos(a)
        return mask | ((along / self.axes_px[0]) ** 2 + (across / self.axes_px[1]) ** 2 <= 1.0)


@dataclass(frozen=True)
class CatheterStroke(_Corruption):
    """A catheter-like stroke: every pixel within ``width_px / 2`` of the quadratic Bézier curve
    through the control points ``control_rc`` (start, control, end; (row, col))."""

    kind: ClassVar[str] = "catheter"
    control_rc: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    width_px: float

    def apply(self, mask: np.ndarray) -> np.ndarray:
        p0, p1, p2 = (np.asarray(p, dtype=np.float64) for p in self.control_rc)
        span = np.linalg.norm(p1 - p0) + np.linalg.norm(p2 - p1)
        t = np.linspace(0.0, 1.0, max(2, int(math.ceil(span * 4))))[:, None]
        curve = (1 - t) ** 2 * p0 + 2 * (1 - t) * t * p1 + t * t * p2
        seeds = np.zeros(mask.shape, dtype=bool)
        rc = np.round(curve).astype(np.int64)
        ok = (rc[:, 0] >= 0) & (rc[:, 0] < mask.shape[0]) & (rc[:, 1] >= 0) & (rc[:, 1] < mask.shape[1])
        seeds[rc[ok, 0], rc[ok, 1]] = True
        if not seeds.any():
            return mask.copy()
        return mask | (ndi.distance_transform_edt(~seeds) <= 0.5 * self.width_px)


_CLASSES = {c.kind: c for c in (Translate, Scale, Rotate, FalsePositives, FalseNegatives, MissingSegment,
                                SpuriousBlob, CatheterStroke)}

CORRUPTION_KINDS: tuple[str, ...] = tuple(_CLASSES)
"""translate=TX,TY  scale=F  rotate=DEG  fp=P  fn=P  missing=N  blob=N  catheter=N"""


def corruption_from_dict(data: dict[str, Any]) -> _Corruption:
    """Rebuild a corruption from :meth:`to_dict` output (a record read back from JSON)."""
    data = dict(data)
    kind = data.pop("kind", None)
    if kind not in _CLASSES:
        raise AngiohullError(f"corruption record: kind must be one of {', '.join(CORRUPTION_KINDS)}, got {kind!r}")
    cls = _CLASSES[kind]
    try:
        for key, value in list(data.items()):
            if isinstance(value, list):
                data[key] = tuple(tuple(v) if isinstance(v, list) else v for v in value)
        return cls(**data)
    except TypeError as exc:
        raise AngiohullError(f"corruption record {kind}: {exc}") from None


# -- specs and drawing ----------------------------------------------------------------------------
_GEOMETRIC = ("translate", "scale", "rotate")


@dataclass(frozen=True)
class CorruptionSpec:
    """What to draw: a kind, its value(s), and the views it applies to.

    ``values``: translate (tx, ty) px; scale (factor,); rotate (degrees,); fp / fn (p,);
    missing / blob / catheter (count,). ``views``: view indices, ``"all"``, or None for the
    default — the first view for translate/scale/rotate (the paper corrupts one view), every view
    otherwise.
    """

    kind: str
    values: tuple[float, ...]
    views: Optional[tuple[int, ...]] | str = None

    def __post_init__(self) -> None:
        if self.kind not in _CLASSES:
            raise AngiohullError(f"corruption: unknown kind {self.kind!r}; expected one of {', '.join(CORRUPTION_KINDS)}")
        expected = 2 if self.kind == "translate" else 1
        values = tuple(float(v) for v in self.values)
        if len(values) != expected or not all(math.isfinite(v) for v in values):
            raise AngiohullError(f"corruption {self.kind}: expected {expected} finite number(s), got {self.values!r}")
        v = values[0]
        if self.kind == "scale" and v <= 0:
            raise AngiohullError(f"corruption scale: the factor must be > 0, got {v}")
        if self.kind in ("fp", "fn") and not 0.0 <= v <= 1.0:
            raise AngiohullError(f"corruption {self.kind}: p must lie in [0, 1], got {v}")
        if self.kind in ("missing", "blob", "catheter") and (v < 0 or not v.is_integer()):
            raise AngiohullError(f"corruption {self.kind}: the count must be a whole number >= 0, got {v}")
        if isinstance(self.views, str):
            if self.views != "all":
                raise AngiohullError(f"corruption {self.kind}: views must be indices or 'all', got {self.views!r}")
        elif self.views is not None:
            views = tuple(int(i) for i in self.views)
            if not views:
                raise AngiohullError(f"corruption {self.kind}: no view index given (an empty list); give view indices "
                                     f"from 0, or leave the views out for the default")
            if any(i < 0 for i in views):
                raise AngiohullError(f"corruption {self.kind}: view indices must be >= 0, got {self.views!r}")
            object.__setattr__(self, "views", views)
        object.__setattr__(self, "values", values)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``{"kind", "values", "views"}``; :meth:`from_dict` gives back an equal spec."""
        views = self.views if self.views is None or isinstance(self.views, str) else list(self.views)
        return {"kind": self.kind, "values": list(self.values), "views": views}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "CorruptionSpec":
        views = data.get("views")
        return cls(data["kind"], tuple(data["values"]), views if views is None or isinstance(views, str) else tuple(views))

    def view_indices(self, n_views: int) -> tuple[int, ...]:
        if self.views is None:
            return (0,) if self.kind in _GEOMETRIC else tuple(range(n_views))
        if self.views == "all":
            return tuple(range(n_views))
        bad = [i for i in self.views if i >= n_views]
        if bad:
            raise AngiohullError(f"corruption {self.kind}: view index {bad[0]} out of range for {n_views} view(s)")
        return self.views


_SPEC = re.compile(r"^\s*(?P<kind>[a-z]+)\s*=\s*(?P<values>[^@]+?)\s*(?:@\s*(?P<views>[0-9,\s]+|all))?\s*$", re.I)


def parse_corruption(text: str) -> CorruptionSpec:
    """Parse ``KIND=VALUES[@VIEWS]``: ``translate=10,0``, ``scale=1.1@2``, ``fp=0.01@all``, ``missing=2@0,1``."""
    match = _SPEC.match(text)
    if match is None:
        raise AngiohullError(f"corruption: cannot read {text!r}; expected KIND=VALUES[@VIEWS] with KIND one of "
                             f"{', '.join(CORRUPTION_KINDS)}, e.g. translate=10,0 or fp=0.01@all")
    kind = match["kind"].lower()
    try:
        values = tuple(float(v) for v in match["values"].split(","))
    except ValueError:
        raise AngiohullError(f"corruption {kind}: cannot read the value(s) {match['values']!r} as numbers") from None
    views_text = match["views"]
    if views_text is None:
        views: Optional[tuple[int, ...]] | str = None
    elif views_text.strip().lower() == "all":
        views = "all"
    else:
        views = tuple(int(v) for v in views_text.split(",") if v.strip())
    return CorruptionSpec(kind, values, views)


def _centreline_pixels(mask: np.ndarray) -> np.ndarray:
    skeleton = thin(mask)
    return np.argwhere(skeleton)


def _draw_one(spec: CorruptionSpec, mask: np.ndarray, rng: np.random.Generator) -> list[_Corruption]:
    rows, cols = mask.shape
    kind, v = spec.kind, spec.values
    if kind == "translate":
        return [Translate(v[0], v[1])]
    if kind == "scale":
        return [Scale(v[0])]
    if kind == "rotate":
        return [Rotate(v[0])]
    if kind == "fp":
        return [FalsePositives(v[0], int(rng.integers(0, 2 ** 63 - 1)))]
    if kind == "fn":
        return [FalseNegatives(v[0], int(rng.integers(0, 2 ** 63 - 1)))]
    count = int(v[0])
    out: list[_Corruption] = []
    if kind == "missing":
        centres = _centreline_pixels(mask)
        if centres.size == 0:
            return out
        for _ in range(count):
            r, c = centres[int(rng.integers(0, len(centres)))]
            out.append(MissingSegment((float(r), float(c)), float(rng.uniform(4.0, 12.0))))
        return out
    margin = 0.1 * np.array([rows, cols])
    for _ in range(count):
        if kind == "blob":
            centre = rng.uniform(margin, np.array([rows, cols]) - margin)
            out.append(SpuriousBlob((float(centre[0]), float(centre[1])),
                                    (float(rng.uniform(5.0, 20.0)), float(rng.uniform(3.0, 12.0))),
                                    float(rng.uniform(0.0, 180.0))))
        else:  # catheter: from a random point of the image border towards the vessel's upper part
            edge = int(rng.integers(0, 4))
            s = float(rng.uniform(0.1, 0.9))
            start = [(0.0, s * (cols - 1)), ((rows - 1.0), s * (cols - 1)), (s * (rows - 1), 0.0),
                     (s * (rows - 1), cols - 1.0)][edge]
            vessel = np.argwhere(mask)
            if vessel.size:
                end = vessel[int(rng.integers(0, len(vessel)))].astype(np.float64)
            else:
                end = rng.uniform(margin, np.array([rows, cols]) - margin)
            mid = 0.5 * (np.asarray(start) + end) + rng.normal(0.0, 0.15 * min(rows, cols), size=2)
            out.append(CatheterStroke(((float(start[0]), float(start[1])), (float(mid[0]), float(mid[1])),
                                       (float(end[0]), float(end[1]))), float(rng.uniform(4.0, 9.0))))
    return out


def draw_corruptions(specs: Sequence[CorruptionSpec], masks: Sequence[np.ndarray],
                     rng: np.random.Generator | int | None = None) -> list[list[_Corruption]]:
    """Draw the records of every spec for every view it applies to, in order.

    Parameters
    ----------
    specs : sequence of CorruptionSpec
    masks : sequence of (rows, cols) bool arrays
        The clean masks (drawing may look at them: a missing segment is placed on the vessel).
    rng : numpy.random.Generator or int or None

    Returns
    -------
    list (one per view) of lists of corruption records, to apply in order with :func:`apply_all`.
    """
    generator = np.random.default_rng(rng)
    per_view: list[list[_Corruption]] = [[] for _ in masks]
    for spec in specs:
        for index in spec.view_indices(len(masks)):
            per_view[index].extend(_draw_one(spec, masks[index], generator))
    return per_view


def apply_all(mask: np.ndarray, corruptions: Sequence[_Corruption]) -> np.ndarray:
    """Apply records in order (a pure function of the records and the mask)."""
    out = np.asarray(mask, dtype=bool)
    for corruption in corruptions:
        out = corruption.apply(out)
    return out

