"""Optional CUDA path of the hierarchical engines (``lookup`` and ``octree``), with CuPy.

:func:`carve_cuda` runs the algorithm of :func:`~angiohull.reconstruction.hierarchical.carve_hierarchical`
(same root and leaf sizes, same sparsest-first view order, same conservative footprint test with a
summed-area table, same exact :class:`~angiohull.reconstruction.engines.MaskLookup` rule) with the
per-cell and per-point work on the GPU, and keeps exactly the points the CPU engines keep. Exactness
rests on the arithmetic: every quantity is computed with the same IEEE operations in the same order
as :func:`~angiohull.reconstruction.engines.project_row` and ``MaskLookup.near_uv``, one CuPy
ufunc per operation (no fused kernels, which could contract a multiply and an add into an FMA);
``+ - * /``, ``sqrt``, ``floor`` and ``ceil`` are correctly rounded on the GPU as on the CPU.

The implementation is :func:`~angiohull.reconstruction.hierarchical.carve_hierarchical` itself,
run with ``xp=cupy``. CuPy is imported only when a function needs it.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import ReconstructionError
from ..geometry import Projection
from .cube import Lattice
from .engines import CarveOutcome
from .hierarchical import HIERARCHICAL_ENGINES, carve_hierarchical, cell_sizes

__all__ = ["cuda_available", "carve_cuda", "CUDA_ENGINES"]

CUDA_ENGINES = HIERARCHICAL_ENGINES
"""Engines :func:`carve_cuda` runs."""

GPU_CHUNK_POINTS = 1 << 24
"""Leaf points tested at once on the device (bounds device memory to a few GiB)."""

_MISSING = ("--device cuda needs CuPy and a CUDA GPU: pip install 'angiohull[gpu]' (cupy-cuda12x) "
            "or the CuPy wheel matching your CUDA version (see https://docs.cupy.dev/en/stable/install.html), "
            "or run on the CPU with --device cpu")


def cuda_available() -> bool:
    """True when CuPy imports and sees at least one CUDA device; never raises."""
    try:
        import cupy

        return int(cupy.cuda.runtime.getDeviceCount()) > 0
    except Exception:  # ImportError, missing driver or libraries, CUDA runtime errors
        return False


def _cupy():
    if not cuda_available():
        raise ReconstructionError(_MISSING)
    import cupy

    return cupy


def carve_cuda(engine: str, lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
               threshold_px: float, min_views: int | None = None) -> CarveOutcome:
    """The ``lookup`` or ``octree`` engine on a CUDA GPU: exactly the CPU engine's kept points.

    Parameters
    ----------
    engine : {"lookup", "octree"}
    lattice, projections, masks, threshold_px, min_views
        As for the CPU engines (masks: (rows, cols) bool NumPy arrays, one per projection).

    Returns
    -------
    CarveOutcome
        NumPy arrays; points in lattice order, survivors per view and the view order as the CPU
        engine's.

    Raises
    ------
    ReconstructionError
        When CuPy or a CUDA device is missing, or for an engine other than lookup/octree.
    """
    if engine not in CUDA_ENGINES:
        raise ReconstructionError(f"the CUDA path runs the engines {list(CUDA_ENGINES)}, not {engine!r}")
    cupy = _cupy()
    root, leaf = cell_sizes(engine, lattice.resolution)
    return carve_hierarchical(lattice, projections, [np.asarray(m, dtype=bool) for m in masks],
                              threshold_px=float(threshold_px), root_size=root, leaf_size=leaf, xp=cupy,
                              chunk_points=GPU_CHUNK_POINTS, min_views=min_views)
