"""The tree method (reconstruction.model): 2D centerline graphs, epipolar correspondences, tubes.

Tiny named cases with analytic truth, two clinical views (RAO 30 CAU 25, LAO 45 CRA 20) of exact
silhouettes. The bars are what the method reaches today (measured 2026-12-02, docs/tree-method.md),
short of the issue's targets where the docs say so; where the visual hull fails (vessels that cross
in one view) the test holds the method to beating the refined hull by a wide margin.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage as ndi

from angiohull.errors import AgreementWarning, InputWarning, ReconstructionError
from angiohull.geometry import CArmGeometry, parse_clinical_angles
from angiohull.metrics.tree import distance_to_centerline, tree_scores
from angiohull.reconstruction import Lattice, reconstruct, view_order_agreement
from angiohull.reconstruction import model
from angiohull.reconstruction.checks import VIEW_ORDER_MARGIN, input_warnings, view_order_warning
from angiohull.reconstruction.model import (MODEL_SETTINGS, centerline_graph, lattice_points_in_tubes, mask_agreement,
                                             Suspect, suspect_pieces, tube_silhouette)
from angiohull.reconstruction.model.matching import triangulate_midpoint
from angiohull.synthetic import Tube, TubePhantom
from angiohull.tree import Branch, VesselTree

TWO = ("RAO 30 CAU 25", "LAO 45 CRA 20")


def _views(angles=TWO):
    return [CArmGeometry(*parse_clinical_angles(v), 1200.0, 800.0, (0.35, 0.35), (512, 512)).projection()
            for v in angles]


def _line(a, b, step=0.5):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.linspace(a, b, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)


def _masks(truth, projections):
    phantom = TubePhantom(tuple(Tube(b.points_mm, b.radius_mm) for b in truth.branches), "truth")
    return [phantom.silhouette(p) for p in projections]


# -- 2D graphs, triangulation, tubes --------------------------------------------------------------
def _disk_line(shape, a, b, radius):
    rows, cols = np.mgrid[:shape[0], :shape[1]]
    p = np.stack([cols, rows], axis=-1).astype(float)
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = np.clip(((p - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
    return np.linalg.norm(p - a - t[..., None] * (b - a), axis=-1) <= radius


def test_the_2d_graph_of_a_y_has_three_chains_meeting_at_one_junction_with_their_half_widths():
    mask = (_disk_line((120, 160), (10, 60), (80, 60), 4.0) | _disk_line((120, 160), (80, 60), (150, 15), 3.0)
            | _disk_line((120, 160), (80, 60), (150, 105), 3.0))
    graph = centerline_graph(mask)
    long = [c for e, c in enumerate(graph.chains) if graph.chain_length_px(e) > 20]
    assert len(long) == 3
    tips = np.flatnonzero(graph.degree == 1)
    assert len(tips) == 3  # the thinning's spurs at the ends are gone
    # half-widths: 4 px on the trunk, 3 px on the daughters (pixel-centre masks: within 0.6 px)
    for chain in long:
        inner = chain[len(chain) // 4: 3 * len(chain) // 4]
        expected = 4.0 if graph.uv_px[inner, 0].mean() < 80 else 3.0
        assert abs(np.median(graph.half_width_px[inner]) - expected) <= 0.6


def test_a_short_side_branch_off_a_wide_vessel_is_a_chain_and_a_shorter_stub_a_spur():
    # a trunk 12 px wide (its half-width at the junction 5.82 px: the distance transform less half
    # a pixel) and a side branch 3 px wide: an end chain is a spur below 1.5 half-widths plus 2 px,
    # 10.7 px here; a side branch 13 px long stays (under two half-widths plus 2 px, 13.6, the bound
    # before 2026-12-05, it went), one 9 px long goes
    shape = (80, 160)
    trunk = _disk_line(shape, (10, 40), (150, 40), 6.0)
    for length, kept in ((13, True), (9, False)):
        graph = centerline_graph(trunk | _disk_line(shape, (80, 40), (80, 40 - length), 1.5))
        junction = int(np.argmin(np.abs(graph.uv_px - [80, 40]).sum(axis=1)))
        bound = 1.5 * graph.half_width_px[junction] + 2.0
        assert abs(graph.half_width_px[junction] - 5.82) < 0.01
        side = [e for e, c in enumerate(graph.chains) if graph.uv_px[c, 1].min() < 34]
        assert bool(side) == kept
        if kept:
            assert bound < graph.chain_length_px(side[0]) < 2.0 * graph.half_width_px[junction] + 2.0


def test_a_diagonal_staircase_is_one_chain_not_a_string_of_junctions():
    mask = _disk_line((100, 100), (10, 15), (90, 70), 2.0)
    graph = centerline_graph(mask)
    assert len(graph.chains) == 1
    assert np.count_nonzero(graph.degree >= 3) == 0


def test_the_mask_core_keeps_the_middle_half_of_a_bar_and_all_of_a_thin_one():
    from angiohull.reconstruction.model import _view_data

    # a bar 9 px wide (rows 10-18) and a line 1 px wide (row 40): the bar's middle row is 5 px from
    # the background, its half-width 4.5 px; a row k px off the middle is 4.5 - k deep, so the core
    # at 0.5 keeps k <= 2.25 (rows 12-16); the line is all within a pixel of its skeleton
    mask = np.zeros((60, 120), dtype=bool)
    mask[10:19, 20:100] = True
    mask[40, 20:100] = True
    projection = _views()[0]
    whole = _view_data(projection, mask, 0.0).image
    core = _view_data(projection, mask, 0.5).image
    np.testing.assert_array_equal(whole, mask.astype(np.float32))
    assert not core[~mask].any()  # only mask pixels
    middle = slice(40, 80)  # away from the bar's ends
    assert np.flatnonzero(core[:35, middle].all(axis=1)).tolist() == [12, 13, 14, 15, 16]
    assert not core[:35, middle][[10, 11, 17, 18]].any()
    assert core[40, 20:100].all()
    # fraction 0.9: 4.5 - k >= 4.05 keeps k = 0 only, and the skeleton's neighbours within a pixel
    assert np.flatnonzero(_view_data(projection, mask, 0.9).image[:35, middle].all(axis=1)).tolist() == [13, 14, 15]


def test_the_mask_core_matches_a_disc_by_disc_reference_on_a_tree_s_masks():
    from scipy import ndimage as ndi

    from angiohull.reconstruction.model import _view_data

    projection = _views()[1]
    mask = _masks(_y(), [projection])[0] | _masks(_crossing(), [projection])[0]
    view = _view_data(projection, mask, 0.5)
    # reference: every skeleton pixel's disc drawn on the whole image, widest last
    uv = view.graph.uv_px.astype(int)
    radius = view.inside_px[uv[:, 1], uv[:, 0]]
    radius = np.where(radius < 8.0, np.floor(2.0 * radius) / 2.0, np.floor(radius))
    covering = np.zeros(mask.shape)
    for k in np.argsort(radius, kind="stable"):
        r = int(radius[k]) + 1
        r0, c0 = max(uv[k, 1] - r, 0), max(uv[k, 0] - r, 0)
        rows, cols = np.mgrid[r0:uv[k, 1] + r + 1, c0:uv[k, 0] + r + 1]
        window = covering[r0:uv[k, 1] + r + 1, c0:uv[k, 0] + r + 1]
        window[np.hypot(cols - uv[k, 0], rows - uv[k, 1])[:window.shape[0], :window.shape[1]] <= radius[k]] = radius[k]
    half = np.where(covering > 0, covering - 0.5, view.graph.half_width_px[np.maximum(view.nearest_skeleton, 0)])
    expected = mask & ((view.inside_px - 0.5 >= 0.5 * half) | (view.skeleton_px <= 1.0))
    assert len(np.unique(radius)) > 4 and expected.sum() > 1000
    np.testing.assert_array_equal(view.image.astype(bool), expected)


def test_the_mask_core_takes_the_widest_disc_not_a_side_spur_of_the_skeleton():
    from types import SimpleNamespace

    from scipy import ndimage as ndi

    from angiohull.reconstruction.model.matching import mask_core

    # a bar 41 px wide (columns 60-100, its axis column 80, 21 px from the background there) whose
    # skeleton has a spur from the axis at row 40 towards the corner (as a wide vessel's skeleton
    # forks into prongs near its rounded end): the spur's pixels lie near the background, and judged
    # by the nearest skeleton pixel the bar's left flank would count as deep beside it
    mask = np.zeros((200, 160), dtype=bool)
    mask[:, 60:101] = True
    axis = [(80, r) for r in range(40, 200)]
    spur = [(80 - k, 40 - k) for k in range(1, 16)]
    uv = np.array(axis + spur, dtype=float)
    inside = ndi.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    index = np.full(mask.shape, -1)
    index[uv[:, 1].astype(int), uv[:, 0].astype(int)] = np.arange(len(uv))
    skeleton_px, (rr, cc) = ndi.distance_transform_edt(index < 0, return_indices=True)
    graph = SimpleNamespace(n_pixels=len(uv), uv_px=uv, half_width_px=inside[uv[:, 1].astype(int), uv[:, 0].astype(int)] - 0.5)
    core = mask_core(mask, graph, inside, skeleton_px, index[rr, cc], 0.5)
    # the axis's disc (21 px) covers the flank: a column k px off the axis is 20.5 - k deep against
    # 0.5 x 20.5, so the core is columns 70-90 on every row the disc reaches fully, spur or not,
    # and the skeleton's band (within a pixel of it) besides
    band = skeleton_px <= 1.0
    middle = np.zeros_like(mask)
    middle[:, 70:91] = True
    np.testing.assert_array_equal(core[25:170], (middle | band)[25:170])  # the image's bottom edge is background
    half = graph.half_width_px[index[rr, cc]]
    by_nearest = mask & ((inside - 0.5 >= 0.5 * half) | band)
    assert (by_nearest & ~band & ~middle)[25:170].sum() > 50  # what the spur's own half-width would keep


def test_midpoint_triangulation_of_two_rays_through_a_point_gives_the_point():
    point = np.array([[3.0, -2.0, 5.0]])
    ca, cb = np.array([0.0, -800.0, 0.0]), np.array([800.0, 0.0, 100.0])
    da, db = point - ca, point - cb
    da /= np.linalg.norm(da)
    db /= np.linalg.norm(db)
    assert np.allclose(triangulate_midpoint(ca, da, cb, db), point, atol=1e-9)
    # skew rays: x-axis at z = 0 and y-axis at z = 2 -> midpoint (0, 0, 1)
    out = triangulate_midpoint(np.array([0.0, 0, 0]), np.array([[1.0, 0, 0]]), np.array([0.0, 0, 2]),
                               np.array([[0.0, 1, 0]]))
    assert np.allclose(out, [[0, 0, 1]])


def test_lattice_points_in_a_capsule_match_the_distance_formula():
    lattice = Lattice(20.0, 81)  # 0.5 mm
    a, b, r = np.array([[-6.0, -3.0, 1.0]]), np.array([[7.0, 4.0, -2.0]]), 1.7
    got = lattice_points_in_tubes(a, b, np.array([r]), np.array([r]), lattice)
    points = lattice.points()
    ab = b[0] - a[0]
    t = np.clip((points - a[0]) @ ab / (ab @ ab), 0, 1)
    distance = np.linalg.norm(points - a[0] - t[:, None] * ab, axis=1)
    inside = {tuple(p) for p in np.round(points[distance <= r - 0.02], 6)}
    outside = {tuple(p) for p in np.round(points[distance > r], 6)}
    got = {tuple(p) for p in np.round(got, 6)}
    assert inside <= got and not (got & outside)


def test_a_vessel_crossing_the_epipolar_lines_at_a_slant_has_a_candidate_on_its_axis():
    from angiohull.reconstruction.model import _view_data
    from angiohull.reconstruction.model.matching import MATCH_SETTINGS, _candidates

    # a straight vessel about 28 degrees off the second view's epipolar lines: each line runs
    # through it for about twice its width, a run split in two pieces, neither at the axis
    projections = _views()
    truth = VesselTree((Branch(_line((-20, 0, -10), (60, 6, 8)), 1.4, name="straight"),))
    a, b = (_view_data(p, m) for p, m in zip(projections, _masks(truth, projections)))
    cands = _candidates(a, b, [], np.arange(a.graph.n_pixels), MATCH_SETTINGS)
    axis = truth.root.points_mm
    distance, _, _, _ = distance_to_centerline(cands.point, truth)
    best = np.full(a.graph.n_pixels, np.inf)
    np.minimum.at(best, cands.sample, distance)
    # the pixels whose ray meets the axis more than 5 mm from its ends (the ends are capped)
    rays = a.projection.project(axis)
    nearest = np.argmin(np.linalg.norm(a.graph.uv_px[:, None, :] - rays[None, :, :], axis=2), axis=1)
    arc = np.linalg.norm(axis[nearest] - axis[0], axis=1)
    inner = (arc > 5.0) & (arc < np.linalg.norm(axis[-1] - axis[0]) - 5.0)
    assert inner.sum() > 200
    # measured: 0.99 within 0.5 mm, median 0.16 mm; without the runs' middles none, median 1.03 mm
    assert np.mean(best[inner] <= 0.5) >= 0.95


def test_a_view_that_shows_every_vessel_wider_is_measured_and_taken_off_where_the_radii_compare():
    from angiohull.reconstruction.model import _view_data
    from angiohull.reconstruction.model.matching import measured_width_bias, with_width_bias
    from angiohull.synthetic import generate_tree

    # a generated left tree; the second view's mask grown or shrunk by whole pixels (4-connected),
    # as a segmentation that draws one view's edges farther out
    projections = _views()
    masks = [generate_tree("left", "moderate", rng=2).phantom.silhouette(p) for p in projections]
    cross = ndi.generate_binary_structure(2, 1)
    views = [_view_data(p, m) for p, m in zip(projections, masks)]
    grown = [views[0], _view_data(projections[1], ndi.binary_dilation(masks[1], cross, iterations=2))]
    shrunk = [views[0], _view_data(projections[1], ndi.binary_erosion(masks[1], cross))]
    # measured 0.01, 1.73, -0.96 px (the grown edge moves 2 px along the rows and columns, 1.4 px
    # diagonally); matched without the radius term instead: -0.16, 1.73, -1.09, and 1.13 px on
    # exact masks of another tree, whose vessels only the radii pair right
    assert abs(measured_width_bias(views)) <= 0.2
    assert 1.5 <= measured_width_bias(grown) <= 2.0
    assert -1.2 <= measured_width_bias(shrunk) <= -0.7
    # split between the views: the radius of a pair, the views' mean, stays what they show
    (first, second), bias = with_width_bias(grown)
    assert first.width_bias_px == -0.5 * bias and second.width_bias_px == 0.5 * bias
    # less than half a pixel is the pixel grid's own: not taken off
    assert [v.width_bias_px for v in with_width_bias(views)[0]] == [0.0, 0.0]
    assert with_width_bias(grown, replace(model.MATCH_SETTINGS, width_bias=False))[1] == 0.0


def _distance_to_line(points, a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = np.clip((points - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return np.linalg.norm(points - a - t[:, None] * (b - a), axis=1)


def test_pixels_nothing_explains_are_matched_again_anchored_where_the_other_view_shows_the_vessel_wider():
    from scipy.spatial import cKDTree

    from angiohull.reconstruction.epipolar import ray_directions
    from angiohull.reconstruction.model import _view_data
    from angiohull.reconstruction.model.matching import anchored_match, match_pixels

    # a straight vessel (radius 1.2 mm) and one apart (1.0 mm); the second view shows a 9 mm stretch
    # of the first 2.2 times as wide, as where another vessel overlaps it
    projections = _views()
    ends, apart_ends = ((-30, -10, 0), (30, 10, 5)), ((-20, 25, -10), (20, 35, -15))
    vessel, apart = _line(*ends), _line(*apart_ends)
    phantom = TubePhantom((Tube(vessel, np.full(len(vessel), 1.2)), Tube(apart, np.full(len(apart), 1.0))), "two")
    masks = [phantom.silhouette(p) for p in projections]
    uv = projections[1].project(vessel[40:80])
    mm_per_px = projections[1].depth_mm(vessel[60:61])[0] / max(projections[1].focal_lengths_px)
    masks[1] = masks[1] | _disk_line(masks[1].shape, uv[0], uv[-1], 2.2 * 1.2 / mm_per_px)
    a, b = _view_data(projections[0], masks[0]), _view_data(projections[1], masks[1])
    # the first view's pixels: pinned to the true axis, but for the middle of that stretch and the
    # vessel apart, which are free
    truth = np.vstack([vessel, apart])
    on_apart = np.arange(len(truth)) >= len(vessel)
    nearest = cKDTree(projections[0].project(truth)).query(a.graph.uv_px)[1]
    stretch = ~on_apart[nearest] & (nearest >= 45) & (nearest < 75)
    free = stretch | on_apart[nearest]
    assert stretch.sum() >= 30 and on_apart[nearest].sum() >= 100
    anchor = np.where(free[:, None], np.nan, truth[nearest])
    points, radii, _, new = anchored_match(a, b, anchor, np.full(len(nearest), 1.2))

    # the plain matching leaves the stretch unmatched (the two views' radii disagree by 2.2 times)
    _, plain_radii, _ = match_pixels(a, b)
    assert np.isfinite(plain_radii[stretch]).mean() <= 0.1  # measured 0.0
    # anchored: the stretch on the true axis with the first view's radius (measured: all of it new,
    # all within 0.5 mm, radius 1.07 mm: the half-width less half a pixel)
    assert new[stretch].mean() >= 0.9
    assert np.mean(_distance_to_line(points[stretch], *ends) <= 0.5) >= 0.9
    assert abs(np.nanmedian(radii[stretch]) - 1.2) <= 0.15
    # the vessel apart joins no pinned pixel: nothing placed anew
    assert not new[on_apart[nearest]].any() and np.isnan(radii[on_apart[nearest]]).all()
    # a pinned pixel comes back at its anchor moved onto its own ray (the foot of the perpendicular)
    pinned = np.flatnonzero(~free & np.isfinite(radii))
    assert len(pinned) >= 0.9 * (~free).sum()
    rays = ray_directions(projections[0], a.graph.uv_px[pinned])
    assert np.allclose(projections[0].project(points[pinned]), a.graph.uv_px[pinned], atol=1e-6)
    assert np.abs(np.einsum("ij,ij->i", points[pinned] - anchor[pinned], rays)).max() < 1e-6
    assert np.allclose(radii[pinned], 1.2)


def _y_with_second_branch_along_the_second_views_rays(shift_mm=8.0):
    """The Y plus a phantom: its second branch moved 8 mm along the second view's rays (toward the
    source), so that the second view sees the two as one vessel and the first view apart."""
    y, projections = _y(), _views()
    second = y.branches[1].points_mm
    rays = projections[1].camera_centre_mm - second
    phantom = second + shift_mm * rays / np.linalg.norm(rays, axis=1)[:, None]
    tree = VesselTree(y.branches + (Branch(phantom, 1.1, parent=0, parent_point=y.branches[1].parent_point,
                                           name="phantom"),))
    return tree, projections


@pytest.mark.parametrize("only", [False, True])
def test_explaining_points_match_a_pixel_by_pixel_reference(only):
    from angiohull.reconstruction.model import explaining_points

    tree, projections = _y_with_second_branch_along_the_second_views_rays()
    points, radius, owner = tree.points()
    by = owner != 2 if only else None
    rows, cols = np.nonzero(_masks(_y(), projections)[0])
    pixels = np.column_stack([cols, rows]).astype(float)[::7]
    got = explaining_points(tree, projections[0], pixels, by=by)
    uv = projections[0].project(points)
    disc = radius * max(projections[0].focal_lengths_px) / projections[0].depth_mm(points) + 1.0
    for pixel, index in zip(pixels, got):
        distance = np.linalg.norm(uv - pixel, axis=1)
        holds = (distance <= disc) & (True if by is None else by)
        if not holds.any():
            assert index == -1
        else:  # the nearest point that holds it (ties: the same distance)
            assert index >= 0 and holds[index] and distance[index] == pytest.approx(distance[holds].min())
    assert (got >= 0).mean() > 0.9  # the mask's pixels: the Y explains nearly all of them


def test_a_branch_only_one_view_needs_is_redundant_and_the_vessel_it_mirrors_too():
    from angiohull.reconstruction.model import redundant_branches

    tree, projections = _y_with_second_branch_along_the_second_views_rays()
    reach = MODEL_SETTINGS.explained_reach_radii
    # the second view shows the phantom on the second branch: each covers the other there, and in
    # the first view neither is covered; the trunk is needed in both
    first, second = redundant_branches(tree, projections, [(0, 1), (1, 0)], 0.9, 0.9, reach)
    assert first.tolist() == [1, 2]
    assert second.tolist() == []


# -- pruning the branches the rest of the tree explains --------------------------------------------
def _with_phantoms(tail_mm: float = 0.0):
    """The Y plus a phantom chain hanging off the trunk: a branch along the trunk's last 20 mm, 0.3 mm
    off its axis, and its child along the second branch, 0.3 mm off (with ``tail_mm`` more beyond
    the second branch's end, along its direction)."""
    y = _y()
    trunk, second = y.branches[0].points_mm, y.branches[1].points_mm
    start = len(_line((-30, 0, 0), (0, 0, 0))) - 41  # 20 mm before the junction
    along = trunk[start:start + 41] + np.array([0.0, 0.3, 0.0])
    child = second[8:] + np.array([0.0, 0.0, 0.3])
    if tail_mm:
        direction = (second[-1] - second[0]) / np.linalg.norm(second[-1] - second[0])
        child = np.vstack([child, _line(child[-1], child[-1] + tail_mm * direction)[1:]])
    phantom = Branch(along, 1.3, parent=0, parent_point=start, name="phantom")
    return VesselTree(y.branches + (phantom, Branch(child, 1.0, parent=2, parent_point=len(along) - 1,
                                                    name="phantom child")))


def _explained_by_brute_force(tree, projection, reach_radii):
    """explained_shares for one view, point by point (the reference)."""
    points, radius, owner = tree.points()
    uv = projection.project(points)
    rho = radius * max(projection.focal_lengths_px) / projection.depth_mm(points) + 0.5
    out = []
    for b in range(tree.n_branches):
        members, todo = set(), [b]
        while todo:
            x = todo.pop()
            members.add(x)
            todo += list(tree.children(x))
        mine = np.isin(owner, list(members))
        covered = [np.any(np.linalg.norm(uv[~mine] - uv[k], axis=1) <= rho[~mine] + reach_radii * rho[k])
                   for k in np.flatnonzero(mine)]
        out.append(np.mean(covered))
    return np.array(out)


@pytest.mark.parametrize("reach_radii", [0.0, 0.5, 1.0])
def test_explained_shares_match_a_point_by_point_reference(reach_radii):
    from angiohull.reconstruction.model import explained_shares

    tree, projections = _with_phantoms(tail_mm=12.0), _views()
    shares = explained_shares(tree, projections, reach_radii)
    for v, projection in enumerate(projections):
        np.testing.assert_allclose(shares[:, v], _explained_by_brute_force(tree, projection, reach_radii), atol=1e-12)


@pytest.mark.parametrize("reach_radii", [0.0, 0.5])
def test_covered_shares_of_any_point_groups_match_a_point_by_point_reference(reach_radii):
    # groups that are not whole branches (the rules' are): every point's own set of groups counts
    from angiohull.reconstruction.model.pruning import _covered_shares

    tree, projections = _with_phantoms(tail_mm=12.0), _views()
    points, radius, _ = tree.points()
    rng = np.random.default_rng(5)
    groups = [rng.random(len(points)) < share for share in (0.1, 0.3, 0.5, 0.8)] + [np.zeros(len(points), bool)]
    by = rng.random(len(points)) < 0.7
    shares = _covered_shares(tree, projections, reach_radii, groups, by=by)
    for v, projection in enumerate(projections):
        uv = projection.project(points)
        rho = radius * max(projection.focal_lengths_px) / projection.depth_mm(points) + 0.5
        for g, mine in enumerate(groups):
            others = ~mine & by
            covered = [np.any(np.linalg.norm(uv[others] - uv[k], axis=1) <= rho[others] + reach_radii * rho[k])
                       for k in np.flatnonzero(mine)]
            assert shares[g, v] == (np.mean(covered) if covered else 0.0)
    assert _covered_shares(tree, projections, reach_radii, []).shape == (0, len(projections))


def test_disc_pairs_searched_once_serve_the_tree_left_when_branches_go():
    from angiohull.reconstruction.model import _DiscPairs, _without, explained_shares

    tree, projections = _with_phantoms(tail_mm=12.0), _views()
    for gone in ([3], [2, 3], [1]):  # (the phantom chain from its leaf; the second branch)
        pairs = _DiscPairs(tree, projections, 0.5)
        smaller = tree
        for b in sorted(gone, reverse=True):
            smaller = _without(smaller, b)
            pairs.without(b)
        np.testing.assert_array_equal(explained_shares(smaller, projections, 0.5, pairs=pairs.current()),
                                      explained_shares(smaller, projections, 0.5))


def test_a_phantom_branch_goes_with_the_phantom_it_carries_and_the_true_tree_stays():
    from angiohull.reconstruction.model import explained_shares, prune_explained_branches

    tree, projections = _with_phantoms(), _views()
    shares = explained_shares(tree, projections, 0.5).min(axis=1)
    assert shares[2] > 0.9 and shares[3] > 0.9  # the phantom's subtree and its child: covered in both views
    pruned, removed = prune_explained_branches(tree, projections, 0.9, 0.5)
    assert removed == 2 and [b.name for b in pruned.branches] == ["trunk", "second"]
    np.testing.assert_array_equal(pruned.branches[1].points_mm, tree.branches[1].points_mm)


def test_a_subtree_with_pixels_nothing_else_explains_stays_whole():
    from angiohull.reconstruction.model import explained_shares, prune_explained_branches

    # the phantom child runs 12 mm past the second branch's end: in both views its last points are
    # its own, so the phantom's subtree stays whole; the second branch, which it covers, goes
    tree, projections = _with_phantoms(tail_mm=12.0), _views()
    shares = explained_shares(tree, projections, 0.5).min(axis=1)
    assert shares[1] == 1.0 and shares[2:].max() < 0.9
    pruned, removed = prune_explained_branches(tree, projections, 0.9, 0.5)
    assert removed == 1 and [b.name for b in pruned.branches] == ["trunk", "phantom", "phantom child"]
    # every point of the branch that went lies in the projected tube of one that stayed, in both views
    everything = VesselTree(pruned.branches + (Branch(tree.branches[1].points_mm, tree.branches[1].radius_mm,
                                                      parent=0, parent_point=tree.branches[1].parent_point),))
    assert explained_shares(everything, projections, 0.5)[3].min() == 1.0


def test_a_branch_pruned_for_a_phantom_that_went_later_comes_back_and_the_phantom_stays_out():
    from angiohull.reconstruction.model import explained_shares, restore_uncovered_branches

    # the explained rule takes the second branch for the phantom chain that covers it (the test
    # above); say the next rule then takes the phantom chain: nothing kept covers the second branch
    # any more, so it comes back, and then covers the phantom's subtree as much as the kept tree
    # did when it went (the unreproduced rule's 30 %), so the phantom stays out
    tree, projections = _with_phantoms(tail_mm=12.0), _views()
    second_alone = explained_shares(_y(), projections, 0.5)[1].min()  # what the trunk covers of it
    phantom_cover = explained_shares(tree, projections, 0.5)[2].min()  # what trunk and second cover of the chain
    assert second_alone < 0.9 and 0.3 <= phantom_cover < 0.9
    explained, unreproduced = np.nextafter(0.9, 1.0), 0.3
    alive, restored = restore_uncovered_branches(tree, [True, False, False, False],
                                                 [0.0, explained, unreproduced, unreproduced], projections, 0.5)
    assert restored == 1 and alive.tolist() == [True, True, False, False]
    # had the explained rule taken the chain too (over 90 % then), the kept tree's cover of it now
    # is below that: it comes back as well, and its child with it (the child's own subtree: the
    # tail nothing else shows)
    alive, restored = restore_uncovered_branches(tree, [True, False, False, False],
                                                 [0.0, explained, explained, explained], projections, 0.5)
    assert restored == 3 and alive.all()
    # the chain without the tail: trunk and second cover it whole, and it stays out
    tree = _with_phantoms()
    assert explained_shares(tree, projections, 0.5)[2].min() > 0.9
    alive, restored = restore_uncovered_branches(tree, [True, True, False, False],
                                                 [0.0, explained, explained, explained], projections, 0.5)
    assert restored == 0 and alive.tolist() == [True, True, False, False]


# -- pruning the branches the views' own matchings do not reproduce --------------------------------
def _own_matchings(tree, projections, lying=()):
    """Per view, a skeleton made of the projected points of ``tree``'s branches, each skeleton pixel
    matched (its "own matching") to the 3D point that projects there, except the branches in
    ``lying``, whose pixels are matched 10 mm off; every seventh pixel is left unmatched. Returns
    (own points per view, nearest-skeleton maps)."""
    from scipy import ndimage as ndi

    own, nearest = [], []
    for projection in projections:
        rows, cols = projection.image_shape
        index = np.full((rows, cols), -1, dtype=np.int64)
        points = []
        for b, branch in enumerate(tree.branches):
            uv = np.rint(projection.project(branch.points_mm)).astype(np.int64)
            for (u, v), x in zip(uv, branch.points_mm):
                if index[v, u] < 0:
                    index[v, u] = len(points)
                    points.append(x + (np.array([0.0, 0.0, 10.0]) if b in lying else 0.0))
        matched = np.array(points)
        matched[::7] = np.nan
        _, (r, c) = ndi.distance_transform_edt(index < 0, return_indices=True)
        own.append(matched)
        nearest.append(index[r, c])
    return own, nearest


def _reproduced_by_brute_force(tree, projections, own, nearest, tolerance_mm):
    points, _, _ = tree.points()
    out = []
    for x in points:
        ok = True
        for projection, matched, near in zip(projections, own, nearest):
            u, v = (int(round(float(c))) for c in projection.project(x[None])[0])
            if not (0 <= v < near.shape[0] and 0 <= u < near.shape[1]) or near[v, u] < 0:
                continue
            gap = float(np.linalg.norm(matched[near[v, u]] - x))
            ok = ok and not gap > tolerance_mm  # an unmatched pixel (nan) is no evidence
        out.append(ok)
    return np.array(out)


def _with_mirror_phantom():
    """The Y plus the phantom two views cannot rule out: the points that project onto the second
    branch in the first view and onto the first branch (the trunk's straight continuation past the
    junction) in the second: the first view's rays through the second branch cut by the plane of
    the second view's camera centre and the first branch. Its stretch 30-95 % of the way along the
    first branch's image, 10-30 mm from the true vessels, runs on for 12 mm (a tail that no other
    branch covers) and hangs off the trunk."""
    y, projections = _y(), _views()
    first, second = y.branches[0].points_mm[60:], y.branches[1].points_mm
    c0, c1 = projections[0].camera_centre_mm, projections[1].camera_centre_mm
    normal = np.cross(first[-1] - first[0], c1 - first[0])
    rays = second - c0
    t = ((first[0] - c0) @ normal) / (rays @ normal)
    phantom = c0 + t[:, None] * rays
    uv = projections[1].project(phantom)
    ends = projections[1].project(first[[0, -1]])
    along = (uv - ends[0]) @ (ends[1] - ends[0]) / np.sum((ends[1] - ends[0]) ** 2)
    phantom = phantom[(along > 0.3) & (along < 0.95)]
    direction = (phantom[-1] - phantom[-2]) / np.linalg.norm(phantom[-1] - phantom[-2])
    phantom = np.vstack([phantom, _line(phantom[-1], phantom[-1] + 12.0 * direction)[1:]])
    attach = int(np.argmin(np.linalg.norm(y.branches[0].points_mm - phantom[0], axis=1)))
    return VesselTree(y.branches + (Branch(phantom, 1.0, parent=0, parent_point=attach, name="phantom"),)), projections


def test_reproduced_points_match_a_point_by_point_reference():
    from angiohull.reconstruction.model import reproduced_points

    tree, projections = _with_mirror_phantom()
    own, nearest = _own_matchings(_y(), projections)
    for tolerance in (0.5, 2.0, 5.0):
        np.testing.assert_array_equal(reproduced_points(tree, projections, own, nearest, tolerance),
                                      _reproduced_by_brute_force(tree, projections, own, nearest, tolerance))


def test_a_mirror_phantom_the_matchings_do_not_reproduce_goes_and_the_true_tree_stays():
    from angiohull.reconstruction.model import (explained_shares, prune_explained_branches,
                                                prune_unreproduced_branches, reproduced_points)

    tree, projections = _with_mirror_phantom()
    own, nearest = _own_matchings(_y(), projections)  # the views' own matchings found the true Y
    reproduced = reproduced_points(tree, projections, own, nearest, 2.0)
    owner = tree.points()[2]
    assert reproduced[owner < 2].all() and reproduced[owner == 2].mean() < 0.1
    # the rest covers it (the first view's second branch, the second view's first branch) but for
    # its tail: not enough for the explained rule, which keeps it
    assert 0.3 <= explained_shares(tree, projections, 0.5)[2].min() < 0.9
    assert prune_explained_branches(tree, projections, 0.9, 0.5)[1] == 0
    pruned, removed = prune_unreproduced_branches(tree, projections, own, nearest, tolerance_mm=2.0, share=0.3,
                                                  explained=0.3, reach_radii=0.5)
    assert removed == 1 and [b.name for b in pruned.branches] == ["trunk", "second"]
    np.testing.assert_array_equal(pruned.branches[1].points_mm, tree.branches[1].points_mm)


def test_a_branch_nothing_else_explains_stays_whatever_the_matchings_say():
    from angiohull.reconstruction.model import explained_shares, prune_unreproduced_branches, reproduced_points

    tree, projections = _y(), _views()
    own, nearest = _own_matchings(tree, projections, lying=(1,))  # the matchings put the second branch 10 mm off
    owner = tree.points()[2]
    assert reproduced_points(tree, projections, own, nearest, 2.0)[owner == 1].mean() < 0.1  # its junction pixel is the trunk's
    assert explained_shares(tree, projections, 0.5)[1].min() < 0.3
    pruned, removed = prune_unreproduced_branches(tree, projections, own, nearest, tolerance_mm=2.0, share=0.3,
                                                  explained=0.3, reach_radii=0.5)
    assert removed == 0 and pruned.n_branches == 2


def _covered_by_brute_force(tree, projections, reach_radii, apart_mm, by):
    points, radius, _ = tree.points()
    out = np.ones(len(points), dtype=bool)
    for projection in projections:
        uv = projection.project(points)
        rho = radius * max(projection.focal_lengths_px) / projection.depth_mm(points) + 0.5
        for k in range(len(points)):
            others = by & (np.linalg.norm(points - points[k], axis=1) > apart_mm)
            out[k] &= bool(np.any(np.linalg.norm(uv[others] - uv[k], axis=1) <= rho[others] + reach_radii * rho[k]))
    return out


@pytest.mark.parametrize("reach_radii, apart_mm", [(0.0, 5.0), (0.5, 5.0), (0.5, 2.0)])
def test_covered_points_match_a_point_by_point_reference(reach_radii, apart_mm):
    from angiohull.reconstruction.model import covered_points

    tree, projections = _with_mirror_phantom()
    by = np.random.default_rng(3).random(len(tree.points()[0])) < 0.8
    np.testing.assert_array_equal(covered_points(tree, projections, reach_radii, apart_mm, by=by),
                                  _covered_by_brute_force(tree, projections, reach_radii, apart_mm, by))
    np.testing.assert_array_equal(covered_points(tree, projections, reach_radii, apart_mm),
                                  _covered_by_brute_force(tree, projections, reach_radii, apart_mm, np.ones_like(by)))


def _runs_at_least(flags, arc_mm, min_mm):
    """The runs of consecutive True flags at least ``min_mm`` of arc long, point by point (the reference)."""
    out = np.zeros(len(flags), dtype=bool)
    k = 0
    while k < len(flags):
        if flags[k]:
            e = k
            while e + 1 < len(flags) and flags[e + 1]:
                e += 1
            if arc_mm[e] - arc_mm[k] >= min_mm:
                out[k:e + 1] = True
            k = e + 1
        else:
            k += 1
    return out


def test_a_contradicted_stretch_that_true_vessels_cover_is_marked_and_its_uncovered_tail_is_not():
    from angiohull.reconstruction.model import contradicted_stretches, covered_points, reproduced_points

    tree, projections = _with_mirror_phantom()
    own, nearest = _own_matchings(_y(), projections)
    marked = contradicted_stretches(tree, projections, own, nearest, tolerance_mm=2.0, reach_radii=0.5, apart_mm=5.0,
                                    min_length_mm=3.0)
    owner = tree.points()[2]
    reproduced = reproduced_points(tree, projections, own, nearest, 2.0)
    covered = covered_points(tree, projections, 0.5, 5.0)
    assert not marked[owner < 2].any()  # the true Y
    phantom = owner == 2
    # on the phantom: exactly the runs of contradicted points that points 5 mm away cover, 3 mm or longer
    expected = np.zeros(len(owner), dtype=bool)
    expected[phantom] = _runs_at_least((~reproduced & covered)[phantom], tree.branches[2].arc_length_mm, 3.0)
    np.testing.assert_array_equal(marked, expected)
    assert marked[phantom].mean() > 0.5 and not marked[phantom][-15:].any()  # the tail's last 7 mm are nobody's


def test_a_contradicted_stretch_goes_when_the_vessel_that_covers_it_is_contradicted_too():
    from angiohull.reconstruction.model import contradicted_stretches, covered_points, reproduced_points

    # the second branch's pixels matched 10 mm off as well: in the first view the phantom is covered
    # only by points the matchings contradict (confused on both sides), and it still goes; the
    # second branch, contradicted but covered by nothing in the second view, stays
    tree, projections = _with_mirror_phantom()
    own, nearest = _own_matchings(_y(), projections, lying=(1,))
    owner = tree.points()[2]
    phantom = owner == 2
    reproduced = reproduced_points(tree, projections, own, nearest, 2.0)
    arc = tree.branches[2].arc_length_mm
    # counting the cover of reproduced points only (the pixels left unmatched), none of it would go
    by_reproduced = covered_points(tree, projections, 0.5, 5.0, by=reproduced)
    assert reproduced[owner == 1].mean() < 0.05 and reproduced[phantom].mean() < 0.1
    assert not _runs_at_least((~reproduced & by_reproduced)[phantom], arc, 3.0).any()
    marked = contradicted_stretches(tree, projections, own, nearest, tolerance_mm=2.0, reach_radii=0.5, apart_mm=5.0,
                                    min_length_mm=3.0)
    assert not marked[owner < 2].any()
    covered = covered_points(tree, projections, 0.5, 5.0)
    np.testing.assert_array_equal(marked[phantom], _runs_at_least((~reproduced & covered)[phantom], arc, 3.0))
    assert marked[phantom].mean() > 0.5 and not marked[phantom][-15:].any()


def _phantom_carrying_a_vessel(twig=False):
    """The Y with its mirror phantom, and a true vessel (40 mm) leaving the phantom's end: the
    views' mismatch ran on into a vessel both show; with ``twig``, a 10 mm vessel leaves the
    second branch's end too. Returns the tree, the views, and the true vessels (the Y and the
    others) for the own matchings."""
    tree, projections = _with_mirror_phantom()
    end = tree.branches[2].points_mm[-1]
    carried = _line(end, end + np.array([-5.0, 25.0, 30.0]))
    more = [Branch(carried, 1.0, parent=2, parent_point=tree.branches[2].n_points - 1, name="carried")]
    if twig:
        end = tree.branches[1].points_mm[-1]
        more.append(Branch(_line(end, end + np.array([0.0, -6.0, 8.0])), 0.8, parent=1,
                           parent_point=tree.branches[1].n_points - 1, name="twig"))
    full = VesselTree(tree.branches + tuple(more))
    truth = VesselTree(_y().branches + tuple(Branch(b.points_mm, b.radius_mm, parent=0, parent_point=0, name=b.name)
                                             for b in more))
    return full, projections, truth


def _inner_by_brute_force(tree, projections, own, nearest, tolerance_mm, share, explained, reach_radii):
    points, radius, owner = tree.points()
    reproduced = _reproduced_by_brute_force(tree, projections, own, nearest, tolerance_mm)
    parents = {b.parent for b in tree.branches[1:]}
    marked = np.zeros(len(points), dtype=bool)
    for b in range(1, tree.n_branches):
        mine = owner == b
        if b not in parents or not reproduced[mine].mean() < share:
            continue
        shares = []
        for projection in projections:
            uv = projection.project(points)
            rho = radius * max(projection.focal_lengths_px) / projection.depth_mm(points) + 0.5
            others = ~mine & reproduced
            hits = [np.any(np.linalg.norm(uv[others] - uv[k], axis=1) <= rho[others] + reach_radii * rho[k])
                    for k in np.flatnonzero(mine)]
            shares.append(np.mean(hits))
        marked[mine] = min(shares) >= explained
    return marked


@pytest.mark.parametrize("twig, lying, share, explained", [(False, (), 0.3, 0.3), (True, (), 0.3, 0.3),
                                                         (True, (1,), 0.3, 0.3), (True, (1,), 0.5, 0.05),
                                                         (False, (), 0.5, 0.9), (True, (2,), 1.0, 0.0)])
def test_unreproduced_inner_branches_match_a_branch_by_branch_reference(twig, lying, share, explained):
    from angiohull.reconstruction.model import unreproduced_inner_branches

    tree, projections, truth = _phantom_carrying_a_vessel(twig)
    own, nearest = _own_matchings(truth, projections, lying=lying)
    np.testing.assert_array_equal(
        unreproduced_inner_branches(tree, projections, own, nearest, tolerance_mm=2.0, share=share,
                                    explained=explained, reach_radii=0.5),
        _inner_by_brute_force(tree, projections, own, nearest, 2.0, share, explained, 0.5))


def test_a_phantom_that_carries_a_true_vessel_is_taken_out_alone():
    from angiohull.reconstruction.model import (prune_explained_branches, prune_unreproduced_branches,
                                                reproduced_points, unreproduced_inner_branches)

    tree, projections, truth = _phantom_carrying_a_vessel()
    own, nearest = _own_matchings(truth, projections)
    owner = tree.points()[2]
    reproduced = reproduced_points(tree, projections, own, nearest, 2.0)
    assert reproduced[owner == 2].mean() < 0.3 and reproduced[owner != 2].all()
    # with the vessel it carries, the phantom's subtree is reproduced enough, and nothing else shows
    # the carried vessel: both subtree rules keep the two
    assert prune_explained_branches(tree, projections, 0.9, 0.5)[1] == 0
    assert prune_unreproduced_branches(tree, projections, own, nearest, tolerance_mm=2.0, share=0.3, explained=0.3,
                                       reach_radii=0.5)[1] == 0
    marked = unreproduced_inner_branches(tree, projections, own, nearest, tolerance_mm=2.0, share=0.3,
                                         explained=0.3, reach_radii=0.5)
    np.testing.assert_array_equal(marked, owner == 2)  # the phantom, all of it, and nothing else
    # without the vessel it carries the phantom is a leaf: the subtree rule's, not this one's
    leaf, projections = _with_mirror_phantom()
    own, nearest = _own_matchings(_y(), projections)
    assert not unreproduced_inner_branches(leaf, projections, own, nearest, tolerance_mm=2.0, share=0.3,
                                           explained=0.3, reach_radii=0.5).any()


# -- named cases -------------------------------------------------------------------------------
def _helix():
    t = np.linspace(0, 3 * np.pi, 300)
    points = np.column_stack([12 * np.cos(t), 12 * np.sin(t), np.linspace(-25, 25, len(t))])
    return VesselTree((Branch(points, 1.3, name="helix"),))


def _y():
    trunk, first, second = _line((-30, 0, 0), (0, 0, 0)), _line((0, 0, 0), (25, 15, 5)), _line((0, 0, 0), (20, -20, -5))
    main = Branch(np.vstack([trunk, first[1:]]),
                  np.concatenate([np.full(len(trunk), 2.0), np.full(len(first) - 1, 1.4)]), name="trunk")
    return VesselTree((main, Branch(second, 1.1, parent=0, parent_point=len(trunk) - 1, name="second")))


def _crossing():
    """A side branch that leaves the trunk and crosses it in the first view (not in the second)."""
    trunk = _line((-30, -10, 0), (30, 10, 0))
    side = _line(trunk[10], trunk[10] + np.array([35.0, -5.0, 25.0]))
    return VesselTree((Branch(trunk, 1.5, name="trunk"), Branch(side, 1.1, parent=0, parent_point=10, name="side")))


def _foreshortened(projections):
    """A bend whose middle 15 mm run along the first view's central ray."""
    d = projections[0].camera_centre_mm / np.linalg.norm(projections[0].camera_centre_mm)
    a = np.array([-30.0, 0, 0])
    b = a + np.array([20.0, 5, 0])
    c = b + 15 * d
    e = c + np.array([20.0, -5, 5])
    return VesselTree((Branch(np.vstack([_line(a, b), _line(b, c)[1:], _line(c, e)[1:]]), 1.4, name="bent"),))


def _scores(truth, method="tree", preset="paper"):
    projections = _views()
    result = reconstruct(projections, _masks(truth, projections), method=method, preset=preset, centerlines=False)
    assert result.tree is not None
    return result, tree_scores(result.tree, truth).as_dict()


def test_a_helix_from_two_views_comes_back_along_its_axis_with_its_radius():
    # measured Ot(1 mm) 1.00, centerline mean 0.093 mm, radius MAE 0.021 mm, the claim cost 3's tree kept and
    # its arc by LAO 45 CRA 20's fold slid along RAO 30 CAU 25's rays (model.sliding, 2026-12-07); before that
    # slide a known limit (docs/tree-method.md, "Named cases"): Ot(1 mm) 0.89, 0.47 mm (0.62 and 2.54 mm with
    # the one matching of the claim cost 1.5, 0.60-0.66 before earlier steps, 0.80 before the root step's
    # seen-tip rule)
    result, s = _scores(_helix())
    assert result.method == "tree"
    assert s["ot1mm"] >= 0.9 and s["branch_recall"] == 1.0
    assert s["radius_mae_mm"] <= 0.1


def _arc_vessel():
    t = np.linspace(0, np.pi, 200)
    return VesselTree((Branch(np.column_stack([-25 * np.cos(t), 10 * np.sin(t), 25 * np.sin(t) - 10]), 1.3,
                              name="arc"),))


def test_a_run_put_off_its_depth_along_one_views_rays_slides_back_to_where_the_other_view_sees_it():
    from angiohull.reconstruction.model.sliding import slid_along_rays

    projections = _views()
    truth = _arc_vessel()
    masks = _masks(truth, projections)
    # the truth itself explains both masks: nothing moves
    same, moved = slid_along_rays(truth, projections, masks)
    assert moved == 0 and same is truth
    # a stretch of 20 mm put up to 4 mm off along view 0's rays (a smooth bump): view 0 sees the same
    points = truth.root.points_mm
    arc = truth.root.arc_length_mm
    bump = 4.0 * np.clip(1 - np.abs(arc - 40) / 10, 0, None)
    rays = points - projections[0].camera_centre_mm
    off = points + bump[:, None] * rays / np.linalg.norm(rays, axis=1, keepdims=True)
    wrong = VesselTree((Branch(off, 1.3, name="arc"),))
    slid, moved = slid_along_rays(wrong, projections, masks)
    assert moved >= 1
    np.testing.assert_allclose(projections[0].project(slid.root.points_mm), projections[0].project(points),
                               atol=1e-6)  # along view 0's rays only
    before = np.linalg.norm(off - points, axis=1)
    after = np.linalg.norm(slid.root.points_mm - points, axis=1)
    assert before.max() > 3.9 and after.max() < 1.0  # measured 3.92 -> 0.34 mm (mean 0.04 mm), 2026-12-07


def test_a_y_from_two_views_gives_both_branches_and_the_bifurcation_within_a_millimetre():
    _, s = _scores(_y())
    assert s["branch_recall"] == 1.0 and s["ot1mm"] >= 0.95 and s["centerline_mean_mm"] < 0.3
    assert s["bifurcations_matched"] == 1 and s["bifurcation_error_mm"] < 1.5  # measured 0.57 mm (0.48 on this machine and 0.67 on another before ties were broken in voxel units, 0.45 before a child's junction moved to where its tube matches the masks, 0.84 before the fit's line rule and one-sided edges, 0.19 before the mask core, 1.06 before slanted runs' middles and the partner's skeleton cost)


def test_vessels_that_cross_in_one_view_keep_their_course_where_the_hull_fails():
    _, tree = _scores(_crossing())
    _, hull = _scores(_crossing(), method="hull", preset="refined")
    assert tree["ot1mm"] >= 0.7 and tree["ot1mm"] > hull["ot1mm"]  # measured 1.00 against 0.57 (0.94 before the unexplained pixels were matched again and before the fit's line rule and one-sided edges, 0.78 before the mask core)
    assert tree["centerline_mean_mm"] < 0.2 * hull["centerline_mean_mm"]  # measured 0.11 mm against 5.76 mm (0.20 before the unexplained pixels were matched again, 0.28 against 5.59 before the fit's line rule and one-sided edges, 0.79 before the mask core)


def test_a_segment_foreshortened_in_one_view_is_rebuilt_from_the_other():
    _, s = _scores(_foreshortened(_views()))
    _, hull = _scores(_foreshortened(_views()), method="hull", preset="refined")
    # measured 0.058 mm, the tree of the claim cost 3 kept (target 0.5 mm; 0.126 before two views built a tree per claim cost, 0.18 before the fit's later steps, 0.22 before the fit's line rule and one-sided edges, 0.36 before the mask core, 0.58 before the partner's skeleton cost) against the refined hull's 0.74 mm (0.54 before)
    assert s["centerline_mean_mm"] <= 0.65 and s["branch_recall"] == 1.0 and s["radius_mae_mm"] <= 0.1
    assert s["ot1mm_reverse"] > hull["ot1mm_reverse"]


def test_a_vessel_that_leaves_the_image_is_rebuilt_as_far_as_both_views_see_it():
    projections = _views()
    truth = VesselTree((Branch(_line((-20, 0, -10), (110, 10, 20)), 1.4, name="long"),))
    masks = _masks(truth, projections)
    with pytest.warns(InputWarning, match=r"vessel runs off the image's edge in view0 in 1 place.*view1 in 1 place"), \
            pytest.warns(AgreementWarning, match=r"vessel runs off the image's edge in view0 \(12 pixels\), view1"):
        result = reconstruct(projections, masks, method="tree", centerlines=False)
    # the part of the true axis inside both images, more than 3 mm from where it leaves
    axis = truth.root.points_mm
    seen = np.ones(len(axis), dtype=bool)
    for p in projections:
        uv = p.project(axis)
        seen &= np.all((uv >= 3 / 0.2) & (uv <= 511 - 3 / 0.2), axis=1)
    distance, _, _, _ = distance_to_centerline(axis[seen], result.tree)
    # measured 1.00 (0.97 before the fit's line rule and one-sided edges, 0.99 before the mask core, 0.12 before slanted runs' middles were candidates and off-skeleton partners cost)
    assert seen.sum() > 50 and np.mean(distance < 1.0) >= 0.9


@pytest.mark.parametrize("start, end, leaves", [((10, -30, 0), (-60, 60, 0), 0), ((-10, -20, 0), (60, 60, 0), 1)])
def test_a_vessel_that_leaves_one_image_only_is_rebuilt_where_both_see_it_and_nothing_is_invented_beyond(
        start, end, leaves):
    """Each vessel crosses the epipolar plane through its middle at 15 and 28 degrees (a vessel
    lying in one has no depth from two views), stays inside one image and leaves the other over
    its last quarter."""
    projections = _views()
    truth = VesselTree((Branch(_line(start, end), 1.4, name="long"),))
    axis = truth.root.points_mm
    inside = [np.all((p.project(axis) >= 0) & (p.project(axis) <= 511), axis=1) for p in projections]
    assert inside[1 - leaves].all() and 0.6 < inside[leaves].mean() < 0.9
    with pytest.warns(InputWarning, match=rf"vessel runs off the image's edge in view{leaves} in 1 place \(u, v px"), \
            pytest.warns(AgreementWarning, match=rf"the views disagree \(view{1 - leaves}\).*vessel runs off the "
                                                 rf"image's edge in view{leaves} \(12 pixels\)"):
        result = reconstruct(projections, _masks(truth, projections), method="tree", centerlines=False)
    distance, _, _, _ = distance_to_centerline(axis[inside[leaves]], result.tree)
    assert np.mean(distance < 1.0) >= 0.95  # measured 0.99 and 1.00
    # the part only one view shows has no partner: no tree point is put anywhere off the true axis
    built = np.vstack([b.points_mm for b in result.tree.branches])
    off_axis = np.linalg.norm(built[:, None, :] - axis[None], axis=2).min(axis=1)
    assert off_axis.max() < 1.0  # measured 0.25 and 0.29 mm (the refined hull: 3.78 and 2.11 mm)


def test_the_same_views_give_the_same_tree_whatever_the_last_bits_of_the_cube():
    """The cube's half-edge comes from a linear-algebra solve, whose last bits can differ from
    machine to machine (two units in the last place between two of OpenBLAS's kernels). Moved by 1,
    2 and 4 such units, the Y comes back the same to 1e-9 mm: the choices between tied candidates
    (equal-length paths through the hull, mirror-image continuations) are made in voxel units.
    Before that (528705d) its centerline distance took four values over these (0.040-0.048 mm), and
    the helix's, over 0 to 6 units, five (2.34-3.92 mm)."""
    from angiohull.geometry import cube_half_edge_mm

    projections = _views()
    masks = _masks(_y(), projections)
    half_edge = cube_half_edge_mm(projections)
    trees = [reconstruct(projections, masks, method="tree", centerlines=False,
                         half_edge_mm=half_edge + k * np.spacing(half_edge)).tree for k in (0, 1, 2, 4)]
    for tree in trees[1:]:
        assert tree.n_branches == trees[0].n_branches
        for a, b in zip(tree.branches, trees[0].branches):
            assert (a.parent, a.parent_point) == (b.parent, b.parent_point) and a.n_points == b.n_points
            np.testing.assert_allclose(a.points_mm, b.points_mm, atol=1e-9)
            np.testing.assert_allclose(a.radius_mm, b.radius_mm, atol=1e-9)


def test_the_tree_method_refuses_one_view_and_hull_only_options():
    projections = _views()
    masks = _masks(_y(), projections)
    with pytest.raises(ReconstructionError, match="two views or more"):
        reconstruct(projections[:1], masks[:1], method="tree")
    with pytest.raises(ReconstructionError, match="preset 'refined' applies to method 'hull' only"):
        reconstruct(projections, masks, method="tree", preset="refined")
    with pytest.raises(ReconstructionError, match="unknown method 'model'"):
        reconstruct(projections, masks, method="model")


def test_the_tree_method_is_the_default_and_a_hull_option_picks_the_hull():
    from angiohull.options import chosen_method
    from angiohull.workflow import ReconstructOptions

    projections = _views()
    masks = _masks(_y(), projections)
    default = reconstruct(projections, masks, centerlines=False)
    assert default.method == "tree" and default.model_build is not None and default.lattice.resolution == 256
    for hull_option in ({"preset": "paper"}, {"preset": "refined"}, {"min_views": 2}, {"tree": False}):
        result = reconstruct(projections, masks, resolution=40, centerlines=False, **hull_option)
        assert result.method == "hull" and result.model_build is None, hull_option
    assert reconstruct(projections, masks, method="hull", resolution=40).preset == "paper"  # the hull's default
    with pytest.raises(ReconstructionError, match="two views or more, got 1; use method='hull'"):
        reconstruct(projections[:1], masks[:1])
    # the command line's options, by the same rule
    assert ReconstructOptions().method == "tree" and ReconstructOptions().resolution is None
    assert (ReconstructOptions(preset="refined").method, ReconstructOptions(min_views=2).method) == ("hull", "hull")
    assert ReconstructOptions(method="hull").preset == "paper" and ReconstructOptions(tree=False).method == "hull"
    with pytest.raises(ReconstructionError, match="no preset or min_views"):
        ReconstructOptions(method="tree", preset="refined")
    assert [chosen_method(None), chosen_method("hull"), chosen_method("tree", "refined")] == ["tree", "hull", "tree"]


def test_specks_go_before_the_tree_method_reads_the_masks():
    """Salt noise (2 % of every mask's background set, as `synth --corrupt fp=0.02` does) leaves the
    Y's tree as it is without it: its specks, pieces under speck_px pixels, go before the carving
    (before they did, such noise took a generated tree's two views 292 s and put its centerline
    7 mm off, docs/tree-method.md)."""
    from angiohull.reconstruction.model import MODEL_SETTINGS
    from angiohull.reconstruction.refine import without_small_components

    projections = _views()
    masks = _masks(_y(), projections)
    rng = np.random.default_rng(5)
    noisy = [m | (rng.random(m.shape) < 0.02) for m in masks]
    # what stays is the pieces that hold the vessel: every true pixel, and the noise pixels touching it
    for clean, salted in zip(masks, noisy):
        kept = without_small_components(salted, MODEL_SETTINGS.speck_px)
        pieces = ndi.label(salted, structure=np.ones((3, 3), dtype=bool))[0]
        assert set(np.unique(pieces[kept])) == set(np.unique(pieces[clean])) and (kept & clean).sum() == clean.sum()
    result = reconstruct(projections, noisy, method="tree", centerlines=False, warn=False)
    s = tree_scores(result.tree, _y()).as_dict()
    assert s["branch_recall"] == 1.0 and s["centerline_mean_mm"] < 0.3  # as the clean Y's (measured 0.045 clean)
    with pytest.raises(ReconstructionError, match="no piece of 20 pixels or more"):
        reconstruct(projections, [masks[0], rng.random(masks[1].shape) < 0.01], warn=False)


def test_three_views_with_salt_are_read_without_the_specks():
    """With three views a salted mask (more specks than salt_pieces_per_px per pixel) is read without
    its specks throughout, carving and refined hull alike: the Y under 5 % salt comes back as from
    the masks without the specks, to the last bit, and as the clean one does (generated trees under
    10 % salt took 13-26 s with the centerline 1.2-1.4 mm off while only the support hull was carved
    without them; docs/tree-method.md, "Noisy masks")."""
    from angiohull.reconstruction.model import MODEL_SETTINGS
    from angiohull.reconstruction.refine import without_small_components

    projections = [CArmGeometry(*parse_clinical_angles(v), 1200.0, 800.0, (0.35, 0.35), (512, 512)).projection()
                   for v in ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30")]
    masks = _masks(_y(), projections)
    rng = np.random.default_rng(6)
    noisy = [m | (rng.random(m.shape) < 0.05) for m in masks]
    clean = tree_scores(reconstruct(projections, masks, centerlines=False, warn=False).tree, _y()).as_dict()
    result = reconstruct(projections, noisy, centerlines=False, warn=False)
    bare = reconstruct(projections, [without_small_components(m, MODEL_SETTINGS.speck_px) for m in noisy],
                       centerlines=False, warn=False)
    np.testing.assert_array_equal(result.vessel_points_mm, bare.vessel_points_mm)
    salted = tree_scores(result.tree, _y()).as_dict()
    assert salted["branch_recall"] == clean["branch_recall"] == 1.0
    assert salted["centerline_mean_mm"] < clean["centerline_mean_mm"] + 0.05  # measured 0.037 against 0.028 mm


def test_pinholes_are_filled_before_the_tree_method_reads_two_views():
    """Pepper (10 % of every mask's vessel pixels cleared, as `synth --corrupt fn=0.1` does) leaves
    the Y's tree as the clean one's: a mask with more small holes than pepper_holes_per_px per pixel
    has its holes of at most pinhole_px pixels filled first (without, measured: centerline 3.59 mm,
    branch recall 0.5, 10.7 s); the clean Y's masks, with none, are read as they are."""
    from angiohull.reconstruction.model import MODEL_SETTINGS
    from angiohull.reconstruction.refine import with_small_holes_filled

    projections = _views()
    masks = _masks(_y(), projections)
    rng = np.random.default_rng(7)
    noisy = [m & ~(rng.random(m.shape) < 0.1) for m in masks]
    for clean, peppered in zip(masks, noisy):
        filled = with_small_holes_filled(peppered, MODEL_SETTINGS.pinhole_px, MODEL_SETTINGS.pepper_holes_per_px)
        assert not np.array_equal(filled, peppered)  # the gate passed
        # nothing outside the vessel is added (the clean masks' background is one piece); inside, the
        # holes left are the rare clusters of more than pinhole_px cleared pixels and notches at the edge
        assert not (filled & ~clean).any() and (filled & clean).sum() > 0.97 * clean.sum()
    s = tree_scores(reconstruct(projections, noisy, method="tree", centerlines=False).tree, _y()).as_dict()
    assert s["branch_recall"] == 1.0 and s["centerline_mean_mm"] < 0.3


def test_small_holes_are_the_4_connected_background_pieces_up_to_the_size():
    from angiohull.reconstruction.refine import with_small_holes_filled

    m = np.ones((7, 9), dtype=bool)
    m[1, 1] = False  # 1 pixel
    m[3, 2] = m[4, 3] = False  # 2 pixels, diagonal: two 4-connected holes of 1
    m[1:3, 5:7] = False  # 4 pixels
    m[6, 4:9] = False  # 5 pixels at the image's edge
    assert with_small_holes_filled(m, 1).sum() == m.sum() + 3
    assert with_small_holes_filled(m, 4).sum() == m.sum() + 7 and not with_small_holes_filled(m, 4)[6].all()
    assert with_small_holes_filled(m, 5).all() and with_small_holes_filled(m, 0).sum() == m.sum()
    assert with_small_holes_filled(np.ones((3, 3), bool), 2).all()
    # pepper only: 4 holes of at most 4 pixels (the diagonal pair two of them) in 51 mask pixels, more
    # than 0.07 per pixel (3.57) but not than 0.08 (4.08)
    assert m.sum() == 51 and with_small_holes_filled(m, 4, min_holes_per_pixel=0.07).sum() == m.sum() + 7
    assert with_small_holes_filled(m, 4, min_holes_per_pixel=0.08).sum() == m.sum()


def test_small_components_are_the_8_connected_pieces_under_the_size():
    from angiohull.reconstruction.refine import without_small_components

    m = np.zeros((8, 10), dtype=bool)
    m[1, 1] = True  # 1 pixel
    m[3, 3] = m[4, 4] = m[5, 5] = True  # 3 pixels, diagonal: one 8-connected piece
    m[1, 5:9] = True  # 4 pixels
    m[7, 0:10] = True  # 10 pixels
    np.testing.assert_array_equal(without_small_components(m, 4), m & ~np.isin(np.arange(8), [3, 4, 5])[:, None]
                                  & ~((np.arange(8)[:, None] == 1) & (np.arange(10) == 1)))
    np.testing.assert_array_equal(without_small_components(m, 3).sum(), 17)
    assert without_small_components(m, 1).sum() == m.sum() and not without_small_components(m, 11).any()
    assert not without_small_components(np.zeros((3, 3), bool), 2).any()


def test_salt_is_many_specks_beside_a_vessel_and_few_pinholes():
    """is_salted: 10 % salt on the Y's masks is salt; the clean masks, a mask of specks alone, and
    pepper that breaks a vessel into fragments (they leave pinholes with them) are not."""
    from angiohull.reconstruction.model import MODEL_SETTINGS as S
    from angiohull.reconstruction.refine import is_salted

    mask = _masks(_y(), _views())[0]
    rng = np.random.default_rng(3)

    def salted(m):
        return is_salted(m, S.speck_px, S.salt_pieces_per_px, S.salt_min_pieces, S.pinhole_px)

    assert salted(mask | (rng.random(mask.shape) < 0.1)) and not salted(mask)
    assert not salted(rng.random(mask.shape) < 0.01)  # specks alone: nothing else would stay
    fragments = mask & (rng.random(mask.shape) < 0.4)  # 60 % pepper: fragments, and pinholes among them
    labels, count = ndi.label(fragments, structure=np.ones((3, 3), dtype=bool))
    assert (np.bincount(labels.ravel())[1:] < S.speck_px).sum() > S.salt_min_pieces and not salted(fragments)
    line = np.zeros((64, 64), bool)
    line[32] = True
    dots = line.copy()
    dots[0, ::8] = True  # 8 specks off the line: fewer than salt_min_pieces
    dots_many = line.copy()
    dots_many[::4, ::4] = True  # 15 x 16 - 16 = 240 specks
    assert not salted(dots) and salted(dots_many)


def test_masks_that_are_not_vessel_masks_fail_at_the_hull_not_minutes_later():
    """Half of every pixel set at random: a hull no vessel tree fills (9.5 million cells, against at
    most 181,000 for the benchmark's two-view trees). The error comes right after the carving, before
    the 2D centerlines and matchings (which ran for more than 10 minutes on such masks before)."""
    projections = _views()
    rng = np.random.default_rng(1)
    noise = [rng.random(p.image_shape) < 0.5 for p in projections]
    stages: list[str] = []
    with pytest.warns(InputWarning) as caught, \
            pytest.raises(ReconstructionError, match=r"more than a vessel tree's 1,000,000; are the masks vessel masks"
                                                     r"\?.*method 'hull' carves the visual hull instead") as error:
        reconstruct(projections, noise, method="tree", centerlines=False, progress=stages.append)
    assert not any(line.startswith("2D centerlines") for line in stages)
    assert "or is it the views" not in str(error.value)  # 85.6 degrees from one line: no deep hull
    said = [str(w.message) for w in caught]  # the checks first: mostly vessel (and off the images' edges)
    assert any("of the pixels are vessel; vessels cover a few percent" in line for line in said)


def test_a_hull_too_large_from_views_nearly_opposite_names_the_views_too():
    """Two views 170 degrees apart (10 from looking along one line): each vessel's hull runs deep
    along the rays (the XCAT vessel's 17 mm tube from views 160-180 degrees apart fills 1.0-2.1
    million cells), so the error asks about the views as well as the masks, with their angle."""
    projections = _views(("LAO 80", "RAO 90"))
    rng = np.random.default_rng(1)
    noise = [rng.random(p.image_shape) < 0.5 for p in projections]
    with pytest.warns(InputWarning), \
            pytest.raises(ReconstructionError, match=r"are the masks vessel masks\?; or is it the views\? every pair "
                                                     r"of them looks within 10\.0 degrees of one line.*30 degrees or "
                                                     r"more from one line"):
        reconstruct(projections, noise, method="tree", centerlines=False)


def test_a_tree_method_failure_says_that_the_hull_is_there_instead():
    """A hull too small for a vessel tree (a coarse lattice): the tree method's error names the hull."""
    projections = _views()
    masks = _masks(_y(), projections)
    with pytest.raises(ReconstructionError, match="method 'hull' carves the visual hull instead"):
        reconstruct(projections, masks, resolution=8)


def test_experiment_configurations_take_the_method_and_refuse_hull_only_options_with_it():
    from pydantic import ValidationError

    from angiohull.experiments.config import ReconstructionSettings

    assert ReconstructionSettings().method == "hull"
    assert ReconstructionSettings(method="tree").method == "tree"
    with pytest.raises(ValidationError, match="method 'tree' has no preset or min_views"):
        ReconstructionSettings(method="tree", preset="refined")
    with pytest.raises(ValidationError, match="method 'tree' has no preset or min_views"):
        ReconstructionSettings(method="tree", min_views=2)


def test_two_views_along_one_line_are_named_as_the_reason_no_point_is_fixed():
    """One view twice: every pixel pairs with itself along rays that do not cross; the error says
    so instead of pointing at the calibration (or, where pairs were made, at the lattice)."""
    projections = _views()
    masks = _masks(_y(), projections)
    with pytest.warns(InputWarning, match=r"the views look along nearly one line \(degrees from it: view0 / view1 0;"), \
            pytest.raises(ReconstructionError, match=r"no correspondence between the views' centerlines; the views "
                                                     r"look along one line \(their central rays 0\.0 degrees from it "
                                                     r"at most\).*30 degrees apart"):
        reconstruct([projections[0]] * 2, [masks[0]] * 2, method="tree", centerlines=False)


def test_an_empty_hull_gives_an_empty_result_when_allowed():
    projections = _views()
    masks = _masks(_y(), projections)
    masks[1] = np.zeros_like(masks[1])
    masks[1][0, 0] = True  # one pixel far from the vessel: the hull is empty
    result = reconstruct(projections, masks, method="tree", allow_empty=True)
    assert len(result.vessel_points_mm) == 0 and result.tree is None and result.tree_error == "the hull is empty"


def test_the_report_of_a_tree_reconstruction_names_its_pairs_prunings_and_stages(tmp_path, capsys):
    import json

    from angiohull.cli import main
    from angiohull.study import View, save_study

    truth = _y()
    carms = [CArmGeometry(*parse_clinical_angles(v), 1200.0, 800.0, (0.35, 0.35), (512, 512)) for v in TWO]
    masks = _masks(truth, [c.projection() for c in carms])
    study = save_study(tmp_path / "y", [View.from_carm(f"view{i}", m, c) for i, (m, c) in enumerate(zip(masks, carms))])
    out = tmp_path / "out"
    assert main(["reconstruct", str(study), "-o", str(out), "--method", "tree", "--no-figure", "--no-viewer",
                 "--no-centerlines"]) == 0
    report = json.loads((out / "report.json").read_text())
    block = report["tree_method"]
    from plyfile import PlyData  # the points file says what its points are (not "visual hull")
    assert "angiohull tree method: lattice points inside the fitted tubes" in PlyData.read(str(out / "vessel.ply")).comments
    # the progress line gives the time the tree took (the method's tree stage; it read 0.000 s before)
    [line] = [line for line in capsys.readouterr().err.splitlines() if "] vessel tree:" in line]
    assert line.endswith(f"({report['timings_s']['tree_tree']:.3f} s)") and report["timings_s"]["tree_tree"] > 0
    assert block["pairs"] == [["view0", "view1"], ["view1", "view0"]]
    # the exact masks of one tree: no width bias between the views (under 0.5 px: nothing taken off)
    assert abs(block["width_bias"]["view_1_wider_by_px"]) < 0.2 and block["width_bias"]["taken_off"] is False
    # the final tree was fitted twice (vessel_tree.refit_tree), the rounds' trees once
    assert report["tree"]["build"]["fit_passes"] == 2 and report["tree"]["build"]["timings_s"]["refit"] > 0
    assert set(block["branches_removed"]) == {"explained_by_the_others", "not_reproduced_by_the_matchings",
                                              "carrying_others_not_reproduced"}
    assert all(isinstance(n, int) and n >= 0 for n in block["branches_removed"].values())
    assert isinstance(block["contradicted_stretch_points_removed"], int)
    assert isinstance(block["pruned_branches_put_back"], int) and block["pruned_branches_put_back"] >= 0
    assert isinstance(block["unexplained_pixels_matched_again"], int) and block["unexplained_pixels_matched_again"] >= 0
    assert isinstance(block["redundant_branches_replaced"], int) and block["redundant_branches_replaced"] >= 0
    assert isinstance(block["runs_slid_along_rays"], int) and block["runs_slid_along_rays"] >= 0
    assert block["rebuilds"] in range(MODEL_SETTINGS.stretch_rounds + MODEL_SETTINGS.rematch_rounds + 1)
    assert set(block["timings_s"]) >= {"centerlines_2d", "correspondence", "tubes", "tree", "agreement", "hypotheses",
                                       "slide", "lumen"}
    # two views: a tree per claim cost, the one whose tubes agree best with the masks kept
    matchings = block["matchings"]
    assert matchings["claim_costs"] == [MODEL_SETTINGS.match.claim_cost, *MODEL_SETTINGS.alternative_claim_costs]
    assert len(matchings["mask_agreement_dice"]) == len(matchings["claim_costs"])
    assert all(0.9 < d <= 1.0 for d in matchings["mask_agreement_dice"])
    assert isinstance(matchings["hypotheses"], list)
    assert len(matchings["judged_score"]) == len(matchings["claim_costs"])
    # the score is the agreement less a penalty (the lengths', module notes)
    assert all(j < d for j, d in zip(matchings["judged_score"], matchings["mask_agreement_dice"]))
    assert all(set(h) == {"claim_cost", "avoided", "avoided_length_mm", "mask_agreement_dice", "judged_score"}
               and h["avoided"] in ("side branch", "root window") for h in matchings["hypotheses"])
    own_best = max(matchings["judged_score"])
    scores = [h["judged_score"] for h in matchings["hypotheses"]]
    if matchings["kept_hypothesis"] is None:
        kept = matchings["claim_costs"].index(matchings["kept_claim_cost"])
        assert matchings["judged_score"][kept] == own_best
        assert all(s < own_best + MODEL_SETTINGS.hypothesis_margin for s in scores)
    else:
        kept = matchings["hypotheses"][matchings["kept_hypothesis"]]["judged_score"]
        assert kept == max(scores) >= own_best + MODEL_SETTINGS.hypothesis_margin


def test_window_medians_are_numpys_medians_of_every_window():
    from angiohull.reconstruction.model import _window_medians

    rng = np.random.default_rng(7)
    values = rng.gamma(2.0, 0.5, 60)
    values[10:14] = 1.0  # ties
    lo = rng.integers(0, 60, 200)
    hi = np.minimum(lo + rng.integers(1, 15, 200), 60)  # widths 1 to 14, odd and even
    expected = np.array([np.median(values[a:b]) for a, b in zip(lo, hi)])
    np.testing.assert_array_equal(_window_medians(values, lo, hi), expected)


def test_radius_spikes_come_down_to_the_ratio_times_the_local_median():
    from angiohull.reconstruction.model import without_radius_spikes

    # a 0.5 mm step, a 1.0 mm radius with a 3-point spike to 3 mm and a narrowing to 0.4 mm
    radius = np.full(81, 1.0)
    radius[40:43], radius[60:63] = 3.0, 0.4
    tree = VesselTree((Branch(_line((0, 0, 0), (40, 0, 0)), radius),))
    out = without_radius_spikes(tree, 3.0, 1.25).root.radius_mm
    # each spike point's window (+-3 mm: 13 points) holds at most 3 spikes: its median is 1.0
    np.testing.assert_allclose(out[40:43], 1.25)
    np.testing.assert_array_equal(out[60:63], 0.4)  # a narrowing stays
    np.testing.assert_array_equal(np.delete(out, [40, 41, 42]), np.delete(radius, [40, 41, 42]))


# -- two views: each matching's tree, judged by its agreement with the masks (model/agreement.py) -----------
def _silhouette_by_brute_force(tree, projection, step_mm):
    """Pixel by pixel: a pixel centre within the projected radius of any sample (the samples as
    the module takes them, every ``step_mm`` of arc)."""
    points = np.concatenate([b.resampled(step_mm).points_mm for b in tree.branches])
    radii = np.concatenate([b.resampled(step_mm).radius_mm for b in tree.branches])
    uv = projection.project(points)
    rho = radii * max(projection.focal_lengths_px) / projection.depth_mm(points)
    rows, cols = projection.image_shape
    out = np.zeros((rows, cols), dtype=bool)
    for (u, v), r in zip(uv, rho):
        for row in range(max(int(v - r) - 1, 0), min(int(v + r) + 2, rows)):
            for col in range(max(int(u - r) - 1, 0), min(int(u + r) + 2, cols)):
                if (col - u) ** 2 + (row - v) ** 2 <= r * r:
                    out[row, col] = True
    return out


@pytest.mark.parametrize("step_mm", [0.25, 1.0])
def test_the_tubes_silhouette_matches_a_pixel_by_pixel_reference(step_mm):
    tree = _y()
    for projection in _views():
        drawn = tube_silhouette(tree, projection, step_mm=step_mm)
        assert drawn.sum() > 1000
        np.testing.assert_array_equal(drawn, _silhouette_by_brute_force(tree, projection, step_mm))


def test_the_tubes_silhouette_agrees_with_the_exact_projection_of_the_tubes():
    """The discs of the samples against the phantom's exact silhouette (its capsules projected as
    cones from the source): they differ only where a disc stands in for a slanted cross-section."""
    tree = _y()
    phantom = TubePhantom(tuple(Tube(b.points_mm, b.radius_mm) for b in tree.branches), "y")
    for projection in _views():
        exact = phantom.silhouette(projection)
        agreement = mask_agreement(tree, [projection], [exact])
        assert agreement[0] > 0.99  # measured 0.999 in both views


def test_mask_agreement_is_the_dice_coefficient_of_mask_and_silhouette():
    tree, projections = _y(), _views()
    own = [tube_silhouette(tree, p) for p in projections]
    np.testing.assert_allclose(mask_agreement(tree, projections, own), [1.0, 1.0])
    shifted = [np.roll(m, 3, axis=0) for m in own]  # the mask 3 px down
    expected = [2 * (m & s).sum() / (m.sum() + s.sum()) for m, s in zip(own, shifted)]
    got = mask_agreement(tree, projections, shifted)
    np.testing.assert_allclose(got, expected)
    assert all(0.2 < g < 0.9 for g in got)
    empty = VesselTree((Branch(_line((400, 400, 400), (420, 400, 400)), 1.0),))  # behind nothing: off the images
    assert mask_agreement(empty, projections[:1], [np.zeros((512, 512), bool)])[0] == 1.0


def test_a_step_that_is_not_positive_is_refused():
    with pytest.raises(ValueError, match="step_mm"):
        tube_silhouette(_y(), _views()[0], step_mm=0.0)


def _generated(kind, seed):
    from angiohull.synthetic import SynthOptions, make_case

    case = make_case(SynthOptions(kind=kind, tortuosity="simple", views=TWO, seed=seed))
    return case.tree.vessel_tree(), [v.projection for v in case.views], [v.mask for v in case.views]


def test_the_view_order_check_finds_the_two_masks_swapped_between_the_views():
    """Generated RCA seed 7021 in the two clinical views, exact masks: swapped between the views,
    its masks still cover nearly the same epipolar planes and the input checks say nothing; the
    tree method's trees agree better with them the right way round (the truth's), and the check
    warns of the swapped study alone. Each side's second build is the other side's first: the
    agreements are the same numbers, though the check builds without the hypotheses and the slide
    (which come after the agreement)."""
    _, projections, masks = _generated("rca", 7021)
    swapped_masks = masks[::-1]
    assert input_warnings(projections, swapped_masks, ["a", "b"]) == []
    right = reconstruct(projections, masks, method="tree", centerlines=False, warn=False)
    wrong = reconstruct(projections, swapped_masks, method="tree", centerlines=False, warn=False)
    given, other = view_order_agreement(projections, masks, right)
    given_wrong, other_wrong = view_order_agreement(projections, swapped_masks, wrong)
    assert given == max(right.model_build.mask_agreement) and given_wrong == max(wrong.model_build.mask_agreement)
    assert other == given_wrong and other_wrong == given
    assert given - other > VIEW_ORDER_MARGIN
    assert view_order_warning(given, other, right.view_names) is None
    message = view_order_warning(given_wrong, other_wrong, wrong.view_names)
    assert message is not None and f"{other_wrong:.3f}" in message and f"{given_wrong:.3f}" in message
    assert "view0's and view1's masks swapped" in message
    # the margin: a swap that agrees better by less than it is no warning
    assert view_order_warning(0.970, 0.970 + 0.5 * VIEW_ORDER_MARGIN, ["a", "b"]) is None
    assert view_order_warning(0.970, 0.970 + 2 * VIEW_ORDER_MARGIN, ["a", "b"]) is not None


def test_the_view_order_check_wants_two_views_and_the_tree_method():
    _, projections, masks = _generated("left", 8000)
    hull = reconstruct(projections, masks, method="hull", resolution=40, centerlines=False, tree=False, warn=False)
    with pytest.raises(ReconstructionError, match="tree method's result"):
        view_order_agreement(projections, masks, hull)
    with pytest.raises(ReconstructionError, match="got 3 views .with three, two masks swapped"):
        view_order_agreement(projections + projections[:1], masks + masks[:1], hull)
    assert view_order_warning(0.97, None, ["a", "b"]) is None  # no tree the other way round: nothing to say
    assert view_order_warning(0.97, 0.97, ["a", "b"]) is None


def test_of_two_views_the_tree_kept_is_the_one_that_agrees_best_with_the_masks(monkeypatch):
    """Generated RCA seed 7000 (the tree method benchmark's first RCA) in the two clinical views,
    exact masks: with the default claim cost the distal RCA of the first view is matched to the
    acute marginal of the second; the matching with the larger claim cost pairs them right, and
    its tree explains the masks better. (Without the hypotheses of a wrong pairing: see the next
    test.)"""
    truth, projections, masks = _generated("rca", 7000)
    # the tree kept as the judge kept it: without the slide along the rays that follows the judge
    # (reconstruction.model.sliding, tested on its own)
    monkeypatch.setitem(model.model_tree.__kwdefaults__, "settings", replace(MODEL_SETTINGS, hypotheses=0,
                                                                             slide=None))
    result = reconstruct(projections, masks, method="tree", centerlines=False)
    build = result.model_build
    assert build.claim_costs == (MODEL_SETTINGS.match.claim_cost,) + MODEL_SETTINGS.alternative_claim_costs
    assert len(build.mask_agreement) == len(build.claim_costs)
    assert build.hypotheses == () and build.kept_hypothesis is None
    kept = build.claim_costs.index(build.kept_claim_cost)
    assert build.judged_score[kept] == max(build.judged_score)
    assert build.mask_agreement[kept] == max(build.mask_agreement)  # here the better agreement decides alone
    assert mask_agreement(result.tree, projections, masks).mean() == pytest.approx(build.mask_agreement[kept])
    monkeypatch.setitem(model.model_tree.__kwdefaults__, "settings",
                        replace(MODEL_SETTINGS, alternative_claim_costs=(), hypotheses=0, slide=None))
    alone = reconstruct(projections, masks, method="tree", centerlines=False)
    assert alone.model_build.claim_costs == () and alone.model_build.kept_claim_cost is None
    chosen, single = tree_scores(result.tree, truth), tree_scores(alone.tree, truth)
    # measured 0.75 mm against 2.49 mm (mask agreement 0.980 against 0.970)
    assert chosen.centerline_mean_mm < 1.0 < 2.0 < single.centerline_mean_mm


def test_a_tree_that_agrees_too_little_with_the_masks_is_built_again_without_a_suspect_pairing():
    """The same RCA: the default claim cost's tree agrees less than the gate with the masks, so it
    is built again with each of its suspect side branches' pairing avoided; one of these trees
    pairs the distal RCA right and agrees best of all, and it is the nearest to the truth."""
    truth, projections, masks = _generated("rca", 7000)
    result = reconstruct(projections, masks, method="tree", centerlines=False)
    build = result.model_build
    assert min(build.mask_agreement) < MODEL_SETTINGS.hypothesis_gate
    tried = [h for h in build.hypotheses]
    assert 1 <= len(tried) <= MODEL_SETTINGS.hypotheses * len(build.claim_costs)
    assert all(c in build.claim_costs and length > 0 for c, length, _, _ in tried)
    assert build.kept_hypothesis is not None
    best = max(score for *_, score in tried)
    assert tried[build.kept_hypothesis][3] == best >= max(build.judged_score) + MODEL_SETTINGS.hypothesis_margin
    agreement = tried[build.kept_hypothesis][2]
    assert agreement == max([*build.mask_agreement, *(a for _, _, a, _ in tried)])  # and it agrees best too
    assert mask_agreement(result.tree, projections, masks).mean() == pytest.approx(agreement)
    # measured 0.20 mm (the claim cost 3's tree without hypotheses: 0.75 mm, test above)
    assert tree_scores(result.tree, truth).centerline_mean_mm < 0.4


def test_a_tree_is_judged_by_its_agreement_less_its_lengths_over_the_matchings_own():
    """Hand-worked: agreement 0.95, a 200 mm tree of which 20 mm only one view needs, the
    matchings' own trees 250 mm long on average: 0.95 - (0.1 * 200 + 0.1 * 20) / 250 = 0.862."""
    from angiohull.reconstruction.model import _Candidate

    settings = replace(MODEL_SETTINGS, length_weight=0.1, redundant_weight=0.1)
    candidate = _Candidate(tree=None, build=None, counts={}, agreement=0.95, correspondence=None, length_mm=200.0,
                           redundant_mm=20.0)
    assert candidate.judged(settings, 250.0) == pytest.approx(0.862, abs=1e-12)
    assert candidate.judged(replace(settings, redundant_weight=0.0), 250.0) == pytest.approx(0.87, abs=1e-12)
    assert candidate.judged(replace(settings, length_weight=0.0, redundant_weight=0.0), 250.0) == 0.95


def test_of_two_trees_the_shorter_one_without_redundant_branches_is_kept_over_a_better_agreeing_one(monkeypatch):
    """Generated left seed 8019 (the tree method benchmark's left tree 19, moderate tortuosity), the
    two clinical views, masks segmented from rendered angiograms: the claim cost 3's tree agrees
    better with the masks (0.970 against 0.950) but is 431 mm long against 346, 152 mm of it in
    branches only one view needs (none in the other), and lies 2.36 mm from the truth (dev run);
    judged with the lengths' penalty the default claim cost's tree is kept, 0.83 mm from it."""
    from angiohull.segmentation import segment_vessels
    from angiohull.synthetic import SynthOptions, make_case
    from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram

    case = make_case(SynthOptions(kind="left", tortuosity="moderate", views=TWO, seed=8019))
    masks = [segment_vessels(render_angiogram(case.tree.phantom, v.carm, 8019 * 10 + i,
                                              AngiogramParameters(collimator_px=8)).image)
             for i, v in enumerate(case.views)]
    monkeypatch.setitem(model.model_tree.__kwdefaults__, "settings", replace(MODEL_SETTINGS, hypotheses=0))
    result = reconstruct([v.projection for v in case.views], masks, method="tree", centerlines=False)
    build = result.model_build
    assert build.claim_costs == (1.5, 3.0) and build.mask_agreement[1] > build.mask_agreement[0] + 0.01
    assert build.judged_score[0] > build.judged_score[1] and build.kept_claim_cost == 1.5
    assert tree_scores(result.tree, case.tree.vessel_tree()).centerline_mean_mm < 1.0  # measured 0.83


def _blob_beside(mask, projection, points, k, radius_px, out_px):
    """``mask`` with a disc of ``radius_px`` whose centre lies ``out_px`` pixels from the projection
    of ``points[k]``, across the projected polyline there (or on along it past its last point)."""
    uv = projection.project(points)
    if k == len(points) - 1:
        step = uv[k] - uv[k - 4]
        centre = uv[k] + out_px * step / np.linalg.norm(step)
    else:
        step = uv[k + 1] - uv[k - 1]
        centre = uv[k] + out_px * np.array([-step[1], step[0]]) / np.linalg.norm(step)
    rows, cols = np.mgrid[:mask.shape[0], :mask.shape[1]]
    return mask | ((cols - centre[0]) ** 2 + (rows - centre[1]) ** 2 <= radius_px ** 2)


def _trunk_with_two_side_branches(second_at: int) -> tuple[VesselTree, np.ndarray, np.ndarray, np.ndarray]:
    """A 60 mm trunk (points 0.5 mm apart, radius 1.5 mm) with a side branch leaving its point 20
    and another leaving its point ``second_at`` (radius 1 mm): the tree, and the three polylines."""
    trunk = _line((-30, 0, 0), (30, 0, 0))
    first = _line(trunk[20], trunk[20] + (0, 25, 5))
    second = _line(trunk[second_at], trunk[second_at] + (5, -25, 0))
    tree = VesselTree((Branch(trunk, 1.5, name="trunk"), Branch(first, 1.0, parent=0, parent_point=20, name="first"),
                       Branch(second, 1.0, parent=0, parent_point=second_at, name="second")))
    return tree, trunk, first, second


def test_suspect_pieces_are_the_side_branches_touching_the_most_unexplained_pixels():
    """A trunk with two side branches, drawn exactly into two views; the first view's mask holds a
    blob beside the second side branch's end (a vessel it does not explain) and a smaller one
    beside the first's: the second comes first, then the first; blobs below ``min_pixels`` count
    for nothing (ties keep the branches' order), and without root windows the root is never a
    suspect."""
    tree, trunk, first, second = _trunk_with_two_side_branches(80)
    projections = _views()
    masks = [tube_silhouette(tree, p) for p in projections]
    drawn = masks[0].copy()
    for points, radius_px in ((second, 6.0), (first, 3.0)):
        end = projections[0].project(points[-1:])[0]
        beyond = end + (end - projections[0].project(points[-5:-4])[0])  # 2 mm on, in the image
        rows, cols = np.mgrid[:masks[0].shape[0], :masks[0].shape[1]]
        masks[0] = masks[0] | ((cols - beyond[0]) ** 2 + (rows - beyond[1]) ** 2 <= radius_px ** 2)
    unexplained = masks[0] & ~drawn
    assert unexplained.sum() > 40  # the two blobs (measured: beside the ends, a part under the tubes)
    whole = {1: Suspect(1, 0, len(first)), 2: Suspect(2, 0, len(second))}
    assert suspect_pieces(tree, projections, masks, 2) == [whole[2], whole[1]]
    assert suspect_pieces(tree, projections, masks, 1) == [whole[2]]
    assert suspect_pieces(tree, projections, masks, 5) == [whole[2], whole[1]]  # the root never
    # no piece counts: ties
    assert suspect_pieces(tree, projections, masks, 2, min_pixels=10 ** 6) == [whole[1], whole[2]]
    assert suspect_pieces(tree, projections, masks, 0) == []
    assert suspect_pieces(VesselTree((Branch(trunk, 1.5),)), projections, masks, 2) == []
    # with windows of the root: these blobs lie beyond the side branches' ends, clear of the trunk's windows
    assert suspect_pieces(tree, projections, masks, 5, root_window_mm=20.0) == [whole[2], whole[1]]


def test_the_root_windows_run_half_overlapping_to_the_roots_end():
    """Hand-worked: a 60 mm root of points 0.5 mm apart read as 20 mm windows: starts at 0, 10, 20,
    30 and 40 mm, each window from its start's point to the first point at or past its end, one
    point more; a root shorter than a window is one window, all of it."""
    from angiohull.reconstruction.model.agreement import _root_windows

    assert _root_windows(Branch(_line((-30, 0, 0), (30, 0, 0)), 1.5), 20.0) == [(0, 41), (20, 61), (40, 81),
                                                                                  (60, 101), (80, 121)]
    assert _root_windows(Branch(_line((0, 0, 0), (15, 0, 0)), 1.5), 20.0) == [(0, 31)]


def test_a_window_of_the_root_beside_unexplained_pixels_is_a_suspect_before_a_side_branch():
    """The trunk and side branches above; the first view's mask holds a large blob beside the
    trunk 25 mm from its start (x = -5 mm; a stretch of the main vessel the tree pairs wrongly
    leaves its true partner's pixels beside it) and a small one beyond the first side branch's
    end. The two windows over the blob (10-30 and 20-40 mm) touch it alike; the first ranks first
    and the second overlaps it by more than half, so it is no suspect; the windows clear of the
    blob touch nothing and are none; then the side branches (the second, touching nothing, last).
    Without root windows the side branches alone."""
    tree, trunk, first, second = _trunk_with_two_side_branches(100)
    projections = _views()
    masks = [tube_silhouette(tree, p) for p in projections]
    drawn = masks[0].copy()
    radius_px = 1.5 * max(projections[0].focal_lengths_px) / float(projections[0].depth_mm(trunk[50:51])[0])
    masks[0] = _blob_beside(masks[0], projections[0], trunk, 50, 6.0, radius_px + 4.0)
    masks[0] = _blob_beside(masks[0], projections[0], first, len(first) - 1, 3.0, 8.0)
    assert (masks[0] & ~drawn).sum() > 80
    whole = {1: Suspect(1, 0, len(first)), 2: Suspect(2, 0, len(second))}
    assert suspect_pieces(tree, projections, masks, 5, root_window_mm=20.0) == [Suspect(0, 20, 61), whole[1],
                                                                                whole[2]]
    assert suspect_pieces(tree, projections, masks, 1, root_window_mm=20.0) == [Suspect(0, 20, 61)]
    assert suspect_pieces(tree, projections, masks, 5) == [whole[1], whole[2]]


def test_a_matching_never_pairs_into_the_region_it_avoids():
    """The Y in two views, its second branch's region avoided: every candidate there costs more
    than leaving the pixel unmatched (10 against 2), so the exact min-sum matching puts no point
    there, while without the region most of that branch's pixels match within it."""
    from scipy.spatial import cKDTree

    from angiohull.reconstruction.model import _view_data
    from angiohull.reconstruction.model.matching import Avoid, match_pixels

    truth, projections = _y(), _views()
    masks = _masks(truth, projections)
    a, b = _view_data(projections[0], masks[0]), _view_data(projections[1], masks[1])
    second = truth.branches[1].points_mm[6:]  # clear of the trunk's radius
    reach = np.full(len(second), 1.1 + 1.0)
    avoid = Avoid(second, reach, 10.0)
    plain, plain_radii, _ = match_pixels(a, b)
    points, radii, _ = match_pixels(a, b, avoid=avoid)
    near_plain = cKDTree(second).query(plain[np.isfinite(plain_radii)])[0] <= 2.1
    near = cKDTree(second).query(points[np.isfinite(radii)])[0] <= 2.1
    assert near_plain.sum() >= 40 and near.sum() == 0
    # with a cache, the same (the avoided matching does not touch the cached candidates)
    cache = {}
    match_pixels(a, b, cache=cache)
    again, again_radii, _ = match_pixels(a, b, cache=cache, avoid=avoid)
    np.testing.assert_array_equal(again, points)
    after, _, _ = match_pixels(a, b, cache=cache)
    np.testing.assert_array_equal(after, plain)


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="os.fork is not available on this platform")
@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # Python 3.12+ warns of a fork where any thread runs
def test_a_forked_build_returns_its_result_and_a_failed_or_abandoned_one_nothing():
    import time

    from angiohull.reconstruction.model import _ForkedBuilds

    assert _ForkedBuilds(lambda: {"tree": np.arange(100_000.0)}).result()["tree"].sum() == 99_999 * 100_000 / 2

    def failing():
        raise RuntimeError("a build that fails in the child")

    assert _ForkedBuilds(failing).result() is None  # the caller then builds it itself
    start = time.perf_counter()
    slow = _ForkedBuilds(lambda: time.sleep(30))
    slow.abandon()  # killed and reaped at once
    assert time.perf_counter() - start < 10


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="os.fork is not available on this platform")
@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # Python 3.12+ warns of a fork where any thread runs
def test_builds_in_processes_come_back_in_order_from_a_process_each_up_to_twice_the_cpus(monkeypatch):
    import os

    from angiohull.reconstruction.model import forking

    here = os.getpid()
    tasks = [lambda k=k: (k * k, os.getpid()) for k in range(7)]
    monkeypatch.setattr(forking, "_can_fork", lambda: True)
    monkeypatch.setattr(forking, "_cpus", lambda: 2)
    results = forking._in_processes(tasks, True)
    assert [value for value, _ in results] == [k * k for k in range(7)]
    pids = [pid for _, pid in results]
    # four processes (twice the CPUs) in runs of consecutive tasks: 1, 2, 2 and 2 tasks, the first run here
    assert pids[0] == here and len(set(pids)) == 4 and here not in pids[1:]
    assert [len(list(group)) for _, group in __import__("itertools").groupby(pids)] == [1, 2, 2, 2]
    monkeypatch.setattr(forking, "_cpus", lambda: 16)
    assert len({pid for _, pid in forking._in_processes(tasks[:3], True)}) == 3  # a process per task

    def only_here(k):
        if os.getpid() != here:
            raise RuntimeError("a build that fails in a child")
        return k

    # a child that fails has its run built here; without fork everything is built here
    assert forking._in_processes([lambda k=k: only_here(k) for k in range(5)], True) == list(range(5))
    assert forking._in_processes([lambda k=k: only_here(k) for k in range(5)], False) == list(range(5))


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="os.fork is not available on this platform")
@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # Python 3.12+ warns of a fork where any thread runs
def test_the_alternative_tree_built_in_a_forked_process_is_the_one_built_here(monkeypatch):
    from angiohull.reconstruction.model import _can_fork, forking

    _, projections, masks = _generated("rca", 7000)
    # (the default build here is one of the two below: forked where this process may fork, as under
    # pytest-xdist, whose workers run one thread; sequential where it may not)
    monkeypatch.setitem(model.model_tree.__kwdefaults__, "settings", replace(MODEL_SETTINGS, fork_alternatives=False))
    sequential = reconstruct(projections, masks, method="tree", centerlines=False)
    monkeypatch.setattr(forking, "_can_fork", lambda: True)
    monkeypatch.setitem(model.model_tree.__kwdefaults__, "settings", MODEL_SETTINGS)
    forked = reconstruct(projections, masks, method="tree", centerlines=False)
    np.testing.assert_array_equal(forked.vessel_points_mm, sequential.vessel_points_mm)
    np.testing.assert_array_equal(forked.tree.points()[0], sequential.tree.points()[0])
    assert forked.model_build.mask_agreement == sequential.model_build.mask_agreement
    assert isinstance(_can_fork(), bool)


@pytest.mark.parametrize("dense_share", [0.0, np.inf])
def test_a_slides_move_scores_and_counts_alike_whether_counted_on_the_whole_image_or_on_the_discs_pixels(
        dense_share, monkeypatch):
    from angiohull.reconstruction.model import sliding

    projections = _views()
    truth = _arc_vessel()
    masks = _masks(truth, projections)
    monkeypatch.setattr(sliding, "_DENSE_SHARE", dense_share)
    picture = sliding._Picture(truth.branches, projections[1], masks[1], 0.25)
    samples = picture.samples[0]
    old, radii = samples.points_mm, samples.radius_mm
    new = old + np.array([0.0, 0.0, 1.5]) * np.clip(1 - np.abs(samples.arc_length_mm - 40) / 10, 0, None)[:, None]
    # the oracle: the counts drawn from scratch at the moved samples
    size = np.asarray(masks[1]).size
    counted = np.bincount(picture.pixels(new, radii)[0], minlength=size)
    weight = np.where(np.asarray(masks[1]).ravel(), 1, -1)
    expected = int((weight * ((counted > 0).astype(int) - (picture.count > 0))).sum())
    score, touched, change = picture.moved(old, new, radii)
    assert score == expected and expected != 0
    picture.keep(touched, change)
    np.testing.assert_array_equal(picture.count, counted)
