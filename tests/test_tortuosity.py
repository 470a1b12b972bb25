"""Tortuosity indices against closed-form curves."""

import math

import numpy as np
import pytest

from angiohull.errors import AngiohullError
from angiohull.synthetic.tortuosity import (curvature_metric, distance_metric, resample_polyline,
                                            sum_of_angles_metric)


def _circle_arc(radius, angle, n=2000):
    t = np.linspace(0.0, angle, n)
    return np.stack([radius * np.cos(t), radius * np.sin(t), np.zeros_like(t)], axis=1)


def _helix(radius, pitch, turns, n=20000):
    t = np.linspace(0.0, 2 * math.pi * turns, n)
    return np.stack([radius * np.cos(t), radius * np.sin(t), pitch * t / (2 * math.pi)], axis=1)


def test_straight_line_is_not_tortuous():
    line = np.linspace([0, 0, 0], [30, 40, 0], 7)
    assert distance_metric(line) == pytest.approx(1.0, abs=1e-12)
    assert curvature_metric(line) == pytest.approx(0.0, abs=1e-6)
    assert sum_of_angles_metric(line) == pytest.approx(0.0, abs=1e-6)


def test_semicircle_distance_metric_is_pi_over_two():
    # Arc length pi r over chord 2 r (the polyline is a fine chord approximation).
    assert distance_metric(_circle_arc(20.0, math.pi)) == pytest.approx(math.pi / 2, rel=1e-5)


@pytest.mark.parametrize("radius", [10.0, 25.0, 60.0])
def test_curvature_metric_of_a_circle_is_its_curvature_per_cm(radius):
    # A 1 mm chord of a circle turns by 2 asin(1 / 2r) per step: 10 / r per cm up to O(1/r^3).
    arc = _circle_arc(radius, 1.5 * math.pi)
    expected = 10.0 / radius
    assert curvature_metric(arc) == pytest.approx(expected, rel=2e-3)
    # Planar: SOAM adds no torsion.
    assert sum_of_angles_metric(arc) == pytest.approx(curvature_metric(arc), rel=1e-9)


def test_helix_soam_combines_curvature_and_torsion():
    # A helix has constant curvature k = r / (r^2 + c^2) and torsion t = c / (r^2 + c^2), c = pitch / 2 pi;
    # per 1 mm step SOAM adds sqrt(k^2 + t^2) (small-step limit), i.e. 10 sqrt(k^2 + t^2) per cm.
    r, pitch = 15.0, 40.0
    c = pitch / (2 * math.pi)
    k, tau = r / (r * r + c * c), c / (r * r + c * c)
    helix = _helix(r, pitch, 3)
    assert curvature_metric(helix) == pytest.approx(10 * k, rel=5e-3)
    assert sum_of_angles_metric(helix) == pytest.approx(10 * math.hypot(k, tau), rel=5e-3)


def test_indices_do_not_depend_on_the_input_sampling():
    coarse = _circle_arc(20.0, math.pi, n=400)
    fine = _circle_arc(20.0, math.pi, n=4000)
    assert curvature_metric(coarse) == pytest.approx(curvature_metric(fine), rel=2e-3)


def test_resample_keeps_the_end_point_and_step():
    line = np.array([[0.0, 0, 0], [10.5, 0, 0]])
    points = resample_polyline(line, 1.0)
    assert points.shape == (12, 3)
    assert np.allclose(np.diff(points[:-1, 0]), 1.0)
    assert points[-1, 0] == pytest.approx(10.5)


def test_degenerate_polyline_is_rejected():
    with pytest.raises(AngiohullError, match="positive length"):
        curvature_metric(np.zeros((3, 3)))
