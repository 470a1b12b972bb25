"""Scores of a reconstruction (docs/conventions.md, "Metrics"). Point sets, trees and arrays only: nothing
here reads files or runs a reconstruction.

* :mod:`.paper`: the paper's protocol: voxel sets (Dice3D, IoU3D, Chamfer) and Dice2D of the
  reprojections (paper protocol and plain);
* :mod:`.tree`: centerline and radius scores of a :class:`~angiohull.tree.VesselTree` against a
  true tree.
"""

from __future__ import annotations

from .paper import (PAPER_DETECTOR_SPACING_MM, PAPER_VOXEL_MM, Scores3D, chamfer_mm, dice2d, dice2d_paper,
                    dice2d_plain, dice3d, iou3d, paper_dilation_side_px, scores_3d, voxel_centres_mm, voxelise)
from .tree import TreeScores, centerline_samples, distance_to_centerline, overlap_key, tree_scores

from . import paper as _paper

__all__ = [*_paper.__all__, "TreeScores", "tree_scores", "centerline_samples", "distance_to_centerline", "overlap_key"]
