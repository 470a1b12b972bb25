"""Re-rooting a vessel tree (:func:`angiohull.tree.skeleton.rerooted`) on hand-built trees."""

from __future__ import annotations

import numpy as np
import pytest

from angiohull.tree import Branch, VesselTree
from angiohull.tree.skeleton import rerooted


def _y_tree() -> VesselTree:
    """A: (0,0,0) -> (20,0,0), radius 2 -> 1; B leaves A's point at x = 10 along +y for 10 mm."""
    x = np.arange(0.0, 20.0 + 1e-9, 0.5)
    a = Branch(np.column_stack([x, 0 * x, 0 * x]), 2.0 - x / 20.0, name="A")
    y = np.arange(0.0, 10.0 + 1e-9, 0.5)
    b = Branch(np.column_stack([10.0 + 0 * y, y, 0 * y]), 0.8, parent=0, parent_point=20, name="B")
    return VesselTree((a, b))


def _points(tree: VesselTree) -> set[tuple[float, float, float]]:
    return {tuple(np.round(p, 9)) for b in tree.branches for p in b.points_mm}


def test_rooted_at_a_leaf_end_reverses_the_path_to_it():
    tree = _y_tree()
    new = rerooted(tree, 1, tree.branches[1].n_points - 1)
    root = new.root
    np.testing.assert_allclose(root.points_mm[0], [10.0, 10.0, 0.0])
    # down B to the junction, then on to the wider side (x = 0, radius 2), the other side a child there
    np.testing.assert_allclose(root.points_mm[-1], [0.0, 0.0, 0.0])
    assert root.length_mm == pytest.approx(20.0)
    assert new.n_branches == 2
    child = new.branches[1]
    assert child.parent == 0 and np.allclose(root.points_mm[child.parent_point], [10.0, 0.0, 0.0])
    np.testing.assert_allclose(child.points_mm[-1], [20.0, 0.0, 0.0])
    # the same points (the junction point once) and radii, the same total length
    assert _points(new) == _points(tree)
    assert new.length_mm == pytest.approx(tree.length_mm)
    radius: dict = {}  # where a child's first point is its parent's point, the parent's radius stays
    for b in tree.branches:
        for p, r in zip(b.points_mm, b.radius_mm):
            radius.setdefault(tuple(np.round(p, 9)), r)
    for b in new.branches:
        for p, r in zip(b.points_mm, b.radius_mm):
            assert r == pytest.approx(radius[tuple(np.round(p, 9))])


def test_rooted_inside_a_branch_carries_on_to_the_wider_side():
    tree = _y_tree()
    new = rerooted(tree, 0, 10)  # x = 5
    root = new.root
    np.testing.assert_allclose(root.points_mm[0], [5.0, 0.0, 0.0])
    np.testing.assert_allclose(root.points_mm[-1], [0.0, 0.0, 0.0])  # the wider side
    assert new.n_branches == 3
    other = [b for b in new.branches[1:] if b.parent == 0]
    assert len(other) == 1 and other[0].parent_point == 0
    np.testing.assert_allclose(other[0].points_mm[-1], [20.0, 0.0, 0.0])
    assert new.length_mm == pytest.approx(tree.length_mm)
    assert _points(new) == _points(tree)


def test_rooted_where_it_is_already_rooted_keeps_the_tree():
    tree = _y_tree()
    new = rerooted(tree, 0, 0)
    assert new.n_branches == 2
    for a, b in zip(new.branches, tree.branches):
        np.testing.assert_allclose(a.points_mm, b.points_mm)
        assert a.parent == b.parent and a.parent_point == b.parent_point


def _trunk_with_side(radius: np.ndarray) -> VesselTree:
    """A 40 mm trunk along x (points every 0.5 mm, ``radius`` per point) with a thin side branch
    leaving at 20 mm."""
    points = np.column_stack([np.arange(81) * 0.5, np.zeros(81), np.zeros(81)])
    side = np.column_stack([np.full(21, 20.0), np.arange(21) * 0.5, np.zeros(21)])
    return VesselTree((Branch(points, radius, name="trunk"), Branch(side, 0.8, parent=0, parent_point=40, name="side")))


def test_a_root_whose_first_millimetres_narrow_to_an_end_cap_stays_at_the_ostium():
    # the root's first 3 mm narrow from 2.0 to 1.2 mm (the end cap's fitted radii), the trunk is
    # 2.0 mm wide, 2.4 mm over 9-15 mm (more than 5 mm before the side branch) and tapers to 1.0 mm
    # past the side branch: 2.4 is 1.3 times the cap's 1.5 mm mean, but not 1.3 times the vessel's
    # 2.0 mm, so the root stays where it starts
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    arc = np.arange(81) * 0.5
    radius = np.where(arc < 3.0, 1.2 + 0.8 * arc / 3.0, np.where(arc <= 20.0, 2.0, 2.0 - (arc - 20.0) / 20.0))
    radius = np.where((arc >= 9.0) & (arc <= 15.0), 2.4, radius)
    arrays = _Arrays.of(_trunk_with_side(radius))
    out, moved = _rooted_at_ostium(arrays, TREE_SETTINGS)
    assert moved == 0.0
    np.testing.assert_array_equal(out.points, arrays.points)
    # a root that is thin over its first 6 mm (1.2 mm: no end cap, a thin vessel) still goes to
    # the wide point inside
    radius = np.where(arc < 6.5, 1.2, radius)
    out, moved = _rooted_at_ostium(_Arrays.of(_trunk_with_side(radius)), TREE_SETTINGS)
    assert 9.0 < moved < 15.5


def _trunk_with_side_at(radius: np.ndarray, at: int) -> VesselTree:
    points = np.column_stack([np.arange(81) * 0.5, np.zeros(81), np.zeros(81)])
    side = np.column_stack([np.full(21, at * 0.5), np.arange(21) * 0.5, np.zeros(21)])
    return VesselTree((Branch(points, radius, name="trunk"), Branch(side, 0.8, parent=0, parent_point=at, name="side")))


def test_a_tip_as_wide_as_the_roots_start_does_not_take_the_root():
    # a trunk 2.0 mm wide all along: its far end is as wide as its start (a stub held at one
    # radius), and the root stays where it starts; wider there, it moves there
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    radius = np.full(81, 2.0)
    assert _rooted_at_ostium(_Arrays.of(_trunk_with_side_at(radius, 40)), TREE_SETTINGS)[1] == 0.0
    radius[-12:] = 2.05
    assert _rooted_at_ostium(_Arrays.of(_trunk_with_side_at(radius, 40)), TREE_SETTINGS)[1] == pytest.approx(40.0)


def test_a_roots_start_next_to_a_junction_is_measured_past_its_end_cap():
    # a side branch 4 mm from the root's start: no point of its first 6 mm is clear of the
    # junction, so the start's radius is the mean one window (3 mm) in, past the end cap (1.2 to
    # 2.0 mm over the first 3 mm; 1.87 mm there), not the cap's own (1.5 mm); a 2.35 mm stretch at
    # 12-18 mm is then not 1.3 times wider, and the root stays
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    arc = np.arange(81) * 0.5
    radius = np.where(arc < 3.0, 1.2 + 0.8 * arc / 3.0, np.where(arc <= 20.0, 2.0, 2.0 - (arc - 20.0) / 20.0))
    radius = np.where((arc >= 12.0) & (arc <= 18.0), 2.35, radius)
    assert _rooted_at_ostium(_Arrays.of(_trunk_with_side_at(radius, 8)), TREE_SETTINGS)[1] == 0.0


def _split_with_phantom_stub() -> tuple[VesselTree, np.ndarray]:
    """A left main seen only near its ostium, rooted at a phantom stub past its split.

    The root runs 9.5 mm along a stub that no view sees (x from -9.5 to 0), then 10.5 mm back up
    the left main to its ostium at x = 10.5; the two daughters leave at x = 0. No view sees the
    stub nor the left main's first 7 mm from the split (the radius there, 2.16 mm, is interpolated
    from the nearest seen point); the views see its last 3.5 mm, the end cap included (2.16 to
    1.15 mm), and both daughters. Returns the tree and the held points (flat, in branch order)."""
    x = np.arange(41) * 0.5 - 9.5
    radius = np.full(41, 2.16)
    radius[-4:] = [1.88, 1.61, 1.15, 1.15]
    root = Branch(np.column_stack([x, np.zeros(41), np.zeros(41)]), radius, name="root")
    t = np.arange(121) * 0.5
    lad = Branch(np.column_stack([-t * 0.8, t * 0.6, np.zeros(121)]), 1.9 - t / 100.0, parent=0, parent_point=19)
    lcx = Branch(np.column_stack([-t * 0.8, -t * 0.6, np.zeros(121)]), 1.4 - t / 100.0, parent=0, parent_point=19)
    held = np.zeros(41 + 2 * 121, dtype=bool)
    held[:34] = True
    return VesselTree((root, lad, lcx)), held


def test_a_phantom_stub_that_no_view_sees_gives_the_root_to_the_seen_ostium():
    # the stub and the ostium end are equally wide by their radii (2.16 mm, one interpolated from
    # the other): told what the views see, the seen end takes the root; told nothing, it stays
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    tree, held = _split_with_phantom_stub()
    assert _rooted_at_ostium(_Arrays.of(tree), TREE_SETTINGS)[1] == 0.0
    out, moved = _rooted_at_ostium(_Arrays.of(tree), TREE_SETTINGS, held)
    assert moved == pytest.approx(20.0)
    np.testing.assert_allclose(out.points[0], [10.5, 0.0, 0.0])


def test_an_unseen_roots_start_keeps_the_root_against_thin_seen_tips():
    # a foreshortened ostium: no view sees the root's first 6 mm (radius 2.3 mm interpolated from
    # the first seen point), the trunk is 2.3 mm wide up to the side branch and the seen tips are
    # thin; the root stays where it starts
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    arc = np.arange(81) * 0.5
    radius = np.where(arc <= 20.0, 2.3, 2.3 - 1.4 * (arc - 20.0) / 20.0)
    held = np.zeros(81 + 21, dtype=bool)
    held[:13] = True
    assert _rooted_at_ostium(_Arrays.of(_trunk_with_side_at(radius, 40)), TREE_SETTINGS, held)[1] == 0.0


def test_a_stub_by_a_junction_that_no_view_sees_does_not_take_the_root():
    # a 2 mm stub at 20 mm whose radii (3 mm) no view measured: it is no longer than the reach of
    # its junction's swelling (ostium_junction_mm), and its radius counts for nothing; seen, it
    # would take the root
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    points = np.column_stack([np.arange(81) * 0.5, np.zeros(81), np.zeros(81)])
    stub = np.column_stack([np.full(5, 20.0), np.arange(5) * 0.5, np.zeros(5)])
    tree = VesselTree((Branch(points, 2.0, name="trunk"), Branch(stub, 3.0, parent=0, parent_point=40, name="stub")))
    held = np.zeros(86, dtype=bool)
    assert _rooted_at_ostium(_Arrays.of(tree), TREE_SETTINGS, held)[1] > 5.0
    held[81:] = True
    assert _rooted_at_ostium(_Arrays.of(tree), TREE_SETTINGS, held)[1] == 0.0


def test_a_wide_branch_that_runs_on_into_a_narrower_child_ends_at_the_ostium():
    # the skeleton's root starts at a thin distal end (x = 40, radius 1.0 mm) and runs up a trunk
    # 2.0 mm wide to x = 0, where the stub to the ostium went as a spur: only a conus branch
    # (0.9 mm) runs on from the trunk's last point. That end is where the wide vessel ends: the
    # root moves there (40 mm), not to the widest point inside (which lies 5 mm or more from it)
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    x = 40.0 - np.arange(81) * 0.5
    trunk = Branch(np.column_stack([x, np.zeros(81), np.zeros(81)]), np.where(x > 20.0, 2.0 - (x - 20.0) / 20.0, 2.0),
                   name="trunk")
    t = np.arange(41) * 0.5
    side = Branch(np.column_stack([np.full(41, 30.0), -t, np.zeros(41)]), 0.8, parent=0, parent_point=20)
    conus = Branch(np.column_stack([-t * 0.6, t * 0.8, np.zeros(41)]), 0.9, parent=0, parent_point=80)
    tree = VesselTree((trunk, side, conus))
    out, moved = _rooted_at_ostium(_Arrays.of(tree), TREE_SETTINGS)
    assert moved == pytest.approx(40.0)
    np.testing.assert_allclose(out.points[0], [0.0, 0.0, 0.0], atol=1e-9)
    # a child as wide as the trunk runs on (1.9 mm): the trunk's end is no tip, the vessel goes on
    # to the child's end, which takes the root
    wide = VesselTree((trunk, side, Branch(conus.points_mm, 1.9, parent=0, parent_point=80)))
    out, moved = _rooted_at_ostium(_Arrays.of(wide), TREE_SETTINGS)
    np.testing.assert_allclose(out.points[0], conus.points_mm[-1], atol=1e-9)


def test_a_roots_start_whose_end_cap_reaches_past_its_first_junction_keeps_the_root():
    # the root's first 6 mm ramp from 0.8 mm (the hull's excess past the end cap) to the vessel's
    # 2.4 mm, and a side branch leaves 8.5 mm in: the stretch clear of that junction holds only
    # the ramp (its widest 3 mm mean 1.6 mm), but up to the junction the start is as wide as any
    # point inside (2.4 mm), and the root stays where it starts
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _rooted_at_ostium

    arc = np.arange(121) * 0.5
    radius = np.where(arc < 6.0, 0.8 + 1.6 * arc / 6.0, np.where(arc <= 30.0, 2.4, 2.4 - 1.2 * (arc - 30.0) / 30.0))
    points = np.column_stack([arc, np.zeros(121), np.zeros(121)])
    side = np.column_stack([np.full(41, 8.5), np.arange(41) * 0.5, np.zeros(41)])
    tree = VesselTree((Branch(points, radius, name="trunk"), Branch(side, 0.8, parent=0, parent_point=17)))
    assert _rooted_at_ostium(_Arrays.of(tree), TREE_SETTINGS)[1] == 0.0


def _fork(first_radius: float, first_turn_deg: float, second_radius: float) -> VesselTree:
    """A 10 mm trunk along x (radius 1.5) that goes on into ``first`` (``first_radius``, turning
    ``first_turn_deg`` in the x-y plane), with ``second`` (``second_radius``) straight on along x
    as its child at the trunk's end; 10 mm each, points every 0.5 mm."""
    s = np.arange(21) * 0.5
    turn = np.radians(first_turn_deg)
    trunk_and_first = np.vstack([np.column_stack([s - 10.0, 0 * s, 0 * s]),
                                 np.column_stack([s[1:] * np.cos(turn), s[1:] * np.sin(turn), 0 * s[1:]])])
    radius = np.concatenate([np.full(21, 1.5), np.full(20, first_radius)])
    second = np.column_stack([s, 0 * s, 0 * s])
    return VesselTree((Branch(trunk_and_first, radius, name="b0"),
                       Branch(second, second_radius, parent=0, parent_point=20, name="b1")))


@pytest.mark.parametrize("first_radius, turn, second_radius, switched", [
    (0.8, 90.0, 1.4, True),  # the tree went into a thin side branch at 90 degrees; the wide vessel runs straight on
    (1.5, 40.0, 0.9, False),  # straight on is better by the score (1 + 0.3 against 0.77 + 0.5), but narrower
])
def test_traced_again_without_narrower_a_continuation_changes_only_to_a_vessel_at_least_as_wide(
        first_radius, turn, second_radius, switched):
    tree = _fork(first_radius, turn, second_radius)
    straight = np.column_stack([np.arange(41) * 0.5 - 10.0, np.zeros(41), np.zeros(41)])
    # the plain rule (the skeleton's) takes the better score either way: straight on
    plain = rerooted(tree, 0, 0, window_mm=3.0)
    np.testing.assert_allclose(plain.root.points_mm, straight)
    kept = rerooted(tree, 0, 0, window_mm=3.0, narrower=False)
    if switched:
        np.testing.assert_allclose(kept.root.points_mm, straight)
    else:
        np.testing.assert_allclose(kept.root.points_mm, tree.root.points_mm)
    assert _points(kept) == _points(tree) and kept.length_mm == pytest.approx(tree.length_mm)


def test_traced_again_without_narrower_from_a_root_at_a_junction_the_root_keeps_its_way():
    # the root starts where a side branch leaves (its head cut): no way in to continue, so where the
    # tree went decides, not the widths (the plain rule takes the wider one)
    s = np.arange(21) * 0.5
    root = Branch(np.column_stack([s, 0 * s, 0 * s]), 1.0, name="b0")
    side = Branch(np.column_stack([0 * s, s, 0 * s]), 1.6, parent=0, parent_point=0, name="b1")
    tree = VesselTree((root, side))
    np.testing.assert_allclose(rerooted(tree, 0, 0, window_mm=3.0).root.points_mm, side.points_mm)
    np.testing.assert_allclose(rerooted(tree, 0, 0, window_mm=3.0, narrower=False).root.points_mm, root.points_mm)
