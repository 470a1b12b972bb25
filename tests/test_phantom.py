"""Tests of the analytic tubular phantom (angiohull.synthetic.phantom) against independent oracles.

Oracles: the conic image of a sphere (``C = (P Q* P^T)^-1``), the tangent planes of a cylinder
parallel to the detector, scalar point-segment loops, pixel rays rebuilt from the C-arm frame of
docs/conventions.md (not from the matrix) with segments sampled densely, and the demo views.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from angiohull.errors import AngiohullError
from angiohull.geometry import CArmGeometry, Projection
from angiohull.synthetic import Tube, TubePhantom, demo_phantom, demo_views
from angiohull.synthetic.phantom import _ray_segment_distance_sq

SID, SOD = 1200.0, 800.0


# -- helpers (the oracles) -------------------------------------------------------------------
def carm(primary=0.0, secondary=0.0, shape=(96, 96), spacing=(0.35, 0.35), offset=(0.0, 0.0)) -> CArmGeometry:
    return CArmGeometry(primary_deg=primary, secondary_deg=secondary, sid_mm=SID, sod_mm=SOD,
                        pixel_spacing_mm=spacing, image_shape=shape, principal_offset_px=offset)


def sphere(centre, radius) -> TubePhantom:
    return TubePhantom((Tube(np.asarray([centre], dtype=float), [radius]),), "sphere")


def pixel_rays(geometry: CArmGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Unit ray directions (rows*cols, 3) from the conventions' detector frame, and the source."""
    rows, cols = geometry.image_shape
    rs, cs = geometry.pixel_spacing_mm
    cu = (cols - 1) / 2 + geometry.principal_offset_px[0]
    cv = (rows - 1) / 2 + geometry.principal_offset_px[1]
    v, u = np.mgrid[0:rows, 0:cols]
    det = (geometry.detector_centre_mm + ((u.ravel() - cu) * cs)[:, None] * geometry.column_direction()
           + ((v.ravel() - cv) * rs)[:, None] * geometry.row_direction())
    dirs = det - geometry.source_mm
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True), geometry.source_mm


def point_segment_distance(p, a, b) -> float:
    """Scalar reference."""
    ab = [b[i] - a[i] for i in range(3)]
    ap = [p[i] - a[i] for i in range(3)]
    den = sum(x * x for x in ab)
    t = 0.0 if den == 0 else min(1.0, max(0.0, sum(ap[i] * ab[i] for i in range(3)) / den))
    return math.sqrt(sum((ap[i] - t * ab[i]) ** 2 for i in range(3)))


def clearance_loop(phantom: TubePhantom, points: np.ndarray) -> np.ndarray:
    """min over segments of (distance - radius), one segment at a time (vectorised over points)."""
    a, b, r = phantom.segments_mm()
    best = np.full(points.shape[0], np.inf)
    for i in range(r.size):
        e = b[i] - a[i]
        rel = points - a[i]
        t = np.clip(rel @ e / (e @ e), 0, 1) if e @ e > 0 else np.zeros(points.shape[0])
        best = np.minimum(best, np.linalg.norm(rel - t[:, None] * e, axis=1) - r[i])
    return best


def sampled_ray_ratio(phantom: TubePhantom, dirs: np.ndarray, source: np.ndarray, step_frac=0.05) -> np.ndarray:
    """Per ray: min over dense samples x of segment s of dist(x, half-line) / r_s (an upper bound
    of the exact value; too large by at most ~step_frac^2 / 8 relative)."""
    a, b, r = phantom.segments_mm()
    samples, radii = [], []
    for i in range(r.size):
        n = max(2, math.ceil(np.linalg.norm(b[i] - a[i]) / (step_frac * r[i])) + 1)
        t = np.linspace(0, 1, n)[:, None]
        samples.append(a[i] + t * (b[i] - a[i]))
        radii.append(np.full(n, r[i]))
    x = np.concatenate(samples) - source
    radii = np.concatenate(radii)
    out = np.empty(dirs.shape[0])
    for lo in range(0, dirs.shape[0], 64):
        d = dirs[lo:lo + 64]
        s = np.maximum(d @ x.T, 0.0)  # (n_rays, n_samples)
        dist_sq = (x * x).sum(axis=1)[None, :] - 2 * s * (d @ x.T) + s * s
        out[lo:lo + 64] = (np.sqrt(np.maximum(dist_sq, 0.0)) / radii[None, :]).min(axis=1)
    return out


def random_phantom(seed=7) -> TubePhantom:
    rng = np.random.default_rng(seed)
    tubes = []
    for _ in range(3):
        steps = rng.normal(size=(6, 3)) * 6.0
        centre = np.cumsum(np.vstack([rng.uniform(-15, 15, 3), steps]), axis=0)
        tubes.append(Tube(centre, rng.uniform(1.0, 4.0, centre.shape[0])))
    tubes.append(Tube([[5.0, -3.0, 8.0]], [3.5]))  # a sphere
    tubes.append(Tube([[-8.0, 4.0, 0.0], [-8.0, 4.0, 0.0], [-2.0, 9.0, -5.0]], [2.0, 2.0, 1.5]))  # repeated vertex
    return TubePhantom(tubes, "random")


def sphere_conic(projection: Projection, centre, radius) -> np.ndarray:
    """Image conic C of a sphere, scaled so that x^T C x < 0 inside its image."""
    c = np.asarray(centre, dtype=float)
    quadric = np.block([[np.eye(3), -c[:, None]], [-c[None, :], np.array([[c @ c - radius ** 2]])]])
    conic = np.linalg.inv(projection.matrix @ np.linalg.inv(quadric) @ projection.matrix.T)
    uv = projection.project(c[None, :])[0]
    x = np.array([uv[0], uv[1], 1.0])
    return conic if x @ conic @ x < 0 else -conic


def conic_value(conic, u, v):
    x = np.stack([u, v, np.ones_like(u)], axis=-1)
    return np.einsum("...i,ij,...j->...", x, conic, x)


# -- a sphere: circle / ellipse ----------------------------------------------------------------
def test_sphere_at_isocentre_is_the_analytic_disk():
    r = 8.0
    view = carm(0.0, 0.0)
    mask = sphere([0, 0, 0], r).silhouette(view.projection())
    f = SID / 0.35
    radius_px = f * r / math.sqrt(SOD ** 2 - r ** 2)
    v, u = np.mgrid[0:96, 0:96]
    rho = np.hypot(u - 47.5, v - 47.5)
    clear = np.abs(rho - radius_px) > 0.05
    assert np.array_equal(mask[clear], (rho <= radius_px)[clear])
    assert mask.sum() == pytest.approx(math.pi * radius_px ** 2, rel=0.02)


@pytest.mark.parametrize("centre", [(0.0, 0.0, 0.0), (2.5, -3.0, 2.0)])
def test_sphere_in_oblique_view_is_the_analytic_ellipse(centre):
    r = 5.0
    view = carm(-35.0, 20.0, shape=(96, 112))
    projection = view.projection()
    mask = sphere(centre, r).silhouette(projection)
    conic = sphere_conic(projection, centre, r)
    v, u = np.mgrid[0:96, 0:112].astype(float)
    inside = conic_value(conic, u, v) <= 0
    # "At least 0.05 px from the boundary": the centre and 8 points around it agree.
    agree = np.ones_like(inside)
    for ang in np.arange(8) * np.pi / 4:
        agree &= (conic_value(conic, u + 0.05 * np.cos(ang), v + 0.05 * np.sin(ang)) <= 0) == inside
    assert agree.mean() > 0.9
    assert np.array_equal(mask[agree], inside[agree])
    a = conic[:2, :2]
    area = -math.pi * np.linalg.det(conic) / np.linalg.det(a) ** 1.5
    assert mask.sum() == pytest.approx(area, rel=0.03)
    assert not mask[0].any() and not mask[-1].any() and not mask[:, 0].any() and not mask[:, -1].any()


# -- a cylinder parallel to the detector: a band bounded by the tangent planes ------------------
@pytest.mark.parametrize("angles,offset_mm,radius_mm", [((0.0, 0.0), 0.0, 3.0), ((40.0, -20.0), 6.3, 2.7),
                                                        ((-70.0, 35.0), -4.1, 1.9)])
def test_cylinder_perpendicular_to_beam_has_the_tangent_plane_width(angles, offset_mm, radius_mm):
    view = carm(*angles, shape=(64, 64), spacing=(0.7, 0.7))
    axis_point = offset_mm * view.row_direction()
    direction = view.column_direction()
    tube = Tube(np.stack([axis_point - 200 * direction, axis_point + 200 * direction]), radius_mm)
    mask = TubePhantom((tube,), "cylinder").silhouette(view)
    distance = math.hypot(SOD, offset_mm)  # source to axis, in the plane perpendicular to the axis
    phi0 = math.atan2(offset_mm, SOD)
    theta = math.asin(radius_mm / distance)
    f_v = SID / 0.7
    v_lo, v_hi = 31.5 + f_v * math.tan(phi0 - theta), 31.5 + f_v * math.tan(phi0 + theta)
    assert min(abs(x - round(x)) for x in (v_lo, v_hi)) > 0.01  # the case is not on a pixel edge
    expected = (np.arange(64) >= v_lo) & (np.arange(64) <= v_hi)
    width = math.floor(v_hi) - math.ceil(v_lo) + 1
    assert mask[:, 32].sum() == width
    # The band is exact at every column (the tangent planes contain the column direction).
    assert np.array_equal(mask, np.repeat(expected[:, None], 64, axis=1))


# -- contains ------------------------------------------------------------------------------------
def test_contains_matches_a_scalar_loop_on_random_points():
    phantom = random_phantom()
    lower, upper = phantom.bounding_box_mm()
    rng = np.random.default_rng(3)
    points = rng.uniform(lower - 2, upper + 2, size=(1500, 3))
    a, b, r = phantom.segments_mm()
    expected, margin = [], []
    for p in points:
        gaps = [point_segment_distance(p, a[i], b[i]) - r[i] for i in range(r.size)]
        expected.append(min(gaps) <= 0)
        margin.append(min(abs(g) for g in gaps))
    expected, margin = np.array(expected), np.array(margin)
    assert 0.02 < expected.mean() < 0.98
    got = phantom.contains(points)
    clear = margin > 1e-9
    assert np.array_equal(got[clear], expected[clear])


def test_contains_matches_a_segment_loop_on_the_demo_phantom():
    phantom = demo_phantom()
    rng = np.random.default_rng(11)
    lower, upper = phantom.bounding_box_mm()
    points = np.concatenate([rng.uniform(lower, upper, size=(20000, 3)),
                             phantom.lumen_points_mm(1.0) + rng.normal(scale=0.5, size=(1, 3))])
    gap = clearance_loop(phantom, points)
    got = phantom.contains(points)
    clear = np.abs(gap) > 1e-9
    assert got.any() and not got.all()
    assert np.array_equal(got[clear], (gap <= 0)[clear])


def test_contains_is_closed_and_handles_empty_input():
    phantom = sphere([1.0, 2.0, 3.0], 2.0)
    assert phantom.contains(np.array([[3.0, 2.0, 3.0], [3.0 + 1e-9, 2.0, 3.0]])).tolist() == [True, False]
    assert phantom.contains(np.empty((0, 3))).shape == (0,)


# -- silhouette vs brute force ------------------------------------------------------------------
def assert_matches_sampled_oracle(phantom: TubePhantom, view: CArmGeometry) -> None:
    mask = phantom.silhouette(view)
    dirs, source = pixel_rays(view)
    ratio = sampled_ray_ratio(phantom, dirs, source).reshape(view.image_shape)
    surely_in, surely_out = ratio <= 1.0, ratio > 1.0 + 1e-3
    assert surely_in.any() and surely_out.any()
    assert np.array_equal(mask[surely_in], np.ones(surely_in.sum(), bool))
    assert not mask[surely_out].any()


def test_silhouette_matches_brute_force_on_a_random_phantom():
    phantom = random_phantom()
    assert_matches_sampled_oracle(phantom, carm(25.0, -15.0, shape=(64, 64), spacing=(1.1, 1.3), offset=(3.0, -2.5)))


def test_silhouette_matches_brute_force_on_the_demo_phantom():
    assert_matches_sampled_oracle(demo_phantom(), carm(-30.0, 30.0, shape=(64, 64), spacing=(2.8, 2.8)))


def test_silhouette_of_a_segment_crossing_the_source_plane():
    view = carm(10.0, 5.0, shape=(40, 48), spacing=(4.0, 4.0))
    s, d, row = view.source_mm, view.detector_direction(), view.row_direction()
    tube = Tube(np.stack([s - 60 * d + 20 * row + 3 * view.column_direction(), s + 300 * d - 15 * row]), [4.0, 4.0])
    assert_matches_sampled_oracle(TubePhantom((tube,), "crossing"), view)


def test_silhouette_behind_and_around_the_source():
    view = carm(20.0, 10.0, shape=(16, 16))
    s, d = view.source_mm, view.detector_direction()
    assert not sphere(s - 100 * d, 5.0).silhouette(view).any()
    assert sphere(s - 2 * d, 5.0).silhouette(view).all()


def test_silhouette_ignores_the_scale_of_the_matrix_and_accepts_carm_geometry():
    phantom, view = random_phantom(), carm(-20.0, 10.0, shape=(48, 48), spacing=(1.5, 1.5))
    projection = view.projection()
    scaled = Projection(3.7 * projection.matrix, projection.image_shape)
    assert np.array_equal(phantom.silhouette(scaled), phantom.silhouette(projection))
    assert np.array_equal(phantom.silhouette(view), phantom.silhouette(projection))


def test_ray_segment_distance_matches_dense_minimisation():
    rng = np.random.default_rng(5)
    n = 400
    source = np.array([0.0, 0.0, 0.0])
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    a = rng.normal(size=(n, 3)) * 5 + dirs * rng.uniform(-5, 20, (n, 1))
    e = rng.normal(size=(n, 3)) * rng.uniform(0.0, 4.0, (n, 1))
    e[:60] = dirs[:60] * rng.uniform(-3, 3, (60, 1)) + rng.normal(size=(60, 3)) * 1e-7  # near-parallel
    e[60:80] = 0.0  # points
    b = a + e
    w0, w1 = source - a, source - b
    edge_sq = (e * e).sum(1)
    t_src = np.where(edge_sq > 0, np.clip((e * w0).sum(1) / np.where(edge_sq > 0, edge_sq, 1), 0, 1), 0)
    near = w0 - t_src[:, None] * e
    got = _ray_segment_distance_sq(dirs, e, edge_sq, w0, (w0 * w0).sum(1), (w1 * w1).sum(1), (e * w0).sum(1),
                                   np.cross(e, w0), (near * near).sum(1))
    t = np.linspace(0, 1, 20001)
    expected = np.empty(n)
    for i in range(n):
        x = a[i] + t[:, None] * e[i] - source
        s = np.maximum(x @ dirs[i], 0)
        expected[i] = np.min(np.linalg.norm(x - s[:, None] * dirs[i], axis=1))
    np.testing.assert_allclose(np.sqrt(got), expected, rtol=1e-6, atol=1e-6)


def test_results_do_not_depend_on_chunk_sizes(monkeypatch):
    import angiohull.synthetic.phantom as module

    phantom, view = random_phantom(), carm(15.0, 25.0, shape=(48, 40), spacing=(1.4, 1.2))
    points = np.random.default_rng(8).uniform(-30, 30, size=(3000, 3))
    before = (phantom.silhouette(view), phantom.contains(points), phantom.lumen_points_mm(1.0),
              phantom.surface_points_mm(1.0))
    monkeypatch.setattr(module, "_PAIR_CHUNK", 997)
    monkeypatch.setattr(module, "_POINT_CHUNK", 101)
    after = (phantom.silhouette(view), phantom.contains(points), phantom.lumen_points_mm(1.0),
             phantom.surface_points_mm(1.0))
    for x, y in zip(before, after):
        assert np.array_equal(x, y)


# -- surface and lumen samplings ---------------------------------------------------------------
def test_surface_points_lie_on_the_boundary_of_the_union():
    phantom = demo_phantom()
    points = phantom.surface_points_mm(0.5)
    assert points.shape[1] == 3 and points.shape[0] > 1000
    gap = clearance_loop(phantom, points)
    assert np.abs(gap).max() < 1e-6
    assert np.array_equal(points, phantom.surface_points_mm(0.5))  # deterministic
    jittered = phantom.surface_points_mm(0.5, rng=4)
    assert np.abs(clearance_loop(phantom, jittered)).max() < 1e-6
    assert np.array_equal(jittered, phantom.surface_points_mm(0.5, rng=np.random.default_rng(4)))


def test_surface_points_cover_a_sphere_and_a_capsule():
    rng = np.random.default_rng(2)
    probe = rng.normal(size=(3000, 3))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    points = sphere([1.0, -2.0, 0.5], 3.0).surface_points_mm(0.4)
    gaps, _ = cKDTree(points).query(np.array([1.0, -2.0, 0.5]) + 3.0 * probe)
    assert gaps.max() < 0.4
    capsule = TubePhantom((Tube([[0, 0, 0], [10, 0, 0]], 2.0),), "capsule")
    cyl = np.stack([rng.uniform(0, 10, 3000), 2 * probe[:, 1], 2 * probe[:, 2]], 1)
    cyl[:, 1:] *= 1 / np.linalg.norm(probe[:, 1:], axis=1, keepdims=True)
    gaps, _ = cKDTree(capsule.surface_points_mm(0.4)).query(cyl)
    assert gaps.max() < 0.4


def test_surface_points_project_inside_every_demo_silhouette():
    phantom = demo_phantom()
    points = phantom.surface_points_mm(0.5)
    for name, view in demo_views():
        projection = view.projection()
        mask = phantom.silhouette(projection)
        uv = projection.project(points)
        # A surface point's own ray meets the solid, so its projection lies in the continuous
        # silhouette: one of the 4 pixel centres around it is vessel, mostly the nearest one.
        col0, row0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        around = mask[row0, col0] | mask[row0 + 1, col0] | mask[row0, col0 + 1] | mask[row0 + 1, col0 + 1]
        assert around.all(), name
        col, row = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        assert mask[row, col].mean() > 0.85, name


def test_lumen_points_are_exactly_the_grid_nodes_inside():
    phantom = random_phantom()
    h = 0.8
    points = phantom.lumen_points_mm(h)
    index = points / h
    assert np.allclose(index, np.rint(index), atol=1e-9)
    lower, upper = phantom.bounding_box_mm()
    axes = [np.arange(math.floor(lower[k] / h) - 1, math.ceil(upper[k] / h) + 2) * h for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    gap = clearance_loop(phantom, grid)
    assert not np.any(np.abs(gap) < 1e-9)  # no node on a boundary: the comparison is exact
    expected = grid[gap <= 0]
    order = np.lexsort(np.rint(expected / h).T[::-1])
    np.testing.assert_allclose(points, expected[order], atol=1e-9)


def test_lumen_volume_of_a_sphere():
    points = sphere([0.3, -0.2, 0.1], 10.0).lumen_points_mm(0.5)
    assert points.shape[0] * 0.5 ** 3 == pytest.approx(4 / 3 * math.pi * 1000, rel=0.01)


# -- the demo ------------------------------------------------------------------------------------
def test_demo_phantom_fits_the_field_of_view():
    phantom = demo_phantom()
    assert 3 <= len(phantom.tubes) <= 4
    main = phantom.tubes[0]
    assert 100 <= main.length_mm <= 120
    assert main.radius_mm[0] == pytest.approx(2.0) and main.radius_mm[-1] == pytest.approx(1.2)
    for branch in phantom.tubes[1:]:
        assert 1.0 <= branch.radius_mm.min() and branch.radius_mm.max() <= 1.4
        assert tube_contains(phantom.tubes[0], branch.centerline_mm[0])  # leaves the main vessel
    lower, upper = phantom.bounding_box_mm()
    assert np.all(np.abs(lower) < 59.7) and np.all(np.abs(upper) < 59.7)
    assert np.linalg.norm(phantom.surface_points_mm(0.5), axis=1).max() < 47.0
    assert np.array_equal(demo_phantom().tubes[1].centerline_mm, phantom.tubes[1].centerline_mm)


def tube_contains(tube: Tube, point) -> bool:
    return bool(TubePhantom((tube,), "main").contains(np.asarray([point]))[0])


def test_demo_views_and_silhouettes():
    views = demo_views()
    assert [name for name, _ in views] == ["RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30"]
    assert [(g.primary_deg, g.secondary_deg) for _, g in views] == [(-30, 30), (60, 30), (-30, -30)]
    phantom = demo_phantom()
    for name, view in views:
        assert (view.sid_mm, view.sod_mm, view.pixel_spacing_mm, view.image_shape) == (1200, 800, (0.35, 0.35), (512, 512))
        assert view.projection().field_half_edge_mm() == pytest.approx(59.73, abs=0.01)
        mask = phantom.silhouette(view)
        assert mask.shape == (512, 512) and mask.sum() > 2000, name
        rows, cols = np.nonzero(mask)
        assert rows.min() >= 10 and cols.min() >= 10 and rows.max() <= 501 and cols.max() <= 501, name


# -- validation ------------------------------------------------------------------------------------
@pytest.mark.parametrize("centerline,radius,match", [
    (np.zeros((3, 2)), 1.0, "M, 3"),
    (np.zeros((0, 3)), 1.0, "M >= 1"),
    ([[0, 0, np.nan]], 1.0, "non-finite"),
    (np.zeros((3, 3)), [1.0, 1.0], "one radius per"),
    (np.zeros((2, 3)), [1.0, 0.0], "> 0"),
    (np.zeros((2, 3)), [1.0, np.inf], "> 0"),
    ("abc", 1.0, "M, 3"),
])
def test_tube_rejects_bad_input(centerline, radius, match):
    with pytest.raises(AngiohullError, match=match):
        Tube(centerline, radius)


def test_phantom_rejects_bad_input():
    tube = Tube([[0, 0, 0]], 1.0)
    with pytest.raises(AngiohullError, match="at least one"):
        TubePhantom((), "x")
    with pytest.raises(AngiohullError, match="wrap it"):
        TubePhantom(tube, "x")
    with pytest.raises(AngiohullError, match=r"tubes\[1\]"):
        TubePhantom((tube, "nope"), "x")
    with pytest.raises(AngiohullError, match="name"):
        TubePhantom((tube,), 3)
    phantom = TubePhantom([tube], "x")
    assert isinstance(phantom.tubes, tuple)
    with pytest.raises(AngiohullError, match=r"\(N, 3\)"):
        phantom.contains(np.zeros((4, 2)))
    with pytest.raises(AngiohullError, match="non-finite"):
        phantom.contains([[0, 0, np.nan]])
    with pytest.raises(AngiohullError, match="Projection"):
        phantom.silhouette(np.eye(3, 4))
    with pytest.raises(AngiohullError, match="spacing_mm"):
        phantom.lumen_points_mm(0.0)
    with pytest.raises(AngiohullError, match="spacing_mm"):
        phantom.surface_points_mm(-1.0)
