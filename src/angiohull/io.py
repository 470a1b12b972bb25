"""File formats: binary masks (PNG, TIFF, NPY) and point clouds (NPY, PLY).

Plain arrays in and out. Every problem with a file raises :class:`~angiohull.errors.StudyError`
whose message starts with the file's path and says what was expected.

Units: points are ``(N, 3)`` float64 arrays of ``x, y, z`` in millimetres, in the DICOM patient
frame (LPS) with the origin at the C-arm isocentre (docs/conventions.md, "Geometry conventions").
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Union

import numpy as np
from PIL import Image
from plyfile import PlyData, PlyElement, PlyParseError

from .errors import StudyError

__all__ = ["read_mask", "write_mask", "read_image", "read_points", "write_points_ply", "MASK_SUFFIXES", "IMAGE_SUFFIXES",
           "POINT_SUFFIXES"]

PathLike = Union[str, "os.PathLike[str]"]

#: File extensions :func:`read_mask` and :func:`write_mask` understand (lower case).
MASK_SUFFIXES: tuple[str, ...] = (".png", ".tif", ".tiff", ".npy")
#: File extensions :func:`read_image` understands (lower case); DICOM files are read by :mod:`angiohull.dicom`.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".tif", ".tiff", ".npy")
#: File extensions :func:`read_points` understands (lower case).
POINT_SUFFIXES: tuple[str, ...] = (".npy", ".ply")

_MASK_EXPECTED = "a 2D binary mask (rows, cols) as PNG, TIFF or NPY, nonzero = vessel"
_IMAGE_EXPECTED = "a 2D grey-scale X-ray image (rows, cols) as PNG, TIFF or NPY"
_POINTS_EXPECTED = "an (N, 3) array of x, y, z points in mm as .npy or .ply"
_PLY_COMMENTS = ("units mm", "frame DICOM patient LPS")
_ALPHA_BANDS = ("A", "a")


# -- shared checks ----------------------------------------------------------------------------
def _suffix(path: Path, allowed: tuple[str, ...], expected: str) -> str:
    suffix = path.suffix.lower()
    if suffix not in allowed:
        raise StudyError(
            f"{path}: unsupported file extension {path.suffix!r}; expected {expected} "
            f"(extension one of {', '.join(allowed)})"
        )
    return suffix


def _require_file(path: Path, expected: str) -> None:
    if not path.exists():
        raise StudyError(f"{path}: file not found; expected {expected}")
    if not path.is_file():
        raise StudyError(f"{path}: is not a regular file; expected {expected}")


_NUMPY_MAGIC = (b"\x93NUMPY", b"PK\x03\x04", b"PK\x05\x06")  # an .npy file; an .npz (zip) archive, or an empty one


def load_numpy_file(path: Path, expected: str, kind: str = "a NumPy .npy file") -> Any:
    """``np.load`` of the file's bytes, ``allow_pickle=False`` (an array, or an NpzFile for an
    archive), any failure a StudyError naming the file and ``expected``: a file that is neither an
    .npy file nor a zip archive is said to be so (not with NumPy's own guess that it holds pickled
    objects), and a damaged archive is an error, not a zipfile traceback (read from memory, so no
    file handle is left open when NumPy gives up on it)."""
    import io
    import zipfile

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise StudyError(f"{path}: cannot read {kind} ({exc.strerror or exc}); expected {expected}") from None
    if not data.startswith(_NUMPY_MAGIC):
        raise StudyError(f"{path}: cannot read as {kind} (it is none: an .npy file begins with \\x93NUMPY and an "
                         f".npz file is a zip archive, this one begins with {data[:8]!r}); expected {expected}")
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise StudyError(f"{path}: cannot read as {kind} ({exc}); expected {expected}") from None


def _load_npy(path: Path, expected: str) -> np.ndarray:
    loaded = load_numpy_file(path, expected)
    if not isinstance(loaded, np.ndarray):  # an .npz archive behind an .npy name
        loaded.close()
        raise StudyError(f"{path}: is an .npz archive, not a single .npy array; expected {expected}")
    return loaded


def _numeric(array: np.ndarray, where: str, expected: str) -> np.ndarray:
    if array.dtype.kind not in "biuf":
        raise StudyError(f"{where}: expected {expected}, got an array of dtype {array.dtype}")
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        count = int(np.count_nonzero(~np.isfinite(array)))
        raise StudyError(f"{where}: contains {count} non-finite values (nan or inf); expected {expected}")
    return array


# -- masks ------------------------------------------------------------------------------------
def _as_mask(array: np.ndarray, where: str) -> np.ndarray:
    """Check a (rows, cols) numeric array and return it as a new C-contiguous bool array."""
    if array.ndim != 2:
        hint = " (a 3D volume, colour stack or image series is not a mask)" if array.ndim > 2 else ""
        raise StudyError(f"{where}: expected {_MASK_EXPECTED}, got an array of shape {array.shape}{hint}")
    if array.size == 0:
        raise StudyError(f"{where}: expected {_MASK_EXPECTED}, got an empty array of shape {array.shape}")
    return np.ascontiguousarray(_numeric(array, where, _MASK_EXPECTED) != 0)


def _colour_array(image: Image.Image) -> np.ndarray:
    """Pixel values of one frame; colour images become 'any colour channel nonzero' (alpha ignored)."""
    if image.mode in ("P", "PA"):
        image = image.convert("RGBA")  # palette entries are colours; RGBA keeps any transparency apart
    elif image.mode in ("CMYK", "YCbCr", "LAB", "HSV"):
        image = image.convert("RGB")
    array = np.asarray(image)
    if array.ndim != 3:
        return array
    colour = [i for i, band in enumerate(image.getbands()) if band not in _ALPHA_BANDS]
    return np.any(array[..., colour] != 0, axis=2)


def _load_image(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as image:
            frames = getattr(image, "n_frames", 1)
            if frames == 1:
                return _colour_array(image)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise StudyError(f"{path}: cannot read as an image ({exc}); expected {_MASK_EXPECTED}") from None
    raise StudyError(f"{path}: has {frames} frames; expected {_MASK_EXPECTED} (a single frame)")


def read_mask(path: PathLike) -> np.ndarray:
    """Read a binary vessel mask.

    Parameters
    ----------
    path : str or path-like
        A ``.png``, ``.tif``/``.tiff`` (read with Pillow; 8- or 16-bit grayscale, float, or colour)
        or ``.npy`` file (read with ``allow_pickle=False``; bool, integer or float).

    Returns
    -------
    mask : ndarray of bool, shape (rows, cols)
        True where the file is nonzero (vessel). For colour images a pixel is vessel when any
        colour channel is nonzero; an alpha channel is ignored.

    Raises
    ------
    StudyError
        If the file is missing or unreadable, has an unsupported extension, holds several frames or
        a 3D array, is empty, or holds non-numeric or non-finite values. The message starts with
        the path.
    """
    path = Path(path)
    suffix = _suffix(path, MASK_SUFFIXES, _MASK_EXPECTED)
    _require_file(path, _MASK_EXPECTED)
    array = _load_npy(path, _MASK_EXPECTED) if suffix == ".npy" else _load_image(path)
    return _as_mask(array, str(path))


def write_mask(path: PathLike, mask: Any) -> None:
    """Write a binary mask; the format follows the extension.

    Parameters
    ----------
    path : str or path-like
        ``.png`` and ``.tif``/``.tiff`` are written as 8-bit grayscale, 0 (background) and 255
        (vessel); ``.npy`` as a bool array. The parent folder must exist.
    mask : array_like, shape (rows, cols)
        Nonzero = vessel.

    Raises
    ------
    StudyError
        If the extension is not supported, the mask is not a non-empty 2D numeric array, or the
        file cannot be written.
    """
    path = Path(path)
    suffix = _suffix(path, MASK_SUFFIXES, _MASK_EXPECTED)
    array = _as_mask(np.asarray(mask), f"{path}: cannot write mask")
    try:
        if suffix == ".npy":
            with open(path, "wb") as handle:
                np.save(handle, array, allow_pickle=False)
        else:
            image = Image.fromarray(array.astype(np.uint8) * np.uint8(255))
            image.save(path, format="PNG" if suffix == ".png" else "TIFF")
    except OSError as exc:
        raise StudyError(f"{path}: cannot write mask ({exc})") from None


# -- raw images -------------------------------------------------------------------------------
def read_image(path: PathLike) -> np.ndarray:
    """Read a raw grey-scale X-ray image (for segmentation).

    Parameters
    ----------
    path : str or path-like
        A ``.png`` or ``.tif``/``.tiff`` (read with Pillow: 8- or 16-bit grey, float; colour images
        are converted to their luminance, an alpha channel is dropped) or ``.npy`` file (a 2D
        numeric array, ``allow_pickle=False``).

    Returns
    -------
    image : ndarray of float64, shape (rows, cols)
        The pixel values as stored.

    Raises
    ------
    StudyError
        If the file is missing or unreadable, has an unsupported extension, holds several frames,
        is not 2D or empty, or holds non-numeric or non-finite values. The message starts with
        the path.
    """
    path = Path(path)
    suffix = _suffix(path, IMAGE_SUFFIXES, _IMAGE_EXPECTED)
    _require_file(path, _IMAGE_EXPECTED)
    if suffix == ".npy":
        array = _load_npy(path, _IMAGE_EXPECTED)
    else:
        try:
            with Image.open(path) as image:
                frames = getattr(image, "n_frames", 1)
                if frames != 1:
                    raise StudyError(f"{path}: has {frames} frames; expected {_IMAGE_EXPECTED} (a single frame)")
                if image.mode in ("RGB", "RGBA", "P", "PA", "CMYK", "YCbCr", "LAB", "HSV", "LA"):
                    image = image.convert("L")
                array = np.asarray(image)
        except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
            raise StudyError(f"{path}: cannot read as an image ({exc}); expected {_IMAGE_EXPECTED}") from None
    if array.ndim != 2 or array.size == 0:
        raise StudyError(f"{path}: expected {_IMAGE_EXPECTED}, got an array of shape {array.shape}")
    return _numeric(array, str(path), _IMAGE_EXPECTED).astype(np.float64)


# -- points -----------------------------------------------------------------------------------
def _as_points(array: np.ndarray, where: str) -> np.ndarray:
    """Check an (N, 3) numeric finite array and return it as a new float64 array."""
    if array.ndim != 2 or array.shape[1] != 3:
        raise StudyError(f"{where}: expected {_POINTS_EXPECTED}, got an array of shape {array.shape}")
    if array.dtype.kind == "b":
        raise StudyError(f"{where}: expected {_POINTS_EXPECTED}, got an array of dtype bool")
    return np.array(_numeric(array, where, _POINTS_EXPECTED), dtype=np.float64, order="C")


def _read_ply_xyz(path: Path) -> np.ndarray:
    try:
        ply = PlyData.read(str(path))
    except (OSError, ValueError, EOFError, PlyParseError) as exc:
        raise StudyError(f"{path}: cannot read as a PLY file ({exc}); expected {_POINTS_EXPECTED}") from None
    names = [element.name for element in ply.elements]
    if "vertex" not in names:
        raise StudyError(f"{path}: has no 'vertex' element (elements: {names}); expected {_POINTS_EXPECTED}")
    vertex = ply["vertex"]
    properties = [prop.name for prop in vertex.properties]
    missing = [axis for axis in "xyz" if axis not in properties]
    if missing:
        raise StudyError(
            f"{path}: the 'vertex' element lacks properties {missing} (has {properties}); "
            f"expected {_POINTS_EXPECTED}"
        )
    columns = [np.asarray(vertex.data[axis]) for axis in "xyz"]
    if any(column.dtype.kind not in "iuf" for column in columns):
        raise StudyError(f"{path}: vertex x, y, z must be numeric scalar properties; expected {_POINTS_EXPECTED}")
    return np.stack(columns, axis=1) if len(vertex.data) else np.empty((0, 3))


def read_points(path: PathLike) -> np.ndarray:
    """Read a point cloud in millimetres.

    Parameters
    ----------
    path : str or path-like
        ``.npy`` holding exactly an (N, 3) numeric array, or ``.ply`` with a ``vertex`` element
        that has ``x``, ``y``, ``z`` properties (other properties are ignored).

    Returns
    -------
    points_mm : ndarray of float64, shape (N, 3)
        ``x, y, z`` in mm; N may be 0.

    Raises
    ------
    StudyError
        If the file is missing or unreadable, has an unsupported extension or the wrong shape
        (named in the message), or holds non-finite values.
    """
    path = Path(path)
    suffix = _suffix(path, POINT_SUFFIXES, _POINTS_EXPECTED)
    _require_file(path, _POINTS_EXPECTED)
    array = _load_npy(path, _POINTS_EXPECTED) if suffix == ".npy" else _read_ply_xyz(path)
    return _as_points(array, str(path))


def _comment_lines(comment: str | None, where: str) -> list[str]:
    if comment is None:
        return []
    if not isinstance(comment, str):
        raise StudyError(f"{where}: comment must be a string, got {type(comment).__name__}")
    if not comment.isascii():
        raise StudyError(f"{where}: comment must be ASCII text (PLY headers are ASCII), got {comment!r}")
    return [line.strip() for line in comment.splitlines() if line.strip()]


def write_points_ply(path: PathLike, points_mm: Any, *, comment: str | None = None) -> None:
    """Write points as a binary little-endian PLY file.

    Parameters
    ----------
    path : str or path-like
        Destination; its parent folder must exist.
    points_mm : array_like, shape (N, 3)
        ``x, y, z`` in mm, finite; N may be 0. Written as a ``vertex`` element with float64 (PLY
        ``double``) properties ``x``, ``y``, ``z``.
    comment : str, optional
        Extra header comment (ASCII; each line becomes one PLY comment), written after the
        ``units mm`` and ``frame DICOM patient LPS`` comments.

    Raises
    ------
    StudyError
        If the points are not a finite (N, 3) numeric array, the comment is not ASCII text, or
        the file cannot be written.
    """
    path = Path(path)
    where = f"{path}: cannot write points"
    points = _as_points(np.asarray(points_mm), where)
    comments = [*_PLY_COMMENTS, *_comment_lines(comment, where)]
    vertex = np.empty(len(points), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vertex["x"], vertex["y"], vertex["z"] = points[:, 0], points[:, 1], points[:, 2]
    ply = PlyData([PlyElement.describe(vertex, "vertex")], text=False, byte_order="<", comments=comments)
    try:
        ply.write(str(path))
    except OSError as exc:
        raise StudyError(f"{where} ({exc})") from None
