"""The CUDA path keeps exactly the points of the CPU ``lookup`` and ``octree`` engines.

Skipped without CuPy or without a CUDA device.
"""

import numpy as np
import pytest

pytest.importorskip("cupy", reason="the CUDA path needs CuPy (pip install 'angiohull[gpu]')")

from angiohull.geometry import CArmGeometry, Projection, cube_half_edge_mm  # noqa: E402
from angiohull.reconstruction import ENGINES, Lattice  # noqa: E402
from angiohull.reconstruction.gpu import carve_cuda, cuda_available  # noqa: E402
from angiohull.synthetic import demo_phantom, demo_views  # noqa: E402
from _cases import random_case  # noqa: E402

if not cuda_available():
    pytest.skip("CuPy is installed but no CUDA device is usable (driver, runtime or GPU missing)",
                allow_module_level=True)


def assert_same(engine, lattice, projections, masks, threshold):
    cpu = ENGINES[engine](lattice, projections, masks, threshold_px=threshold)
    gpu = carve_cuda(engine, lattice, projections, masks, threshold_px=threshold)
    assert isinstance(gpu.points_mm, np.ndarray) and gpu.points_mm.dtype == np.float64
    np.testing.assert_array_equal(gpu.points_mm, cpu.points_mm, err_msg=engine)
    assert gpu.survivors_per_view == cpu.survivors_per_view
    assert gpu.order == cpu.order
    return cpu


@pytest.mark.parametrize("engine", ["lookup", "octree"])
@pytest.mark.parametrize("k", [48, 200])
@pytest.mark.parametrize("threshold", [0.5, 1.0, 1.5, 2.3])
@pytest.mark.parametrize("seed", range(6))
def test_cuda_equals_cpu_on_random_cases(engine, k, threshold, seed):
    projections, masks = random_case(seed, n_views=2 + seed % 3)
    lattice = Lattice(cube_half_edge_mm(projections), k)
    cpu = assert_same(engine, lattice, projections, masks, threshold)
    assert len(cpu.points_mm) > 0 or threshold < 1


@pytest.mark.parametrize("engine", ["lookup", "octree"])
def test_cuda_equals_cpu_with_the_source_inside_the_cube(engine):
    k = np.array([[40.0, 0, 31.5], [0, 40.0, 31.5], [0, 0, 1]])
    q, _ = np.linalg.qr(CArmGeometry(20, 10, 1200, 800, (1, 1), (64, 64)).projection().matrix[:, :3])
    p = Projection(k @ np.concatenate([q, q @ -np.array([[1.0], [-2.0], [0.5]])], axis=1), (64, 64))
    mask = np.zeros((64, 64), bool)
    mask[10:50, 20:30] = True
    lattice = Lattice(10.0, 33)
    cpu = assert_same(engine, lattice, [p], [mask], 1.0)
    assert 0 < len(cpu.points_mm) < lattice.n_points


@pytest.mark.parametrize("engine", ["lookup", "octree"])
def test_cuda_equals_cpu_on_the_demo_phantom_at_k512(engine):
    phantom = demo_phantom()
    projections = [carm.projection() for _, carm in demo_views()]
    masks = [phantom.silhouette(p) for p in projections]
    lattice = Lattice(cube_half_edge_mm(projections), 512)
    cpu = assert_same(engine, lattice, projections, masks, 1.0)
    assert len(cpu.points_mm) > 10000


def test_cuda_rejects_other_engines():
    from angiohull.errors import ReconstructionError

    projections, masks = random_case(0, 2)
    with pytest.raises(ReconstructionError, match="lookup"):
        carve_cuda("kdtree", Lattice(cube_half_edge_mm(projections), 16), projections, masks, threshold_px=1.0)


def test_reconstruct_on_cuda_equals_the_cpu():
    from angiohull.reconstruction import reconstruct

    projections, masks = random_case(21, n_views=3)
    cpu = reconstruct(projections, masks, resolution=64, centerlines=False)
    gpu = reconstruct(projections, masks, resolution=64, centerlines=False, device="cuda")
    assert gpu.device == "cuda" and gpu.engine == "octree"
    np.testing.assert_array_equal(gpu.vessel_points_mm, cpu.vessel_points_mm)
