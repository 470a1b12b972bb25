"""The angiogram renderer: exact chord lengths, its mask, noise statistics, collimator, determinism."""

import math

import numpy as np
import pytest

from angiohull.errors import AngiohullError
from angiohull.geometry import CArmGeometry
from angiohull.synthetic import Tube, TubePhantom, demo_phantom, demo_views
from angiohull.synthetic.angiogram import (
    AngiogramParameters,
    collimator_field,
    render_angiogram,
    to_counts,
    vessel_chord_length_mm,
)

AP = CArmGeometry(0.0, 0.0, 1200.0, 800.0, (0.7, 0.7), (64, 64))  # source at y = +800, beam towards -y


def _rays(carm):
    """Source and unit ray direction of every pixel centre, (rows*cols, 3)."""
    p = carm.projection()
    rows, cols = p.image_shape
    v, u = np.mgrid[0:rows, 0:cols]
    d = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1) @ np.linalg.inv(p.matrix[:, :3]).T
    return p.camera_centre_mm, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_chord_through_one_ball_is_twice_the_half_chord():
    centre, radius = np.array([3.0, -2.0, 1.5]), 6.0
    ball = TubePhantom((Tube(centre[None], radius),), "ball")
    chord = vessel_chord_length_mm(ball, AP)
    source, dirs = _rays(AP)
    rel = centre - source
    dist_sq = rel @ rel - (dirs @ rel) ** 2
    expected = np.where(dist_sq < radius ** 2, 2.0 * np.sqrt(np.maximum(radius ** 2 - dist_sq, 0.0)), 0.0)
    np.testing.assert_allclose(chord.ravel(), expected, rtol=0, atol=1e-9)
    assert chord.max() > 11.9  # the central rays pass near the diameter


def test_overlapping_balls_along_a_ray_count_once():
    # Two balls of radius 5 centred at y = 0 and y = -4 on the central ray: the union spans
    # y in [-9, 5], 14 mm (the sum of the chords would be 20 mm).
    carm = CArmGeometry(0.0, 0.0, 1200.0, 800.0, (0.7, 0.7), (65, 65))  # pixel (32, 32) is the central ray
    tubes = (Tube(np.array([[0.0, 0.0, 0.0]]), 5.0), Tube(np.array([[0.0, -4.0, 0.0]]), 5.0))
    chord = vessel_chord_length_mm(TubePhantom(tubes, "two"), carm)
    assert chord[32, 32] == pytest.approx(14.0, abs=1e-9)


def test_oblique_capsule_matches_sampling_along_the_ray():
    # Independent oracle: integrate the indicator of the solid along each ray (step 0.01 mm).
    tube = Tube(np.array([[-8.0, -5.0, -6.0], [2.0, 4.0, 3.0], [9.0, -3.0, 7.0]]), np.array([1.5, 2.5, 2.0]))
    phantom = TubePhantom((tube,), "bent")
    carm = CArmGeometry(35.0, -20.0, 1100.0, 750.0, (1.0, 1.0), (40, 40))
    chord = vessel_chord_length_mm(phantom, carm)
    source, dirs = _rays(carm)
    rng = np.random.default_rng(3)
    hit = np.flatnonzero(chord.ravel() > 0.5)
    picks = np.concatenate([rng.choice(hit, 8, replace=False), rng.choice(chord.size, 4, replace=False)])
    step = 0.01
    s = 750.0 - 20.0 + step * (np.arange(4000) + 0.5)  # covers |X| < 20 mm around the isocentre
    for pixel in picks:
        samples = source + s[:, None] * dirs[pixel]
        measured = step * np.count_nonzero(phantom.contains(samples))
        assert chord.ravel()[pixel] == pytest.approx(measured, abs=2 * step), pixel


@pytest.mark.parametrize("view", range(3))
def test_chord_is_positive_exactly_on_the_silhouette(view):
    phantom = demo_phantom()
    _, carm = demo_views()[view]
    chord = vessel_chord_length_mm(phantom, carm)
    np.testing.assert_array_equal(chord > 0, phantom.silhouette(carm))


def test_render_is_reproducible_and_vessels_are_dark():
    phantom = demo_phantom()
    _, carm = demo_views()[0]
    params = AngiogramParameters(collimator_px=8)
    first = render_angiogram(phantom, carm, 7, params)
    again = render_angiogram(phantom, carm, np.random.default_rng(7), params)
    other = render_angiogram(phantom, carm, 8, params)
    np.testing.assert_array_equal(first.image, again.image)
    assert not np.array_equal(first.image, other.image)
    np.testing.assert_array_equal(first.mask, phantom.silhouette(carm))
    inside = first.image[first.mask & first.field].mean()
    around = first.image[~first.mask & first.field].mean()
    assert inside < 0.8 * around
    assert first.image[~first.field].mean() < 0.3 * around  # behind the shutters
    assert first.image.dtype == np.float64 and first.image.min() >= 0


def test_quantum_noise_has_the_poisson_standard_deviation():
    # No texture, ramp, blur or electronic noise: an unattenuated flat field of N quanta has a
    # relative standard deviation 1 / sqrt(N).
    params = AngiogramParameters(background_attenuation=0.0, background_texture=0.0, background_ramp=0.0, blur_px=0.0,
                                 photons_per_pixel=2500.0, electronic_noise=0.0)
    far = TubePhantom((Tube(np.array([[0.0, 0.0, 0.0]]), 0.1),), "dot")
    image = render_angiogram(far, CArmGeometry(0.0, 0.0, 1200.0, 800.0, (0.5, 0.5), (256, 256)), 0, params).image
    background = image[:100]
    assert background.mean() == pytest.approx(1.0, abs=0.002)
    assert background.std() == pytest.approx(1.0 / math.sqrt(2500.0), rel=0.03)


def test_noise_free_image_is_beer_lambert():
    params = AngiogramParameters(background_attenuation=0.5, background_texture=0.0, background_ramp=0.0, blur_px=0.0,
                                 photons_per_pixel=math.inf, electronic_noise=0.0, vessel_attenuation_per_mm=0.3)
    phantom = demo_phantom()
    _, carm = demo_views()[1]
    result = render_angiogram(phantom, carm, 0, params)
    np.testing.assert_allclose(result.image, np.exp(-(0.5 + 0.3 * result.chord_mm)), rtol=1e-12)


def test_collimator_field_has_rounded_corners():
    field = collimator_field((100, 120), 10, 20.0)
    assert field[50, 10] and field[50, 109] and field[10, 60] and field[89, 60]
    assert not field[50, 9] and not field[9, 60] and not field[90, 60] and not field[50, 110]
    assert not field[10, 10]  # the corner is cut by the rounding
    assert field[10 + 20, 10 + 20 - 20]  # the arc's tangent point on the left edge
    assert collimator_field((5, 5), 0, 3.0).all()


def test_bad_parameters_and_inputs_are_reported():
    with pytest.raises(AngiohullError, match="photons_per_pixel must be a positive number"):
        AngiogramParameters(photons_per_pixel=0)
    with pytest.raises(AngiohullError, match="blur_px must be >= 0"):
        AngiogramParameters(blur_px=-1)
    with pytest.raises(AngiohullError, match="collimator_px must be an integer >= 0"):
        AngiogramParameters(collimator_px=2.5)
    with pytest.raises(AngiohullError, match="phantom must be a TubePhantom"):
        vessel_chord_length_mm("tree", AP)
    with pytest.raises(AngiohullError, match="projection must be a Projection or CArmGeometry"):
        render_angiogram(demo_phantom(), "RAO 30")


def test_to_counts_quantises_to_the_bit_depth():
    image = np.array([[0.0, 0.25], [0.5, 1.0]])
    np.testing.assert_array_equal(to_counts(image, bits=8), [[0, 64], [128, 255]])
    counts = to_counts(image, bits=12, white=2.0)
    assert counts.dtype == np.uint16 and counts.max() == 2048
    with pytest.raises(AngiohullError, match="bits must be within 1..16"):
        to_counts(image, bits=17)
