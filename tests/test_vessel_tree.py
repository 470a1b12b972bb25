"""The VesselTree type: validation, topology, resampling, arc length, tangents, JSON."""

import re

import numpy as np
import pytest

from angiohull.errors import TreeError
from angiohull.tree import Branch, VesselTree


def _line(start, end, count):
    return np.linspace(np.asarray(start, float), np.asarray(end, float), count)


def _y_tree():
    """A 20 mm trunk along x (11 points), a side branch up from its point 5, another down from point 5."""
    trunk = Branch(_line((0, 0, 0), (20, 0, 0), 11), np.linspace(2.0, 1.5, 11), name="trunk")
    up = Branch(_line((10, 0, 0), (10, 8, 0), 5), 1.0, parent=0, parent_point=5, name="up")
    down = Branch(_line((10, 0, 0), (10, -6, 0), 4), 0.8, parent=0, parent_point=5, name="down")
    return VesselTree((trunk, up, down))


@pytest.mark.parametrize("points, radius, message", [
    (np.zeros((1, 3)), 1.0, "M >= 2"),
    (np.zeros((3, 2)), 1.0, "M >= 2"),
    ([[0, 0, 0], [1, np.nan, 0]], 1.0, "points_mm[1] is not finite"),
    ([[0, 0, 0], [0, 0, 0], [1, 0, 0]], 1.0, "points 0 and 1 are equal"),
    ([[0, 0, 0], [1, 0, 0]], [1.0, 0.0], "radius_mm[1] = 0.0"),
    ([[0, 0, 0], [1, 0, 0]], [1.0, -2.0], "radius_mm[1] = -2.0"),
    ([[0, 0, 0], [1, 0, 0]], [1.0, np.inf], "radius_mm[1] = inf"),
    ([[0, 0, 0], [1, 0, 0]], [1.0, 1.0, 1.0], "one radius per point"),
])
def test_a_branch_that_fails_validation_says_what_is_wrong(points, radius, message):
    with pytest.raises(TreeError, match=re.escape(message)):
        Branch(points, radius, name="x")


def test_parent_and_parent_point_go_together():
    with pytest.raises(TreeError, match="give both parent and parent_point"):
        Branch(_line((0, 0, 0), (1, 0, 0), 2), 1.0, parent=0)
    with pytest.raises(TreeError, match="parent must be an index"):
        Branch(_line((0, 0, 0), (1, 0, 0), 2), 1.0, parent=-1, parent_point=0)


def test_a_branch_under_another_parent_keeps_its_checked_arrays_and_fields():
    branch = Branch([[0, 0, 0], [1, 0, 0], [2, 1, 0]], [1.0, 0.9, 0.8], parent=3, parent_point=1, name="b")
    moved = branch._with_parent(np.int64(2))
    assert (moved.parent, moved.parent_point, moved.name) == (2, 1, "b") and type(moved.parent) is int
    assert moved.points_mm is branch.points_mm and moved.radius_mm is branch.radius_mm
    assert not moved.points_mm.flags.writeable and not moved.radius_mm.flags.writeable
    rebuilt = Branch(branch.points_mm, branch.radius_mm, 2, 1, "b")  # what the checks would give
    np.testing.assert_array_equal(moved.points_mm, rebuilt.points_mm)
    np.testing.assert_array_equal(moved.radius_mm, rebuilt.radius_mm)
    assert moved.points_mm.dtype == rebuilt.points_mm.dtype and moved.radius_mm.dtype == rebuilt.radius_mm.dtype


def test_a_tree_has_one_root_listed_first_and_parents_before_children():
    root = Branch(_line((0, 0, 0), (10, 0, 0), 11), 1.0)
    child = Branch(_line((5, 0, 0), (5, 5, 0), 6), 0.5, parent=0, parent_point=5)
    with pytest.raises(TreeError, match="at least one branch"):
        VesselTree(())
    with pytest.raises(TreeError, match="branches\\[0\\] must be the root"):
        VesselTree((child, root))
    with pytest.raises(TreeError, match="exactly one root"):
        VesselTree((root, root))
    with pytest.raises(TreeError, match="not listed before it"):
        VesselTree((root, Branch(child.points_mm, 0.5, parent=1, parent_point=0)))
    with pytest.raises(TreeError, match="the parent has 11 points"):
        VesselTree((root, Branch(child.points_mm, 0.5, parent=0, parent_point=11)))
    with pytest.raises(TreeError, match="single Branch"):
        VesselTree(root)


def test_reordered_puts_parents_first_and_rejects_cycles_and_two_roots():
    root = Branch(_line((0, 0, 0), (10, 0, 0), 11), 1.0, name="root")
    a = Branch(_line((5, 0, 0), (5, 5, 0), 6), 0.5, parent=2, parent_point=0, name="a")  # leaves b
    b = Branch(_line((2, 0, 0), (2, -5, 0), 6), 0.5, parent=1, parent_point=2, name="b")  # leaves the root
    tree = VesselTree.reordered([a, root, b])
    assert [x.name for x in tree.branches] == ["root", "b", "a"]
    assert [x.parent for x in tree.branches] == [None, 0, 1]
    cyclic_a = Branch(a.points_mm, 0.5, parent=1, parent_point=0)
    cyclic_b = Branch(b.points_mm, 0.5, parent=0, parent_point=0)
    with pytest.raises(TreeError, match="cycle"):
        VesselTree.reordered([root, cyclic_b, Branch(a.points_mm, 0.5, parent=3, parent_point=0),
                              Branch(a.points_mm, 0.5, parent=2, parent_point=0)])
    with pytest.raises(TreeError, match="exactly one root"):
        VesselTree.reordered([root, root, cyclic_a])


def test_bifurcations_are_derived_from_the_topology():
    tree = _y_tree()
    (bifurcation,) = tree.bifurcations
    assert (bifurcation.parent, bifurcation.parent_point, bifurcation.children) == (0, 5, (1, 2))
    np.testing.assert_array_equal(tree.bifurcation_points_mm, [[10.0, 0.0, 0.0]])
    assert tree.children(0) == (1, 2) and tree.children(1) == ()
    assert VesselTree((tree.root,)).bifurcation_points_mm.shape == (0, 3)


def test_arc_length_length_and_tangents_of_a_helix():
    # helix x = R cos t, y = R sin t, z = c t: arc length sqrt(R^2 + c^2) t, tangent (-R sin, R cos, c) / norm
    radius, pitch = 10.0, 2.0
    t = np.linspace(0, 2 * np.pi, 2001)
    points = np.column_stack([radius * np.cos(t), radius * np.sin(t), pitch * t])
    branch = Branch(points, 1.0)
    speed = np.hypot(radius, pitch)
    np.testing.assert_allclose(branch.arc_length_mm[-1], speed * 2 * np.pi, rtol=1e-5)
    assert branch.length_mm == pytest.approx(branch.arc_length_mm[-1])
    expected = np.column_stack([-radius * np.sin(t), radius * np.cos(t), np.full_like(t, pitch)]) / speed
    np.testing.assert_allclose(branch.tangents()[1:-1], expected[1:-1], atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(branch.tangents(), axis=1), 1.0)


def test_resampling_keeps_the_ends_spaces_evenly_and_moves_parent_points_along():
    tree = _y_tree()
    fine = tree.resampled(0.3)
    trunk = fine.branches[0]
    steps = np.linalg.norm(np.diff(trunk.points_mm, axis=0), axis=1)
    assert steps.max() <= 0.3 + 1e-12 and np.ptp(steps) < 1e-9
    np.testing.assert_allclose(trunk.points_mm[[0, -1]], tree.root.points_mm[[0, -1]])
    # radii interpolated linearly along the arc (the trunk tapers linearly from 2.0 to 1.5)
    np.testing.assert_allclose(trunk.radius_mm, 2.0 - 0.5 * trunk.points_mm[:, 0] / 20.0)
    # the side branches still leave at x = 10 (the trunk's resampled point nearest in arc length)
    for child in fine.branches[1:]:
        np.testing.assert_allclose(trunk.points_mm[child.parent_point], [10.0, 0.0, 0.0], atol=0.15)
    assert fine.length_mm == pytest.approx(tree.length_mm)
    with pytest.raises(TreeError, match="step_mm must be a positive"):
        tree.resampled(0.0)
    with pytest.raises(TreeError, match=r"a step of 1e-09 mm cuts a branch of .* into 2.*pieces, more than "
                                        r"10,000,000; use a larger step_mm"):
        tree.resampled(1e-9)  # (numpy's MemoryError before, asking for tens of GiB)


def test_capsules_join_a_child_that_starts_off_its_parent_point():
    root = Branch(_line((0, 0, 0), (10, 0, 0), 3), 1.0)
    detached = Branch(_line((5, 2, 0), (5, 6, 0), 2), 0.5, parent=0, parent_point=1)
    starts, ends, radius, owner = VesselTree((root, detached)).capsules()
    assert len(starts) == 2 + 1 + 1  # two root segments, the connector, the child's segment
    np.testing.assert_allclose(starts[2], [5, 0, 0])
    np.testing.assert_allclose(ends[2], [5, 2, 0])
    assert owner.tolist() == [0, 0, 1, 1] and radius[2] == 0.5


def test_json_round_trip_and_bad_documents():
    tree = _y_tree()
    back = VesselTree.from_dict(tree.to_dict())
    for a, b in zip(tree.branches, back.branches):
        np.testing.assert_array_equal(a.points_mm, b.points_mm)
        np.testing.assert_array_equal(a.radius_mm, b.radius_mm)
        assert (a.parent, a.parent_point, a.name) == (b.parent, b.parent_point, b.name)
    document = tree.to_dict()
    assert document["bifurcations"][0]["children"] == [1, 2]
    assert document["branches"][1]["length_mm"] == pytest.approx(8.0)
    with pytest.raises(TreeError, match="not an angiohull vessel tree"):
        VesselTree.from_dict({"branches": []}, "x.json")
    document["branches"][1]["radius_mm"] = [1.0, 1.0, -1.0, 1.0, 1.0]
    with pytest.raises(TreeError, match="x.json: branches\\[1\\]: .*radius_mm\\[2\\] = -1.0"):
        VesselTree.from_dict(document, "x.json")


def test_attached_to_nearest_infers_parents_from_the_first_points():
    main = _line((0, 0, 0), (20, 0, 0), 21)
    side = _line((7, 0, 0), (7, 5, 0), 6)
    twig = _line((7, 3, 0), (9, 3, 0), 3)
    tree = VesselTree.attached_to_nearest([main, side, twig], [1.0, 0.5, 0.3])
    assert [(b.parent, b.parent_point) for b in tree.branches] == [(None, None), (0, 7), (1, 3)]


def test_transformed_moves_points_and_keeps_radii():
    tree = _y_tree()
    mirror = np.diag([-1.0, -1.0, 1.0, 1.0])
    moved = tree.transformed(mirror)
    np.testing.assert_allclose(moved.root.points_mm[:, 0], -tree.root.points_mm[:, 0])
    np.testing.assert_array_equal(moved.root.radius_mm, tree.root.radius_mm)
    with pytest.raises(TreeError, match="4x4"):
        tree.transformed(np.eye(3))


# -- the fit's last smoothing: a quadratic fit along each branch -------------------------------------
def test_the_quadratic_smoothing_keeps_a_bend_whose_gaussian_cuts_it_and_smooths_noise_as_its_formula_says():
    from scipy import ndimage as ndi

    from angiohull.reconstruction.vessel_tree import quadratic_smoothed

    step, radius = 0.5, 5.0
    s = np.arange(0.0, 20.0 + step / 2, step)  # 20 mm of a helix of radius 5 mm, a point every 0.5 mm
    arc = np.column_stack([radius * np.cos(s / radius), radius * np.sin(s / radius), 0.3 * s])
    inner = slice(7, -7)  # points the 15-point window reaches past neither end

    def length(p):
        return np.linalg.norm(np.diff(p[inner], axis=0), axis=1).sum()

    true = length(arc)
    gaussian = ndi.gaussian_filter1d(arc, 1.0, axis=0, mode="nearest")  # sigma 0.5 mm, the fit's before
    # a Gaussian of sigma draws a circle of radius R in by exp(-sigma^2 / (2 R^2)) (the helix's axis part)
    in_plane = np.exp(-0.5**2 / (2 * radius**2))
    expected = np.linalg.norm(np.diff(np.column_stack([in_plane * arc[:, :2], arc[:, 2]])[inner], axis=0), axis=1).sum()
    assert length(gaussian) == pytest.approx(expected, rel=5e-4) and length(gaussian) < 0.996 * true  # -0.46 %
    quadratic = length(quadratic_smoothed(arc, 15))  # -0.10 % (its bias goes with (window / R)^4)
    assert quadratic == pytest.approx(true, rel=1.5e-3) and true - quadratic < 0.25 * (true - length(gaussian))
    parabola = np.column_stack([s, 0.2 * s**2 - s, np.full_like(s, 3.0)])
    np.testing.assert_allclose(quadratic_smoothed(parabola, 15), parabola, atol=1e-9)  # a parabola is kept, ends too
    # white noise of sd 1 on a line: the centred 15-point parabola leaves it a variance of
    # 3 (3 m^2 + 3 m - 1) / ((2 m + 3)(2 m + 1)(2 m - 1)), m = 7 (Savitzky-Golay's centre weights)
    rng = np.random.default_rng(3)
    noisy = rng.normal(size=(20000, 1))
    m = 7
    factor = 3 * (3 * m * m + 3 * m - 1) / ((2 * m + 3) * (2 * m + 1) * (2 * m - 1))
    assert np.var(quadratic_smoothed(noisy, 15)[m:-m]) == pytest.approx(factor, rel=0.05)


def test_the_quadratic_smoothing_is_each_windows_least_squares_parabola_ends_included():
    """Against a slow reference: for each point, numpy's polyfit of a parabola through the window
    centred on it (within half a window of an end, the first or last window), evaluated there."""
    from angiohull.reconstruction.vessel_tree import quadratic_smoothed

    rng = np.random.default_rng(11)
    for n, window in ((5, 5), (9, 3), (40, 15), (41, 21), (12, 11)):
        points = rng.normal(size=(n, 3)).cumsum(axis=0)
        half = window // 2
        expected = np.empty_like(points)
        for i in range(n):
            first = min(max(i - half, 0), n - window)
            x = np.arange(first, first + window, dtype=float)
            for k in range(3):
                expected[i, k] = np.polyval(np.polyfit(x - i, points[first:first + window, k], 2), 0.0)
        np.testing.assert_allclose(quadratic_smoothed(points, window), expected, atol=1e-10)
    assert quadratic_smoothed(np.arange(7.0), 7).shape == (7,)  # any trailing shape, a plain series too
    for window in (4, 1, 9):  # even, too short, longer than the 7 points
        with pytest.raises(ValueError, match="window"):
            quadratic_smoothed(np.zeros((7, 3)), window)
