"""Geometry against hand-worked cases (docs/conventions.md, "Geometry conventions")."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from angiohull.errors import GeometryError
from angiohull.geometry import (CArmGeometry, Projection, cube_half_edge_mm, format_clinical_angles,
                                parse_clinical_angles)


def carm(primary=0.0, secondary=0.0, sid=1200.0, sod=800.0, spacing=(0.35, 0.35), shape=(512, 512), offset=(0.0, 0.0)):
    return CArmGeometry(primary, secondary, sid, sod, spacing, shape, offset)


def test_ap_view_puts_detector_in_front_of_the_chest():
    c = carm()
    np.testing.assert_allclose(c.detector_direction(), [0, -1, 0], atol=1e-15)  # LPS: -y is anterior
    np.testing.assert_allclose(c.source_mm, [0, 800, 0], atol=1e-12)  # source behind the patient
    np.testing.assert_allclose(c.detector_centre_mm, [0, -400, 0], atol=1e-12)


def test_lao_90_puts_detector_on_patients_left():
    c = carm(primary=90)
    np.testing.assert_allclose(c.detector_direction(), [1, 0, 0], atol=1e-15)  # +x = patient left
    np.testing.assert_allclose(c.projection().camera_centre_mm, [-800, 0, 0], atol=1e-9)


def test_rao_90_puts_detector_on_patients_right():
    np.testing.assert_allclose(carm(primary=-90).detector_direction(), [-1, 0, 0], atol=1e-15)


def test_cranial_tilts_detector_towards_the_head():
    d = carm(secondary=30).detector_direction()
    assert d[2] == pytest.approx(0.5)
    assert d[1] == pytest.approx(-math.cos(math.radians(30)))
    assert carm(secondary=-30).detector_direction()[2] == pytest.approx(-0.5)


def test_isocentre_projects_to_principal_point_with_offset():
    p = carm(primary=-30, secondary=20, shape=(400, 600), offset=(3.0, -2.0)).projection()
    np.testing.assert_allclose(p.project(np.zeros((1, 3))), [[299.5 + 3.0, 199.5 - 2.0]], atol=1e-9)
    assert p.principal_point_px == pytest.approx((302.5, 197.5))


def test_magnification_sid_over_sod_at_isocentre():
    c = carm(primary=25, secondary=-15, spacing=(0.3, 0.4))
    p = c.projection()
    u0, v0 = p.project(np.zeros((1, 3)))[0]
    u1, v1 = p.project(c.column_direction()[None] * 1.0)[0]  # 1 mm along the column direction
    assert u1 - u0 == pytest.approx(1200 / 800 / 0.4)
    assert v1 == pytest.approx(v0)
    u2, v2 = p.project(c.row_direction()[None] * 1.0)[0]
    assert v2 - v0 == pytest.approx(1200 / 800 / 0.3)
    assert c.isocentre_pixel_spacing_mm == pytest.approx((0.2, 0.4 / 1.5))


def test_ap_image_orientation_left_to_the_right_head_up():
    p = carm().projection()
    centre = p.project(np.zeros((1, 3)))[0]
    left = p.project(np.array([[10.0, 0, 0]]))[0]  # patient left
    head = p.project(np.array([[0, 0, 10.0]]))[0]  # towards the head
    assert left[0] > centre[0] and left[1] == pytest.approx(centre[1])
    assert head[1] < centre[1] and head[0] == pytest.approx(centre[0])


def test_hand_worked_point_lao_30():
    # LAO 30, no angulation: d = (1/2, -sqrt3/2, 0), col = (sqrt3/2, 1/2, 0), row = (0, 0, -1)
    c = carm(primary=30)
    x = np.array([[10.0, 20.0, -5.0]])
    w = 10 * 0.5 + 20 * -math.sqrt(3) / 2 + 800
    u = 255.5 + 1200 / w * (10 * math.sqrt(3) / 2 + 20 * 0.5) / 0.35
    v = 255.5 + 1200 / w * 5.0 / 0.35
    np.testing.assert_allclose(c.projection().project(x), [[u, v]], rtol=1e-12)
    assert c.projection().depth_mm(x)[0] == pytest.approx(w)


def test_matrix_round_trip_camera_centre_and_focal_lengths():
    c = carm(primary=-42, secondary=17, sid=1100, sod=760, spacing=(0.3, 0.25))
    p = c.projection()
    np.testing.assert_allclose(p.camera_centre_mm, c.source_mm, atol=1e-9)
    assert p.focal_lengths_px == pytest.approx((1100 / 0.25, 1100 / 0.3))
    assert p.depth_mm(np.zeros((1, 3)))[0] == pytest.approx(760)
    # the same view rebuilt from the bare matrix
    q = Projection(p.matrix.tolist(), p.image_shape)
    pts = np.random.default_rng(0).uniform(-50, 50, (20, 3))
    np.testing.assert_allclose(q.project(pts), p.project(pts))


def test_carm_matrices_are_mirrored():
    # col x row = -d for the docs/conventions.md frame, so every C-arm matrix has det < 0
    assert carm(primary=33, secondary=-12).projection().is_mirrored


def test_positive_multiple_describes_the_same_view():
    p = carm(primary=10, secondary=5).projection()
    q = Projection(p.matrix * 7.5, p.image_shape)
    pts = np.random.default_rng(1).uniform(-60, 60, (10, 3))
    np.testing.assert_allclose(q.project(pts), p.project(pts), rtol=1e-12)
    np.testing.assert_allclose(q.depth_mm(pts), p.depth_mm(pts), rtol=1e-12)


def test_mirrored_matrix_flips_columns_and_keeps_the_cube():
    p = carm(primary=0, secondary=0, shape=(512, 512)).projection()
    flip = np.array([[-1.0, 0, 511.0], [0, 1, 0], [0, 0, 1]])  # u' = 511 - u
    q = Projection(flip @ p.matrix, p.image_shape)
    assert q.is_mirrored != p.is_mirrored
    pts = np.random.default_rng(2).uniform(-50, 50, (10, 3))
    np.testing.assert_allclose(q.project(pts)[:, 0], 511 - p.project(pts)[:, 0])
    assert q.field_half_edge_mm() == pytest.approx(p.field_half_edge_mm())
    np.testing.assert_allclose(q.camera_centre_mm, p.camera_centre_mm, atol=1e-9)


def test_cube_half_edge_from_carm_formula_and_from_bare_matrix():
    views = [carm(primary=30, sid=1200, sod=800, spacing=(0.35, 0.35), shape=(512, 512)),
             carm(primary=-20, sid=1000, sod=700, spacing=(0.3, 0.3), shape=(600, 400))]
    expected = max(800 * 512 * 0.35 / (2 * 1200), 700 * 600 * 0.3 / (2 * 1000))
    assert cube_half_edge_mm([v.projection() for v in views]) == pytest.approx(expected)
    # the authors' mirrored matrix of the peer-synthetic data (docs/conventions.md: 59.733 mm)
    peer = Projection([[0.0, 3428.5714285714284, 256.0, 204800.0], [3428.5714285714284, 0.0, 256.0, 204800.0],
                       [0.0, 0.0, 1.0, 800.0]], (512, 512))
    assert peer.is_mirrored
    assert cube_half_edge_mm([peer]) == pytest.approx(59.7333333, abs=1e-6)
    with pytest.raises(GeometryError, match="at least one view"):
        cube_half_edge_mm([])


@pytest.mark.parametrize("matrix, match", [
    (np.zeros((3, 3)), r"shape \(3, 4\)"),
    ([[1, 2, 3, 4], [5, 6, 7, 8]], r"shape \(3, 4\)"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, np.nan, 1]], "non-finite"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 1]], "degenerate"),
    ("abc", "3x4"),
])
def test_bad_matrices_are_rejected(matrix, match):
    with pytest.raises(GeometryError, match=match):
        Projection(matrix, (10, 10))


@pytest.mark.parametrize("shape", [(0, 10), (10,), (10, 10, 3), (10.5, 4), (-1, 4)])
def test_bad_image_shapes_are_rejected(shape):
    with pytest.raises(GeometryError, match="image_shape"):
        Projection(np.eye(3, 4) + np.array([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 5.0]]), shape)


@pytest.mark.parametrize("kwargs, match", [
    (dict(sid=800, sod=800), "sod_mm must be smaller than sid_mm"),
    (dict(sid=700, sod=800), "sod_mm must be smaller than sid_mm"),
    (dict(sod=-5), "sod_mm must be a positive"),
    (dict(sid=float("inf")), "sid_mm must be a positive finite"),
    (dict(spacing=(0.35, -0.1)), r"pixel_spacing_mm\[1\]"),
    (dict(spacing=(0.35, float("nan"))), r"pixel_spacing_mm\[1\]"),
    (dict(spacing=0.35), "pixel_spacing_mm must be"),
    (dict(primary=float("nan")), "primary_deg"),
    (dict(primary=270), "primary_deg must be within"),
    (dict(secondary=95), "secondary_deg must be within"),
    (dict(shape=(512, 0)), "image_shape"),
])
def test_bad_carm_parameters_are_rejected(kwargs, match):
    with pytest.raises(GeometryError, match=match):
        carm(**kwargs)


@pytest.mark.parametrize("text, expected", [
    ("RAO 30 CRA 20", (-30, 20)), ("LAO 45, CAU 10", (45, -10)), ("lao45 cau10", (45, -10)),
    ("RAO 30", (-30, 0)), ("CRA 40", (0, 40)), ("AP", (0, 0)), ("LAO 31.3° CRA 0.1°", (31.3, 0.1)),
    ("CAUD 25 RAO 10", (-10, -25)), ("LAO 60; CRANIAL 30", (60, 30)),
])
def test_parse_clinical_angles(text, expected):
    assert parse_clinical_angles(text) == pytest.approx(expected)


@pytest.mark.parametrize("text", ["", "RAO", "RAO -30", "RAO 30 LAO 10", "CRA 10 CAU 5", "left 30", "RAO 30 CRA 20 x", None])
def test_parse_clinical_angles_rejects_nonsense(text):
    with pytest.raises(ValueError, match="clinical angles"):
        parse_clinical_angles(text)


@given(st.floats(-180, 180), st.floats(-90, 90))
def test_format_then_parse_round_trips_to_a_tenth_of_a_degree(primary, secondary):
    back = parse_clinical_angles(format_clinical_angles(primary, secondary))
    assert back[0] == pytest.approx(primary, abs=0.05 + 1e-9)
    assert back[1] == pytest.approx(secondary, abs=0.05 + 1e-9)


@settings(max_examples=60)
@given(st.floats(-180, 180), st.floats(-90, 90), st.floats(500, 1500), st.floats(0.2, 0.9))
def test_carm_frame_is_orthonormal_and_the_central_ray_hits_the_principal_point(primary, secondary, sid, sod_frac):
    c = carm(primary, secondary, sid=sid, sod=sid * sod_frac, shape=(300, 200))
    frame = np.stack([c.column_direction(), c.row_direction(), c.detector_direction()])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
    p = c.projection()
    np.testing.assert_allclose(p.camera_centre_mm, c.source_mm, atol=1e-7 * sid)
    ray = c.source_mm + np.outer([0.3, 0.7, 0.95], c.detector_centre_mm - c.source_mm)
    np.testing.assert_allclose(p.project(ray), [[99.5, 149.5]] * 3, atol=1e-7)
    assert p.field_half_edge_mm() == pytest.approx(c.sod_mm * max(200 * 0.35, 300 * 0.35) / (2 * sid))


def test_magnified_view_is_the_same_pose_with_a_longer_source_to_image_distance():
    # Oracle: the C-arm formula with SID * f (the principal point stays; focal lengths scale by f).
    from dataclasses import replace

    carm = CArmGeometry(-31.0, 22.0, 1100.0, 760.0, (0.3, 0.35), (480, 512), (4.0, -3.0))
    points = np.random.default_rng(3).uniform(-60, 60, (50, 3))
    for factor in (0.9, 1.0, 1.07):
        expected = replace(carm, sid_mm=carm.sid_mm * factor).projection().project(points)
        np.testing.assert_allclose(carm.projection().magnified(factor).project(points), expected, atol=1e-9)
    # scaled about the principal point: that pixel does not move
    p = carm.projection()
    centre = np.array(p.principal_point_px)
    ray_point = p.camera_centre_mm + 500.0 * np.linalg.solve(p.matrix[:, :3], np.append(centre, 1.0))
    np.testing.assert_allclose(p.magnified(0.8).project(ray_point[None])[0], centre, atol=1e-9)


def test_jacobian_matches_central_differences():
    projection = carm(25.0, -15.0, offset=(3.0, -2.0)).projection()
    points = np.random.default_rng(4).uniform(-60.0, 60.0, size=(20, 3))
    step = 1e-4
    expected = np.stack([(projection.project(points + step * e) - projection.project(points - step * e)) / (2 * step)
                         for e in np.eye(3)], axis=2)
    assert projection.jacobian(points).shape == (20, 2, 3)
    np.testing.assert_allclose(projection.jacobian(points), expected, rtol=1e-7, atol=1e-9)


def test_every_storage_of_a_view_has_the_same_canonical_image():
    import itertools

    from angiohull.geometry import ImageStorage, canonical_storage

    rng = np.random.default_rng(5)
    for _ in range(10):
        carm = CArmGeometry(rng.uniform(-120, 120), rng.uniform(-45, 45), 1100.0, rng.uniform(600, 800),
                            (0.3, 0.4), (60, 70), tuple(rng.uniform(-5, 5, 2)))
        projection, image = carm.projection(), rng.random((60, 70))
        points = rng.normal(size=(20, 3)) * 15
        canonical = canonical_storage(projection)
        reference_image, reference = canonical.apply_image(image), canonical.apply(projection)
        for flags in itertools.product([False, True], repeat=3):
            storage = ImageStorage(*flags)
            stored, stored_image = storage.apply(projection), storage.apply_image(image)
            # the same view: every point lands on the same image value
            uv, uv_stored = projection.project(points), stored.project(points)
            rows, cols = np.floor(uv[:, 1] + 0.5).astype(int), np.floor(uv[:, 0] + 0.5).astype(int)
            inside = (rows >= 0) & (rows < 60) & (cols >= 0) & (cols < 70)
            stored_rc = np.floor(uv_stored[inside][:, ::-1] + 0.5).astype(int)
            np.testing.assert_array_equal(stored_image[tuple(stored_rc.T)], image[rows[inside], cols[inside]])
            again = canonical_storage(stored)
            np.testing.assert_array_equal(again.apply_image(stored_image), reference_image)
            np.testing.assert_allclose(again.apply(stored).project(points), reference.project(points), atol=1e-9)


@pytest.mark.parametrize("first, second", [("RAO 30 CAU 25", "LAO 45 CRA 20"), ("AP", "LAO 90"),
                                           ("RAO 30 CAU 25", "LAO 150 CRA 15"), ("LAO 10 CRA 5", "LAO 10 CRA 5")])
def test_the_angle_between_views_is_the_angle_between_their_detector_directions(first, second):
    from angiohull.geometry import angle_between_views_deg

    carms = [CArmGeometry(*parse_clinical_angles(v), 1200.0, 800.0, (0.35, 0.35), (512, 512)) for v in (first, second)]
    expected = np.degrees(np.arccos(np.clip(carms[0].detector_direction() @ carms[1].detector_direction(), -1, 1)))
    # the central ray runs from the source through the isocentre to the detector's centre
    assert angle_between_views_deg(carms[0].projection(), carms[1].projection()) == pytest.approx(expected, abs=1e-6)
    # a positive scale of the matrix changes nothing
    scaled = Projection(3.0 * carms[1].projection().matrix, carms[1].projection().image_shape)
    assert angle_between_views_deg(carms[0].projection(), scaled) == pytest.approx(expected, abs=1e-6)
