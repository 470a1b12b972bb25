"""Robust carving (min_views = k of N): the fast engines keep exactly the reference's points."""

import numpy as np
import pytest

from angiohull.errors import EmptyHullError, ReconstructionError
from angiohull.reconstruction import Lattice, reconstruct
from angiohull.reconstruction.engines import ENGINES, mask_pixel_centres
from angiohull.synthetic import SynthOptions, make_case

from _cases import random_case


def _brute_force(lattice, projections, masks, threshold, need):
    """Oracle: every lattice point, every view, every mask pixel centre (no tree, no culling)."""
    points = lattice.points(0, lattice.n_points)
    votes = np.zeros(len(points), dtype=int)
    for projection, mask in zip(projections, masks):
        h = projection.homogeneous(points)
        front = h[:, 2] > 0
        uv = h[:, :2] / np.where(front, h[:, 2], 1.0)[:, None]
        centres = mask_pixel_centres(mask)
        near = np.zeros(len(points), dtype=bool)
        for start in range(0, len(centres), 256):
            d = np.linalg.norm(uv[:, None, :] - centres[None, start:start + 256], axis=2)
            near |= (d < threshold).any(axis=1)
        votes += near & front
    return points[votes >= need]


@pytest.mark.parametrize("seed, n_views, need", [(0, 3, 2), (1, 4, 2), (2, 4, 3), (3, 5, 1), (4, 3, 1)])
def test_k_of_n_engines_equal_the_brute_force_oracle(seed, n_views, need):
    projections, masks = random_case(seed, n_views=n_views)
    lattice = Lattice(60.0, 24)
    expected = _brute_force(lattice, projections, masks, 1.0, need)
    for engine in ("kdtree", "lookup", "octree"):
        outcome = ENGINES[engine](lattice, projections, masks, threshold_px=1.0, min_views=need)
        assert np.array_equal(outcome.points_mm, expected), engine


def test_all_views_is_the_papers_rule_and_more_tolerance_keeps_more():
    projections, masks = random_case(7, n_views=4)
    paper = reconstruct(projections, masks, resolution=30, centerlines=False, tree=False, allow_empty=True, warn=False)
    same = reconstruct(projections, masks, resolution=30, centerlines=False, tree=False, allow_empty=True, min_views=4,
                       warn=False)
    assert np.array_equal(paper.vessel_points_mm, same.vessel_points_mm) and same.min_views is None
    sizes = [len(reconstruct(projections, masks, resolution=30, centerlines=False, tree=False, allow_empty=True,
                             min_views=k, warn=False).vessel_points_mm) for k in (4, 3, 2, 1)]
    assert sizes == sorted(sizes) and sizes[0] < sizes[-1]


def test_two_of_three_survives_a_missing_segment():
    # A gap cut into one view's mask carves the vessel away under the paper's rule; 2-of-3 keeps it.
    clean = make_case(SynthOptions(seed=3, views="clinical"))
    broken = make_case(SynthOptions(seed=3, views="clinical", corruptions=("missing=3@0",)))
    projections = [v.projection for v in clean.views]

    def count(views, **kw):
        return len(reconstruct(projections, [v.mask for v in views], centerlines=False, tree=False, **kw).vessel_points_mm)

    assert count(broken.views) < count(clean.views)
    truth = clean.tree.phantom
    lost_paper = truth.contains(reconstruct(projections, [v.mask for v in clean.views],
                                            centerlines=False, tree=False).vessel_points_mm).sum() - \
        truth.contains(reconstruct(projections, [v.mask for v in broken.views], centerlines=False, tree=False).vessel_points_mm).sum()
    robust = reconstruct(projections, [v.mask for v in broken.views], centerlines=False, tree=False, min_views=2)
    assert lost_paper > 0
    assert truth.contains(robust.vessel_points_mm).sum() >= truth.contains(
        reconstruct(projections, [v.mask for v in clean.views], centerlines=False, tree=False).vessel_points_mm).sum()


@pytest.mark.parametrize("value", [0, 4, 2.5, "two"])
def test_bad_min_views(value):
    projections, masks = random_case(0)
    with pytest.raises(ReconstructionError, match="min_views"):
        reconstruct(projections, masks, resolution=10, min_views=value, warn=False)


def test_empty_k_of_n_hull_says_so():
    projections, masks = random_case(0, n_views=3)
    masks = [np.zeros_like(m) for m in masks]
    for m, (r, c) in zip(masks, [(0, 0), (95, 79), (0, 79)]):
        m[r, c] = True
    with pytest.raises(EmptyHullError, match="2 of the 3 views"):
        reconstruct(projections, masks, resolution=10, min_views=2, centerlines=False, tree=False)
