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
