"""Sub-pixel view shifts from 2D centrelines (reconstruction.centreline_fit)."""

import numpy as np
import pytest

from angiohull.geometry import CArmGeometry
from angiohull.reconstruction.calibration import _jacobian
from angiohull.reconstruction.centreline_fit import (Centreline, centreline_rays, consistency_cost, fit_jointly,
                                                       fit_scales_jointly, fit_view_shift, match_pair, polish_shifts)
from angiohull.synthetic import SynthOptions, make_case

from _cases import geometry_error_px


def _views():
    return [CArmGeometry(a, b, 1200.0, 800.0, (0.3, 0.3), (512, 512)).projection()
            for a, b in ((-30.0, 25.0), (45.0, 20.0), (0.0, -40.0))]


def _tube_mask(projection, centre_mm, radius_mm, shape=(512, 512)):
    """Exact mask of a set of 3D balls (a sampled tube): pixel centres within the projected radius."""
    rows, cols = np.indices(shape)
    mask = np.zeros(shape, dtype=bool)
    uv = projection.project(centre_mm)
    px_per_mm = max(projection.focal_lengths_px) / projection.depth_mm(centre_mm)
    for (u, v), r in zip(uv, radius_mm * px_per_mm):
        lo_r, hi_r = int(max(0, v - r - 1)), int(min(shape[0], v + r + 2))
        lo_c, hi_c = int(max(0, u - r - 1)), int(min(shape[1], u + r + 2))
        sub = (rows[lo_r:hi_r, lo_c:hi_c] - v) ** 2 + (cols[lo_r:hi_r, lo_c:hi_c] - u) ** 2 <= r * r
        mask[lo_r:hi_r, lo_c:hi_c] |= sub
    return mask


def test_centreline_is_the_midpoint_of_the_edges_not_the_thinned_pixel():
    # even width: thinning keeps row 12 or 13, the vessel's middle is 12.5 (pixel-centre convention)
    for rows, middle in ((slice(10, 16), 12.5), (slice(10, 17), 13.0)):
        mask = np.zeros((40, 60), dtype=bool)
        mask[rows, 5:55] = True
        uv = Centreline(mask).uv_px
        inner = (uv[:, 0] > 12) & (uv[:, 0] < 48)
        np.testing.assert_allclose(uv[inner, 1], middle, atol=1e-9)
    # oblique bands: signed distance of the centreline from the band's axis, unbiased on average
    rows, cols = np.indices((80, 80))
    for slope in (0.3, 0.6, 1.7):
        norm = np.hypot(1.0, slope)
        uv = Centreline(np.abs(rows - slope * cols - 10.0) / norm < 3.2).uv_px
        distance = (uv[:, 1] - slope * uv[:, 0] - 10.0) / norm
        inner = (uv[:, 0] > 15) & (uv[:, 0] < 40)
        assert abs(distance[inner].mean()) < 0.1 and np.abs(distance[inner]).max() <= 1.0


def _curve():
    s = np.linspace(0.0, 1.0, 400)
    return np.column_stack([30 * np.cos(3 * s) - 5, 25 * np.sin(4 * s), 40 * s - 20])


def test_matches_of_a_curve_contain_the_curve():
    # Oracle: every sample of a known 3D curve has a triangulated match within a pixel's size of it.
    p_i, p_j, _ = _views()
    curve = _curve()
    masks = [_tube_mask(p, curve, 1.2) for p in (p_i, p_j)]
    points, weights = match_pair(p_i, p_j, Centreline(masks[0]), Centreline(masks[1]))
    assert len(points) > len(curve) / 4 and np.all(weights > 0) and np.all(weights <= 1)
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(points).query(curve[20:-20])  # the ends are capped by the balls
    mm_per_px = 800.0 / max(p_i.focal_lengths_px)
    assert np.percentile(distance, 95) < 2.0 * mm_per_px


def test_distances_to_the_centreline_equal_brute_force():
    # Oracle: the distance to every centreline point, the smallest taken, cut off. Points near and
    # on the centreline (where the per-pixel candidates answer), far from it (the floor), off the
    # image and not finite (the k-d tree), and a cutoff beyond the floor's reach.
    centre_line = Centreline(_tube_mask(_views()[0], _curve(), 1.2))
    rng = np.random.default_rng(3)
    base = centre_line.uv_px[rng.integers(0, len(centre_line.uv_px), 4000)]
    points = np.vstack([base + rng.normal(scale=s, size=base.shape) for s in (0.3, 1.5, 4.0)]
                       + [rng.uniform(-40.0, 552.0, size=(3000, 2)), [[np.nan, 3.0], [-0.6, 511.6], [511.4, 0.0]]])
    for cutoff in (0.5, 1.0, 2.0, 3.0, 5.0):
        brute = np.full(len(points), cutoff)
        finite = np.all(np.isfinite(points), axis=1)
        d = np.sqrt(((points[finite, None, :] - centre_line.uv_px[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
        brute[finite] = np.minimum(d, cutoff)
        np.testing.assert_allclose(centre_line.distances(points, cutoff), brute, rtol=0, atol=1e-12)
        assert (brute < cutoff).sum() > 1000 and (brute == cutoff).sum() > 1000


def test_match_pair_with_rays_at_hand_is_the_same():
    p_i, p_j, _ = _views()
    lines = [Centreline(_tube_mask(p, _curve(), 1.2)) for p in (p_i, p_j)]
    plain = match_pair(p_i, p_j, *lines)
    given = match_pair(p_i, p_j, *lines, rays_i=centreline_rays(p_i, lines[0]), rays_j=centreline_rays(p_j, lines[1]))
    assert len(plain[0]) > 100
    for a, b in zip(plain, given):
        np.testing.assert_array_equal(a, b)


def test_fit_recovers_a_known_sub_pixel_shift():
    # Points on a centreline, displaced by a known shift: the fit finds the shift back.
    projection = _views()[0]
    mask = _tube_mask(projection, _curve(), 1.2)
    centre_line = Centreline(mask)
    truth = np.array([0.3, -0.7])
    uv = centre_line.uv_px[::3] - truth
    shift, cost = fit_view_shift(centre_line, uv, np.ones(len(uv)), (2.0, 1.0))
    assert np.allclose(shift, truth, atol=0.1) and cost < 0.05


def test_polish_brings_a_view_back_to_within_half_a_pixel():
    # Three views of one tube; view 2's mask content moved by (1.6, -2.3) px; the others are right.
    projections = _views()
    curve = _curve()
    truth = np.array([1.6, -2.3])
    masks = [_tube_mask(p, curve, 1.2) for p in projections[:2]]
    masks.append(_tube_mask(projections[2].shifted(*truth), curve, 1.2))
    shifts = polish_shifts(projections, [Centreline(m) for m in masks], np.zeros((3, 2)))
    # The shifts are fixed up to a common 3D translation t (every view moved by J_v t, J_v the
    # Jacobian at the isocentre): compare after removing the t that best explains the difference.
    truths = np.array([[0.0, 0.0], [0.0, 0.0], truth])
    assert geometry_error_px([_jacobian(p) for p in projections], shifts, truths) < 0.5


def test_polish_needs_three_views():
    case = make_case(SynthOptions(seed=1, views="clinical"))
    projections = [v.projection for v in case.views][:2]
    with pytest.raises(ValueError, match="three views"):
        polish_shifts(projections, [Centreline(v.mask) for v in case.views[:2]], np.zeros((2, 2)))


def _shifted_tube(view2_shift_px):
    """The views of :func:`_views`, the centrelines of one tube seen in them with view 2's mask
    content moved by ``view2_shift_px``, and the true shifts."""
    projections = _views()
    truth = np.array([[0.0, 0.0], [0.0, 0.0], view2_shift_px])
    masks = [_tube_mask(p.shifted(*s), _curve(), 1.2) for p, s in zip(projections, truth)]
    return projections, [Centreline(m) for m in masks], truth


def test_joint_fit_lowers_the_summed_cost_without_moving_the_object():
    # Three views of one tube; view 2's mask content moved by (1.6, -2.3) px. The joint fit starts
    # from no correction and walks only across the directions a common 3D translation leaves open.
    projections, centre_lines, truth = _shifted_tube((1.6, -2.3))
    jacobians = [_jacobian(p) for p in projections]
    gauge = np.vstack(jacobians)
    start = np.zeros((3, 2))
    shifts, cost = fit_jointly(projections, centre_lines, start, gauge)
    assert cost == pytest.approx(consistency_cost(projections, centre_lines, shifts))
    assert cost < consistency_cost(projections, centre_lines, start)
    # orthogonal to every translation column: the object stays where it was
    np.testing.assert_allclose(gauge.T @ (shifts - start).ravel(), 0.0, atol=1e-9)
    assert geometry_error_px(jacobians, shifts, truth) < 0.3


def test_joint_fit_of_some_views_holds_the_others():
    # The tube of the test above, view 2 moved by (3.6, -2.3) px. Only view 2 may move: views 0 and
    # 1 keep their (exact) shifts bit for bit, and view 2 comes back to the truth from 4 px away.
    projections, centre_lines, truth = _shifted_tube((3.6, -2.3))
    gauge = np.vstack([_jacobian(p) for p in projections])
    shifts, cost = fit_jointly(projections, centre_lines, np.zeros((3, 2)), gauge, views=[2], reach_px=4)
    np.testing.assert_array_equal(shifts[:2], 0.0)
    assert np.linalg.norm(shifts[2] - truth[2]) < 0.3
    assert cost == pytest.approx(consistency_cost(projections, centre_lines, shifts))


def test_a_scale_that_trades_against_a_shift_is_found_jointly():
    # A generated tree whose view 0 is 10 % too large (its image scaled about the centre, which is
    # the principal point). Its vessels lie off the principal point, so a smaller scale plus a shift
    # explains it almost as well: the calibration's view-by-view fit once stopped at 1.073 with a
    # 3 px shift (the paper's rasteriser). Scaling about the vessels' own centroid, jointly with
    # every view's shift, goes from 1.05 to 1.1, at a lower summed cost than that trade-off.
    case = make_case(SynthOptions(seed=10, views="clinical", rasteriser="exact", corruptions=("scale=1.1",)))
    projections = [v.projection for v in case.views]
    centre_lines = [Centreline(v.mask) for v in case.views]
    scales = np.array([1.05, 1.0, 1.0])
    gauge = np.vstack([_jacobian(p.magnified(f)) for p, f in zip(projections, scales)])
    fitted_scales, shifts, cost = fit_scales_jointly(projections, centre_lines, scales, np.zeros((3, 2)), [0], gauge,
                                                     cutoff_px=1.0)
    assert fitted_scales[0] == pytest.approx(1.1, abs=0.005)
    np.testing.assert_array_equal(fitted_scales[1:], 1.0)
    # what is left of the shifts is a common 3D translation (the true shifts are 0)
    assert geometry_error_px([_jacobian(p.magnified(f)) for p, f in zip(projections, fitted_scales)], shifts,
                             np.zeros((3, 2))) < 0.5

    def summed(factor, view0_shift):
        return consistency_cost([projections[0].magnified(factor), *projections[1:]], centre_lines,
                                np.array([view0_shift, (0.0, 0.0), (0.0, 0.0)]), cutoff_px=1.0)

    assert cost == pytest.approx(consistency_cost([p.magnified(f) for p, f in zip(projections, fitted_scales)],
                                                  centre_lines, shifts, cutoff_px=1.0))
    assert cost < summed(1.073, (2.9, 2.6))
