"""The silhouette fit against masks rendered from known tubes and shifts (an exact capsule
renderer, not the fit's own union of discs)."""

import numpy as np
import pytest

from angiohull.geometry import CArmGeometry
from angiohull.reconstruction.silhouette_fit import fit_silhouettes, mask_edge_points
from angiohull.synthetic import Tube, TubePhantom


def test_mask_edge_points_of_a_block_are_its_pixel_sides():
    mask = np.zeros((5, 6), dtype=bool)
    mask[1:3, 2:5] = True  # rows 1-2, columns 2-4
    expected = {(1.5, 1.0), (1.5, 2.0), (4.5, 1.0), (4.5, 2.0),  # left and right sides, (u, v)
                (2.0, 0.5), (3.0, 0.5), (4.0, 0.5), (2.0, 2.5), (3.0, 2.5), (4.0, 2.5)}  # top and bottom
    got = mask_edge_points(mask)
    assert got.shape == (10, 2)
    assert {tuple(p) for p in got} == expected


def _gauge_free(projections, shifts, truth):
    """Largest per-view difference left after the common 3D translation that best explains it."""
    jacobians = np.vstack([p.jacobian(np.zeros((1, 3)))[0] for p in projections])
    difference = (np.asarray(shifts) - np.asarray(truth)).ravel()
    t = np.linalg.lstsq(jacobians, difference, rcond=None)[0]
    return float(np.linalg.norm((difference - jacobians @ t).reshape(-1, 2), axis=1).max())


def _coil():
    """A tube that winds around itself, so that it overlaps itself in every view."""
    s = np.linspace(0.0, 1.0, 2000)
    centre = np.column_stack([30 * np.sin(2 * np.pi * 1.5 * s), 25 * np.cos(2 * np.pi * 2 * s), 60 * (s - 0.5)])
    radius = 1.8 - 0.8 * s
    return centre, radius


@pytest.mark.parametrize("seed", [0, 1])
def test_fit_recovers_subpixel_shifts_through_overlaps(seed):
    rng = np.random.default_rng(seed)
    centre, radius = _coil()
    phantom = TubePhantom((Tube(centre, radius),), "coil")
    carms = [CArmGeometry(a, b, 1100.0, 750.0, (0.3, 0.3), (512, 512)) for a, b in ((-30, 25), (45, 20), (10, -35))]
    projections = [c.projection() for c in carms]
    truth = np.array([[0.0, 0.0], [1.4, -1.0], [-1.0, 1.5]])
    masks = [phantom.silhouette(p.shifted(*s)) for p, s in zip(projections, truth)]
    # start: the header's shifts (zero), balls every 0.43 mm, off by 0.2 mm (per axis) and 20 % too wide
    centres = centre[::2] + rng.normal(0.0, 0.2, size=centre[::2].shape)
    fit = fit_silhouettes(projections, [mask_edge_points(m) for m in masks], centres, 1.2 * radius[::2],
                          np.zeros((3, 2)))
    assert _gauge_free(projections, np.zeros((3, 2)), truth) > 0.9
    assert _gauge_free(projections, fit.shifts_px, truth) < 0.1
    assert np.median(np.abs(fit.radius_mm - radius[::2])) < 0.05
    assert max(fit.residual_rms_px) < 0.4 and fit.iterations < 30
