"""Small generated inputs shared by several test files."""

import numpy as np
from scipy import ndimage as ndi

from angiohull.geometry import CArmGeometry


def random_case(seed, n_views=3, shape=(96, 80)):
    """Blobby random masks (vessel-like clusters plus speckle) in random C-arm views."""
    rng = np.random.default_rng(seed)
    projections, masks = [], []
    for _ in range(n_views):
        carm = CArmGeometry(rng.uniform(-120, 120), rng.uniform(-45, 45), 1000.0, rng.uniform(600, 800),
                            (1.5, 1.5), shape, tuple(rng.uniform(-5, 5, 2)))
        seeds = rng.random(shape) < 0.004
        mask = ndi.binary_dilation(seeds, iterations=int(rng.integers(1, 4))) | (rng.random(shape) < 0.01)
        projections.append(carm.projection())
        masks.append(mask)
    return projections, masks


def geometry_error_px(jacobians, estimated, truth):
    """Largest per-view difference of two sets of view shifts ``(N, 2)`` left after removing the
    common 3D translation ``t`` (every view moved by ``J_v t``) that best explains it, in the least-
    squares sense: the error of the geometry, whatever the calibration's gauge."""
    jacobians = np.vstack(jacobians)
    difference = (np.asarray(estimated, dtype=float) - np.asarray(truth, dtype=float)).ravel()
    t = np.linalg.lstsq(jacobians, difference, rcond=None)[0]
    return float(np.linalg.norm((difference - jacobians @ t).reshape(-1, 2), axis=1).max())
