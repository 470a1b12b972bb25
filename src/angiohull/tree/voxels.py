"""Voxel helpers shared by the skeleton code: 26-neighbour edges of a set of voxels, cube dilation."""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

__all__ = ["FORWARD_OFFSETS", "neighbour_edges", "dilated"]

FORWARD_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                            if (i, j, k) > (0, 0, 0)], dtype=np.int64)
"""The 13 offsets of the 26-neighbourhood that come after (0, 0, 0): each edge once."""


def neighbour_edges(voxels: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair of 26-neighbours among ``voxels`` ((N, 3) integer indices into a grid of ``shape``):
    ``(heads (E,), tails (E,), lengths (E,))``, indices into ``voxels`` and lengths in voxels (1,
    sqrt 2 or sqrt 3), each pair once."""
    index = np.full(shape, -1, dtype=np.int32)
    index[tuple(voxels.T)] = np.arange(len(voxels), dtype=np.int32)
    upper = np.array(shape)
    heads, tails, lengths = [], [], []
    for offset in FORWARD_OFFSETS:
        other = voxels + offset
        ok = np.all((other >= 0) & (other < upper), axis=1)
        j = np.full(len(voxels), -1, dtype=np.int64)
        j[ok] = index[tuple(other[ok].T)]
        found = j >= 0
        heads.append(np.flatnonzero(found))
        tails.append(j[found])
        lengths.append(np.full(int(found.sum()), float(np.linalg.norm(offset))))
    return np.concatenate(heads), np.concatenate(tails), np.concatenate(lengths)


def dilated(volume: np.ndarray, cells: int = 1) -> np.ndarray:
    """A bool volume dilated by ``cells`` in the 26-neighbourhood (a cube of side ``2 cells + 1``),
    as three 1D maximum filters; outside the volume counts as empty."""
    out = volume.view(np.uint8) if volume.dtype == bool else volume.astype(np.uint8)
    for axis in range(3):
        out = ndi.maximum_filter1d(out, 2 * cells + 1, axis=axis, mode="constant", cval=0)
    return out.astype(bool)
