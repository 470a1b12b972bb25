"""The lumen of a vessel tree: signed distance, watertight mesh and label volume against analytic volumes."""

import numpy as np
import pytest
import trimesh

from angiohull.errors import TreeError
from angiohull.synthetic import Tube, TubePhantom
from angiohull.tree import Branch, VesselTree
from angiohull.tree.solid import (_distance_grid, contains, default_step_mm, lumen_labels, signed_distance_mm,
                                  surface_and_labels, surface_mesh)


def _line(start, end, count):
    return np.linspace(np.asarray(start, float), np.asarray(end, float), count)


def _straight(radius=1.5, length=20.0):
    return VesselTree((Branch(_line((0, 0, 0), (length, 0, 0), 41), radius),))


def _arc(radius=1.2, bend=15.0, count=181):
    t = np.linspace(0, np.pi / 2, count)
    return VesselTree((Branch(np.column_stack([bend * np.cos(t), bend * np.sin(t), np.zeros_like(t)]), radius),))


def _y():
    trunk = Branch(_line((0, 0, 0), (30, 0, 0), 61), 2.0)
    side = Branch(_line((15, 0, 0), (15, 20, 4), 41), 1.0, parent=0, parent_point=30)
    return VesselTree((trunk, side))


def _checked(mesh):
    solid = trimesh.Trimesh(mesh.vertices_mm, mesh.faces, process=True)
    assert solid.is_watertight and solid.is_winding_consistent
    assert solid.volume == pytest.approx(mesh.volume_mm3, rel=1e-9)
    return solid


def test_straight_tube_mesh_is_watertight_with_the_capsule_volume():
    radius, length = 1.5, 20.0
    exact = np.pi * radius**2 * length + 4.0 / 3.0 * np.pi * radius**3
    mesh = surface_mesh(_straight(radius, length))
    solid = _checked(mesh)
    assert mesh.volume_mm3 == pytest.approx(exact, rel=0.02)
    assert solid.volume > 0  # outward normals
    assert mesh.area_mm2 == pytest.approx(2 * np.pi * radius * length + 4 * np.pi * radius**2, rel=0.03)


def test_bent_tube_mesh_has_the_volume_of_pappus():
    # a ball of radius r swept along a quarter circle of radius R > r: pi r^2 (R pi / 2) + 4/3 pi r^3
    radius, bend = 1.2, 15.0
    exact = np.pi * radius**2 * bend * np.pi / 2 + 4.0 / 3.0 * np.pi * radius**3
    mesh = surface_mesh(_arc(radius, bend))
    _checked(mesh)
    assert mesh.volume_mm3 == pytest.approx(exact, rel=0.03)


def test_y_mesh_and_labels_have_the_volume_of_the_union():
    tree = _y()
    # the union's volume by Monte Carlo with the synthetic phantom's own inside test (an independent oracle)
    phantom = TubePhantom(tuple(Tube(b.points_mm, b.radius_mm) for b in tree.branches), "y")
    low, high = tree.bounding_box_mm()
    samples = np.random.default_rng(7).uniform(low, high, (1_000_000, 3))
    union = float(np.prod(high - low) * phantom.contains(samples).mean())
    mesh, lumen = surface_and_labels(tree)
    _checked(mesh)
    assert mesh.volume_mm3 == pytest.approx(union, rel=0.03)
    assert lumen.volume_mm3 == pytest.approx(union, rel=0.03)
    assert set(np.unique(lumen.labels)) == {0, 1, 2}
    # a voxel at the side branch's far end is labelled 2, one at the trunk's far end 1
    for point, label in (((15, 19, 3.8), 2), ((29, 0, 0), 1)):
        index = np.round((np.array(point) - lumen.origin_mm) / lumen.spacing_mm).astype(int)
        assert lumen.labels[tuple(index)] == label
        np.testing.assert_allclose(lumen.affine_lps @ np.r_[index, 1.0], np.r_[lumen.origin_mm + lumen.spacing_mm * index, 1])
    # the same labels as lumen_labels alone
    np.testing.assert_array_equal(lumen.labels, lumen_labels(tree).labels)


def test_signed_distance_against_every_capsule():
    tree = _y()
    a, b, radius, _ = tree.capsules()
    points = np.random.default_rng(3).uniform([-5, -5, -5], [35, 25, 9], (3000, 3))
    ab = b - a
    t = np.clip(np.einsum("pkj,kj->pk", points[:, None, :] - a[None], ab) / np.einsum("kj,kj->k", ab, ab), 0, 1)
    nearest = a[None] + t[..., None] * ab[None]
    brute = (np.linalg.norm(points[:, None, :] - nearest, axis=2) - radius[None]).min(axis=1)
    np.testing.assert_allclose(signed_distance_mm(tree, points), brute, atol=1e-12)
    np.testing.assert_array_equal(contains(tree, points), brute <= 0)


def test_grid_step_follows_the_smallest_radius_and_refuses_huge_grids():
    assert default_step_mm(_straight(radius=0.4)) == pytest.approx(0.2)
    assert default_step_mm(_straight(radius=2.0)) == pytest.approx(0.3)
    with pytest.raises(TreeError, match="give a larger step_mm"):
        surface_mesh(_straight(radius=1.0, length=200.0), step_mm=0.01)
    with pytest.raises(TreeError, match="step_mm must be a positive"):
        surface_mesh(_straight(), step_mm=-1.0)


def test_the_blocked_grid_gives_the_whole_grids_mesh_and_labels():
    # a tree longer than several blocks of 64 cells at this step: vertices on shared block planes merged
    tree = VesselTree((Branch(_line((0, 0, 0), (60, 10, 5), 121), 1.2),
                       Branch(_line((30, 5, 2.5), (35, 30, -10), 61), 0.8, parent=0, parent_point=60)))
    step = 0.25
    mesh, lumen = surface_and_labels(tree, step_mm=step)
    distance, origin, owner = _distance_grid(tree, step)
    owner[distance > 0] = 0
    np.testing.assert_array_equal(lumen.labels, owner)
    from skimage.measure import marching_cubes

    vertices, faces, _, _ = marching_cubes(distance, 0.0, mask=distance < np.float32(2 * step * 0.999),
                                           allow_degenerate=False)
    assert len(mesh.faces) == len(faces) and len(mesh.vertices_mm) == len(vertices)
    np.testing.assert_allclose(np.sort(mesh.vertices_mm, axis=0), np.sort(origin + step * vertices, axis=0), atol=1e-5)
    _checked(mesh)


def test_capsules_computed_together_give_the_single_capsule_numbers():
    # the grid fills a block from groups of capsules at once; bit for bit the capsule-by-capsule
    # reference (Grid.capsule, merged in capsule order: of equal distances the first capsule owns)
    from angiohull.tree.solid import _Grid

    tree = VesselTree((Branch(_line((0, 0, 0), (12, 3, 1), 25), np.linspace(1.4, 0.6, 25)),
                       Branch(_line((6, 1.5, 0.5), (7, 9, -3), 17), 0.7, parent=0, parent_point=12),
                       Branch(np.array([[12.3, 3.2, 1.0], [13.0, 3.5, 1.0], [14.0, 3.0, 1.5]]), 0.5, parent=0,
                              parent_point=24)))  # leaves its parent point through a connecting capsule
    grid = _Grid.of(tree, 0.2)
    start, stop = np.array([5, 3, 0]), np.minimum(np.array([70, 60, 50]), grid.shape)
    distance = np.full(tuple(stop - start), np.float32(grid.band), dtype=np.float32)
    owner = np.zeros(tuple(stop - start), dtype=np.uint16)
    for i in range(len(grid.a)):
        first, last = np.maximum(grid.lo[i], start), np.minimum(grid.hi[i] + 1, stop)
        if np.any(last <= first):
            continue
        d = grid.capsule(i, first, last)
        window = tuple(slice(f - s, l - s) for f, l, s in zip(first, last, start))
        closer = d < distance[window]
        np.copyto(distance[window], d, where=closer)
        np.copyto(owner[window], np.uint16(grid.branch[i] + 1), where=closer)
    assert np.count_nonzero(distance <= 0) > 1000 and len(np.unique(owner)) == 4
    got_distance, got_owner = grid.fill(start, stop, range(len(grid.a)))
    np.testing.assert_array_equal(got_distance, distance)
    np.testing.assert_array_equal(got_owner, owner)
