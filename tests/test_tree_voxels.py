"""The voxel helpers of the skeleton code against independent oracles on small random volumes."""

import numpy as np
import pytest
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from angiohull.tree.voxels import coordinates, dilated, distance_to, neighbour_edges


def _volumes(seed, count=40):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        shape = tuple(int(x) for x in rng.integers(1, 10, 3))
        yield rng, rng.random(shape) < rng.uniform(0.02, 0.6)


def test_coordinates_are_argwhere():
    for _, volume in _volumes(1):
        np.testing.assert_array_equal(coordinates(volume), np.argwhere(volume))
    assert coordinates(np.zeros((3, 4, 5), dtype=bool)).shape == (0, 3)


@pytest.mark.parametrize("cells", [1, 2, 3])
def test_dilation_is_a_cube_dilation_with_empty_outside(cells):
    cube = np.ones((2 * cells + 1,) * 3, dtype=bool)
    for _, volume in _volumes(2 + cells):
        np.testing.assert_array_equal(dilated(volume, cells), ndi.binary_dilation(volume, cube, border_value=0))


def test_neighbour_edges_are_every_26_neighbour_pair_once():
    for _, volume in _volumes(5):
        voxels = np.argwhere(volume)
        heads, tails, lengths = neighbour_edges(voxels, volume.shape)
        gap = np.abs(voxels[:, None, :] - voxels[None, :, :])
        i, j = np.nonzero((gap.max(axis=2) == 1) & (np.arange(len(voxels))[:, None] < np.arange(len(voxels))[None, :]))
        got = {tuple(sorted(p)) for p in zip(heads.tolist(), tails.tolist())}
        assert len(got) == len(heads) == len(i)  # each pair once
        assert got == set(zip(i.tolist(), j.tolist()))
        np.testing.assert_array_equal(lengths, np.linalg.norm(voxels[heads] - voxels[tails], axis=1))


@pytest.mark.parametrize("max_cells", [1, 2, 8])
def test_distance_to_a_set_is_the_k_d_trees(max_cells):
    # rings up to max_cells, a k-d tree beyond: the same numbers as a k-d tree on the set, to the bit
    for rng, volume in _volumes(9 + max_cells):
        target = rng.random(volume.shape) < 0.05
        if not target.any():
            continue
        voxels = np.argwhere(np.ones(volume.shape, dtype=bool))
        expected, _ = cKDTree(np.argwhere(target)).query(voxels)
        np.testing.assert_array_equal(distance_to(target, voxels, max_cells=max_cells), expected)


def test_distance_to_a_thick_object_reads_the_distance_transform_and_gives_the_k_d_trees():
    # a ball 14 voxels in radius: most of its voxels lie farther from the shell around it than the
    # rings reach cheaply, so the rest are read off the exact distance transform; the same numbers
    # as a k-d tree on the shell, to the bit, and a thin tube's stay on the rings
    grid = np.indices((33, 33, 33)).transpose(1, 2, 3, 0) - 16
    ball = (grid ** 2).sum(axis=3) <= 14 ** 2
    shell = dilated(ball, 1) & ~ball
    voxels = np.argwhere(ball)
    expected, _ = cKDTree(np.argwhere(shell)).query(voxels)
    np.testing.assert_array_equal(distance_to(shell, voxels), expected)
    assert expected.max() > 8  # past the rings' reach: without the transform the k-d tree would answer
    tube = np.zeros((40, 9, 9), dtype=bool)
    tube[:, 3:6, 3:6] = True
    rim = dilated(tube, 1) & ~tube
    voxels = np.argwhere(tube)
    np.testing.assert_array_equal(distance_to(rim, voxels), cKDTree(np.argwhere(rim)).query(voxels)[0])
    # no target at all: infinitely far, either way
    assert np.all(np.isinf(distance_to(np.zeros(ball.shape, dtype=bool), np.argwhere(ball))))
