"""Optional CUDA path of the hierarchical engines (``lookup`` and ``octree``), with CuPy.

:func:`carve_cuda` runs the algorithm of :func:`~angiohull.reconstruction.hierarchical.carve_hierarchical`
(same root and leaf sizes, same sparsest-first view order, same conservative footprint test with a
summed-area table, same exact :class:`~angiohull.reconstruction.engines.MaskLookup` rule) with the
per-cell and per-point work on the GPU, and keeps exactly the points the CPU engines keep. Exactness
rests on the arithmetic: every quantity is computed with the same IEEE operations in the same order
as :func:`~angiohull.reconstruction.engines.project_in_front` and ``MaskLookup.near``, one CuPy
ufunc per operation (no fused kernels, which could contract a multiply and an add into an FMA);
``+ - * /``, ``sqrt``, ``floor`` and ``ceil`` are correctly rounded on the GPU as on the CPU.

The helpers take the array module ``xp`` (``cupy`` here; ``numpy`` gives the CPU result, which is
how they can be checked without a GPU). CuPy is imported only when a function needs it.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import ReconstructionError
from ..geometry import Projection
from .cube import Lattice
from .engines import CarveOutcome, MaskLookup, sparsest_first
from .hierarchical import FootprintTest

__all__ = ["cuda_available", "carve_cuda", "CUDA_ENGINES"]

CUDA_ENGINES = ("lookup", "octree")
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


def _root_leaf(engine: str, k: int) -> tuple[int, int]:
    """Root and leaf cell sizes of carve_lookup / carve_octree."""
    if engine == "lookup":
        return 16, 4
    return min(128, 1 << max(2, int(np.ceil(np.log2(k))))), 4


def _project(x, y, z, m, rows: int):
    """``(x*m[r,0] + y*m[r,1] + z*m[r,2] + m[r,3])``, left to right, as project_in_front."""
    return x * m[rows][0] + y * m[rows][1] + z * m[rows][2] + m[rows][3]


class _Footprint:
    """FootprintTest.may_keep on the array module ``xp`` (the table is the CPU class's)."""

    def __init__(self, xp, projection: Projection, mask: np.ndarray, threshold_px: float):
        cpu = FootprintTest(projection, mask, threshold_px)
        self.xp, self.rows, self.cols, self.reach = xp, cpu.rows, cpu.cols, cpu.reach
        self.m = [[float(v) for v in row] for row in cpu.matrix]
        self.table = xp.asarray(cpu.table)
        self.bits = [xp.asarray(np.array([(c >> s) & 1 for c in range(8)], dtype=bool)) for s in (2, 1, 0)]

    def may_keep(self, lo, hi):
        xp, m = self.xp, self.m
        # (n, 8) corners, corner c taking hi on axis 0/1/2 where bit 4/2/1 of c is set
        x, y, z = (xp.where(bit[None, :], hi[:, a:a + 1], lo[:, a:a + 1]) for a, bit in enumerate(self.bits))
        w = _project(x, y, z, m, 2)
        front = w > 0
        all_front = front.all(axis=1)
        w = xp.where(front, w, 1.0)  # the boxes with a corner behind the source are kept whatever u, v
        u = _project(x, y, z, m, 0) / w
        v = _project(x, y, z, m, 1) / w
        c0 = xp.clip(xp.ceil(u.min(axis=1) - self.reach), 0, self.cols).astype(np.intp)
        c1 = xp.clip(xp.floor(u.max(axis=1) + self.reach) + 1, 0, self.cols).astype(np.intp)
        r0 = xp.clip(xp.ceil(v.min(axis=1) - self.reach), 0, self.rows).astype(np.intp)
        r1 = xp.clip(xp.floor(v.max(axis=1) + self.reach) + 1, 0, self.rows).astype(np.intp)
        t = self.table
        count = t[r1, c1] - t[r0, c1] - t[r1, c0] + t[r0, c0]
        return ~all_front | ((count > 0) & (c1 > c0) & (r1 > r0))


class _Lookup:
    """The view's projection and MaskLookup.near on ``xp`` (padded mask from the CPU class)."""

    def __init__(self, xp, projection: Projection, mask: np.ndarray, threshold_px: float):
        cpu = MaskLookup(mask, threshold_px)
        self.xp, self.cpu = xp, cpu
        self.m = [[float(v) for v in row] for row in projection.matrix]
        self.flat = xp.asarray(cpu.flat)

    def kept(self, x, y, z):
        """Indices of the points in front of the source and closer than the threshold to the mask."""
        xp, m, cpu = self.xp, self.m, self.cpu
        w = _project(x, y, z, m, 2)
        front = xp.flatnonzero(w > 0)
        x, y, z, w = x[front], y[front], z[front], w[front]
        u = _project(x, y, z, m, 0) / w
        v = _project(x, y, z, m, 1) / w
        rows, cols = cpu.shape
        fu = xp.floor(xp.clip(xp.where(xp.isnan(u), -1e9, u), -cpu.reach - 1, cols + cpu.reach))
        fv = xp.floor(xp.clip(xp.where(xp.isnan(v), -1e9, v), -cpu.reach - 1, rows + cpu.reach))
        base = (fv.astype(np.intp) + cpu.pad) * cpu.stride + (fu.astype(np.intp) + cpu.pad)
        keep = xp.zeros(len(u), dtype=bool)
        for a, b in cpu.offsets:  # every window pixel for every point: no data-dependent compaction
            du = u - (fu + a)
            dv = v - (fv + b)
            keep |= self.flat[base + (b * cpu.stride + a)] & (xp.sqrt(du * du + dv * dv) < cpu.threshold_px)
        return front[keep]


def _carve(xp, engine: str, lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
           threshold_px: float) -> CarveOutcome:
    """carve_hierarchical on the array module ``xp``; returns NumPy arrays."""
    if engine not in CUDA_ENGINES:
        raise ReconstructionError(f"the CUDA path runs the engines {list(CUDA_ENGINES)}, not {engine!r}")
    k = lattice.resolution
    root_size, leaf_size = _root_leaf(engine, k)
    order = sparsest_first(masks)
    tests = [_Footprint(xp, projections[i], masks[i], threshold_px) for i in order]
    lookups = [_Lookup(xp, projections[i], masks[i], threshold_px) for i in order]
    axis = xp.asarray(lattice.axis_mm())
    r = xp.arange(0, k, root_size, dtype=np.int64)
    starts = xp.stack(xp.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    size = root_size
    while True:
        cell_survivors = []
        for test in tests:
            if len(starts):
                lo, hi = axis[starts], axis[xp.minimum(starts + size, k) - 1]
                starts = starts[test.may_keep(lo, hi)]
            cell_survivors.append(len(starts) * size ** 3)
        if size <= leaf_size or len(starts) == 0:
            break
        half = size // 2
        offsets = xp.asarray(np.array([[a, b, c] for a in (0, half) for b in (0, half) for c in (0, half)], dtype=np.int64))
        children = (starts[:, None, :] + offsets[None]).reshape(-1, 3)
        starts = children[(children < k).all(axis=1)]
        size = half
    if len(starts) == 0:
        return CarveOutcome(np.empty((0, 3)), tuple(cell_survivors), order)
    r = xp.arange(size, dtype=np.int64)
    offsets = xp.stack(xp.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    survivors = [0] * len(order)
    kept = []
    cells_per_chunk = max(1, GPU_CHUNK_POINTS // size ** 3)
    for c in range(0, len(starts), cells_per_chunk):
        ijk = (starts[c:c + cells_per_chunk, None, :] + offsets[None]).reshape(-1, 3)
        ijk = ijk[(ijk < k).all(axis=1)]
        flat = (ijk[:, 0] * k + ijk[:, 1]) * k + ijk[:, 2]
        x, y, z = axis[ijk[:, 0]], axis[ijk[:, 1]], axis[ijk[:, 2]]
        del ijk
        for i, lookup in enumerate(lookups):
            if len(flat):
                sel = lookup.kept(x, y, z)
                x, y, z, flat = x[sel], y[sel], z[sel], flat[sel]
            survivors[i] += int(len(flat))
        kept.append(flat)
    flat = xp.sort(xp.concatenate(kept))
    points = xp.stack([axis[flat // (k * k)], axis[(flat // k) % k], axis[flat % k]], axis=1)
    points = points.get() if hasattr(points, "get") else points
    return CarveOutcome(np.ascontiguousarray(points, dtype=np.float64), tuple(survivors), order)


def carve_cuda(engine: str, lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
               threshold_px: float) -> CarveOutcome:
    """The ``lookup`` or ``octree`` engine on a CUDA GPU: exactly the CPU engine's kept points.

    Parameters
    ----------
    engine : {"lookup", "octree"}
    lattice, projections, masks, threshold_px
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
    return _carve(cupy, engine, lattice, projections, [np.asarray(m, dtype=bool) for m in masks],
                  threshold_px=float(threshold_px))
