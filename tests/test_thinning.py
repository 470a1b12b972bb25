"""Guo–Hall thinning (angiohull.thinning) against a per-pixel reference and the authors' skeletons."""

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage as ndi

from angiohull.reconstruction import skeletonise
from angiohull.thinning import guo_hall_skeleton_pixels, guo_hall_thin, guo_hall_thin_many


def _reference_thin(mask: np.ndarray, keep_edge: bool) -> np.ndarray:
    """The rule of Guo & Hall (1989), algorithm A1, pixel by pixel on the whole image (slow): the
    module notes' formulas written out, no rule table, no candidate sets."""
    image = np.pad(np.asarray(mask, dtype=bool), 1)
    rows, cols = image.shape
    while True:
        changed = 0
        for sub in (0, 1):
            delete = []
            for y in range(1, rows - 1):
                for x in range(1, cols - 1):
                    if not image[y, x]:
                        continue
                    if keep_edge and (y in (1, rows - 2) or x in (1, cols - 2)):
                        continue
                    p2, p3, p4, p5 = image[y - 1, x], image[y - 1, x + 1], image[y, x + 1], image[y + 1, x + 1]
                    p6, p7, p8, p9 = image[y + 1, x], image[y + 1, x - 1], image[y, x - 1], image[y - 1, x - 1]
                    c = (int(not p2 and (p3 or p4)) + int(not p4 and (p5 or p6)) + int(not p6 and (p7 or p8))
                         + int(not p8 and (p9 or p2)))
                    n1 = int(p9 or p2) + int(p3 or p4) + int(p5 or p6) + int(p7 or p8)
                    n2 = int(p2 or p3) + int(p4 or p5) + int(p6 or p7) + int(p8 or p9)
                    n = min(n1, n2)
                    m = (p4 and (p2 or p3 or not p5)) if sub == 0 else (p8 and (p6 or p7 or not p9))
                    if c == 1 and 2 <= n <= 3 and not m:
                        delete.append((y, x))
            for y, x in delete:
                image[y, x] = False
            changed += len(delete)
        if changed == 0:
            return image[1:-1, 1:-1]


def _blobs(seed: int, shape=(40, 56), touching_edge=False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    mask = ndi.binary_dilation(rng.random(shape) < 0.01, iterations=int(rng.integers(1, 4)))
    mask |= rng.random(shape) < 0.03  # specks and rough edges
    if touching_edge:
        mask[0, 5:30] = True
        mask[5:20, -1] = True
    return mask


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("keep_edge", [False, True])
def test_equals_the_per_pixel_rule_on_random_images(seed, keep_edge, kernel_backend):
    mask = _blobs(seed, touching_edge=seed % 2 == 0)
    np.testing.assert_array_equal(guo_hall_thin(mask, keep_edge=keep_edge), _reference_thin(mask, keep_edge))


@pytest.mark.parametrize("keep_edge", [False, True])
def test_several_images_at_once_equal_the_per_pixel_rule_on_each(keep_edge, kernel_backend):
    # images of different shapes, one touching the edges, one empty, one a single pixel wide: thinned
    # together, each comes out as the per-pixel rule thins it alone
    masks = [_blobs(10, touching_edge=True), _blobs(11, shape=(23, 71)), np.zeros((9, 9), bool),
             _blobs(12, shape=(64, 30), touching_edge=True), np.eye(12, dtype=bool)]
    for mask, skeleton in zip(masks, guo_hall_thin_many(masks, keep_edge=keep_edge)):
        assert skeleton.shape == mask.shape and skeleton.dtype == bool
        np.testing.assert_array_equal(skeleton, _reference_thin(mask, keep_edge))
    assert guo_hall_thin_many([]) == []
    # the skeletons' pixel centres, as np.nonzero lists them (u = column, v = row)
    for mask, pixels in zip(masks, guo_hall_skeleton_pixels(masks, keep_edge=keep_edge)):
        rows, cols = np.nonzero(_reference_thin(mask, keep_edge))
        assert pixels.shape == (len(rows), 2) and pixels.dtype == np.float64
        np.testing.assert_array_equal(pixels, np.stack([cols, rows], axis=1))
    assert guo_hall_skeleton_pixels([]) == []


def test_hand_worked_cases():
    # worked by hand through the rule: a 3 x 7 bar loses its top row, right end and corners in the
    # first subiteration, its bottom row and left end in the second, and keeps row 2, columns 2-6
    bar = np.zeros((5, 9), bool)
    bar[1:4, 1:8] = True
    expected = np.zeros_like(bar)
    expected[2, 2:7] = True
    np.testing.assert_array_equal(guo_hall_thin(bar), expected)
    # a 2 x 2 block keeps its lower-left pixel (the first subiteration keeps only that one)
    block = np.zeros((4, 4), bool)
    block[1:3, 1:3] = True
    np.testing.assert_array_equal(np.argwhere(guo_hall_thin(block)), [[2, 1]])
    # a one-pixel line and a single pixel are skeletons already
    line = np.zeros((3, 7), bool)
    line[1, 1:6] = True
    np.testing.assert_array_equal(guo_hall_thin(line), line)
    assert not guo_hall_thin(np.zeros((5, 5), bool)).any()


def test_keeps_topology_and_stays_inside_the_mask():
    for seed in range(4):
        mask = ndi.binary_dilation(_blobs(seed + 10, (120, 150)), iterations=2)
        skeleton = guo_hall_thin(mask)
        assert not (skeleton & ~mask).any()
        eight = np.ones((3, 3), bool)
        assert ndi.label(skeleton, eight)[1] == ndi.label(mask, eight)[1]


def test_keep_edge_never_deletes_edge_pixels():
    mask = np.zeros((20, 20), bool)
    mask[0:6, 4:12] = True  # a thick vessel leaving the image at the top
    free, kept = guo_hall_thin(mask), guo_hall_thin(mask, keep_edge=True)
    np.testing.assert_array_equal(kept[0], mask[0])
    assert free[0].sum() < mask[0].sum()


def test_rejects_non_2d_input():
    with pytest.raises(ValueError, match="2D"):
        guo_hall_thin(np.zeros((3, 3, 3)))


def test_skeletons_equal_the_authors_on_all_48_peer_studies(peer_synthetic_dir, kernel_backend):
    differing = []
    for folder in sorted(p for p in peer_synthetic_dir.iterdir() if p.is_dir()):
        theirs = np.load(folder / "peer_reconstruction.npz", allow_pickle=False)["skeletons"]
        for i, reference in enumerate(theirs):
            mask = np.asarray(Image.open(folder / "masks" / f"view{i}.png")) > 0
            if not np.array_equal(skeletonise(mask), reference > 0):
                differing.append(f"{folder.name} view {i}")
    assert not differing, differing
