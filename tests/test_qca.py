"""Quantitative coronary analysis (angiohull.qca) against closed forms and hand-worked trees.

Every tree here is built by hand (straight or gently curved polylines, radii from analytic
profiles), so each expected value comes from a formula, not from the code under test:

* stenoses: a straight taper ``ref(a) = 3.0 - 0.01 a`` (3.0 -> 2.4 mm over 60 mm) times a
  raised-cosine or Gaussian window of severity ``s`` and extent ``L``;
* bifurcations: straight arms at known angles;
* views: straight segments through the isocentre, whose foreshortening is ``sin`` of the angle to
  the ray and whose overlap follows from the module's definition in closed form.
"""

import json
import math
import re

import numpy as np
import pytest
from scipy.optimize import brentq

from angiohull.errors import QcaError
from angiohull.geometry import CArmGeometry, parse_clinical_angles
from angiohull.qca import (BRANCH_COLUMNS, LESION_COLUMNS, ProfileSettings, QcaSettings, ViewMapSettings,
                           analyse_bifurcations, analyse_tree, branch_profile, foreshortening, segment_view_map,
                           view_map, window_lesion_length_mm)
from angiohull.qca.profile import smoothed_along
from angiohull.qca.vessels import VesselSettings, tree_vessels
from angiohull.qca.views import carm_for, carm_frames, view_report
from angiohull.tree import Branch, VesselTree

NO_VIEWS = QcaSettings(lesion_views=False)  # the profile / bifurcation tests need no view maps
SOD = 800.0

# The robust reference is a least-squares line over the points it keeps: a window's shallow tails
# (dips under k_low x noise floor = 2.5 x 1 % x median diameter, about 0.067 mm) stay in and lower
# the line by their mean. Measured over every (profile, s, L, step) below: at most 3.4e-3 mm
# (Gaussian, s = 0.3, L = 16); the cosine windows (compact support) at most 1.5e-3 mm.
REF_TOL_MM = 4e-3


def taper(a):
    """The healthy reference diameter (mm) at arc length ``a`` (mm): 3.0 -> 2.4 over 60 mm."""
    return 3.0 - 0.01 * np.asarray(a, dtype=np.float64)


def window(kind, x, s, extent):
    """The synthetic generator's windows: diameter factor at offset ``x`` from the centre."""
    x = np.asarray(x, dtype=np.float64)
    if kind == "cosine":
        return np.where(np.abs(x) <= extent / 2, 1.0 - s * 0.5 * (1.0 + np.cos(2 * np.pi * x / extent)), 1.0)
    sigma = extent / 6.0
    return 1.0 - s * np.exp(-x * x / (2 * sigma * sigma))


def window_rise(kind, h, extent):
    """An upper bound on ``(w(h) - w(0)) / s``: how much shallower the window is ``h`` off centre
    (1 - cos u <= u^2 / 2 for the cosine, 1 - exp(-t) <= t for the Gaussian)."""
    if kind == "cosine":
        return (math.pi * h / extent) ** 2
    return h * h / (2 * (extent / 6.0) ** 2)


def polyline(arc, direction=(1.0, 0.0, 0.0), origin=(0.0, 0.0, 0.0)):
    u = np.asarray(direction, dtype=np.float64)
    u = u / np.linalg.norm(u)
    return np.asarray(origin, dtype=np.float64) + np.asarray(arc, dtype=np.float64)[:, None] * u


def arcs(length, step):
    return np.linspace(0.0, length, int(round(length / step)) + 1)


def tube(diameter, length=60.0, step=0.25):
    """A single straight branch along +x with ``diameter(arc)`` (mm)."""
    a = arcs(length, step)
    return VesselTree((Branch(polyline(a), 0.5 * diameter(a), name="tube"),))


def rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    m = np.eye(4)
    m[:3, :3] = q * np.sign(np.linalg.det(q))
    m[:3, 3] = [3.0, -7.0, 11.0]
    return m


# -- 1. analytic stenoses -------------------------------------------------------------------------

@pytest.mark.parametrize("edge", [0.1, 0.25, 0.5, 0.75])
@pytest.mark.parametrize("extent", [6.0, 10.0, 16.0])
def test_window_lesion_length_closed_forms(extent, edge):
    # defaults: 2L/3 (cosine) and (L/3) sqrt(2 ln 4) (Gaussian, sigma = L/6)
    assert window_lesion_length_mm("cosine", extent) == pytest.approx(2 * extent / 3, rel=1e-12)
    assert window_lesion_length_mm("gaussian", extent) == pytest.approx(extent / 3 * math.sqrt(2 * math.log(4)),
                                                                        rel=1e-12)
    # any edge fraction: twice the offset where the narrowing s (1 - w) / s falls to `edge` of its peak
    for kind in ("cosine", "gaussian"):
        half = brentq(lambda x: (1.0 - float(window(kind, x, 1.0, extent))) - edge, 1e-12, extent / 2 if
                      kind == "cosine" else 3 * extent, xtol=1e-14)
        assert window_lesion_length_mm(kind, extent, edge) == pytest.approx(2 * half, rel=1e-9)
    with pytest.raises(QcaError, match="'box'"):
        window_lesion_length_mm("box", extent)


@pytest.mark.parametrize("extent", [6.0, 10.0, 16.0])
@pytest.mark.parametrize("s", [0.3, 0.5, 0.7])
@pytest.mark.parametrize("kind", ["cosine", "gaussian"])
@pytest.mark.parametrize("step", [0.25, 0.5])
def test_single_stenosis_on_a_taper(step, kind, s, extent):
    c = 30.0  # a sample: the MLD sample is the centre itself
    tree = tube(lambda a: taper(a) * window(kind, a - c, s, extent), step=step)
    profile = branch_profile(tree, 0)
    assert len(profile.lesions) == 1
    result = analyse_tree(tree, settings=NO_VIEWS)
    assert result.lesions == profile.lesions
    les = profile.lesions[0]

    # MLD: the centre sample, ref(c) (1 - s); its point is the centreline point there
    assert les.mld_arc_mm == pytest.approx(c, abs=1e-9)
    np.testing.assert_allclose(les.mld_point_mm, (c, 0.0, 0.0), atol=1e-9)
    assert les.mld_mm == pytest.approx(float(taper(c)) * (1 - s), abs=1e-9)
    # the reference at the MLD is the taper (REF_TOL_MM, see above), the fit's slope is the taper's
    assert abs(les.reference_diameter_mm - float(taper(c))) <= REF_TOL_MM
    assert profile.reference.slope_mm_per_mm == pytest.approx(-0.01, abs=1e-5)
    # the fit is least squares over the points it keeps, and keeps every healthy point
    a, d = profile.arc_mm, profile.diameter_mm
    kept = profile.reference.kept
    assert kept[window(kind, a - c, s, extent) > 1 - 1e-12].all()
    assert not kept[taper(a) - d > 3 * 2.5 * 0.01 * np.median(d)].any()
    slope, intercept = np.polyfit(a[kept], d[kept], 1)
    assert profile.reference.slope_mm_per_mm == pytest.approx(slope, abs=1e-9)
    assert profile.reference.diameter_at_start_mm == pytest.approx(intercept, abs=1e-9)

    # %DS = 100 s, off by the reference's error only: 100 (1 - s) REF_TOL / ref (< 0.11 points)
    ds_tol = 100 * (1 - s) * REF_TOL_MM / float(taper(c)) + 1e-9
    assert abs(les.diameter_stenosis_pct - 100 * s) <= ds_tol
    ratio = 1 - les.diameter_stenosis_pct / 100
    assert les.area_stenosis_pct == pytest.approx(100 * (1 - ratio * ratio), abs=1e-9)

    # lesion length: the closed form, within one sampling step (measured: <= 0.031 mm at 0.25 mm,
    # <= 0.063 mm at 0.5 mm); the lesion is centred on the window (measured <= 3.4e-4 mm)
    expected = window_lesion_length_mm(kind, extent)
    assert abs(les.length_mm - expected) <= step
    assert les.length_mm == pytest.approx(les.end_mm - les.start_mm)
    assert abs(0.5 * (les.start_mm + les.end_mm) - c) <= step / 10


@pytest.mark.parametrize("extent", [6.0, 10.0, 16.0])
@pytest.mark.parametrize("s", [0.3, 0.5, 0.7])
@pytest.mark.parametrize("kind", ["cosine", "gaussian"])
def test_stenosis_centre_between_samples(kind, s, extent):
    # the centre 0.1 mm past a sample: the MLD sample lies h <= one step from it, and the window is
    # shallower there by at most s * window_rise(h); the taper adds |slope| h to the MLD
    step, c = 0.25, 30.1
    tree = tube(lambda a: taper(a) * window(kind, a - c, s, extent), step=step)
    (les,) = branch_profile(tree, 0).lesions
    h = abs(les.mld_arc_mm - c)
    assert h <= step
    a = tree.root.arc_length_mm
    true_d = taper(a) * window(kind, a - c, s, extent)
    k = int(np.argmin(true_d))  # the MLD is the thinnest sample of the analytic profile
    assert les.mld_arc_mm == pytest.approx(a[k], abs=1e-12)
    assert les.mld_mm == pytest.approx(true_d[k], abs=1e-12)
    np.testing.assert_allclose(les.mld_point_mm, tree.root.points_mm[k], atol=1e-12)
    ref_c = float(taper(c))
    assert les.mld_mm <= ref_c * (1 - s) + ref_c * s * window_rise(kind, h, extent) + 0.01 * h + 1e-12
    assert les.mld_mm >= ref_c * (1 - s) - 0.01 * step - 1e-12
    rho = REF_TOL_MM / 2.4  # |true / fitted reference - 1|
    low = 100 * (1 - (1 - s + s * window_rise(kind, h, extent)) * (1 + rho))
    high = 100 * (1 - (1 - s) * (1 - rho))
    assert low <= les.diameter_stenosis_pct <= high
    assert abs(les.length_mm - window_lesion_length_mm(kind, extent)) <= step


def test_stenosis_on_a_gently_curved_branch():
    # a circular arc of radius 40 mm, 60 mm long (86 degrees), in a tilted plane; the diameter is
    # defined along the true arc, which the 0.25 mm polyline shortens by (h/R)^2/24 (5e-5 mm at 30 mm)
    big_r, c, s, extent = 40.0, 30.0, 0.5, 10.0
    sigma_ = arcs(60.0, 0.25)
    local = np.column_stack([big_r * np.sin(sigma_ / big_r), big_r * (1 - np.cos(sigma_ / big_r)), 0 * sigma_])
    m = rotation(5)
    points = local @ m[:3, :3].T + m[:3, 3]
    tree = VesselTree((Branch(points, 0.5 * taper(sigma_) * window("gaussian", sigma_ - c, s, extent)),))
    (les,) = analyse_tree(tree, settings=NO_VIEWS).lesions
    centre = np.array([big_r * math.sin(c / big_r), big_r * (1 - math.cos(c / big_r)), 0.0]) @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(les.mld_point_mm, centre, atol=1e-3)
    assert abs(les.diameter_stenosis_pct - 100 * s) <= 100 * (1 - s) * REF_TOL_MM / float(taper(c))
    assert abs(les.length_mm - window_lesion_length_mm("gaussian", extent)) <= 0.25


# -- 2. two lesions, a healthy taper, noise -------------------------------------------------------------

def test_two_lesions_far_apart_are_both_found_in_order():
    tree = tube(lambda a: taper(a) * window("cosine", a - 15, 0.5, 10) * window("gaussian", a - 45, 0.6, 8))
    profile = branch_profile(tree, 0)
    first, second = profile.lesions
    assert first.end_mm < second.start_mm
    assert first.mld_arc_mm == pytest.approx(15.0) and second.mld_arc_mm == pytest.approx(45.0)
    assert first.diameter_stenosis_pct == pytest.approx(50, abs=0.1)
    assert second.diameter_stenosis_pct == pytest.approx(60, abs=0.1)
    assert first.length_mm == pytest.approx(window_lesion_length_mm("cosine", 10), abs=0.25)
    assert second.length_mm == pytest.approx(window_lesion_length_mm("gaussian", 8), abs=0.25)
    result = analyse_tree(tree, settings=NO_VIEWS)
    assert result.lesions == profile.lesions
    rows = result.lesion_rows()
    assert [r["lesion"] for r in rows] == [0, 1] and [r["mld_arc_mm"] for r in rows] == pytest.approx([15, 45])
    assert result.branch_rows()[0]["lesions"] == 2
    assert result.branch_rows()[0]["max_diameter_stenosis_pct"] == pytest.approx(60, abs=0.1)


def test_healthy_taper_has_no_lesion_and_its_reference_is_the_taper():
    tree = tube(taper)
    profile = branch_profile(tree, 0)
    assert profile.lesions == ()
    assert profile.analysed.all() and profile.reference.kept.all()
    assert profile.reference.slope_mm_per_mm == pytest.approx(-0.01, abs=1e-9)
    assert profile.reference.diameter_at_start_mm == pytest.approx(3.0, abs=1e-9)
    np.testing.assert_allclose(profile.reference_mm(), taper(profile.arc_mm), atol=1e-9)
    row = analyse_tree(tree, settings=NO_VIEWS).branch_rows()[0]
    assert row["lesions"] == 0 and row["max_diameter_stenosis_pct"] is None
    assert row["reference_start_mm"] == pytest.approx(3.0, abs=1e-9)
    assert row["reference_end_mm"] == pytest.approx(2.4, abs=1e-9)
    assert row["length_mm"] == pytest.approx(60.0, abs=1e-9)
    assert row["mean_diameter_mm"] == pytest.approx(2.7, abs=1e-12)  # the trapezoid rule is exact on a line
    assert (row["min_diameter_mm"], row["max_diameter_mm"]) == pytest.approx((2.4, 3.0), abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_noise_of_one_percent_reports_no_lesion(seed):
    rng = np.random.default_rng(seed)
    a = arcs(60.0, 0.25)
    d = taper(a) * (1 + 0.01 * rng.normal(size=a.size))
    tree = VesselTree((Branch(polyline(a), 0.5 * d),))
    profile = branch_profile(tree, 0)
    assert profile.lesions == ()  # a 20 % narrowing would be 20 noise sd
    # measured over these seeds: the reference within 0.3 % of the taper everywhere
    assert np.abs(profile.reference_mm() / taper(a) - 1).max() <= 0.02
    assert 0.5 * 0.027 <= profile.reference.noise_mm <= 1.5 * 0.027  # ~1 % of the ~2.7 mm diameter


@pytest.mark.parametrize("sigma", [0.3, 0.5, 1.0])
def test_smoothed_along_is_the_normalised_gaussian_average_within_four_sigma(sigma):
    rng = np.random.default_rng(3)
    a = np.cumsum(rng.uniform(0.1, 0.7, size=120))  # uneven steps
    v = rng.normal(size=a.size)
    got = smoothed_along(a, v, sigma)
    for i in range(a.size):  # the definition, sample by sample
        w = [math.exp(-0.5 * ((a[j] - a[i]) / sigma) ** 2) if abs(a[j] - a[i]) <= 4 * sigma else 0.0
             for j in range(a.size)]
        assert got[i] == pytest.approx(sum(wj * vj for wj, vj in zip(w, v)) / sum(w), abs=1e-12)
    # an average: a constant stays, and on even steps a line stays wherever the window is whole
    np.testing.assert_allclose(smoothed_along(a, np.full(a.size, 2.5), sigma), 2.5, atol=1e-12)
    even = arcs(30.0, 0.25)
    whole = (even >= 4 * sigma) & (even <= 30.0 - 4 * sigma)
    np.testing.assert_allclose(smoothed_along(even, taper(even), sigma)[whole], taper(even)[whole], atol=1e-12)
    np.testing.assert_array_equal(smoothed_along(a, v, 0.0), v)


def test_a_dip_of_one_or_two_samples_is_no_lesion_but_a_stenosis_is_found_and_measured_unsmoothed():
    # 0.5 mm steps. With sigma 0.5 mm the Gaussian's weights at 0, 0.5, 1, 1.5, 2 mm are 1, e^-1/2,
    # e^-2, e^-9/2, e^-8: a dip keeps 1 / 2.507 of its depth over one sample and 1.607 / 2.507 over
    # two, so a 30 % dip is found on 12.0 % and 19.2 %: under the 20 % that starts a lesion.
    step, c, s, extent = 0.5, 40.0, 0.4, 6.0
    a = arcs(60.0, step)
    d = taper(a) * window("cosine", a - c, s, extent)
    d[a == 12.0] *= 0.7
    d[(a == 24.0) | (a == 24.5)] *= 0.7
    tree = VesselTree((Branch(polyline(a), 0.5 * d),))
    (les,) = branch_profile(tree, 0).lesions
    # measured on the profile: the MLD is the window's centre sample, not the smoothed minimum
    assert les.mld_arc_mm == pytest.approx(c, abs=1e-12)
    assert les.mld_mm == pytest.approx(float(taper(c)) * (1 - s), abs=1e-12)
    assert smoothed_along(a, d, 0.5).min() > les.mld_mm + 0.05
    assert abs(les.diameter_stenosis_pct - 100 * s) <= 100 * (1 - s) * REF_TOL_MM / float(taper(c)) + 1e-9
    assert abs(les.length_mm - window_lesion_length_mm("cosine", extent)) <= step
    # found on the profile itself, the two dips are lesions of their own (30 %; the MLD of the
    # two-sample dip is its distal sample, where the taper is thinner)
    unsmoothed = ProfileSettings(detection_smoothing_mm=0.0)
    dips = branch_profile(tree, 0, settings=unsmoothed).lesions
    assert [round(x.mld_arc_mm, 6) for x in dips] == [12.0, 24.5, 40.0]
    assert [x.diameter_stenosis_pct for x in dips[:2]] == pytest.approx([30.0, 30.0], abs=0.2)
    # three samples (1 mm) keep 2.213 / 2.507 of the dip: 26.5 % is found, and measured at 30 %
    d[a == 12.5] = taper(12.5) * 0.7
    d[a == 13.0] = taper(13.0) * 0.7
    found = branch_profile(VesselTree((Branch(polyline(a), 0.5 * d),)), 0).lesions
    assert [round(x.mld_arc_mm, 6) for x in found] == [13.0, 40.0]
    assert found[0].diameter_stenosis_pct == pytest.approx(30.0, abs=0.2)


def test_the_profile_keeps_the_smoothed_diameter_its_lesions_were_found_on():
    # the side branch's first r_parent mm lie in the parent's lumen: not analysed, no smoothed value;
    # elsewhere the Gaussian average over the analysed samples only (not the junction's)
    tree = side_branch_tree(0.0, junction_radius=2.2)
    result = analyse_tree(tree, settings=NO_VIEWS)
    for branch in result.branches:
        p = branch.profile
        a, d, on = p.arc_mm, p.diameter_mm, p.analysed
        assert np.isnan(p.smoothed_diameter_mm[~on]).all()
        np.testing.assert_allclose(p.smoothed_diameter_mm[on], smoothed_along(a[on], d[on], 0.5), atol=1e-12)
    assert (~result.branches[1].profile.analysed).sum() >= 2  # the junction is there
    assert result.branches[1].profile.smoothed_diameter_mm[~result.branches[1].profile.analysed].size >= 2


# -- 3. open-ended narrowings ---------------------------------------------------------------------

def test_narrowing_to_the_tip_is_not_a_lesion():
    def tip(a):
        return taper(a) * (1 - 0.8 * np.clip((a - 45) / 15, 0, None) ** 2)  # 80 % narrower at the end

    profile = branch_profile(tube(tip), 0)
    assert profile.lesions == ()
    assert 1 - profile.diameter_mm[-1] / profile.reference_mm()[-1] > 0.7


def test_narrowing_at_the_ostium_is_not_a_lesion():
    profile = branch_profile(tube(lambda a: taper(a) * (1 - 0.6 * np.clip(1 - a / 8, 0, None) ** 2)), 0)
    assert profile.lesions == ()
    assert 1 - profile.diameter_mm[0] / profile.reference_mm()[0] > 0.5


def test_a_window_is_a_lesion_only_while_its_edges_lie_inside():
    # cosine, L = 10: the 1/4 edges lie 3.33 mm either side of the centre
    inside = branch_profile(tube(lambda a: taper(a) * window("cosine", a - 54, 0.5, 10)), 0)
    (les,) = inside.lesions
    assert les.end_mm == pytest.approx(54 + 10 / 3, abs=0.25)
    past_end = branch_profile(tube(lambda a: taper(a) * window("cosine", a - 57, 0.5, 10)), 0)
    assert past_end.lesions == ()  # the edge would be at 60.33 mm, past the 60 mm end
    n = 1 - past_end.diameter_mm / past_end.reference_mm()
    assert n.max() >= 0.45


# -- 4. side branch junction ----------------------------------------------------------------------

def side_branch_tree(gap_mm=0.0, junction_radius=None):
    """Parent along +x (radius 1.6 -> 1.2 over 40 mm, 1.4 at the bifurcation, x = 20); a straight
    child at 60 degrees starting `gap_mm` from that point, radius 1.2 -> 0.9 over 30 mm (the
    reference diameter 2.4 - 0.02 a); `junction_radius` replaces its radius within 1.4 mm of the
    parent point (inside the parent's lumen)."""
    xp = arcs(40.0, 0.5)
    parent = Branch(polyline(xp), 1.6 - 0.01 * xp, name="main")
    u = (math.cos(math.radians(60)), math.sin(math.radians(60)), 0.0)
    a = arcs(30.0, 0.5)
    p0 = np.array([20.0, 0, 0]) + gap_mm * np.asarray(u)
    radius = 1.2 - 0.01 * a
    if junction_radius is not None:
        radius = np.where(a + gap_mm < 1.4, junction_radius, radius)
    child = Branch(polyline(a, u, p0), radius, 0, 40, name="side")
    return VesselTree((parent, child))


@pytest.mark.parametrize("gap_mm", [0.0, 0.6])
@pytest.mark.parametrize("junction_radius", [None, 2.2, 0.3])
def test_side_branch_points_inside_the_parent_are_not_analysed(gap_mm, junction_radius):
    tree = side_branch_tree(gap_mm, junction_radius)
    assert tree.branches[0].radius_mm[40] == pytest.approx(1.4)
    profile = branch_profile(tree, 1)
    inside = np.linalg.norm(tree.branches[1].points_mm - tree.branches[0].points_mm[40], axis=1) <= 1.4
    np.testing.assert_array_equal(profile.analysed, ~inside)
    assert np.count_nonzero(~profile.analysed) == (3 if gap_mm == 0 else 2)  # 0, 0.5, 1.0 mm / 0, 0.5 mm
    # a flare or a narrowing in the junction changes nothing: the reference is the child's taper
    assert profile.lesions == ()
    assert profile.reference.slope_mm_per_mm == pytest.approx(-0.02, abs=1e-9)
    assert profile.reference.diameter_at_start_mm == pytest.approx(2.4, abs=1e-9)
    assert not profile.reference.kept[~profile.analysed].any()
    assert branch_profile(tree, 0).analysed.all()  # the root has no junction


# -- 4b. vessels: a branch that runs into a stub and goes on as its child --------------------------

def split_tube(kind, s, extent, split_mm, stub_mm, stub_deg=40.0, step=0.25, c=30.0):
    """The tube of test_single_stenosis_on_a_taper cut in two at ``split_mm``: the parent runs on
    past the cut into a straight stub of ``stub_mm`` (``stub_deg`` off the axis, the radius of the
    cut), the rest of the tube is its child."""
    a = arcs(60.0, step)
    d = taper(a) * window(kind, a - c, s, extent)
    points = polyline(a)
    j = int(round(split_mm / step))
    t = math.radians(stub_deg)
    stub = polyline(arcs(stub_mm, step)[1:], (math.cos(t), math.sin(t), 0.0), points[j])
    parent = Branch(np.vstack([points[:j + 1], stub]), 0.5 * np.concatenate([d[:j + 1], np.full(len(stub), d[j])]),
                    name="parent")
    child = Branch(points[j:], 0.5 * d[j:], 0, j, name="child")
    return VesselTree((parent, child)), VesselTree((Branch(points, 0.5 * d, name="tube"),)), a[j]


@pytest.mark.parametrize("split_mm", [24.0, 30.0, 33.0, 45.0])
@pytest.mark.parametrize("kind", ["cosine", "gaussian"])
def test_a_vessel_cut_into_a_stub_and_a_child_reads_as_one(kind, split_mm):
    # a 1.5 mm stub (about one radius): the child continues the parent; the analysis is that of
    # the uncut tube, the lesion listed under the branch of its MLD in that branch's arc lengths
    tree, whole, cut = split_tube(kind, 0.6, 12.0, split_mm, 1.5)
    vessels = tree_vessels(tree)
    assert vessels.continues_into == {0: 1} and len(vessels.vessels) == 1
    np.testing.assert_allclose(vessels.vessels[0].points_mm, whole.root.points_mm, atol=1e-12)
    (expected,) = branch_profile(whole, 0).lesions
    result = analyse_tree(tree, settings=NO_VIEWS)
    (les,) = result.lesions
    mld_branch = 0 if expected.mld_arc_mm <= cut + 1e-9 else 1
    offset = 0.0 if mld_branch == 0 else cut
    assert les.branch == mld_branch
    assert les.mld_arc_mm == pytest.approx(expected.mld_arc_mm - offset, abs=1e-9)
    assert les.start_mm == pytest.approx(expected.start_mm - offset, abs=1e-9)
    assert les.end_mm == pytest.approx(expected.end_mm - offset, abs=1e-9)
    for name in ("mld_mm", "reference_diameter_mm", "diameter_stenosis_pct", "length_mm"):
        assert getattr(les, name) == pytest.approx(getattr(expected, name), abs=1e-9)
    assert les.mld_point_mm == expected.mld_point_mm
    # each branch's reference is the vessel's line in its own arc lengths; the stub is not analysed
    whole_ref = branch_profile(whole, 0).reference
    for index, shift in ((0, 0.0), (1, cut)):
        profile = result.branches[index].profile
        assert profile.vessel == (0, 1)
        assert profile.reference.slope_mm_per_mm == pytest.approx(whole_ref.slope_mm_per_mm, abs=1e-12)
        assert profile.reference(np.array([0.0]))[0] == pytest.approx(whole_ref(np.array([shift]))[0], abs=1e-9)
    assert not result.branches[0].profile.analysed[int(round(split_mm / 0.25)) + 1:].any()
    assert result.bifurcations == ()  # the cut is no bifurcation
    assert branch_profile(tree, mld_branch).lesions == (les,)


def test_a_stub_longer_than_its_limit_is_a_vessel_of_its_own():
    # 7 mm past the cut is more than 4 radii (the radius there is about 1.1 mm): two branches
    tree, _, _ = split_tube("cosine", 0.6, 12.0, 45.0, 7.0)
    assert tree_vessels(tree).continues_into == {}
    assert tree_vessels(tree, VesselSettings(stub_radii=8.0)).continues_into == {0: 1}
    (bif,) = analyse_tree(tree, settings=NO_VIEWS).bifurcations
    assert [arm.role for arm in bif.arms] == ["proximal main", "distal main", "side"]


@pytest.mark.parametrize("earlier_mm, continues", [(60.0, False), (5.0, True)])
def test_a_child_in_the_stub_continues_unless_an_earlier_child_carries_more(earlier_mm, continues):
    # parent 30 mm along x (diameter 3); a child at 60 degrees leaves 10 mm before its end, another
    # (20 mm, straight on) 1 mm before it: the latter continues the parent unless the earlier one
    # carries more of the tree (then the parent's last 10 mm are a second path through a wide
    # vessel, not a stub)
    parent = Branch(polyline(arcs(30.0, 0.5)), 1.5, name="parent")
    t = math.radians(60)
    earlier = Branch(polyline(arcs(earlier_mm, 0.5), (math.cos(t), math.sin(t), 0), (20, 0, 0)), 1.2, 0, 40)
    late = Branch(polyline(arcs(20.0, 0.5), (1, 0, 0), (29, 0, 0)), 1.2, 0, 58)
    tree = VesselTree((parent, earlier, late))
    assert tree_vessels(tree).continues_into == ({0: 2} if continues else {})
    bifs = analyse_tree(tree, settings=NO_VIEWS).bifurcations
    assert [b.parent_point for b in bifs] == ([40] if continues else [40, 58])
    (first, *_) = bifs
    (side,) = first.sides
    assert side.side_branch == 1 and side.distal_angle_deg == pytest.approx(60.0, abs=1e-6)


# -- 5. bifurcation angles and Medina --------------------------------------------------------------

def y_tree(theta_deg, parent_length=30.0, at=15.0, child_length=20.0, step=0.5):
    xp = arcs(parent_length, step)
    parent = Branch(polyline(xp), 1.5, name="main")
    k = int(round(at / step))
    t = math.radians(theta_deg)
    child = Branch(polyline(arcs(child_length, step), (math.cos(t), math.sin(t), 0), (at, 0, 0)), 1.0, 0, k,
                   name="side")
    return VesselTree((parent, child))


@pytest.mark.parametrize("theta", [30.0, 45.0, 60.0, 90.0])
def test_y_bifurcation_angles(theta):
    tree = y_tree(theta)
    for t in (tree, tree.transformed(rotation(int(theta)))):  # a rigid motion changes no angle
        for bifs in (analyse_bifurcations(t), analyse_tree(t, settings=NO_VIEWS).bifurcations):
            (bif,) = bifs
            assert (bif.parent, bif.parent_point) == (0, 30)
            assert [arm.role for arm in bif.arms] == ["proximal main", "distal main", "side"]
            (side,) = bif.sides
            assert side.side_branch == 1
            assert side.distal_angle_deg == pytest.approx(theta, abs=1e-6)
            assert side.proximal_angle_deg == pytest.approx(180 - theta, abs=1e-6)
            assert side.medina == (0, 0, 0)


@pytest.mark.parametrize("wider", ["plus", "minus"])
def test_bifurcation_at_the_parents_last_point(wider):
    a, b = 30.0, 50.0
    parent = Branch(polyline(arcs(20.0, 0.5)), 1.5)
    end = (20.0, 0.0, 0.0)

    def child(angle, radius):
        t = math.radians(angle)
        return Branch(polyline(arcs(20.0, 0.5), (math.cos(t), math.sin(t), 0), end), radius, 0, 40)

    tree = VesselTree((parent, child(a, 1.2 if wider == "plus" else 0.9), child(-b, 0.9 if wider == "plus" else 1.2)))
    (bif,) = analyse_bifurcations(tree)
    roles = {arm.role: arm.branch for arm in bif.arms}
    main, side_branch, side_angle = (1, 2, b) if wider == "plus" else (2, 1, a)
    assert roles == {"proximal main": 0, "distal main": main, "side": side_branch}
    (side,) = bif.sides
    assert side.side_branch == side_branch
    assert side.distal_angle_deg == pytest.approx(a + b, abs=1e-6)
    assert side.proximal_angle_deg == pytest.approx(180 - side_angle, abs=1e-6)


def medina_tree(parent_lesion=None, side_lesion=None):
    """Parent 60 mm along +x, diameter 3.0; a side branch from x = 30 at 60 degrees, 30 mm, diameter
    2.4 - 0.01 a; lesions (centre, severity) as cosine windows of extent 6 mm (1/4 edges +-2 mm)."""
    xp = arcs(60.0, 0.5)
    dp = np.full(xp.shape, 3.0)
    if parent_lesion is not None:
        dp = dp * window("cosine", xp - parent_lesion[0], parent_lesion[1], 6.0)
    a = arcs(30.0, 0.5)
    dc = 2.4 - 0.01 * a
    if side_lesion is not None:
        dc = dc * window("cosine", a - side_lesion[0], side_lesion[1], 6.0)
    t = math.radians(60)
    return VesselTree((Branch(polyline(xp), 0.5 * dp), Branch(polyline(a, (math.cos(t), math.sin(t), 0), (30, 0, 0)),
                                                               0.5 * dc, 0, 60)))


@pytest.mark.parametrize("parent_lesion, side_lesion, medina", [
    (None, (7.0, 0.6), (0, 0, 1)),  # side branch, 5-9 mm from its origin
    ((25.0, 0.6), None, (1, 0, 0)),  # proximal main, 3-7 mm before the bifurcation
    ((35.0, 0.6), None, (0, 1, 0)),  # distal main, 3-7 mm after it
    ((25.0, 0.6), (7.0, 0.6), (1, 0, 1)),
    ((25.0, 0.3), None, (0, 0, 0)),  # a 30 % lesion does not count
    ((48.0, 0.6), None, (0, 0, 0)),  # 16-20 mm past the bifurcation: beyond the 10 mm reach
])
def test_medina(parent_lesion, side_lesion, medina):
    result = analyse_tree(medina_tree(parent_lesion, side_lesion), settings=NO_VIEWS)
    assert len(result.lesions) == (parent_lesion is not None) + (side_lesion is not None)
    for les, (branch, lesion) in zip(result.lesions, [(0, parent_lesion), (1, side_lesion)][parent_lesion is None:]):
        assert les.branch == branch and les.mld_arc_mm == pytest.approx(lesion[0])
        assert les.diameter_stenosis_pct == pytest.approx(100 * lesion[1], abs=0.15)
    (bif,) = result.bifurcations
    (side,) = bif.sides
    assert side.medina == medina
    assert side.distal_angle_deg == pytest.approx(60, abs=1e-6)
    assert analyse_bifurcations(result.tree, result.lesions)[0].sides[0].medina == medina


# -- 6. foreshortening --------------------------------------------------------------------------

@pytest.mark.parametrize("phi", [0.0, 15.0, 30.0, 60.0, 90.0])
@pytest.mark.parametrize("pose", [(0.0, 0.0), (30.0, 20.0), (-40.0, -15.0)])
def test_foreshortening_of_a_segment_through_the_isocentre(pose, phi):
    carm = CArmGeometry(pose[0], pose[1], 1200, SOD, (0.2, 0.2), (1024, 1024))
    projection = carm.projection()
    d, col, row = carm.detector_direction(), carm.column_direction(), carm.row_direction()
    psi = math.radians(35)
    p = math.radians(phi)
    t = math.cos(p) * d + math.sin(p) * (math.cos(psi) * col + math.sin(psi) * row)  # phi from the central ray
    # 10 mm at 0.25 mm: the perspective error is second order in 5 mm / SOD (measured < 2e-5)
    segment = np.linspace(-5, 5, 41)[:, None] * t
    assert foreshortening(segment, projection.camera_centre_mm) == pytest.approx(math.sin(p), abs=1e-3)
    # the same from the pixels: a 1 mm segment's projected length times the isocentre pixel spacing
    short = np.array([-0.5 * t, 0.5 * t])
    uv = projection.project(short)
    measured = float(np.linalg.norm(uv[1] - uv[0])) * carm.isocentre_pixel_spacing_mm[0] / 1.0
    fs = foreshortening(short, projection.camera_centre_mm)
    assert measured == pytest.approx(fs, rel=0.01, abs=1e-4)
    assert measured == pytest.approx(math.sin(p), rel=0.01, abs=1e-4)


# -- 7. view map ----------------------------------------------------------------------------------

DIRECTION = np.array([1.0, 0.3, 0.5]) / np.linalg.norm([1.0, 0.3, 0.5])
RADIUS = 1.2


@pytest.fixture(scope="module")
def straight_segment():
    """10 mm along DIRECTION through the isocentre, 0.5 mm steps, radius 1.2 mm."""
    return VesselTree((Branch(np.linspace(-5, 5, 21)[:, None] * DIRECTION, RADIUS, name="lad"),))


@pytest.mark.parametrize("settings", [ViewMapSettings(), ViewMapSettings(step_deg=2.0)], ids=["5deg", "2deg"])
def test_view_map_of_a_straight_segment(straight_segment, settings):
    vm = view_map(straight_segment, 0, settings=settings)
    step = settings.step_deg
    assert vm.primary_deg[0] == -90 and vm.primary_deg[-1] == 90 and vm.secondary_deg[-1] == 45
    assert vm.foreshortening.shape == vm.overlap.shape == (len(vm.secondary_deg), len(vm.primary_deg))
    grid_p, grid_s = np.meshgrid(vm.primary_deg, vm.secondary_deg)
    d, _, _ = carm_frames(grid_p.ravel(), grid_s.ravel())
    dt = (d @ DIRECTION).reshape(grid_p.shape)
    # everywhere: sqrt(1 - (d.t)^2), to the perspective error (measured 6.5e-6)
    np.testing.assert_allclose(vm.foreshortening, np.sqrt(1 - dt * dt), atol=2e-5)
    # the most foreshortening-free cell sees the segment side on, the least end on
    i = np.unravel_index(np.argmax(vm.foreshortening), dt.shape)
    assert abs(dt[i]) <= math.sin(math.radians(step))
    j = np.unravel_index(np.argmin(vm.foreshortening), dt.shape)
    assert abs(dt[j]) == pytest.approx(np.abs(dt).max(), abs=1e-9)
    assert vm.foreshortening[j] < 0.05  # RAO 73 CAU 26 looks along -t, within the grid step

    # overlap: a straight vessel covers itself seen nearly end on. Points > 2r + near_mm = 3.4 mm
    # apart (the first: 3.5 mm, 7 steps) project within r + r of each other iff 3.5 sin(angle) < 2r,
    # and then every point has such a partner: the share is 1 below fs = 2.4 / 3.5, 0 above
    # (perspective smears the switch by < 0.3 %)
    edge = 2 * RADIUS / 3.5
    fs, ov = vm.foreshortening, vm.overlap
    assert (ov[fs < 0.98 * edge] == 1).all() and (ov[fs > 1.02 * edge] == 0).all()
    assert (ov == 1).any() and (ov == 0).any()

    # the best view: a clinical name, and no worse than any cell of the map by more than the
    # tie margin (scores within tie_score of the highest are ties, won by the least angulation)
    assert re.fullmatch(r"(LAO|RAO) \d+(\.\d)? (CRA|CAU) \d+(\.\d)?", vm.best_name)
    assert parse_clinical_angles(vm.best_name) == pytest.approx((vm.best_primary_deg, vm.best_secondary_deg),
                                                                abs=0.051)
    assert -90 <= vm.best_primary_deg <= 90 and -45 <= vm.best_secondary_deg <= 45
    source = carm_for(vm.best_primary_deg, vm.best_secondary_deg).projection().camera_centre_mm
    best_fs = foreshortening(straight_segment.root.points_mm, source)
    assert best_fs > 1.02 * edge  # so no overlap there: the score is the foreshortening
    tie = ViewMapSettings().tie_score
    assert best_fs >= vm.score.max() - tie - 1e-9
    tied = vm.score >= vm.score.max() - tie - 1e-12
    grid_p, grid_s = np.meshgrid(vm.primary_deg, vm.secondary_deg)
    least = (np.abs(grid_p) + np.abs(grid_s))[tied].min()
    assert abs(vm.best_primary_deg) + abs(vm.best_secondary_deg) <= least + 1e-9
    d_best = CArmGeometry(vm.best_primary_deg, vm.best_secondary_deg, 1200, SOD, (0.2, 0.2),
                          (1024, 1024)).detector_direction()
    # a tie has foreshortening >= 1 - tie (the map's best is ~1): |d . t| <= sqrt(1 - (1 - tie)^2)
    assert abs(float(d_best @ DIRECTION)) <= math.sqrt(1 - (1 - tie) ** 2) + 1e-6


def test_view_map_without_end_on_views_has_no_overlap(straight_segment):
    # LAO 0-45, CRA/CAU 45 (far from RAO 73 CAU 26 and LAO 107 CRA 26, the poses along -t and t):
    # |d.t| <= 0.608 there, so fs >= 0.79 > 2.4 / 3.5: no overlap anywhere
    vm = view_map(straight_segment, 0, settings=ViewMapSettings(primary_range_deg=(0.0, 45.0)))
    assert vm.foreshortening.min() > 0.79
    assert (vm.overlap == 0).all()
    assert 0 <= vm.best_primary_deg <= 45


def crossing_tree():
    """A along x (y = z = 0), B along y at x = 0, z = 20; both -30..30 mm at 0.5 mm, radius 1. B is
    A's child from A's last point, its own first point 47 mm away (no connector in the views)."""
    x = arcs(60.0, 0.5) - 30.0
    a = Branch(np.column_stack([x, 0 * x, 0 * x]), 1.0, name="A")
    b = Branch(np.column_stack([0 * x, x, 0 * x + 20.0]), 1.0, 0, len(x) - 1, name="B")
    return VesselTree((a, b))


# the four poses LAO 0 / 90 x CRA 0 / 90 look along -y (AP), +x and +z (twice)
AXES = ViewMapSettings(primary_range_deg=(0.0, 90.0), secondary_range_deg=(0.0, 90.0), step_deg=90.0,
                       refine_step_deg=0.0)


def crossing_counts():
    """Seen along z (source at z = -SOD) A's point (x, 0, 0) is covered by B's (0, 0, 20) iff
    |x| / SOD < r_A / SOD + r_B / (SOD + 20), and B's (0, y, 20) by A's (0, 0, 0) iff
    |y| / (SOD + 20) < r_B / (SOD + 20) + r_A / SOD."""
    s = arcs(60.0, 0.5) - 30.0
    return (np.abs(s) < 1 + SOD / (SOD + 20)), (np.abs(s) < 1 + (SOD + 20) / SOD)


def test_view_map_overlap_of_crossing_vessels():
    tree = crossing_tree()
    d, _, _ = carm_frames(np.array([0.0, 90.0, 0.0]), np.array([0.0, 0.0, 90.0]))
    np.testing.assert_allclose(d, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    a_hit, b_hit = crossing_counts()
    assert (a_hit.sum(), b_hit.sum()) == (7, 9)
    vm_a = view_map(tree, 0, settings=AXES)
    vm_b = view_map(tree, 1, settings=AXES)
    # along z they cross: the points around the crossing are overlapped, in both vessels
    assert vm_a.at(0, 90)[1] == pytest.approx(a_hit.mean()) and vm_a.at(90, 90)[1] == pytest.approx(a_hit.mean())
    assert vm_b.at(0, 90)[1] == pytest.approx(b_hit.mean())
    # along y (AP) B is end on, 20 mm from A's line: A is not overlapped (B covers itself);
    # along x A is end on: B is not overlapped (A covers itself)
    assert vm_a.at(0, 0)[1] == 0.0 and vm_b.at(0, 0)[1] == 1.0
    assert vm_b.at(90, 0)[1] == 0.0 and vm_a.at(90, 0)[1] == 1.0
    # foreshortening there: side on ~1, end on sin(atan(20 / 800)) for B offset from the ray
    assert vm_a.at(0, 0)[0] == pytest.approx(1, abs=1e-3) and vm_a.at(90, 0)[0] == pytest.approx(0, abs=1e-12)
    assert vm_b.at(0, 0)[0] == pytest.approx(math.sin(math.atan(20 / SOD)), rel=2e-3)

    # the default map: A is seen side on from every LAO 0 pose; B's projection reaches A's only
    # for |secondary| >= atan(20 / 30) = 33.7 degrees. Best: AP, the least angulation
    vm = view_map(tree, 0)
    assert vm.at(0, 0)[1] == 0.0 and vm.at(0, 20)[1] == 0.0 and vm.at(0, -20)[1] == 0.0
    assert vm.at(0, 40)[1] > 0 and vm.at(0, -40)[1] > 0
    assert vm.best_name == "LAO 0 CRA 0"
    assert vm.score[vm.secondary_deg == 0, vm.primary_deg == 0][0] >= vm.score.max() - ViewMapSettings().tie_score


# -- 8. the views of acquired projections --------------------------------------------------------------

def test_view_report_of_crossing_vessels():
    tree = crossing_tree()
    along_z = CArmGeometry(0, 90, 1200, SOD, (0.2, 0.2), (1024, 1024)).projection()
    ap = CArmGeometry(0, 0, 1200, SOD, (0.2, 0.2), (1024, 1024)).projection()
    (report_z, report_ap) = view_report(tree, [along_z, ap], ["v", "ap"])
    assert report_z["view"] == "v" and report_ap["view"] == "ap"
    s = arcs(60.0, 0.5)
    for entry, hit in zip(report_z["branches"], crossing_counts()):
        # one run around the crossing at arc 30 mm: exactly the samples the closed form covers
        assert entry["overlapped_mm"] == [pytest.approx([s[hit].min(), s[hit].max()])]
        lo, hi = entry["overlapped_mm"][0]
        assert lo < 30 < hi and hi - lo <= 2 * 2.03
        assert entry["overlapped_share"] == pytest.approx(hit.mean())
    # foreshortening seen along z from (0, 0, -800): step midpoints m of A give SOD / |(m, 0, SOD)|,
    # of B SOD+20 / |(0, m, SOD+20)|
    mid = 0.5 * (s[1:] + s[:-1]) - 30.0
    fs_a = np.mean(SOD / np.hypot(mid, SOD))
    fs_b = np.mean((SOD + 20) / np.hypot(mid, SOD + 20))
    assert report_z["branches"][0]["foreshortening"] == pytest.approx(fs_a, abs=1e-12)
    assert report_z["branches"][1]["foreshortening"] == pytest.approx(fs_b, abs=1e-12)
    # AP: A is not overlapped, B (end on) covers itself
    a_ap, b_ap = report_ap["branches"]
    assert a_ap["overlapped_mm"] == [] and a_ap["overlapped_share"] == 0.0
    assert b_ap["overlapped_share"] == 1.0 and b_ap["overlapped_mm"] == [[0.0, pytest.approx(60.0)]]
    # analyse_tree carries the same report
    views = analyse_tree(tree, [along_z, ap], ["v", "ap"], settings=NO_VIEWS).views
    assert views[0]["branches"][0]["overlapped_mm"] == report_z["branches"][0]["overlapped_mm"]


# -- 9. bad input -------------------------------------------------------------------------------

def two_branch_tree():
    return y_tree(45.0)


def test_bad_input_raises_one_clear_qca_error():
    with pytest.raises(QcaError, match="got None"):
        analyse_tree(None)
    with pytest.raises(QcaError, match="needs a VesselTree, got dict"):
        analyse_tree({"branches": []})
    short = VesselTree((Branch(polyline(arcs(5.0, 0.25)), 1.0),))
    with pytest.raises(QcaError, match=r"10 mm") as info:
        analyse_tree(short)
    assert "5.0 mm" in str(info.value)
    sparse = VesselTree((Branch(np.array([[0.0, 0, 0], [60.0, 0, 0]]), 1.0),))  # long enough, too few points
    with pytest.raises(QcaError, match=r"branch 0, is 60\.0 mm with 2 points; the fit needs 10 mm and 8 points"):
        analyse_tree(sparse)
    assert analyse_tree(sparse.resampled(0.5)).branches[0].profile.reference is not None  # as the error says
    with pytest.raises(QcaError, match=r"view_names needs one name per projection: \['a'\] for 2 projections"):
        analyse_tree(two_branch_tree(), [CArmGeometry(0, 0, 1200, 800, (0.3, 0.3), (512, 512)).projection()] * 2, ["a"])
    with pytest.raises(QcaError, match=r"5\.0 mm .*10 mm"):
        branch_profile(short, 0)
    assert branch_profile(short, 0, strict=False).reference is None
    tree = two_branch_tree()
    with pytest.raises(QcaError, match=r"branch 7 does not exist.*0 to 1"):
        branch_profile(tree, 7)
    with pytest.raises(QcaError, match=r"segment 50-10 mm of branch 0"):
        segment_view_map(tree, 0, 50, 10)
    with pytest.raises(QcaError, match=r"segment 0-1e\+06 mm of branch 0.*30\.000 mm long"):
        segment_view_map(tree, 0, 0, 1e6)
    odd = VesselTree((Branch(np.array([[0.0, 0, 0], [126.3975, 0, 0]]), 1.0),))  # 126.3975 mm
    with pytest.raises(QcaError, match=r"126\.397 mm long; give 0 <= start < end <= 126\.397 mm") as info:
        segment_view_map(odd, 0, 0, 126.4)
    segment_view_map(odd, 0, 0, float(str(info.value).split("<= ")[-1].split(" mm")[0]))  # the end it names is taken
    with pytest.raises(QcaError, match=r"branch 5 does not exist"):
        segment_view_map(tree, 5)
    with pytest.raises(QcaError, match=r"primary range \(-200, 0\)"):
        view_map(tree, 0, settings=ViewMapSettings(primary_range_deg=(-200, 0)))
    with pytest.raises(QcaError, match=r"primary range \(-200, 0\)"):
        segment_view_map(tree, 0, settings=QcaSettings(view_map=ViewMapSettings(primary_range_deg=(-200, 0))))
    with pytest.raises(QcaError, match=r"edge_fraction.*1\.5"):
        ProfileSettings(edge_fraction=1.5)
    for bad in (-0.5, math.nan, math.inf):
        with pytest.raises(QcaError, match=r"detection_smoothing_mm"):
            ProfileSettings(detection_smoothing_mm=bad)


def test_a_short_side_branch_is_kept_without_reference():
    # the side branch is 5 mm long (3.5 mm outside the parent): analysed without lesions, reason given
    tree = y_tree(45.0, child_length=5.0)
    result = analyse_tree(tree, settings=NO_VIEWS)
    side = result.branches[1].profile
    assert side.reference is None and side.lesions == () and "10 mm" in side.reason
    row = result.branch_rows()[1]
    assert row["reference_start_mm"] is None and row["lesions"] == 0


@pytest.mark.parametrize("bad", [dict(sample_mm=0.0), dict(sample_mm=-0.5), dict(refine_step_deg=-1.0)])
def test_bad_view_map_settings_raise_qca_error(straight_segment, bad):
    with pytest.raises(QcaError):
        view_map(straight_segment, 0, settings=ViewMapSettings(**bad))


# -- 10. tables and JSON ------------------------------------------------------------------------

def test_result_tables_and_json():
    tree = medina_tree((25.0, 0.6), (7.0, 0.6))
    tree = VesselTree(tree.branches + (Branch(polyline(arcs(4.0, 0.5), (0, 0, 1), (50, 0, 0)), 0.8, 0, 100),))
    views = [CArmGeometry(30, 20, 1200, SOD, (0.2, 0.2), (1024, 1024)).projection()]
    result = analyse_tree(tree, views, ["LAO 30 CRA 20"])
    assert len(result.lesions) == 2 and len(result.lesion_views) == 2
    assert result.branches[2].profile.reference is None  # the 4 mm stub
    data = result.to_dict()
    text = json.dumps(data, allow_nan=False)
    back = json.loads(text)
    assert back["format"] == "angiohull-qca" and len(back["lesions"]) == 2 and len(back["branches"]) == 3
    assert back["branches"][2]["profile"]["reference_mm"] == [None] * 9
    assert back["branches"][2]["profile"]["smoothed_diameter_mm"] == [None] * 9
    trunk = back["branches"][0]["profile"]
    assert trunk["smoothed_diameter_mm"] == pytest.approx(
        np.round(smoothed_along(np.array(trunk["arc_mm"]), np.array(trunk["diameter_mm"]), 0.5), 4).tolist(), abs=2e-4)
    assert back["bifurcations"][0]["side_branches"][0]["medina"] == "1,0,1"
    rows = result.lesion_rows()
    assert all(tuple(row) == LESION_COLUMNS for row in rows)
    assert all(tuple(row) == BRANCH_COLUMNS for row in result.branch_rows())
    for row, les in zip(rows, result.lesions):
        assert (row["x_mm"], row["y_mm"], row["z_mm"]) == les.mld_point_mm
        assert re.fullmatch(r"(LAO|RAO) \d+(\.\d)? (CRA|CAU) \d+(\.\d)?", row["best_view"])
        assert 0 <= row["best_view_foreshortening"] <= 1 and 0 <= row["best_view_overlap"] <= 1


def test_a_shoulder_that_runs_into_a_deeper_lesion_is_part_of_it():
    # a deep narrowing with a shallower one beside it, joined above the shallower one's edge level:
    # one lesion (the deep one), not a second lesion sharing its MLD
    arc = np.arange(0.0, 60.0 + 1e-9, 0.25)

    def bump(centre, sd):
        return np.exp(-0.5 * ((arc - centre) / sd) ** 2)

    narrowing = 0.8 * bump(25, 1.0) + 0.3 * bump(33, 1.5) + 0.1 * bump(29, 3.0)
    points = np.column_stack([arc, np.zeros_like(arc), np.zeros_like(arc)])
    tree = VesselTree((Branch(points, 1.5 * (1.0 - narrowing)),))
    lesions = branch_profile(tree, 0).lesions
    assert len(lesions) == 1
    assert lesions[0].mld_arc_mm == pytest.approx(25.0, abs=0.25)
    assert len({les.mld_point_mm for les in lesions}) == len(lesions)


def test_a_stub_whose_continuation_leaves_its_first_point_adds_no_sample_and_no_crash():
    # A ends where the short B begins; B's child C leaves B's first point and carries A on: the
    # vessel A -> B -> C holds none of B's points (its first is A's last, the rest lie beyond C's start)
    from angiohull.qca.vessels import tree_vessels

    a = Branch(np.column_stack([np.linspace(0, 20, 41), np.zeros(41), np.zeros(41)]), 1.5, name="a")
    b = Branch(np.array([[20.0, 0, 0], [20.5, 0.2, 0], [21.0, 0.4, 0]]), 1.5, parent=0, parent_point=40, name="b")
    c = Branch(np.column_stack([np.linspace(20, 40, 41), np.zeros(41), np.zeros(41)]), 1.4, parent=1, parent_point=0,
               name="c")
    vessels = tree_vessels(VesselTree((a, b, c)))
    (vessel,) = [v for v in vessels.vessels if 0 in v.branches]
    assert vessel.branches == (0, 1, 2)
    assert 1 not in vessel.owner  # B adds no sample
    # C's first point is A's last: not repeated; the vessel runs 0..40 mm straight, every 0.5 mm
    np.testing.assert_allclose(vessel.points_mm[:, 0], np.linspace(0, 40, 81))
    np.testing.assert_allclose(vessel.arc_mm, np.linspace(0, 40, 81), atol=1e-9)
    analysis = analyse_tree(VesselTree((a, b, c)))
    assert len(analysis.branches) == 3
    # a side branch D leaving the stub past C's start: its bifurcation sits where B and C begin
    # (a thin one, turning back a little, so that C still carries the vessel on)
    d = Branch(np.array([21.0, 0.4, 0.0]) + np.linspace(0, 10, 21)[:, None] * np.array([-0.4, 1.0, 0.0]), 1.0,
               parent=1, parent_point=2, name="d")
    (bifurcation,) = analyse_tree(VesselTree((a, b, c, d))).bifurcations
    roles = {arm.role: arm for arm in bifurcation.arms}
    assert roles["distal main"].branch == 2 and roles["side"].branch == 3  # the proximal arm runs back along A
    np.testing.assert_allclose(roles["proximal main"].direction, [-1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(roles["distal main"].direction, [1, 0, 0], atol=1e-9)


def test_a_lesion_at_a_junction_does_not_split_the_vessel_it_narrows():
    # A (radius 2 mm) narrows to 0.8 mm over 12-20 mm; C leaves A at 15 mm and carries the vessel
    # straight on at 2 mm, while A's last 5 mm (narrow) run on a little aside. At the junction A is
    # 0.8 mm wide: 4 of those radii (3.2 mm) would not hold A's 5 mm tail as a stub; 4 of C's do
    from angiohull.qca.vessels import tree_vessels

    arc = np.linspace(0, 20, 41)
    radius = np.where(arc < 10, 2.0, np.where(arc < 12, 2.0 - 0.6 * (arc - 10), 0.8))
    a = Branch(np.column_stack([arc, np.where(arc > 15, 0.3 * (arc - 15), 0.0), np.zeros(41)]), radius, name="a")
    c_arc = np.linspace(0, 40, 81)
    c_radius = np.where(c_arc < 3, 0.8 + 0.4 * c_arc, 2.0)
    c = Branch(np.column_stack([15 + c_arc, np.zeros(81), np.zeros(81)]), c_radius, parent=0, parent_point=30, name="c")
    tree = VesselTree((a, c))
    vessels = tree_vessels(tree)
    assert vessels.continues_into == {0: 1}
    (lesion,) = [les for les in analyse_tree(tree).lesions if les.diameter_stenosis_pct >= 50]
    assert abs(lesion.reference_diameter_mm - 4.0) < 0.1
    assert abs(lesion.mld_mm - 1.6) < 0.05
