"""Tree scores (angiohull.metrics.tree) against hand-worked cases and brute-force references."""

import math

import numpy as np
import pytest
from scipy import integrate
from scipy.spatial import cKDTree

from angiohull.errors import TreeError
from angiohull.metrics import TreeScores, centerline_samples, distance_to_centerline, overlap_key, tree_scores
from angiohull.metrics.tree import undefined_scores
from angiohull.tree.model import Branch, VesselTree
from angiohull.tree.solid import contains


def line(a, b, n=2, radius=1.0, parent=None, parent_point=None):
    return Branch(np.linspace(a, b, n), radius, parent, parent_point)


def single(a, b, radius=1.0, n=2):
    return VesselTree((line(a, b, n, radius),))


def shifted(tree, offset):
    m = np.eye(4)
    m[:3, 3] = offset
    return tree.transformed(m)


T20 = single([0, 0, 0], [20, 0, 0])  # a straight 20 mm branch of radius 1 along x


# -- hand-worked cases ------------------------------------------------------------------------------

def test_parallel_line_every_distance_is_the_offset():
    # R: the same 20 mm line moved 0.7 mm along y (perpendicular: the ends too are 0.7 mm apart),
    # radius 1.2 against the true 1.0
    r = single([0, 0.7, 0], [20, 0.7, 0], radius=1.2)
    s = tree_scores(r, T20)
    assert s.centerline_mean_mm == pytest.approx(0.7, abs=1e-12)
    assert s.centerline_mean_true_to_rec_mm == pytest.approx(0.7, abs=1e-12)
    assert s.centerline_mean_rec_to_true_mm == pytest.approx(0.7, abs=1e-12)
    assert s.centerline_p95_mm == pytest.approx(0.7, abs=1e-12)
    assert s.centerline_hausdorff_mm == pytest.approx(0.7, abs=1e-12)
    d = s.as_dict()
    assert (d["ot05mm"], d["ot1mm"], d["ot2mm"]) == (0.0, 1.0, 1.0)
    assert (d["ot05mm_reverse"], d["ot1mm_reverse"], d["ot2mm_reverse"]) == (0.0, 1.0, 1.0)
    # error r_R - r_T = 1.2 - 1.0 everywhere, every true point within its radius (0.7 <= 1)
    assert s.radius_bias_mm == pytest.approx(0.2, abs=1e-12)
    assert s.radius_mae_mm == pytest.approx(0.2, abs=1e-12)
    assert s.radius_rmse_mm == pytest.approx(0.2, abs=1e-12)
    assert s.radius_matched_share == pytest.approx(1.0, abs=1e-12)
    # 0.7 < 1.2 (T's centerline in R's solid) and 0.7 < 1.0 (R's in T's)
    assert (s.cldice_sensitivity, s.cldice_precision, s.cldice) == (1.0, 1.0, 1.0)
    assert (s.branch_recall, s.branches_true, s.branches_found) == (1.0, 1, 1)
    assert (s.branch_precision, s.branches_reconstructed) == (1.0, 1)
    assert (s.bifurcations_true, s.bifurcations_reconstructed, s.bifurcations_matched) == (0, 0, 0)
    assert math.isnan(s.bifurcation_error_mm)


def test_partial_cover_of_a_line():
    # R: the first c = 12 mm of T's 20 mm line. A true point at x has distance max(0, x - c).
    c, L = 12.0, 20.0
    s = tree_scores(single([0, 0, 0], [c, 0, 0]), T20)
    # within d of R: x <= c + d
    for d in (0.5, 1.0, 2.0):
        assert s.as_dict()[overlap_key(d)] == pytest.approx((c + d) / L, abs=1e-12)
        assert s.as_dict()[overlap_key(d) + "_reverse"] == 1.0
    assert s.centerline_mean_true_to_rec_mm == pytest.approx((L - c) ** 2 / 2 / L, abs=1e-12)  # (8²/2)/20 = 1.6
    assert s.centerline_mean_rec_to_true_mm == pytest.approx(0.0, abs=1e-12)
    assert s.centerline_mean_mm == pytest.approx((L - c) ** 2 / 2 / L / 2, abs=1e-12)
    # 95 % of T's length: c + v = 0.95 L
    assert s.centerline_p95_mm == pytest.approx(0.95 * L - c, abs=1e-9)
    assert s.centerline_hausdorff_mm == pytest.approx(L - c, abs=1e-12)
    # found: the part within radius 1 is c + 1 = 13 mm > L / 2
    assert (s.branch_recall, s.branches_found) == (1.0, 1)
    assert s.branch_precision == 1.0
    # clDice: T inside R's capsule up to x = c + 1; R wholly inside T's solid
    assert s.cldice_sensitivity == pytest.approx((c + 1) / L, abs=1e-12)
    assert s.cldice_precision == 1.0
    assert s.cldice == pytest.approx(2 * (c + 1) / L / ((c + 1) / L + 1), abs=1e-12)
    assert s.radius_matched_share == pytest.approx((c + 1) / L, abs=1e-12)
    assert s.radius_bias_mm == pytest.approx(0.0, abs=1e-12)

    # R of 8.5 mm: 8.5 + 1 = 9.5 mm within the radius, not more than half of 20 mm
    short = tree_scores(single([0, 0, 0], [8.5, 0, 0]), T20)
    assert (short.branch_recall, short.branches_true, short.branches_found) == (0.0, 1, 0)
    # R's only branch is shorter than min_branch_mm: nothing to score precision on
    assert short.branches_reconstructed == 0 and math.isnan(short.branch_precision)


def test_tilted_line_crossing_the_radius():
    # R from the origin to (20, p, 0), radius 1: a true point (x, 0, 0) is x sin(a) from R's line (its
    # foot stays on the segment) and R's point at arc u is u sin(a) from T's, sin(a) = p / |R|
    p = 1.5
    length_r = math.hypot(20.0, p)
    sin_a = p / length_r
    reach = 1 / sin_a  # the distance is 1 at x = 1 / sin(a), and at u = 1 / sin(a)
    s = tree_scores(single([0, 0, 0], [20, p, 0]), T20, overlap_mm=(1.0,))
    sens, prec = reach / 20, reach / length_r
    assert s.cldice_sensitivity == pytest.approx(sens, abs=1e-12)
    assert s.cldice_precision == pytest.approx(prec, abs=1e-12)
    assert s.cldice == pytest.approx(2 * sens * prec / (sens + prec), abs=1e-12)
    assert s.as_dict()["ot1mm"] == pytest.approx(sens, abs=1e-12)
    assert s.as_dict()["ot1mm_reverse"] == pytest.approx(prec, abs=1e-12)
    assert s.centerline_mean_true_to_rec_mm == pytest.approx(10 * sin_a, abs=1e-12)
    assert s.centerline_mean_rec_to_true_mm == pytest.approx(length_r / 2 * sin_a, abs=1e-12)
    assert s.centerline_hausdorff_mm == pytest.approx(p, abs=1e-12)  # R's end, p mm off T
    # the distance along each is linear from 0: its 95th percentile is 0.95 of its largest value
    assert s.centerline_p95_mm == pytest.approx(0.95 * p, abs=1e-9)
    # 13.4 mm of each within radius 1: more than half of 20 mm and of 20.06 mm
    assert (s.branch_recall, s.branch_precision) == (1.0, 1.0)
    # the radius matched where the distance <= 1, the error 0 there
    assert s.radius_matched_share == pytest.approx(sens, abs=1e-12)
    assert s.radius_mae_mm == pytest.approx(0.0, abs=1e-12)


def test_cldice_of_parallel_lines_one_mm_apart():
    thin = tree_scores(single([0, 1, 0], [20, 1, 0], radius=0.5), single([0, 0, 0], [20, 0, 0], radius=0.5))
    assert (thin.cldice_sensitivity, thin.cldice_precision, thin.cldice) == (0.0, 0.0, 0.0)
    thick = tree_scores(single([0, 1, 0], [20, 1, 0], radius=1.5), single([0, 0, 0], [20, 0, 0], radius=1.5))
    assert (thick.cldice_sensitivity, thick.cldice_precision, thick.cldice) == (1.0, 1.0, 1.0)
    # a thick R around a thin T: T's centerline is inside R's solid, not the reverse
    mixed = tree_scores(single([0, 1, 0], [20, 1, 0], radius=1.5), single([0, 0, 0], [20, 0, 0], radius=0.5))
    assert (mixed.cldice_sensitivity, mixed.cldice_precision, mixed.cldice) == (1.0, 0.0, 0.0)
    # and nothing matched for the radius (1 mm > the true 0.5 mm)
    assert mixed.radius_matched_share == 0.0 and math.isnan(mixed.radius_mae_mm)
    assert math.isnan(mixed.radius_rmse_mm) and math.isnan(mixed.radius_bias_mm)


def test_radius_errors_integrate_a_linear_error_exactly():
    # R on T's line with radius 0.45 -> 1.45: e(x) = -0.55 + x / 20, zero at x = 11, between samples
    # at a 0.3 mm step (20 / 67 mm apart). Over the 20 mm: mean e = -0.05, mean |e| = (0.55² + 0.45²) / 2,
    # mean e² = (0.55³ + 0.45³) / 3 (e runs over [-0.55, 0.45] uniformly).
    r = VesselTree((Branch(np.array([[0.0, 0, 0], [20, 0, 0]]), np.array([0.45, 1.45])),))
    s = tree_scores(r, T20, sample_step_mm=0.3)
    assert s.radius_bias_mm == pytest.approx(-0.05, abs=1e-12)
    assert s.radius_mae_mm == pytest.approx((0.55 ** 2 + 0.45 ** 2) / 2, abs=1e-12)
    assert s.radius_rmse_mm == pytest.approx(math.sqrt((0.55 ** 3 + 0.45 ** 3) / 3), abs=1e-12)
    assert s.radius_matched_share == pytest.approx(1.0, abs=1e-12)


# -- branches and bifurcations ----------------------------------------------------------------------

MAIN = line([0, 0, 0], [30, 0, 0], 31)  # 30 mm, points 1 mm apart
SIDE_A = line([10, 0, 0], [10, 15, 0], 16, 0.8, 0, 10)  # 15 mm, leaves main at x = 10
SIDE_B = line([20, 0, 0], [20, 0, 12], 13, 0.8, 0, 20)  # 12 mm, leaves main at x = 20
Y = VesselTree((MAIN, SIDE_A, SIDE_B))


def test_identical_trees_score_perfectly():
    s = tree_scores(Y, Y)
    assert s.centerline_mean_mm == 0.0 and s.centerline_hausdorff_mm == 0.0
    assert s.overlap == (1.0, 1.0, 1.0) and s.overlap_reverse == (1.0, 1.0, 1.0)
    assert s.cldice == 1.0 and s.radius_matched_share == 1.0
    # the one tie: a side branch's first sample is as near to R's main branch (radius 1) as to R's
    # side branch (0.8); the first in tree order wins (main): an error of 0.2 mm at that sample,
    # 0 at the next (0.1 mm on), at each of the two junctions
    expected = 2 * (0.2 * 0.1 / 2) / Y.length_mm
    assert s.radius_mae_mm == pytest.approx(expected, abs=1e-12)
    assert s.radius_bias_mm == pytest.approx(expected, abs=1e-12)
    assert (s.branch_recall, s.branch_precision, s.branches_true, s.branches_reconstructed) == (1.0, 1.0, 3, 3)
    assert (s.bifurcations_true, s.bifurcations_reconstructed, s.bifurcations_matched) == (2, 2, 2)
    assert s.bifurcation_error_mm == 0.0


def test_missing_side_branch_lowers_recall():
    s = tree_scores(VesselTree((MAIN, SIDE_A)), Y)
    # SIDE_B is within its radius 0.8 of R's main over its first 0.8 mm only: 0.8 / 12 < 1/2
    assert (s.branches_true, s.branches_found) == (3, 2)
    assert s.branch_recall == pytest.approx(2 / 3)
    assert (s.branch_precision, s.branches_reconstructed) == (1.0, 2)
    assert (s.bifurcations_true, s.bifurcations_reconstructed, s.bifurcations_matched) == (2, 1, 1)
    assert s.bifurcation_error_mm == 0.0
    # T within 1 mm of R: all but SIDE_B beyond z = 1
    assert s.as_dict()["ot1mm"] == pytest.approx((30 + 15 + 1) / (30 + 15 + 12), abs=1e-12)


def test_phantom_branch_lowers_precision():
    phantom = Branch(np.array([[100.0, 100, 100], [100, 100, 120]]), 1.0, 0, 30)  # 20 mm, far from T
    s = tree_scores(VesselTree((MAIN, SIDE_A, SIDE_B, phantom)), Y)
    assert (s.branches_reconstructed, s.branch_precision) == (4, pytest.approx(3 / 4))
    assert s.branch_recall == 1.0
    length_r = 30 + 15 + 12 + 20
    assert s.as_dict()["ot2mm_reverse"] == pytest.approx((length_r - 20) / length_r, abs=1e-12)
    assert s.as_dict()["ot2mm"] == 1.0
    # the phantom's point (100, 100, 100 + z) is nearest to SIDE_B's tip (20, 0, 12)
    integral, _ = integrate.quad(lambda z: math.sqrt(80 ** 2 + 100 ** 2 + (88 + z) ** 2), 0, 20)
    assert s.centerline_mean_rec_to_true_mm == pytest.approx(integral / length_r, rel=1e-6)
    assert s.centerline_mean_true_to_rec_mm == 0.0
    # a third bifurcation in R (where the phantom leaves main, x = 30): the two true ones match
    assert (s.bifurcations_true, s.bifurcations_reconstructed, s.bifurcations_matched) == (2, 3, 2)


def test_bifurcation_offset_within_and_beyond_the_match_distance():
    t = VesselTree((MAIN, SIDE_A))  # one bifurcation at (10, 0, 0), the tree in the plane z = 0
    near = tree_scores(shifted(t, [0, 0, 1.5]), t)  # moved 1.5 mm perpendicular to its plane
    assert (near.bifurcations_matched, near.bifurcation_error_mm) == (1, pytest.approx(1.5, abs=1e-12))
    assert near.centerline_mean_mm == pytest.approx(1.5, abs=1e-12)
    assert near.centerline_hausdorff_mm == pytest.approx(1.5, abs=1e-12)
    assert (near.as_dict()["ot1mm"], near.as_dict()["ot2mm"]) == (0.0, 1.0)
    far = tree_scores(shifted(t, [0, 0, 6.0]), t)
    assert (far.bifurcations_true, far.bifurcations_reconstructed, far.bifurcations_matched) == (1, 1, 0)
    assert math.isnan(far.bifurcation_error_mm)
    assert tree_scores(shifted(t, [0, 0, 6.0]), t, bifurcation_match_mm=6.5).bifurcations_matched == 1


def test_bifurcation_matching_keeps_the_most_pairs():
    # true bifurcations a = (0, 0), b = (4, 0); reconstructed c = (4, 0.5), d = (4.5, -4.9) (z = 0).
    # |a-c| = 4.03, |b-d| = 4.93 (both <= 5), |a-d| = 6.65 (> 5), |b-c| = 0.5: the cheapest assignment
    # (a-d, b-c: 7.15 < 8.96) would keep one pair; the matching keeps both.
    up = [0, 0, 10]
    t_main = Branch(np.array([[-5.0, 0, 0], [0, 0, 0], [4, 0, 0], [10, 0, 0]]), 1.0)
    t = VesselTree((t_main, line([0, 0, 0], up, 2, 1.0, 0, 1), line([4, 0, 0], [4, 0, 10], 2, 1.0, 0, 2)))
    r_main = Branch(np.array([[-5.0, 0.5, 0], [4, 0.5, 0], [4.5, -4.9, 0], [10, -4.9, 0]]), 1.0)
    r = VesselTree((r_main, line([4, 0.5, 0], [4, 0.5, 10], 2, 1.0, 0, 1),
                    line([4.5, -4.9, 0], [4.5, -4.9, 10], 2, 1.0, 0, 2)))
    s = tree_scores(r, t)
    assert s.bifurcations_matched == 2
    assert s.bifurcation_error_mm == pytest.approx((math.hypot(4, 0.5) + math.hypot(0.5, 4.9)) / 2, abs=1e-12)


def test_short_branches_are_not_counted():
    short = line([10, 0, 0], [10, 8, 0], 9, 0.8, 0, 10)  # 8 mm < 10 mm
    s = tree_scores(VesselTree((MAIN,)), VesselTree((MAIN, short)))
    assert (s.branches_true, s.branches_found, s.branch_recall) == (1, 1, 1.0)
    assert tree_scores(VesselTree((MAIN,)), VesselTree((MAIN, short)), min_branch_mm=5).branches_true == 2
    exact = line([10, 0, 0], [10, 10, 0], 2, 0.8, 0, 10)  # exactly min_branch_mm long: counted
    assert tree_scores(VesselTree((MAIN, exact)), VesselTree((MAIN, exact))).branches_true == 2


def test_scores_are_symmetric_where_stated():
    r = VesselTree((MAIN, SIDE_A, Branch(SIDE_B.points_mm + [0.4, 0.3, 0], 0.6, 0, 20)))
    a, b = tree_scores(r, Y), tree_scores(Y, r)
    for key in ("centerline_mean_mm", "centerline_p95_mm", "centerline_hausdorff_mm", "cldice",
                "bifurcation_error_mm"):
        assert getattr(a, key) == pytest.approx(getattr(b, key), abs=1e-12), key
    assert a.overlap == pytest.approx(b.overlap_reverse, abs=1e-12)
    assert a.cldice_sensitivity == pytest.approx(b.cldice_precision, abs=1e-12)
    assert a.centerline_mean_true_to_rec_mm == pytest.approx(b.centerline_mean_rec_to_true_mm, abs=1e-12)
    assert (a.bifurcations_true, a.bifurcations_matched) == (b.bifurcations_reconstructed, b.bifurcations_matched)


def test_as_dict_keys_and_types():
    d = tree_scores(Y, Y).as_dict()
    assert list(d) == [
        "centerline_mean_mm", "centerline_mean_true_to_rec_mm", "centerline_mean_rec_to_true_mm",
        "centerline_p95_mm", "centerline_hausdorff_mm", "ot05mm", "ot1mm", "ot2mm",
        "ot05mm_reverse", "ot1mm_reverse", "ot2mm_reverse", "cldice_sensitivity", "cldice_precision", "cldice",
        "radius_mae_mm", "radius_rmse_mm", "radius_bias_mm", "radius_matched_share", "branch_recall",
        "branches_true", "branches_found", "branch_precision", "branches_reconstructed", "bifurcations_true",
        "bifurcations_reconstructed", "bifurcations_matched", "bifurcation_error_mm"]
    counts = {k for k in d if k.startswith(("branches_", "bifurcations_"))}
    assert all(type(d[k]) is int for k in counts)
    assert all(type(v) is float for k, v in d.items() if k not in counts)
    custom = tree_scores(Y, Y, overlap_mm=[1.5, 0.25]).as_dict()
    assert [k for k in custom if k.startswith("ot")] == ["ot15mm", "ot025mm", "ot15mm_reverse", "ot025mm_reverse"]
    assert (overlap_key(0.5), overlap_key(1.0), overlap_key(2), overlap_key(1.5)) == ("ot05mm", "ot1mm", "ot2mm",
                                                                                          "ot15mm")
    assert isinstance(tree_scores(Y, Y), TreeScores)


# -- sampling and exact distances against brute force ----------------------------------------------

def random_curve(rng, length, step=0.5):
    """A smooth random course: a straight run plus two perpendicular sine bends, vertices ~step apart."""
    s = np.arange(0.0, length + 1e-9, step)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    v = np.cross(u, rng.normal(size=3))
    v /= np.linalg.norm(v)
    w = np.cross(u, v)
    amp, freq, phase = rng.uniform(1, 4, 2), rng.uniform(0.05, 0.3, 2), rng.uniform(0, 2 * np.pi, 2)
    return (rng.uniform(-5, 5, 3) + s[:, None] * u + amp[0] * np.sin(freq[0] * s + phase[0])[:, None] * v
            + amp[1] * np.sin(freq[1] * s + phase[1])[:, None] * w)


def random_tree(rng, n_branches=3, length=(20, 45)):
    branches = []
    for i in range(n_branches):
        points = random_curve(rng, rng.uniform(*length))
        radius = rng.uniform(0.5, 2.0, len(points))
        if i == 0:
            branches.append(Branch(points, radius))
        else:
            parent = int(rng.integers(0, i))
            branches.append(Branch(points, radius, parent, int(rng.integers(0, branches[parent].n_points))))
    # and a long straight two-point branch (long segments next to short ones)
    branches.append(Branch(np.array([rng.uniform(-20, 20, 3), rng.uniform(-20, 20, 3) + 40]), 1.0, 0, 0))
    return VesselTree(tuple(branches))


def dense(tree, step=0.001):
    """Points every `step` or less along every branch (arc length), with their branch."""
    out, owner = [], []
    for i, b in enumerate(tree.branches):
        arc = b.arc_length_mm
        s = np.linspace(0, arc[-1], int(np.ceil(arc[-1] / step)) + 1)
        out.append(np.column_stack([np.interp(s, arc, b.points_mm[:, k]) for k in range(3)]))
        owner.append(np.full(len(s), i))
    return np.concatenate(out), np.concatenate(owner)


def brute_force(points, tree):
    """Distance, radius and branch of the nearest point over all segments (an (N, S) table)."""
    a = np.concatenate([b.points_mm[:-1] for b in tree.branches])
    e = np.concatenate([b.points_mm[1:] for b in tree.branches])
    ra = np.concatenate([b.radius_mm[:-1] for b in tree.branches])
    rb = np.concatenate([b.radius_mm[1:] for b in tree.branches])
    owner = np.concatenate([np.full(b.n_points - 1, i) for i, b in enumerate(tree.branches)])
    ab = e - a
    t = np.clip(np.einsum("nsj,sj->ns", points[:, None] - a[None], ab) / (ab * ab).sum(1), 0, 1)
    d = np.linalg.norm(points[:, None] - (a[None] + t[..., None] * ab[None]), axis=2)
    j = d.argmin(axis=1)
    rows = np.arange(len(points))
    second = np.partition(d, 1, axis=1)[:, 1]
    return d[rows, j], ra[j] + t[rows, j] * (rb[j] - ra[j]), owner[j], second - d[rows, j]


def test_distance_to_centerline_is_exact():
    rng = np.random.default_rng(20240611)
    for _ in range(3):
        tree = random_tree(rng)
        other = random_tree(rng)
        lo, hi = tree.bounding_box_mm()
        queries = np.concatenate([rng.uniform(lo - 10, hi + 10, (600, 3)),
                                  centerline_samples(other, 0.5)[0][::3],
                                  centerline_samples(tree, 0.5)[0][::5] + rng.normal(0, 0.3, (1, 3))])
        distance, closest, radius, branch = distance_to_centerline(queries, tree)
        exact, exact_radius, exact_branch, gap = brute_force(queries, tree)
        np.testing.assert_allclose(distance, exact, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(queries - closest, axis=1), exact, rtol=0, atol=1e-9)
        clear = gap > 1e-6  # a unique nearest segment: the same radius and branch
        np.testing.assert_allclose(radius[clear], exact_radius[clear], rtol=0, atol=1e-9)
        assert np.array_equal(branch[clear], exact_branch[clear])
        # the closest points lie on the centerline
        np.testing.assert_allclose(distance_to_centerline(closest, tree)[0], 0, atol=1e-9)
        # a dense sampling (0.001 mm) is never nearer, and at most half its spacing farther
        points, _ = dense(tree)
        reference = cKDTree(points).query(queries)[0]
        assert np.all(reference - distance >= -1e-9) and np.all(reference - distance <= 1e-3)


def test_centerline_samples_cover_each_branch_evenly():
    rng = np.random.default_rng(5)
    tree = random_tree(rng)
    points, weights, radius, branch = centerline_samples(tree, 0.3)
    assert weights.sum() == pytest.approx(tree.length_mm, rel=1e-12)
    for i, b in enumerate(tree.branches):
        own = branch == i
        n = int(np.ceil(b.length_mm / 0.3))
        assert own.sum() == n + 1
        np.testing.assert_array_equal(points[own][[0, -1]], b.points_mm[[0, -1]])
        np.testing.assert_allclose(radius[own][[0, -1]], b.radius_mm[[0, -1]], rtol=0, atol=1e-12)
        h = b.length_mm / n
        np.testing.assert_allclose(weights[own], np.r_[h / 2, np.full(n - 1, h), h / 2], rtol=1e-12)
        # evenly spaced in arc length: each sample at arc k h on its own polyline
        arc = b.arc_length_mm
        expected = np.column_stack([np.interp(np.arange(n + 1) * h, arc, b.points_mm[:, k]) for k in range(3)])
        np.testing.assert_allclose(points[own], expected, rtol=0, atol=1e-9)
        np.testing.assert_allclose(radius[own], np.interp(np.arange(n + 1) * h, arc, b.radius_mm), rtol=0, atol=1e-9)


def test_scores_converge_to_a_dense_reference():
    rng = np.random.default_rng(11)
    t = random_tree(rng)
    # R: T bent by a smooth offset of up to 0.8 mm along x and y each, thinner
    def bend(p):
        return p + 0.8 * np.column_stack([np.sin(0.2 * p[:, 1]), np.cos(0.15 * p[:, 2]), 0 * p[:, 0]])
    r = VesselTree(tuple(Branch(bend(b.points_mm), 0.5 * b.radius_mm, b.parent, b.parent_point) for b in t.branches))
    s = tree_scores(r, t)
    t_dense, r_dense = dense(t, 0.005), dense(r, 0.005)
    # uniform dense samples: plain means and quantiles are length-weighted ones
    d = cKDTree(dense(r, 0.001)[0]).query(t_dense[0])[0]
    back = cKDTree(dense(t, 0.001)[0]).query(r_dense[0])[0]
    assert 0.2 < s.centerline_mean_mm < 2
    assert s.centerline_mean_true_to_rec_mm == pytest.approx(d.mean(), abs=2e-3)
    assert s.centerline_mean_rec_to_true_mm == pytest.approx(back.mean(), abs=2e-3)
    for threshold in (0.5, 1.0, 2.0):
        assert s.as_dict()[overlap_key(threshold)] == pytest.approx((d <= threshold).mean(), abs=2e-3)
        assert s.as_dict()[overlap_key(threshold) + "_reverse"] == pytest.approx((back <= threshold).mean(), abs=2e-3)
    assert s.centerline_p95_mm == pytest.approx(max(np.quantile(d, 0.95), np.quantile(back, 0.95)), abs=5e-3)
    assert s.centerline_hausdorff_mm == pytest.approx(max(d.max(), back.max()), abs=0.05)
    # clDice against contains() at the dense samples
    assert s.cldice_sensitivity == pytest.approx(contains(r, t_dense[0][::4]).mean(), abs=2e-3)
    assert s.cldice_precision == pytest.approx(contains(t, r_dense[0][::4]).mean(), abs=2e-3)
    assert 0.05 < s.cldice_sensitivity < 0.99  # T in part outside the thinner R
    assert 0.05 < s.overlap[0] < 0.95 and 0.05 < s.overlap[1] < 0.99  # within 0.5 mm and 1 mm: in part


# -- bad input ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, match", [
    ({"sample_step_mm": 0}, "sample_step_mm"),
    ({"sample_step_mm": -0.1}, "sample_step_mm"),
    ({"sample_step_mm": float("nan")}, "sample_step_mm"),
    ({"overlap_mm": ()}, "overlap_mm.*at least one"),
    ({"overlap_mm": [1.0, -2]}, r"overlap_mm\[1\]"),
    ({"overlap_mm": "1"}, "overlap_mm"),
    ({"overlap_mm": (1.5, 15)}, "clashing"),
    ({"min_branch_mm": -1}, "min_branch_mm"),
    ({"bifurcation_match_mm": 0}, "bifurcation_match_mm"),
    ({"sample_step_mm": 1e-9}, "larger step"),
])
def test_bad_options_are_rejected(kwargs, match):
    with pytest.raises(TreeError, match=match):
        tree_scores(T20, T20, **kwargs)


def test_bad_trees_and_points_are_rejected():
    with pytest.raises(TreeError, match="reconstructed must be a VesselTree, got ndarray"):
        tree_scores(np.zeros((4, 3)), T20)
    with pytest.raises(TreeError, match="truth must be a VesselTree, got Branch"):
        tree_scores(T20, T20.root)
    with pytest.raises(TypeError):
        tree_scores(T20, T20, 0.1)  # options are keyword-only
    with pytest.raises(TreeError, match="step_mm"):
        centerline_samples(T20, 0)
    with pytest.raises(TreeError, match=r"\(N, 3\)"):
        distance_to_centerline(np.zeros((3, 2)), T20)
    with pytest.raises(TreeError, match="VesselTree"):
        distance_to_centerline(np.zeros((3, 3)), [T20])
    empty = distance_to_centerline(np.zeros((0, 3)), T20)
    assert [a.shape for a in empty] == [(0,), (0, 3), (0,), (0,)]


def test_undefined_scores_have_the_keys_of_a_score_and_the_truths_counts():
    t = random_tree(np.random.default_rng(5), n_branches=4, length=(12, 20))
    undefined = undefined_scores(t)
    scored = tree_scores(t, t).as_dict()
    assert list(undefined) == list(scored)
    assert undefined["branches_true"] == scored["branches_true"]
    assert undefined["bifurcations_true"] == scored["bifurcations_true"]
    assert math.isnan(undefined["centerline_mean_mm"]) and undefined["branches_found"] == 0
