"""Small argument checks shared by the layers above (imports nothing from angiohull but errors)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import AngiohullError


def positive_finite(value: Any, name: str, *, error: type[AngiohullError] = AngiohullError) -> float:
    """Return ``value`` as a float, or raise ``error`` if it is not a finite number > 0."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise error(f"{name} must be a positive number, got {value!r}") from None
    if not math.isfinite(number) or number <= 0:
        raise error(f"{name} must be a positive finite number, got {value!r}")
    return number


def finite(value: Any, name: str, *, error: type[AngiohullError] = AngiohullError) -> float:
    """Return ``value`` as a float, or raise ``error`` if it is not a finite number."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise error(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise error(f"{name} must be a finite number, got {value!r}")
    return number


def positive_int(value: Any, name: str, *, error: type[AngiohullError] = AngiohullError) -> int:
    """Return ``value`` as an int, or raise ``error`` if it is not an integer >= 1."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        if isinstance(value, (float, np.floating)) and float(value).is_integer():
            value = int(value)
        else:
            raise error(f"{name} must be a positive integer, got {value!r}")
    if int(value) < 1:
        raise error(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def image_shape(value: Any, name: str = "image_shape", *, error: type[AngiohullError] = AngiohullError) -> tuple[int, int]:
    """Return ``(rows, cols)`` as a tuple of two positive ints, or raise ``error``."""
    try:
        items = tuple(value)
    except TypeError:
        raise error(f"{name} must be (rows, cols), got {value!r}") from None
    if len(items) != 2:
        raise error(f"{name} must be (rows, cols) with 2 entries, got {len(items)}: {value!r}")
    return (positive_int(items[0], f"{name}[0] (rows)", error=error), positive_int(items[1], f"{name}[1] (cols)", error=error))


def points_array(points: Any, name: str = "points", *, error: type[AngiohullError] = AngiohullError) -> np.ndarray:
    """Return ``points`` as a finite float64 (N, 3) array, or raise ``error`` saying what was received."""
    try:
        array = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{name} must be an (N, 3) array of x, y, z in mm, got {type(points).__name__}") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise error(f"{name} must be an (N, 3) array of x, y, z in mm, got shape {array.shape}")
    finite = np.isfinite(array).all(axis=1)
    if not finite.all():
        raise error(f"{name} contains {int(np.count_nonzero(~finite))} non-finite point(s) (NaN or infinite coordinates)")
    return array


def readonly_copy(array: Any, dtype: Any = np.float64) -> np.ndarray:
    """A C-contiguous copy of ``array`` as ``dtype`` that cannot be written to (for frozen records)."""
    copy = np.array(array, dtype=dtype, copy=True, order="C")
    copy.setflags(write=False)
    return copy


#: A mask with fewer rows or columns than this cannot show a vessel with background beside it.
MIN_MASK_SIDE_PX = 4
#: A vessel mask covering more than this share of its image is probably inverted (vessels cover a few percent).
MAX_VESSEL_SHARE = 0.5


def vessel_share_problem(mask: Any) -> str | None:
    """What is wrong with a mask whose vessel covers more than :data:`MAX_VESSEL_SHARE` of its
    pixels (probably inverted), None otherwise: the text of a warning, after the mask's name."""
    mask = np.asarray(mask)
    share = float(np.count_nonzero(mask)) / max(mask.size, 1)
    if share <= MAX_VESSEL_SHARE:
        return None
    what = "every pixel is vessel" if share == 1.0 else f"{100.0 * share:.0f} % of the pixels are vessel"
    return (f"{what}; vessels cover a few percent of an angiogram, so the mask is probably inverted (vessel must be "
            f"nonzero) or not a vessel mask, and the view removes almost nothing from the hull")
