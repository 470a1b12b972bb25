"""The cube of interest: a K x K x K lattice of points centred on the isocentre."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _validation as _v
from ..errors import ReconstructionError

__all__ = ["Lattice", "MAX_DENSE_RESOLUTION"]

MAX_DENSE_RESOLUTION = 1024
"""Largest K accepted for a lattice (the dense engines hold K**3 points)."""


@dataclass(frozen=True)
class Lattice:
    """``linspace(-R, R, K)`` on each axis (docs/conventions.md, method step 2).

    Attributes
    ----------
    half_edge_mm : float
        R, half the cube's edge, mm.
    resolution : int
        K, points per axis (>= 2).
    """

    half_edge_mm: float
    resolution: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "half_edge_mm", _v.positive_finite(self.half_edge_mm, "half_edge_mm", error=ReconstructionError))
        k = _v.positive_int(self.resolution, "resolution", error=ReconstructionError)
        if not 2 <= k <= MAX_DENSE_RESOLUTION:
            raise ReconstructionError(f"resolution (points per axis) must be within [2, {MAX_DENSE_RESOLUTION}], got {k}")
        object.__setattr__(self, "resolution", k)

    @property
    def spacing_mm(self) -> float:
        """Distance between neighbouring lattice points, ``2R / (K - 1)``, mm."""
        return 2.0 * self.half_edge_mm / (self.resolution - 1)

    @property
    def n_points(self) -> int:
        """K**3."""
        return self.resolution ** 3

    def axis_mm(self) -> np.ndarray:
        """The K coordinates of one axis, mm."""
        return np.linspace(-self.half_edge_mm, self.half_edge_mm, self.resolution)

    def points(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Lattice points ``[start, stop)`` in C order (x slowest, z fastest), shape (n, 3), mm.

        Slicing lets engines walk the lattice in chunks without holding all K**3 points.
        """
        stop = self.n_points if stop is None else min(stop, self.n_points)
        return self.points_at(np.arange(start, stop, dtype=np.int64))

    def points_at(self, flat_indices: np.ndarray) -> np.ndarray:
        """Lattice points of the given C-order flat indices, shape (n, 3), mm."""
        k = self.resolution
        flat = np.asarray(flat_indices, dtype=np.int64)
        axis = self.axis_mm()
        return np.stack([axis[flat // (k * k)], axis[(flat // k) % k], axis[flat % k]], axis=1)
