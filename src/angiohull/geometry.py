"""Acquisition geometry: projection matrices, C-arm poses and clinical angle strings.

Conventions (see docs/conventions.md, "Geometry conventions"):

* world frame: DICOM patient coordinates (LPS), millimetres, origin at the C-arm isocentre;
* a view is a 3x4 matrix ``P`` mapping ``[X, Y, Z, 1]`` to ``[u*w, v*w, w]`` with ``u`` the column
  index and ``v`` the row index of the mask array, pixel centres at integer ``(u, v)``, and
  ``w > 0`` in front of the source;
* C-arm angles follow DICOM PS3.3 C.8.7.5: primary angle LAO positive / RAO negative, secondary
  angle CRA positive / CAU negative.

Matrices may be mirrored (``det(P[:, :3]) < 0``); the C-arm convention itself produces mirrored
matrices, so nothing here assumes a proper rotation.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from . import _validation as _v
from .errors import GeometryError

__all__ = [
    "Projection",
    "CArmGeometry",
    "parse_clinical_angles",
    "format_clinical_angles",
    "cube_half_edge_mm",
    "angle_between_views_deg",
    "degrees_from_one_line",
    "ImageStorage",
    "canonical_storage",
]


@dataclass(frozen=True, eq=False)
class Projection:
    """One view: a 3x4 projection matrix and the shape of the image it projects into.

    Parameters
    ----------
    matrix : array_like, shape (3, 4)
        Maps homogeneous world points (mm) to ``[u*w, v*w, w]``; ``u`` = column, ``v`` = row.
        Any positive multiple describes the same view. Must be finite with an invertible left
        3x3 block (a camera at a finite position).
    image_shape : (int, int)
        ``(rows, cols)`` of the image (mask) this view produces.

    Raises
    ------
    GeometryError
        If the matrix is not 3x4, not finite or degenerate, or the shape is not two positive ints.
    """

    matrix: np.ndarray
    image_shape: tuple[int, int]
    _centre: np.ndarray = field(init=False, repr=False)
    _k: np.ndarray | None = field(init=False, repr=False, default=None)  # intrinsics(), once asked for

    def __post_init__(self) -> None:
        try:
            matrix = np.asarray(self.matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise GeometryError(f"projection matrix must be a 3x4 array of numbers, got {self.matrix!r}") from None
        if matrix.shape != (3, 4):
            raise GeometryError(f"projection matrix must have shape (3, 4), got {matrix.shape}")
        if not np.all(np.isfinite(matrix)):
            raise GeometryError("projection matrix contains non-finite values (nan or inf)")
        left = matrix[:, :3]
        scale = np.abs(left).max()
        if scale == 0 or abs(np.linalg.det(left / scale)) < 1e-12:
            raise GeometryError(
                "projection matrix is degenerate: its left 3x3 block is singular, so it has no "
                "finite camera centre (an orthographic or rank-deficient matrix is not a C-arm view)"
            )
        shape = _v.image_shape(self.image_shape, error=GeometryError)
        object.__setattr__(self, "matrix", _v.readonly_copy(matrix))
        object.__setattr__(self, "image_shape", shape)
        object.__setattr__(self, "_centre", _v.readonly_copy(-np.linalg.solve(left, matrix[:, 3])))

    # -- projecting points ------------------------------------------------------------------
    def homogeneous(self, points_mm: np.ndarray) -> np.ndarray:
        """Return ``[u*w, v*w, w]`` for each point, shape (N, 3)."""
        points = _v.points_array(points_mm, "points_mm", error=GeometryError)
        return points @ self.matrix[:, :3].T + self.matrix[:, 3]

    def project(self, points_mm: np.ndarray) -> np.ndarray:
        """Project world points (N, 3) in mm to pixel coordinates (N, 2) as ``(u, v)``.

        Points at ``w == 0`` give non-finite coordinates; use :meth:`in_front` to filter.
        """
        h = self.homogeneous(points_mm)
        with np.errstate(divide="ignore", invalid="ignore"):
            return h[:, :2] / h[:, 2:3]

    def jacobian(self, points_mm: np.ndarray) -> np.ndarray:
        """``d(u, v)/dX`` at each point, shape (N, 2, 3), pixels per mm."""
        h = self.homogeneous(points_mm)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = h[:, :2] / h[:, 2:3]
            return (self.matrix[None, :2, :3] - uv[:, :, None] * self.matrix[None, 2:3, :3]) / h[:, 2, None, None]

    def shifted(self, du_px: float, dv_px: float) -> "Projection":
        """The projection whose image is moved by ``(du, dv)`` pixels: ``T(du, dv) P``."""
        shift = np.array([[1.0, 0.0, du_px], [0.0, 1.0, dv_px], [0.0, 0.0, 1.0]])
        return Projection(shift @ self.matrix, self.image_shape)

    def magnified(self, factor: float) -> "Projection":
        """The projection whose image is scaled by ``factor`` about the principal point: the same
        view with the source-to-image distance (or one over the pixel spacing) times ``factor``."""
        c_u, c_v = self.principal_point_px
        scale = np.array([[factor, 0.0, (1.0 - factor) * c_u], [0.0, factor, (1.0 - factor) * c_v], [0.0, 0.0, 1.0]])
        return Projection(scale @ self.matrix, self.image_shape)

    def depth_mm(self, points_mm: np.ndarray) -> np.ndarray:
        """Distance (mm) of each point from the source along the viewing axis; > 0 in front."""
        h = self.homogeneous(points_mm)
        return h[:, 2] / np.linalg.norm(self.matrix[2, :3])

    def in_front(self, points_mm: np.ndarray) -> np.ndarray:
        """Boolean mask (N,) of the points strictly in front of the source (``w > 0``)."""
        return self.homogeneous(points_mm)[:, 2] > 0

    # -- intrinsic properties ---------------------------------------------------------------
    @property
    def camera_centre_mm(self) -> np.ndarray:
        """The X-ray source position (3,) in mm: the null space of the matrix."""
        return self._centre

    @property
    def is_mirrored(self) -> bool:
        """True when ``det(P[:, :3]) < 0`` (the image is a mirror image of a proper camera's)."""
        return bool(np.linalg.det(self.matrix[:, :3]) < 0)

    def intrinsics(self) -> np.ndarray:
        """Upper-triangular calibration matrix K (3, 3), ``K[2, 2] = 1``, positive focal lengths.

        From an RQ decomposition of the left 3x3 block; signs of mirrored matrices are moved into
        the rotation factor so that the focal lengths come out positive.
        """
        if self._k is None:  # the matrix is read-only: decompose it once (calibration asks thousands of times)
            import scipy.linalg  # only here: importing it costs a noticeable share of a command's start

            k, _ = scipy.linalg.rq(self.matrix[:, :3])
            signs = np.sign(np.diag(k))
            signs[signs == 0] = 1.0
            k = k * signs  # flips columns of K (and rows of the rotation): K @ R unchanged
            object.__setattr__(self, "_k", _v.readonly_copy(k / k[2, 2]))
        return self._k.copy()

    @property
    def focal_lengths_px(self) -> tuple[float, float]:
        """``(f_u, f_v)``: source-to-detector distance divided by the column / row pixel spacing."""
        k = self.intrinsics()
        return float(k[0, 0]), float(k[1, 1])

    @property
    def principal_point_px(self) -> tuple[float, float]:
        """``(u, v)`` of the foot of the perpendicular from the source onto the detector."""
        k = self.intrinsics()
        return float(k[0, 2]), float(k[1, 2])

    def field_half_edge_mm(self) -> float:
        """Half the detector's field of view scaled to the isocentre (world origin), in mm.

        ``|camera centre| * max(cols / f_u, rows / f_v) / 2``; for a C-arm view this equals
        ``SOD * max(cols * col_spacing, rows * row_spacing) / (2 * SID)``.
        """
        rows, cols = self.image_shape
        f_u, f_v = self.focal_lengths_px
        return float(np.linalg.norm(self._centre) * max(cols / f_u, rows / f_v) / 2.0)

    def __repr__(self) -> str:
        rows, cols = self.image_shape
        c = self._centre
        return f"Projection(image_shape=({rows}, {cols}), camera_centre_mm=({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}))"


@dataclass(frozen=True)
class CArmGeometry:
    """A C-arm pose and detector, in DICOM terms.

    Parameters
    ----------
    primary_deg : float
        PositionerPrimaryAngle (0018,1510): LAO positive, RAO negative, degrees.
    secondary_deg : float
        PositionerSecondaryAngle (0018,1511): CRA positive, CAU negative, degrees.
    sid_mm : float
        Source-to-image (detector) distance, mm.
    sod_mm : float
        Source-to-object (isocentre) distance, mm; ``0 < SOD < SID``.
    pixel_spacing_mm : (float, float)
        ImagerPixelSpacing at the detector, ``(row spacing, column spacing)`` in mm.
    image_shape : (int, int)
        Detector ``(rows, cols)``.
    principal_offset_px : (float, float)
        Offset ``(du, dv)`` of the principal point from the image centre, pixels.
    """

    primary_deg: float
    secondary_deg: float
    sid_mm: float
    sod_mm: float
    pixel_spacing_mm: tuple[float, float]
    image_shape: tuple[int, int]
    principal_offset_px: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        err = GeometryError
        primary = _v.finite(self.primary_deg, "primary_deg", error=err)
        secondary = _v.finite(self.secondary_deg, "secondary_deg", error=err)
        if not -180.0 <= primary <= 180.0:
            raise err(f"primary_deg must be within [-180, 180] degrees, got {primary}")
        if not -90.0 <= secondary <= 90.0:
            raise err(f"secondary_deg must be within [-90, 90] degrees, got {secondary}")
        sid = _v.positive_finite(self.sid_mm, "sid_mm", error=err)
        sod = _v.positive_finite(self.sod_mm, "sod_mm", error=err)
        if sod >= sid:
            raise err(
                f"sod_mm must be smaller than sid_mm (the isocentre lies between source and "
                f"detector), got sod_mm={sod} >= sid_mm={sid}"
            )
        spacing = tuple(self.pixel_spacing_mm) if not isinstance(self.pixel_spacing_mm, (int, float)) else None
        if spacing is None or len(spacing) != 2:
            raise err(f"pixel_spacing_mm must be [row_spacing, col_spacing] in mm, got {self.pixel_spacing_mm!r}")
        spacing = tuple(_v.positive_finite(s, f"pixel_spacing_mm[{i}]", error=err) for i, s in enumerate(spacing))
        offset = tuple(self.principal_offset_px)
        if len(offset) != 2:
            raise err(f"principal_offset_px must be [du, dv] in pixels, got {self.principal_offset_px!r}")
        offset = tuple(_v.finite(o, f"principal_offset_px[{i}]", error=err) for i, o in enumerate(offset))
        for name, value in (("primary_deg", primary), ("secondary_deg", secondary), ("sid_mm", sid),
                            ("sod_mm", sod), ("pixel_spacing_mm", spacing), ("principal_offset_px", offset),
                            ("image_shape", _v.image_shape(self.image_shape, error=err))):
            object.__setattr__(self, name, value)

    # -- the frame of the C-arm, docs/conventions.md -----------------------------------------------------
    def detector_direction(self) -> np.ndarray:
        """Unit vector from the isocentre towards the detector centre, ``d``."""
        a, b = math.radians(self.primary_deg), math.radians(self.secondary_deg)
        return np.array([math.sin(a) * math.cos(b), -math.cos(a) * math.cos(b), math.sin(b)])

    def column_direction(self) -> np.ndarray:
        """Unit world vector along which the column index ``u`` grows."""
        a = math.radians(self.primary_deg)
        return np.array([math.cos(a), math.sin(a), 0.0])

    def row_direction(self) -> np.ndarray:
        """Unit world vector along which the row index ``v`` grows."""
        a, b = math.radians(self.primary_deg), math.radians(self.secondary_deg)
        return np.array([math.sin(a) * math.sin(b), -math.cos(a) * math.sin(b), -math.cos(b)])

    @property
    def source_mm(self) -> np.ndarray:
        """Position of the X-ray source, ``-SOD * d``."""
        return -self.sod_mm * self.detector_direction()

    @property
    def detector_centre_mm(self) -> np.ndarray:
        """Position of the detector centre, ``(SID - SOD) * d``."""
        return (self.sid_mm - self.sod_mm) * self.detector_direction()

    @property
    def magnification(self) -> float:
        """Geometric magnification at the isocentre, ``SID / SOD``."""
        return self.sid_mm / self.sod_mm

    @property
    def isocentre_pixel_spacing_mm(self) -> tuple[float, float]:
        """Pixel spacing scaled to the isocentre, ``ImagerPixelSpacing * SOD / SID``."""
        return (self.pixel_spacing_mm[0] / self.magnification, self.pixel_spacing_mm[1] / self.magnification)

    def projection(self) -> Projection:
        """The 3x4 projection of this pose (the one place C-arm parameters become a matrix).

        ``u = c_u + (SID / w) (X . col_dir) / col_spacing``,
        ``v = c_v + (SID / w) (X . row_dir) / row_spacing``, ``w = X . d + SOD``,
        with ``(c_u, c_v) = ((cols - 1) / 2, (rows - 1) / 2) + principal_offset_px``.
        """
        rows, cols = self.image_shape
        row_spacing, col_spacing = self.pixel_spacing_mm
        c_u = (cols - 1) / 2.0 + self.principal_offset_px[0]
        c_v = (rows - 1) / 2.0 + self.principal_offset_px[1]
        intrinsics = np.array([
            [self.sid_mm / col_spacing, 0.0, c_u],
            [0.0, self.sid_mm / row_spacing, c_v],
            [0.0, 0.0, 1.0],
        ])
        frame = np.stack([self.column_direction(), self.row_direction(), self.detector_direction()])
        extrinsics = np.concatenate([frame, [[0.0], [0.0], [self.sod_mm]]], axis=1)
        return Projection(intrinsics @ extrinsics, (rows, cols))

    def clinical_name(self) -> str:
        """The pose as an angiographer says it, e.g. ``"RAO 30 CRA 20"``."""
        return format_clinical_angles(self.primary_deg, self.secondary_deg)


_ANGLE_TOKEN = re.compile(
    r"(?P<word>LAO|RAO|CRAN(?:IAL)?|CRA|CAUD(?:AL)?|CAU|AP|PA)\s*(?P<value>[+-]?\d+(?:\.\d*)?|\.\d+)?\s*°?",
    re.IGNORECASE,
)


def parse_clinical_angles(text: str) -> tuple[float, float]:
    """Parse a clinical view name into ``(primary_deg, secondary_deg)``.

    Accepts ``"RAO 30 CRA 20"``, ``"LAO 45, CAU 10"``, ``"lao45 cau10"``, ``"RAO 30"`` (no
    angulation), ``"CRA 40"`` and ``"AP"``. RAO and CAU become negative angles.

    Raises
    ------
    ValueError
        For anything else, with the text received.
    """
    if not isinstance(text, str):
        raise ValueError(f"clinical angles must be a string like 'RAO 30 CRA 20', got {text!r}")
    remaining = text.strip()
    primary: float | None = None
    secondary: float | None = None
    pos = 0
    stripped = remaining
    while pos < len(stripped):
        if stripped[pos] in " ,;/\t":
            pos += 1
            continue
        match = _ANGLE_TOKEN.match(stripped, pos)
        if match is None:
            raise ValueError(
                f"cannot read clinical angles from {text!r}: expected e.g. 'RAO 30 CRA 20' or "
                f"'LAO 45, CAU 10' (unexpected text at {stripped[pos:]!r})"
            )
        word = match["word"].upper()
        value = match["value"]
        if word in ("AP", "PA"):
            if value is not None or word == "PA":
                raise ValueError(f"cannot read clinical angles from {text!r}: 'AP' takes no number (and PA is not a C-arm view)")
            primary = 0.0 if primary is None else primary
        else:
            if value is None:
                raise ValueError(f"cannot read clinical angles from {text!r}: {word} needs a number of degrees")
            degrees = float(value)
            if degrees < 0:
                raise ValueError(f"cannot read clinical angles from {text!r}: give {word} a non-negative angle; the word gives the sign")
            limit = 180.0 if word in ("LAO", "RAO") else 90.0
            if degrees > limit:
                raise ValueError(f"cannot read clinical angles from {text!r}: {word} {value} is beyond {limit:g} degrees "
                                 f"({'LAO/RAO within 0-180' if limit == 180.0 else 'CRA/CAU within 0-90'})")
            if word in ("LAO", "RAO"):
                if primary is not None:
                    raise ValueError(f"cannot read clinical angles from {text!r}: two primary angles (LAO/RAO)")
                primary = degrees if word == "LAO" else -degrees
            else:
                if secondary is not None:
                    raise ValueError(f"cannot read clinical angles from {text!r}: two secondary angles (CRA/CAU)")
                secondary = degrees if word.startswith("CRA") else -degrees
        pos = match.end()
    if primary is None and secondary is None:
        raise ValueError(f"cannot read clinical angles from {text!r}: expected e.g. 'RAO 30 CRA 20'")
    return (primary or 0.0, secondary or 0.0)


def _format_number(value: float) -> str:
    rounded = round(abs(value), 1)
    return f"{rounded:g}"


def format_clinical_angles(primary_deg: float, secondary_deg: float) -> str:
    """Format ``(primary_deg, secondary_deg)`` as e.g. ``"RAO 30 CRA 20"`` (0.1 degree precision)."""
    first = ("LAO " if primary_deg >= 0 else "RAO ") + _format_number(primary_deg)
    second = ("CRA " if secondary_deg >= 0 else "CAU ") + _format_number(secondary_deg)
    return f"{first} {second}"


def cube_half_edge_mm(projections: Iterable[Projection]) -> float:
    """Half-edge R (mm) of the cube of interest ``[-R, R]^3`` that covers every view.

    The largest :meth:`Projection.field_half_edge_mm` over the views (docs/conventions.md, method step 2).
    """
    values = [p.field_half_edge_mm() for p in projections]
    if not values:
        raise GeometryError("the cube of interest needs at least one view, got none")
    return max(values)


def _central_ray(projection: Projection) -> np.ndarray:
    """Unit direction (3,) from the source through the centre of the image."""
    rows, cols = projection.image_shape
    direction = np.linalg.solve(projection.matrix[:, :3], np.array([(cols - 1) / 2.0, (rows - 1) / 2.0, 1.0]))
    direction /= np.linalg.norm(direction)
    if not projection.in_front(projection.camera_centre_mm[None, :] + direction[None, :])[0]:
        direction = -direction
    return direction


def angle_between_views_deg(first: Projection, second: Projection) -> float:
    """The angle (degrees, 0-180) between the two views' central rays (from each source through the
    centre of its image). Near 0 the views look along the same line, near 180 along opposite
    lines (mirror images): either way the depth along it is poorly determined from the two."""
    cosine = float(np.clip(_central_ray(first) @ _central_ray(second), -1.0, 1.0))
    return float(np.degrees(np.arccos(cosine)))


def degrees_from_one_line(first: Projection, second: Projection) -> float:
    """How far two views' central rays are from lying along one line: their angle, or 180 less it
    where that is smaller (degrees, 0-90; :func:`angle_between_views_deg`)."""
    angle = angle_between_views_deg(first, second)
    return min(angle, 180.0 - angle)


def stack_projections(projections: Sequence[Projection]) -> np.ndarray:
    """The matrices of several views as one (V, 3, 4) array."""
    return np.stack([p.matrix for p in projections])


@dataclass(frozen=True)
class ImageStorage:
    """A way of storing a view's image: transposed first, then columns and rows reversed.

    Applied to an image and to its projection together, it leaves the view (rays and pixels)
    unchanged: ``apply_image(image)`` is the array stored that way and ``apply(projection)`` the
    equivalent matrix.
    """

    transpose: bool = False
    flip_cols: bool = False
    flip_rows: bool = False

    def apply_image(self, image: np.ndarray) -> np.ndarray:
        out = np.asarray(image)
        if self.transpose:
            out = out.T
        if self.flip_cols:
            out = out[:, ::-1]
        if self.flip_rows:
            out = out[::-1]
        return np.ascontiguousarray(out)

    def apply(self, projection: Projection) -> Projection:
        matrix = projection.matrix
        rows, cols = projection.image_shape
        if self.transpose:
            matrix = matrix[[1, 0, 2]]
            rows, cols = cols, rows
        if self.flip_cols:
            matrix = np.stack([(cols - 1) * matrix[2] - matrix[0], matrix[1], matrix[2]])
        if self.flip_rows:
            matrix = np.stack([matrix[0], (rows - 1) * matrix[2] - matrix[1], matrix[2]])
        return Projection(matrix, (rows, cols))


def canonical_storage(projection: Projection) -> ImageStorage:
    """The storage that brings a view's image into a canonical orientation set by the geometry alone.

    The world directions in which the image's column and row indices grow (the first two columns
    of the inverse of the matrix's left 3x3 block) swap under a transpose and change sign under a
    flip. The canonical image is the one whose row index grows, of these four directions, the most
    toward the feet (-z), and whose columns complete the DICOM C-arm convention's handedness
    (column direction x row direction points back toward the source). Every view of the C-arm
    convention (secondary angle within +-90 degrees) is canonical as it is; any storage of the same
    view (flipped, transposed, with the equivalent matrix) gives the same image once brought into
    this orientation, so steps that look at pixel neighbourhoods (thinning, ties of distance
    transforms) give the same answer whatever the storage.
    """
    matrix = projection.matrix
    inverse = np.linalg.inv(matrix[:, :3])
    column, row = inverse[:, 0], inverse[:, 1]
    rows, cols = projection.image_shape
    view = inverse @ np.array([(cols - 1) / 2.0, (rows - 1) / 2.0, 1.0])  # into the scene (w > 0)
    # (direction, transpose, reverse it) for the canonical row direction; after a transpose the
    # stored rows are the old columns and the stored columns the old rows
    options = [(row, False, False), (-row, False, True), (column, True, False), (-column, True, True)]
    new_row, transpose, reverse_rows = min(options, key=lambda o: float(o[0][2] / np.linalg.norm(o[0])))
    new_column = row if transpose else column
    reverse_cols = float(np.cross(new_column, new_row) @ view) > 0  # it must point back toward the source
    return ImageStorage(transpose=transpose, flip_cols=reverse_cols, flip_rows=reverse_rows)
