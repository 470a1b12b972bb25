"""Metrics against hand-worked cases and brute-force references."""

import itertools
import math

import numpy as np
import pytest

from angiohull.errors import AngiohullError
from angiohull.geometry import CArmGeometry, Projection
from angiohull.metrics import (chamfer_mm, dice2d, dice2d_paper, dice3d, iou3d, paper_dilation_side_px, scores_3d,
                               voxel_centres_mm, voxelise)
from angiohull.rasterise import cell_silhouette, dilated_square, rasterise_points_paper, splat_points


def test_voxelise_floors_on_the_origin_aligned_grid():
    pts = np.array([[0, 0, 0], [2.9, 0.1, 2.99], [3.0, 0, 0], [-0.1, 0, 0], [-3.0, -3.0, -3.0], [-3.01, 0, 0]])
    got = {tuple(v) for v in voxelise(pts)}
    assert got == {(0, 0, 0), (1, 0, 0), (-1, 0, 0), (-1, -1, -1), (-2, 0, 0)}
    np.testing.assert_allclose(voxel_centres_mm(np.array([[0, 0, 0], [-1, 2, 3]])), [[1.5, 1.5, 1.5], [-1.5, 7.5, 10.5]])


def test_dice_iou_chamfer_hand_worked():
    a = np.array([[1.0, 1, 1], [4, 1, 1]])  # voxels (0,0,0), (1,0,0)
    b = np.array([[4.5, 1, 1], [7, 1, 1], [10, 1, 1]])  # voxels (1,0,0), (2,0,0), (3,0,0)
    assert dice3d(a, b) == pytest.approx(100 * 2 * 1 / 5)
    assert iou3d(a, b) == pytest.approx(100 * 1 / 4)
    # a->b: (0)->3 mm, (1)->0 ; b->a: 0, 3, 6 mm
    assert chamfer_mm(a, b) == pytest.approx((1.5 + 3.0) / 2)


def test_scores_match_brute_force_on_random_sets():
    rng = np.random.default_rng(7)
    for _ in range(5):
        a = rng.uniform(-20, 20, (300, 3))
        b = a[:150] + rng.normal(0, 2, (150, 3))
        va = {tuple(v) for v in np.floor(a / 3).astype(int)}
        vb = {tuple(v) for v in np.floor(b / 3).astype(int)}
        ca = (np.array(sorted(va)) + 0.5) * 3
        cb = (np.array(sorted(vb)) + 0.5) * 3
        d = np.linalg.norm(ca[:, None] - cb[None], axis=2)
        s = scores_3d(a, b)
        assert s.dice3d == pytest.approx(200 * len(va & vb) / (len(va) + len(vb)))
        assert s.iou3d == pytest.approx(100 * len(va & vb) / len(va | vb))
        assert s.chamfer_mm == pytest.approx((d.min(1).mean() + d.min(0).mean()) / 2)
        assert (s.n_voxels_reconstruction, s.n_voxels_ground_truth) == (len(va), len(vb))


def test_empty_reconstruction_scores_zero_and_undefined_chamfer():
    s = scores_3d(np.zeros((0, 3)), np.ones((4, 3)))
    assert s.dice3d == 0 and s.iou3d == 0 and math.isnan(s.chamfer_mm)


def test_voxelise_rejects_bad_points():
    with pytest.raises(AngiohullError, match=r"\(N, 3\)"):
        voxelise(np.zeros((4, 2)))
    with pytest.raises(AngiohullError, match="non-finite"):
        voxelise(np.array([[0, np.nan, 0]]))


def test_dice2d_images():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    a[0, :2] = True
    b[0, 1:4] = True
    assert dice2d(a, b) == pytest.approx(100 * 2 / 5)
    assert math.isnan(dice2d(np.zeros((2, 2)), np.zeros((2, 2))))
    with pytest.raises(AngiohullError, match="same shape"):
        dice2d(a, np.zeros((3, 3)))


@pytest.mark.parametrize("spacing, side", [(0.35, 9), (0.3, 10), (0.5, 6), (0.375, 8), (None, 9), (0.1, 30)])
def test_paper_dilation_side(spacing, side):
    assert paper_dilation_side_px(spacing) == side


def _affine_projection(shape=(64, 64)):
    # u = x, v = y for points at z = 0 (w = 1 there); the tiny z term keeps the matrix invertible
    return Projection([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1e-9, 1.0]], shape)


def test_paper_rasteriser_truncates_and_keeps_a_lone_pixel():
    p = _affine_projection()
    image = rasterise_points_paper(np.array([[10.7, 20.2, 0.0]]), p)
    # closing of one pixel gives that pixel; sigma 0.5 blur leaves 0.619 there, 0.084 at neighbours
    assert np.argwhere(image).tolist() == [[20, 10]]


def test_paper_rasteriser_drops_points_on_or_outside_the_border():
    p = _affine_projection((32, 32))
    pts = np.array([[0.0, 5.0, 0], [5.0, 0.0, 0], [32.0, 5.0, 0], [-0.5, 5, 0], [31.9, 31.9, 0]])
    assert np.argwhere(rasterise_points_paper(pts, p)).tolist() == [[31, 31]]


def test_paper_rasteriser_closing_fills_a_one_pixel_hole():
    p = _affine_projection()
    pts = np.array([[x + 0.5, y + 0.5, 0] for x in range(20, 27) for y in range(30, 37) if (x, y) != (23, 33)])
    image = rasterise_points_paper(pts, p)
    assert image[33, 23] and image.sum() == 49


def test_dice2d_paper_hand_worked_single_point():
    p = _affine_projection()
    mask = np.zeros((64, 64), bool)
    mask[16:25, 6:15] = True  # the 9x9 square the dilation makes around pixel (20, 10)
    assert dice2d_paper(np.array([[10.7, 20.2, 0.0]]), [p], [mask]) == [pytest.approx(100.0)]
    assert dice2d_paper(np.array([[10.7, 20.2, 0.0]]), [p], [mask], detector_spacings_mm=[0.5]) == [
        pytest.approx(100 * 2 * 36 / (36 + 81))]


def test_the_square_dilation_by_running_maxima_is_scipys_square_dilation():
    """Odd and even sides (scipy's even square reaches one pixel further back than forward), pixels
    at the image's edges, empty and full images."""
    from scipy import ndimage as ndi

    rng = np.random.default_rng(3)
    images = [rng.random(shape) < p for shape in ((64, 48), (5, 7), (1, 9)) for p in (0.0, 0.01, 0.2, 1.0)]
    corner = np.zeros((20, 20), bool)
    corner[0, 0] = corner[19, 19] = corner[0, 19] = True
    for image in (*images, corner):
        for side in range(1, 12):
            np.testing.assert_array_equal(dilated_square(image, side),
                                          ndi.binary_dilation(image, np.ones((side, side), bool)))
    four = dilated_square(corner, 4)  # a pixel's square of side 4: 2 pixels back, 1 forward
    assert four[:2, :2].all() and not four[2, 0] and four[17:, 17:].all() and not four[16, 19]
    with pytest.raises(ValueError, match="at least 1 pixel"):
        dilated_square(corner, 0)


def test_splat_rounds_to_the_nearest_pixel_centre():
    p = _affine_projection()
    assert np.argwhere(splat_points(np.array([[10.49, 20.51, 0]]), p)).tolist() == [[21, 10]]


def test_cell_silhouette_of_one_cell_at_the_isocentre():
    p = CArmGeometry(0, 0, 1200, 800, (0.35, 0.35), (512, 512)).projection()
    image = cell_silhouette(np.zeros((1, 3)), p, 1.2)
    # front face at depth 799.4 mm: half-size 0.6 * 1200 / 799.4 / 0.35 = 2.573 px around 255.5
    rows, cols = np.nonzero(image)
    assert sorted(set(rows)) == list(range(253, 259)) and sorted(set(cols)) == list(range(253, 259))
    assert image.sum() == 36


def test_cell_silhouette_matches_convex_hulls_of_projected_corners():
    # oracle: a pixel centre is in the silhouette iff it lies inside the convex hull of the 8
    # projected corners of some cell (the projection of a convex box)
    from scipy.spatial import Delaunay

    p = CArmGeometry(35, -20, 1200, 800, (0.35, 0.35), (96, 96)).projection()
    rng = np.random.default_rng(3)
    centres = rng.uniform(-5, 5, (25, 3))
    image = cell_silhouette(centres, p, 1.3, chunk_pairs=50)  # tiny chunks exercise the chunking
    grid = np.stack(np.meshgrid(np.arange(96), np.arange(96), indexing="xy"), -1).reshape(-1, 2)
    expected = np.zeros(96 * 96, bool)
    corners = np.array(list(itertools.product((-0.65, 0.65), repeat=3)))
    for c in centres:
        expected |= Delaunay(p.project(c + corners)).find_simplex(grid) >= 0
    assert image.sum() > 100
    np.testing.assert_array_equal(image.reshape(-1), expected)


def test_boundary_cells_of_a_block_leave_out_its_inside():
    from angiohull.rasterise import boundary_cells

    grid = np.stack(np.meshgrid(*[np.arange(4) * 0.5] * 3, indexing="ij"), axis=-1).reshape(-1, 3) + 0.25
    boundary = boundary_cells(grid, 0.5)
    assert len(boundary) == 64 - 8  # the 2 x 2 x 2 inner cells have all six neighbours
    jittered = grid + rng_offsets(len(grid))
    assert len(boundary_cells(jittered, 0.5)) == 64  # not on a grid: nothing is left out


def rng_offsets(n):
    return np.random.default_rng(0).uniform(0.01, 0.1, (n, 3))


def test_silhouette_skipping_interior_cells_equals_the_silhouette_of_every_cell():
    rng = np.random.default_rng(3)
    axis = np.linspace(-12.0, 12.0, 49)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    # a thick bent tube and a ball: solid insides, many interior cells
    tube = np.linalg.norm(grid[:, :2] - np.c_[3 * np.sin(grid[:, 2] / 5), np.zeros(len(grid))], axis=1) < 4
    ball = np.linalg.norm(grid - [6, 6, 6], axis=1) < 5
    points = grid[tube | ball]
    spacing = axis[1] - axis[0]
    for _ in range(3):
        carm = CArmGeometry(rng.uniform(-90, 90), rng.uniform(-40, 40), 1000.0, 700.0, (0.4, 0.4), (90, 110))
        projection = carm.projection()
        fast = cell_silhouette(points, projection, spacing)
        every = cell_silhouette(points, projection, spacing, skip_interior=False)
        assert fast.sum() > 500
        np.testing.assert_array_equal(fast, every)
