"""The fast engines keep exactly the points the reference ``kdtree`` keeps."""

import csv

import numpy as np
import pytest

from angiohull.geometry import CArmGeometry, Projection, cube_half_edge_mm
from angiohull.reconstruction import ENGINES, Lattice, reconstruct
from angiohull.reconstruction.engines import MaskLookup, carve_dense_lookup, carve_kdtree
from angiohull.reconstruction.hierarchical import carve_hierarchical
from angiohull.study import load_study
from angiohull.synthetic import demo_phantom, demo_views
from _cases import random_case


def carve(name, projections, masks, k, threshold):
    lattice = Lattice(cube_half_edge_mm(projections), k)
    return ENGINES[name](lattice, projections, masks, threshold_px=threshold).points_mm


def _fast_engines_equal_kdtree_on_peer_studies(peer_synthetic_dir, every: int):
    with open(peer_synthetic_dir / "peer_results.csv", newline="") as handle:
        cases = [row["case"] for row in csv.DictReader(handle)]
    assert len(cases) == 48
    for case in cases[::every]:
        study = load_study(peer_synthetic_dir / case)
        reference = carve("kdtree", study.projections, study.masks, 100, 1.0)
        for engine in ("lookup", "octree"):
            got = carve(engine, study.projections, study.masks, 100, 1.0)
            np.testing.assert_array_equal(got, reference, err_msg=f"{case} {engine}")


def test_fast_engines_equal_kdtree_on_a_sixth_of_the_peer_studies(peer_synthetic_dir, kernel_backend):
    """Every sixth study (both view sets, every tortuosity); all 48 behind the slow marker."""
    _fast_engines_equal_kdtree_on_peer_studies(peer_synthetic_dir, 6)


@pytest.mark.slow
def test_fast_engines_equal_kdtree_on_every_peer_study(peer_synthetic_dir):
    _fast_engines_equal_kdtree_on_peer_studies(peer_synthetic_dir, 1)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("threshold", [0.5, 1.0, 1.5, 2.3, 4.5])
def test_fast_engines_equal_kdtree_on_random_cases(seed, threshold, kernel_backend):
    projections, masks = random_case(seed, n_views=2 + seed % 3)
    reference = carve("kdtree", projections, masks, 48, threshold)
    assert len(reference) > 0 or threshold < 1  # sub-pixel thresholds may carve everything away
    for engine in ("lookup", "octree"):
        np.testing.assert_array_equal(carve(engine, projections, masks, 48, threshold), reference, err_msg=engine)


def test_fast_engines_with_the_source_inside_the_cube(kernel_backend):
    k = np.array([[40.0, 0, 31.5], [0, 40.0, 31.5], [0, 0, 1]])
    rotation = CArmGeometry(20, 10, 1200, 800, (1, 1), (64, 64)).projection().matrix[:, :3] / 1.0
    q, _ = np.linalg.qr(rotation)
    p = Projection(k @ np.concatenate([q, q @ -np.array([[1.0], [-2.0], [0.5]])], axis=1), (64, 64))
    mask = np.zeros((64, 64), bool)
    mask[10:50, 20:30] = True
    lattice = Lattice(10.0, 33)
    reference = carve_kdtree(lattice, [p], [mask], threshold_px=1.0).points_mm
    assert 0 < len(reference) < lattice.n_points
    for engine in ("lookup", "octree"):
        np.testing.assert_array_equal(ENGINES[engine](lattice, [p], [mask], threshold_px=1.0).points_mm, reference)


def test_octree_equals_the_dense_lookup_at_k200(peer_synthetic_dir):
    for case in ("perpendicular_tortuous_004", "clinical_simple_007"):
        study = load_study(peer_synthetic_dir / case)
        lattice = Lattice(cube_half_edge_mm(study.projections), 200)
        dense = carve_dense_lookup(lattice, study.projections, study.masks, threshold_px=1.0).points_mm
        octree = ENGINES["octree"](lattice, study.projections, study.masks, threshold_px=1.0).points_mm
        assert len(dense) > 10000
        np.testing.assert_array_equal(octree, dense, err_msg=case)


def test_octree_equals_the_dense_lookup_at_k200_on_the_demo_phantom():
    phantom = demo_phantom()
    projections = [carm.projection() for _, carm in demo_views()]
    masks = [phantom.silhouette(p) for p in projections]
    lattice = Lattice(cube_half_edge_mm(projections), 200)
    dense = carve_dense_lookup(lattice, projections, masks, threshold_px=1.0).points_mm
    for root, leaf in ((128, 4), (32, 2), (8, 8)):
        got = carve_hierarchical(lattice, projections, masks, threshold_px=1.0, root_size=root, leaf_size=leaf).points_mm
        np.testing.assert_array_equal(got, dense, err_msg=f"root {root} leaf {leaf}")


def test_mask_lookup_matches_brute_force_distances():
    rng = np.random.default_rng(5)
    mask = rng.random((30, 40)) < 0.05
    rows, cols = np.nonzero(mask)
    uv = rng.uniform(-3, 43, (4000, 2))
    uv[:200] = np.round(uv[:200])  # exactly on pixel centres
    uv[200:400, 0] = np.round(uv[200:400, 0]) + 0.5  # exactly between two centres
    d = np.sqrt((uv[:, None, 0] - cols) ** 2 + (uv[:, None, 1] - rows) ** 2).min(1)
    for t in (0.3, 0.5, 1.0, 1.5, 2.0, 2.5, 3.7, 6.0, 8.49):  # from 2.5 on: the distance-transform band first
        np.testing.assert_array_equal(MaskLookup(mask, t).near(uv), d < t, err_msg=str(t))


def test_auto_engine_runs_the_fastest_exact_engine_and_says_so():
    projections, masks = random_case(11)
    result = reconstruct(projections, masks, resolution=40, centerlines=False, tree=False, warn=False)
    assert result.engine == "octree"
    reference = reconstruct(projections, masks, resolution=40, centerlines=False, tree=False, engine="kdtree",
                            warn=False)
    np.testing.assert_array_equal(result.vessel_points_mm, reference.vessel_points_mm)
    assert sorted(result.view_order) == [0, 1, 2]


@pytest.mark.slow
def test_octree_equals_the_dense_lookup_at_k512(peer_synthetic_dir):
    study = load_study(peer_synthetic_dir / "clinical_tortuous_002")
    lattice = Lattice(cube_half_edge_mm(study.projections), 512)
    dense = carve_dense_lookup(lattice, study.projections, study.masks, threshold_px=1.0).points_mm
    octree = ENGINES["octree"](lattice, study.projections, study.masks, threshold_px=1.0).points_mm
    np.testing.assert_array_equal(octree, dense)
