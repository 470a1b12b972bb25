"""Epipolar geometry of two views: the pencil of planes around their baseline, and the one image
shift that two views alone determine.

Every 3D point lies in one plane through the baseline ``C_0 C_1`` of the two sources, and projects
into both views on rays of that plane. A plane is named by its angle around the baseline, so each
pixel of either view has an *epipolar angle*. Two masks of the same object therefore cover the
same set of angles.

Two views constrain their image shifts by one number only: of the four shift components, three are
what a common 3D translation of the object explains (the calibration's gauge), and the fourth moves
one view across its epipolar lines, which changes its pixels' angles by about a constant.
:func:`two_view_shift` finds it by making the two masks' sets of angles agree:

1. Each pixel of the mask's large connected parts (isolated false positives would each claim a
   plane) covers an interval of angles: its centre's angle plus and minus half its extent along the
   angle's gradient. The intervals are marked in bins of ``bin_px`` pixels (converted with the rate
   at which the angle changes across view 1's epipolar lines, at its mask's centroid); pixel
   centres alone would leave every other bin empty where a vessel runs across the epipolar lines
   along a pixel row.
2. **Coarse:** the occupied bins of view 1, moved by whole bins, against those of view 0; the
   score is their intersection over union (1 when every pixel of each mask has a partner plane in
   the other). Of the best moves, the one nearest to no move is kept.
3. **Fine:** the exact angles of view 1's pixels with its image moved across its epipolar lines in
   steps of ``FINE_STEP_PX`` (bins as fine) within 2 px of the coarse move; the middle of the best
   ones is returned.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

from ..geometry import Projection

__all__ = ["EpipolarPencil", "ray_directions", "two_view_shift", "MIN_COMPONENT_FRACTION"]


def ray_directions(projection: Projection, uv_px: np.ndarray) -> np.ndarray:
    """Unit directions of the rays through pixels ``uv_px`` (pointing in front of the source)."""
    homogeneous = np.column_stack([uv_px, np.ones(len(uv_px))])
    directions = np.linalg.solve(projection.matrix[:, :3], homogeneous.T).T
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


class EpipolarPencil:
    """The pencil of planes around the baseline of two camera centres: a plane's angle (radians)."""

    def __init__(self, centre_i: np.ndarray, centre_j: np.ndarray):
        b = centre_j - centre_i
        self.axis = b / np.linalg.norm(b)
        helper = np.array([1.0, 0.0, 0.0]) if abs(self.axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        self.e1 = np.cross(self.axis, helper)
        self.e1 /= np.linalg.norm(self.e1)
        self.e2 = np.cross(self.axis, self.e1)
        self.offset = 0.0

    def angle(self, directions: np.ndarray) -> np.ndarray:
        """The angle of the plane through the baseline and each ray (unit directions (N, 3)),
        less :attr:`offset`, in (-pi, pi]."""
        return self.wrapped(self.unwrapped_angle(directions))

    def unwrapped_angle(self, directions: np.ndarray) -> np.ndarray:
        """:meth:`angle` before :attr:`offset` is taken off (measured from ``e1``)."""
        # the plane through the baseline and a ray from either centre has normal axis x direction
        # (for a ray from C_j, axis x (C_j - C_i + l d) = l axis x d): one formula for both views
        a = self.axis
        x, y, z = directions[:, 0], directions[:, 1], directions[:, 2]
        normals = np.column_stack([a[1] * z - a[2] * y, a[2] * x - a[0] * z, a[0] * y - a[1] * x])
        return np.arctan2(normals @ self.e2, normals @ self.e1)

    def wrapped(self, unwrapped: np.ndarray) -> np.ndarray:
        """Angles from :meth:`unwrapped_angle` with :attr:`offset` taken off, wrapped to (-pi, pi]."""
        return np.angle(np.exp(1j * (unwrapped - self.offset)))

    def pixel_angles(self, projection: Projection, uv_px: np.ndarray) -> np.ndarray:
        """The angles of the planes through the rays of pixels ``uv_px``."""
        return self.angle(ray_directions(projection, uv_px))


FINE_STEP_PX = 0.1
"""Step (and bin width) of the fine search of :func:`two_view_shift`, pixels."""

MIN_COMPONENT_FRACTION = 0.01
""":func:`two_view_shift` reads only the mask's connected parts (8-connected) that hold at least this
fraction of its pixels: a stray false-positive pixel would claim an epipolar plane of its own."""


def _pixels(mask: np.ndarray) -> np.ndarray:
    """``(u, v)`` of the pixels of the mask's large connected parts (MIN_COMPONENT_FRACTION)."""
    labels, count = ndi.label(mask, structure=np.ones((3, 3), dtype=bool))
    if count:
        sizes = np.bincount(labels.ravel())[1:]
        mask = np.isin(labels, np.flatnonzero(sizes >= MIN_COMPONENT_FRACTION * sizes.sum()) + 1)
    rows, cols = np.nonzero(mask)
    return np.column_stack([cols, rows]).astype(float)


def _angle_gradient(pencil: EpipolarPencil, projection: Projection, uv_px: np.ndarray) -> np.ndarray:
    """d(angle)/d(u, v) at the centroid of ``uv_px`` (radians per pixel)."""
    centroid = uv_px.mean(axis=0)
    angles = pencil.pixel_angles(projection, centroid + np.vstack([np.zeros(2), np.eye(2)]))
    return np.angle(np.exp(1j * (angles[1:] - angles[0])))


def two_view_shift(projection_0: Projection, projection_1: Projection, mask_0: np.ndarray, mask_1: np.ndarray,
                   *, max_shift_px: float = 60.0, bin_px: float = 0.5) -> np.ndarray:
    """The image shift of view 1, across its epipolar lines, that makes the two masks cover the same
    epipolar planes (see the module notes). Returns ``(du, dv)`` in pixels, to be applied as
    ``projection_1.shifted(du, dv)``; ``(0, 0)`` when the masks give no preference.
    """
    uv_0, uv_1 = _pixels(mask_0), _pixels(mask_1)
    if len(uv_0) == 0 or len(uv_1) == 0:
        return np.zeros(2)
    pencil = EpipolarPencil(projection_0.camera_centre_mm, projection_1.camera_centre_mm)
    pencil.offset = float(np.angle(np.mean(np.exp(1j * pencil.pixel_angles(projection_0, uv_0)))))  # away from +-pi
    angles_0 = pencil.pixel_angles(projection_0, uv_0)
    angles_1 = pencil.pixel_angles(projection_1, uv_1)
    gradient_0, gradient_1 = _angle_gradient(pencil, projection_0, uv_0), _angle_gradient(pencil, projection_1, uv_1)
    rate = float(np.linalg.norm(gradient_1))  # radians per pixel across view 1's epipolar lines
    if rate <= 0:
        return np.zeros(2)
    across = gradient_1 / rate
    # a pixel is a unit square: it covers the planes within half its extent along the gradient
    half_0, half_1 = 0.5 * np.abs(gradient_0).sum(), 0.5 * np.abs(gradient_1).sum()
    margin = (max_shift_px + 5.0) * rate
    low = min(angles_0.min(), angles_1.min()) - margin
    span = max(angles_0.max(), angles_1.max()) + margin - low

    def occupied(angles: np.ndarray, half: float, width: float) -> np.ndarray:
        n_bins = int(np.ceil(span / width)) + 2
        first = np.floor((angles - half - low) / width).astype(np.int64)
        last = np.floor((angles + half - low) / width).astype(np.int64)
        edges = np.zeros(n_bins + 1)
        np.add.at(edges, first, 1.0)
        np.add.at(edges, last + 1, -1.0)
        return np.cumsum(edges[:-1]) > 0.5

    def agreement(bins_0: np.ndarray, bins_1: np.ndarray) -> float:
        return np.count_nonzero(bins_0 & bins_1) / np.count_nonzero(bins_0 | bins_1)

    # moving view 1's image by d px across its epipolar lines moves its pixels' angles by -d * rate
    width = bin_px * rate
    occupied_0, occupied_1 = occupied(angles_0, half_0, width), occupied(angles_1, half_1, width)
    moves = np.arange(-int(max_shift_px / bin_px), int(max_shift_px / bin_px) + 1)
    coarse = np.array([agreement(occupied_0, np.roll(occupied_1, -k)) for k in moves])
    best = moves[coarse >= coarse.max() - 1e-12]
    start = float(best[np.argmin(np.abs(best))]) * bin_px
    fine_width = FINE_STEP_PX * rate
    fine_0 = occupied(angles_0, half_0, fine_width)
    fine_moves = start + np.arange(-round(2.0 / FINE_STEP_PX), round(2.0 / FINE_STEP_PX) + 1) * FINE_STEP_PX
    # a pixel's ray is linear in the pixel (M^-1 (u, v, 1)) and a plane's angle does not depend on the
    # ray's length: the rays of view 1's pixels moved by d are the unmoved ones less d times one step
    matrix = projection_1.matrix[:, :3]
    rays_1 = np.linalg.solve(matrix, np.column_stack([uv_1, np.ones(len(uv_1))]).T).T
    ray_step = np.linalg.solve(matrix, np.array([across[0], across[1], 0.0]))
    fine = np.array([agreement(fine_0, occupied(pencil.angle(rays_1 - d * ray_step), half_1, fine_width))
                     for d in fine_moves])
    return float(np.mean(fine_moves[fine >= fine.max() - 1e-12])) * across
