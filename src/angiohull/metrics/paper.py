"""Scores of a reconstruction following the paper's protocol (docs/conventions.md, "Metrics"): voxel sets and reprojections.

Point sets and arrays only: nothing here reads files or runs a reconstruction.

* 3D scores work on voxel index sets: a point set is voxelised at ``voxel_mm`` (3 mm in the paper)
  on a grid aligned to the world origin (index ``floor(p / voxel_mm)``).
* Dice2D, paper protocol: the paper's rasteriser, a square dilation of side
  ``ceil(3 mm / detector pixel spacing)``, Dice against the input mask, mean over views.
* Dice2D, plain: the reconstruction's silhouette at pixel resolution (each point a lattice cell),
  no dilation, Dice against the input mask.

Percentages are in [0, 100]; an undefined score (e.g. the Chamfer distance of an empty set) is nan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from .. import _validation as _v
from ..errors import AngiohullError
from ..geometry import Projection
from ..rasterise import cell_silhouette, dilated_square, rasterise_points_paper

__all__ = [
    "PAPER_VOXEL_MM",
    "PAPER_DETECTOR_SPACING_MM",
    "voxelise",
    "voxel_centres_mm",
    "dice3d",
    "iou3d",
    "chamfer_mm",
    "dice2d",
    "paper_dilation_side_px",
    "dice2d_paper",
    "dice2d_plain",
    "Scores3D",
    "scores_3d",
]

PAPER_VOXEL_MM = 3.0
"""Voxel edge of the paper's 3D metrics, mm."""

PAPER_DETECTOR_SPACING_MM = 0.35
"""Detector pixel spacing of every experiment in the paper, mm; used for the Dice2D dilation of
views whose detector spacing is unknown (views given only as a projection matrix)."""

_KEY_BITS = 21
_KEY_LIMIT = 1 << (_KEY_BITS - 1)


def voxelise(points_mm: np.ndarray, voxel_mm: float = PAPER_VOXEL_MM) -> np.ndarray:
    """Unique voxel indices ``floor(p / voxel_mm)`` of a point set, shape (M, 3) int64, sorted."""
    points = _v.points_array(points_mm, "points_mm")
    size = _v.positive_finite(voxel_mm, "voxel_mm")
    return _decode(np.unique(_encode(np.floor(points / size).astype(np.int64))))


def voxel_centres_mm(indices: np.ndarray, voxel_mm: float = PAPER_VOXEL_MM) -> np.ndarray:
    """Centres ``(index + 0.5) * voxel_mm`` of voxel indices (M, 3), mm."""
    return (np.asarray(indices, dtype=np.float64) + 0.5) * voxel_mm


def _encode(indices: np.ndarray) -> np.ndarray:
    if indices.size and (indices.min() < -_KEY_LIMIT or indices.max() >= _KEY_LIMIT):
        raise AngiohullError(f"voxel indices beyond +-{_KEY_LIMIT}: points too far from the origin for the voxel size")
    shifted = indices + _KEY_LIMIT
    return (shifted[:, 0] << (2 * _KEY_BITS)) | (shifted[:, 1] << _KEY_BITS) | shifted[:, 2]


def _decode(keys: np.ndarray) -> np.ndarray:
    mask = (1 << _KEY_BITS) - 1
    return np.stack([(keys >> (2 * _KEY_BITS)) & mask, (keys >> _KEY_BITS) & mask, keys & mask], axis=1) - _KEY_LIMIT


@dataclass(frozen=True)
class Scores3D:
    """3D scores of a reconstruction against ground truth (percent and mm)."""

    dice3d: float  # 2|A n B| / (|A| + |B|) on voxel sets, percent
    iou3d: float  # |A n B| / |A u B|, percent
    chamfer_mm: float  # symmetric mean nearest-neighbour distance of voxel centres, mm; nan if a set is empty
    n_voxels_reconstruction: int
    n_voxels_ground_truth: int


def scores_3d(reconstruction_mm: np.ndarray, ground_truth_mm: np.ndarray, *,
              voxel_mm: float = PAPER_VOXEL_MM) -> Scores3D:
    """Dice3D, IoU3D and Chamfer distance of two point sets after voxelisation (one pass)."""
    a_keys = _encode(voxelise(reconstruction_mm, voxel_mm))
    b_keys = _encode(voxelise(ground_truth_mm, voxel_mm))
    common = np.intersect1d(a_keys, b_keys, assume_unique=True).size
    total = a_keys.size + b_keys.size
    dice = 100.0 * 2 * common / total if total else math.nan
    union = total - common
    iou = 100.0 * common / union if union else math.nan
    if a_keys.size == 0 or b_keys.size == 0:
        chamfer = math.nan
    else:
        a = voxel_centres_mm(_decode(a_keys), voxel_mm)
        b = voxel_centres_mm(_decode(b_keys), voxel_mm)
        a_to_b = cKDTree(b).query(a)[0].mean()
        b_to_a = cKDTree(a).query(b)[0].mean()
        chamfer = float((a_to_b + b_to_a) / 2.0)
    return Scores3D(float(dice), float(iou), chamfer, int(a_keys.size), int(b_keys.size))


def dice3d(reconstruction_mm: np.ndarray, ground_truth_mm: np.ndarray, *, voxel_mm: float = PAPER_VOXEL_MM) -> float:
    """Dice of the voxel sets, percent."""
    return scores_3d(reconstruction_mm, ground_truth_mm, voxel_mm=voxel_mm).dice3d


def iou3d(reconstruction_mm: np.ndarray, ground_truth_mm: np.ndarray, *, voxel_mm: float = PAPER_VOXEL_MM) -> float:
    """Intersection over union of the voxel sets, percent."""
    return scores_3d(reconstruction_mm, ground_truth_mm, voxel_mm=voxel_mm).iou3d


def chamfer_mm(reconstruction_mm: np.ndarray, ground_truth_mm: np.ndarray, *, voxel_mm: float = PAPER_VOXEL_MM) -> float:
    """Symmetric Chamfer distance of the voxel centres, mm (nan when either set is empty)."""
    return scores_3d(reconstruction_mm, ground_truth_mm, voxel_mm=voxel_mm).chamfer_mm


def dice2d(image: np.ndarray, reference: np.ndarray) -> float:
    """Dice of two bool images of the same shape, percent (nan when both are empty)."""
    a = np.asarray(image, dtype=bool)
    b = np.asarray(reference, dtype=bool)
    if a.shape != b.shape:
        raise AngiohullError(f"images must have the same shape, got {a.shape} and {b.shape}")
    total = int(a.sum()) + int(b.sum())
    return 100.0 * 2 * int(np.count_nonzero(a & b)) / total if total else math.nan


def paper_dilation_side_px(detector_spacing_mm: float | None = None) -> int:
    """Side of the square that dilates the reprojection: ``ceil(3 mm / spacing)`` (9 at 0.35 mm)."""
    spacing = PAPER_DETECTOR_SPACING_MM if detector_spacing_mm is None else detector_spacing_mm
    return math.ceil(PAPER_VOXEL_MM / _v.positive_finite(spacing, "detector_spacing_mm") - 1e-9)


def _check_views(projections: Sequence[Projection], masks: Sequence[np.ndarray]) -> None:
    if len(projections) != len(masks):
        raise AngiohullError(f"got {len(projections)} projections but {len(masks)} masks")
    for i, (p, m) in enumerate(zip(projections, masks)):
        if np.shape(m) != p.image_shape:
            raise AngiohullError(f"view {i}: mask shape {np.shape(m)} differs from the projection's image shape {p.image_shape}")


def dice2d_paper(points_mm: np.ndarray, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 detector_spacings_mm: Sequence[float | None] | None = None) -> list[float]:
    """Per-view Dice2D of the paper's protocol, percent.

    Each view: :func:`~angiohull.rasterise.rasterise_points_paper`, then a binary dilation with a
    square of side :func:`paper_dilation_side_px`, then Dice against the input mask.

    Parameters
    ----------
    detector_spacings_mm : sequence of float or None, keyword-only
        Detector pixel spacing of each view (None: unknown, use the paper's 0.35 mm).
    """
    _check_views(projections, masks)
    spacings = detector_spacings_mm if detector_spacings_mm is not None else [None] * len(projections)
    scores = []
    for projection, mask, spacing in zip(projections, masks, spacings):
        side = paper_dilation_side_px(spacing)
        image = rasterise_points_paper(points_mm, projection)
        dilated = dilated_square(image, side)  # ndi.binary_dilation with a side x side square, faster
        scores.append(dice2d(dilated, mask))
    return scores


def dice2d_plain(points_mm: np.ndarray, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                 cell_mm: float) -> list[float]:
    """Per-view Dice2D of the reconstruction's silhouette at pixel resolution, percent.

    The silhouette is :func:`~angiohull.rasterise.cell_silhouette` of the points with lattice cells
    of edge ``cell_mm``; no dilation.
    """
    _check_views(projections, masks)
    return [dice2d(cell_silhouette(points_mm, p, cell_mm), m) for p, m in zip(projections, masks)]
