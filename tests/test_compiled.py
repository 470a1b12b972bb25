"""The compiled kernels (angiohull.compiled, numba) give what the NumPy reference code gives, bit for bit."""

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from angiohull import compiled
from angiohull.geometry import CArmGeometry, cube_half_edge_mm
from angiohull.reconstruction import Lattice, extract_centerlines, reconstruct
from angiohull.reconstruction.centreline_fit import Centreline
from angiohull.reconstruction.hierarchical import carve_hierarchical, cell_sizes
from angiohull.reconstruction.nearest import nearest_with_ties
from angiohull.study import load_study
from _cases import random_case

numba = pytest.importorskip("numba", reason="numba is not installed (pip install '.[fast]'): the compiled kernels "
                                            "are not tested")


@pytest.fixture(autouse=True)
def _compiled_on():
    previous = compiled.set_enabled(True)
    if compiled.kernels() is None:
        compiled.set_enabled(previous)
        pytest.skip(f"the compiled kernels do not load: {compiled.status()}")
    yield
    compiled.set_enabled(previous)


def _both(function):
    """``function()`` with the compiled kernels, then with the NumPy code."""
    got = function()
    with compiled.disabled():
        reference = function()
    return got, reference


@pytest.mark.parametrize("engine", ["lookup", "octree"])
@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("threshold", [0.5, 1.0, 2.3, 4.5])
def test_carving_keeps_the_same_points_and_counts(engine, seed, threshold):
    """Views of different image sizes, lattices that are not a multiple of the cell size."""
    projections, masks = random_case(seed, n_views=2 + seed % 3, shape=(96, 80) if seed % 2 else (64, 100))
    k = 37 + 6 * seed
    lattice = Lattice(cube_half_edge_mm(projections), k)
    root, leaf = cell_sizes(engine, k)

    def carve():
        return carve_hierarchical(lattice, projections, masks, threshold_px=threshold, root_size=root, leaf_size=leaf)

    got, reference = _both(carve)
    np.testing.assert_array_equal(got.points_mm, reference.points_mm)
    assert got.survivors_per_view == reference.survivors_per_view
    assert got.order == reference.order


def test_carving_of_a_view_that_keeps_nothing_says_which_view():
    """Nothing kept: the compiled path hands over to the NumPy code, whose counts say which view
    removed the last cells (the empty-hull error message)."""
    projections, masks = random_case(3, n_views=3)
    masks = [m.copy() for m in masks]
    masks[1][:] = False
    masks[1][0, 0] = True  # one pixel in a corner: nothing in the cube projects near it with the others
    lattice = Lattice(cube_half_edge_mm(projections), 40)
    got, reference = _both(lambda: carve_hierarchical(lattice, projections, masks, threshold_px=1.0, root_size=16,
                                                      leaf_size=4))
    assert len(got.points_mm) == len(reference.points_mm) == 0
    assert got.survivors_per_view == reference.survivors_per_view


def test_reconstruction_and_centerlines_equal_on_peer_studies(peer_synthetic_dir):
    for name in ("clinical_tortuous_003", "perpendicular_simple_002", "perpendicular_moderate_005"):
        study = load_study(peer_synthetic_dir / name)

        def run():
            result = reconstruct(study.projections, study.masks, resolution=100, tree=False)
            rows = extract_centerlines(result.vessel_points_mm, study.projections, study.masks, keep_duplicates=True)
            return result.vessel_points_mm, result.centerline_points_mm, rows

        got, reference = _both(run)
        for a, b in zip(got, reference):
            np.testing.assert_array_equal(a, b, err_msg=name)


def _brute_nearest(points, query, tie, rank):
    """Every distance, as cKDTree computes it; the lowest rank within ``tie`` of the nearest."""
    difference = points[None, :, :] - query[:, None, :]
    distance = np.sqrt(difference[..., 0] ** 2 + difference[..., 1] ** 2)
    nearest = distance.min(axis=1)
    tied = distance <= nearest[:, None] + tie
    ranked = np.where(tied, rank[None, :], np.iinfo(np.int64).max)
    return nearest, np.argmin(ranked, axis=1)


@pytest.mark.parametrize("seed", range(8))
def test_nearest_with_ties_equals_brute_force_and_the_kdtree_path(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    if seed % 4 == 0:
        points = rng.integers(0, 12, (n, 2)).astype(float)  # many exact ties, repeated points
    elif seed % 4 == 1:
        points = np.stack([rng.uniform(-50, 50, n), np.full(n, 3.0)], axis=1)  # on a line: no area
    elif seed % 4 == 2:
        points = np.repeat(rng.uniform(-5, 5, (1, 2)), n, axis=0)  # all at one place
    else:
        points = rng.normal(0, 30, (n, 2)) * np.array([1.0, 0.01])
    query = np.concatenate([rng.integers(-3, 15, (60, 2)).astype(float), rng.uniform(-1e4, 1e4, (5, 2)), points[:3]])
    rank = rng.permutation(n)
    (distance, index), (ref_distance, ref_index) = _both(lambda: nearest_with_ties(points, query, 1e-9, rank))
    brute_distance, brute_index = _brute_nearest(points, query, 1e-9, rank)
    np.testing.assert_array_equal(index, brute_index)
    np.testing.assert_array_equal(ref_index, brute_index)
    np.testing.assert_allclose(distance, brute_distance, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ref_distance, brute_distance, rtol=0, atol=1e-12)


def test_nearest_of_projected_lattice_points_equals_the_kdtree_path():
    """The centerline step's case: a lattice seen in a view (rows of exactly equidistant points)."""
    view = CArmGeometry(30, 30, 1200, 800, (0.35, 0.35), (512, 512)).projection()
    axis = np.linspace(-10, 10, 21)
    lattice = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    uv = view.project(lattice)
    query = np.stack(np.meshgrid(np.arange(200, 320), np.arange(200, 320)), -1).reshape(-1, 2).astype(float)
    got, reference = _both(lambda: nearest_with_ties(uv, query, 1e-9))
    np.testing.assert_array_equal(got[1], reference[1])
    np.testing.assert_array_equal(got[0], cKDTree(uv).query(query)[0])


@pytest.mark.parametrize("seed", range(3))
def test_distances_to_a_centreline_equal_the_numpy_path(seed):
    """Points on, near, far from and off the image, not finite; cutoffs as a Python float (compared
    with the single-precision floor as NumPy compares them), a float64 one, and one past the floor's
    reach (every point asks the k-d tree)."""
    _, masks = random_case(seed, n_views=1, shape=(90, 120))
    centre_line = Centreline(masks[0])
    rng = np.random.default_rng(seed)
    uv = np.concatenate([centre_line.uv_px + rng.normal(0, 1.5, centre_line.uv_px.shape),
                         rng.uniform(-20, 140, (400, 2)), [[np.nan, 3.0], [np.inf, 1.0], [-5.0, 40.0]]])
    for cutoff in (2.0, np.float64(1.3), 1.0 + 1e-7, 6.0):
        got, reference = _both(lambda: centre_line.distances(uv, cutoff))
        np.testing.assert_array_equal(got, reference, err_msg=str(cutoff))


def _lattice_case(seed):
    """Axis points and queries on a lattice of spacing 0.3 mm: axis points on a coarse sub-lattice
    (many exactly tied neighbours) or scattered, queries near, far (beyond the eight-spacing shell
    table) and beyond reach."""
    rng = np.random.default_rng(seed)
    spacing, offset = 0.3, -9.15
    if seed % 2:
        axis_ijk = 3 * rng.integers(2, 12, (int(rng.integers(5, 80)), 3))
    else:
        axis_ijk = rng.integers(0, 40, (int(rng.integers(1, 300)), 3))
    axis_ijk = np.unique(axis_ijk, axis=0)  # distinct, in lattice order
    query_ijk = np.concatenate([rng.integers(-4, 44, (400, 3)), rng.integers(-30, 70, (40, 3)), axis_ijk[:5]])
    return axis_ijk, offset + spacing * axis_ijk, query_ijk, offset + spacing * query_ijk


@pytest.mark.parametrize("seed", range(8))
def test_nearest_axis_point_equals_the_numpy_path_and_brute_force(seed):
    """The refined preset's nearest axis point: distance as the k-d tree computes it, the lowest
    index of equally near ones; beyond reach inf and 0. Reaches: generous, tight, and one exactly
    at a squared distance that occurs (the k-d tree's strict bound decides those)."""
    from angiohull.reconstruction.refine import _nearest_axis

    axis_ijk, axis_mm, query_ijk, query_mm = _lattice_case(seed)
    difference = query_mm[:, None, :] - axis_mm[None, :, :]
    exact = (query_ijk[:, None, :] - axis_ijk[None, :, :]) ** 2
    length = exact.sum(axis=2)
    nearest = length.min(axis=1)
    brute_index = np.argmax(length == nearest[:, None], axis=1)  # the lowest index of the least
    brute_distance = np.sqrt(np.where(length == nearest[:, None], (difference ** 2).sum(axis=2), np.inf).min(axis=1))
    for reach in (50.0, 1.0, 0.3 * np.sqrt(float(np.median(nearest)))):
        (distance, index), (ref_distance, ref_index) = _both(
            lambda: _nearest_axis(axis_ijk, axis_mm, query_ijk, query_mm, reach))
        np.testing.assert_array_equal(distance, ref_distance)
        np.testing.assert_array_equal(index, ref_index)
        within = brute_distance < reach * (1 - 1e-9)
        np.testing.assert_array_equal(index[within], brute_index[within])
        np.testing.assert_allclose(distance[within], brute_distance[within], rtol=0, atol=1e-12)
        beyond = brute_distance > reach * (1 + 1e-9)
        assert np.all(np.isinf(distance[beyond])) and np.all(index[beyond] == 0)


def _rivals_brute_force(axis_uv, reach_px, axis_points, axis_piece, tube_uv, tube_points, tube_piece, hull):
    """The rivals by their definition, pair by pair: a tube point of another piece within the axis
    point's reach whose segment to it, sampled every half spacing (rounded halves to even), meets a
    lattice point outside the hull."""
    found = set()
    for a in range(len(axis_uv)):
        for t in range(len(tube_uv)):
            if tube_piece[t] == axis_piece[a] or (a, tube_piece[t]) in found:
                continue
            du, dv = axis_uv[a] - tube_uv[t]
            if not np.sqrt(du * du + dv * dv) <= reach_px[a]:
                continue
            step = (tube_points[t] - axis_points[a]).astype(float)
            n = max(int(np.ceil(2.0 * np.sqrt((step * step).sum()))), 1)
            samples = axis_points[a] + np.rint(step[None, :] * (np.arange(1, n) / n)[:, None]).astype(np.int64)
            if not hull[tuple(samples.T)].all():
                found.add((a, int(tube_piece[t])))
    return sorted(found)


@pytest.mark.parametrize("seed", range(6))
def test_rivals_equal_the_numpy_path_and_their_definition(seed):
    """Random hulls (blobs with holes), pieces and projections: each (axis point, piece) pair once,
    ordered, as the NumPy code and a pair-by-pair reading of the definition give them."""
    from scipy import ndimage as ndi

    from angiohull.reconstruction.refine import _rivals

    rng = np.random.default_rng(seed)
    hull = ndi.binary_dilation(rng.random((18, 20, 22)) < 0.02, iterations=2)
    hull[rng.random(hull.shape) < 0.05] = False  # holes: gaps inside the blobs
    points = np.argwhere(hull)
    pick = rng.permutation(len(points))
    axis_points = points[np.sort(pick[:60])]
    tube_points = points[np.sort(pick[:400])]
    n_pieces = 2 + seed % 4
    axis_piece = rng.integers(0, n_pieces, len(axis_points))
    tube_piece = rng.integers(0, n_pieces, len(tube_points))
    view = np.array([[1.0, 0.3, 0.1], [0.2, 0.1, 1.0]])  # a parallel view: points on one ray share (u, v)
    axis_uv, tube_uv = axis_points @ view.T, tube_points @ view.T + rng.normal(0, 0.3, (len(tube_points), 2))
    reach = rng.uniform(0.5, 2.5, len(axis_points))
    args = (axis_uv, reach, axis_points, axis_piece, tube_uv, tube_points, tube_piece, hull)
    (got_axis, got_piece), (ref_axis, ref_piece) = _both(lambda: _rivals(*args))
    np.testing.assert_array_equal(got_axis, ref_axis)
    np.testing.assert_array_equal(got_piece, ref_piece)
    assert list(zip(got_axis.tolist(), got_piece.tolist())) == _rivals_brute_force(*args)
    assert len(got_axis) > 0


@pytest.mark.parametrize("views", ["clinical", "perpendicular"])
def test_refined_points_equal_the_numpy_path(views):
    from angiohull.synthetic import SynthOptions, make_case

    case = make_case(SynthOptions(seed=4, views=views))
    projections, masks = [v.projection for v in case.views], [v.mask for v in case.views]
    got, reference = _both(lambda: reconstruct(projections, masks, preset="refined", tree=False,
                                               centerlines=False).vessel_points_mm)
    np.testing.assert_array_equal(got, reference)


@pytest.mark.parametrize("seed", range(6))
def test_lattice_points_in_tubes_equal_the_numpy_path_and_the_balls(seed):
    """Random tubes, some reaching past the lattice's faces, with and without a margin: the same
    points as the NumPy code, and exactly the lattice points within a ball's radius (plus the
    margin) of one of the balls the tubes are covered by, point by point (the NumPy code raised
    where a run passed the lattice's last point)."""
    from angiohull.reconstruction.model.tubes import _densified, lattice_points_in_tubes

    rng = np.random.default_rng(seed)
    lattice = Lattice(12.0, 37 + 4 * seed)
    n = int(rng.integers(1, 9))
    starts, ends = rng.uniform(-14, 14, (n, 3)), rng.uniform(-14, 14, (n, 3))
    r0, r1 = rng.uniform(0.2, 3.0, n), rng.uniform(0.2, 3.0, n)
    for margin in (0.0, 0.35):
        got, reference = _both(lambda: lattice_points_in_tubes(starts, ends, r0, r1, lattice, margin_mm=margin))
        np.testing.assert_array_equal(got, reference)
        centres, radii = _densified(starts, ends, r0, r1, 0.5 * lattice.spacing_mm)
        axis = lattice.axis_mm()
        inside = np.zeros((lattice.resolution,) * 3, dtype=bool)
        for c, grow in zip(centres, radii + margin):  # every lattice point of the ball's box, tested
            lo = np.searchsorted(axis, c - grow - 1.0)
            hi = np.searchsorted(axis, c + grow + 1.0, side="right")
            dx, dy, dz = (axis[a:b] - x for a, b, x in zip(lo, hi, c))
            # the test of the code: the squared distance across the column first
            rest = grow ** 2 - (dx * dx)[:, None, None] - (dy * dy)[None, :, None]
            inside[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] |= (rest >= 0) & ((dz * dz)[None, None, :] <= rest)
        expected = {tuple(p) for p in lattice.points()[inside.ravel()]}
        assert {tuple(p) for p in got} == expected


def test_the_environment_switch_and_status():
    code = "from angiohull import compiled; print(compiled.kernels() is None); print(compiled.status())"
    env = dict(os.environ, ANGIOHULL_COMPILED="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == ["True", "NumPy (compiled kernels disabled)"]
    # numba missing: the NumPy code runs, and the status says why
    code = ("import sys; sys.modules['numba'] = None; from angiohull import compiled; "
            "from angiohull.thinning import guo_hall_thin; import numpy as np; "
            "print(compiled.kernels() is None); print(int(guo_hall_thin(np.ones((5, 9), bool)).sum())); "
            "print(compiled.status())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[:2] == ["True", "5"] and out[2].startswith("NumPy (numba not available: ModuleNotFoundError")
    assert compiled.status() == f"numba {numba.__version__}"
    with compiled.disabled():
        assert compiled.kernels() is None
    assert compiled.kernels() is not None


@pytest.mark.parametrize("seed", range(4))
def test_junction_wrong_pixels_equal_the_numpy_path_and_their_definition(seed):
    """Random candidate and tree discs over random windows and strides of a mask, some centres on
    half pixels and radii whole (distances on the radii): the compiled counts equal the NumPy
    code's (k-d trees) and the counts by definition, every grid pixel against every disc."""
    from angiohull.reconstruction.vessel_tree import _wrong_pixels

    rng = np.random.default_rng(seed)
    for trial in range(40):
        image = (rng.random((50, 60)) < 0.5).astype(np.float32) if trial % 2 else rng.random((50, 60)).astype(np.float32)
        lo = rng.integers(0, 20, 2)
        hi = np.minimum(lo + rng.integers(1, 40, 2), (60, 50))
        stride = int(rng.integers(1, 4))
        n_candidates = int(rng.integers(1, 6))
        n, m = int(rng.integers(1, 50)), int(rng.integers(0, 30))
        uv, others_uv = rng.uniform(-5, 65, (n, 2)), rng.uniform(-5, 65, (m, 2))
        radius_px, others_px = rng.uniform(0.3, 9.0, n), rng.uniform(0.3, 9.0, m)
        if trial % 3 == 0:
            uv, others_uv = np.round(2 * uv) / 2, np.round(2 * others_uv) / 2
            radius_px, others_px = np.round(radius_px) + 0.0, np.round(others_px) + 0.0
        owner = np.sort(rng.integers(0, n_candidates, n))

        got, reference = _both(lambda: _wrong_pixels(image, lo, hi, stride, uv, radius_px, owner, n_candidates,
                                                     others_uv, others_px))
        assert got.dtype == reference.dtype
        np.testing.assert_array_equal(got, reference)

        v, u = np.mgrid[lo[1]:hi[1]:stride, lo[0]:hi[0]:stride]
        pixels = np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)

        def inside_discs(centres, radii):  # (pixels, discs): as the k-d tree pairs them, then each radius
            if len(centres) == 0:
                return np.zeros((len(pixels), 0), dtype=bool)
            d = ((pixels[:, None, 0] - centres[None, :, 0]) ** 2 + (pixels[:, None, 1] - centres[None, :, 1]) ** 2)
            return (d <= radii.max() ** 2) & (np.sqrt(d) <= radii[None, :])

        hits = inside_discs(uv, radius_px)
        covers = np.stack([hits[:, owner == c].any(axis=1) for c in range(n_candidates)], axis=1)
        rest = inside_discs(others_uv, others_px).any(axis=1)
        reached = covers.any(axis=1)
        inside = image[v.ravel(), u.ravel()] >= 0.5
        expected = ((covers | rest[:, None]) != inside[:, None])[reached].sum(axis=0)
        np.testing.assert_array_equal(got, expected)


def test_bilinear_samples_equal_map_coordinates_inside_on_and_past_the_borders():
    """The runs kernel's samples: scipy's order-1 ``map_coordinates`` (constant 0 outside), float32,
    bit for bit, on random and binary images of every small size, coordinates on and past the
    last row and column, whole and nan."""
    from scipy import ndimage

    bilinear = compiled.kernels()._bilinear
    rng = np.random.default_rng(0)
    for trial in range(60):
        rows, cols = int(rng.integers(1, 25)), int(rng.integers(1, 25))
        image = (rng.random((rows, cols)) < 0.5 if trial % 2 else rng.random((rows, cols))).astype(np.float32)
        v, u = rng.uniform(-2, rows + 1, 300), rng.uniform(-2, cols + 1, 300)
        v[:40], u[40:80] = np.round(v[:40]), np.round(u[40:80])
        v[80:90], u[90:100], v[100:105], u[105:110] = rows - 1, cols - 1, -1e-12, cols - 1 + 1e-12
        v[110:115] = np.nan
        expected = ndimage.map_coordinates(image, [v, u], order=1, mode="constant", cval=0.0)
        got = np.array([bilinear(image, a, b) for a, b in zip(v, u)], dtype=np.float32)
        np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("seed", range(4))
def test_cross_section_runs_equal_the_numpy_path(seed):
    """Points on, beside and off random thick lines (binary masks and blurred ones), some past the
    image's edges, with random normals (some along the axes) and reaches: the same runs found and
    the same edges as the NumPy code's binned profiles, bit for bit."""
    from scipy import ndimage

    from angiohull.reconstruction.vessel_tree import _all_runs

    rng = np.random.default_rng(seed)
    rows, cols = 80, 90
    y, x = np.mgrid[:rows, :cols]
    for trial in range(20):
        image = np.zeros((rows, cols), np.float32)
        for _ in range(int(rng.integers(1, 6))):
            centre, angle, radius = rng.uniform(0, [cols, rows]), rng.uniform(0, np.pi), rng.uniform(0.5, 8.0)
            image[np.abs((x - centre[0]) * np.sin(angle) - (y - centre[1]) * np.cos(angle)) <= radius] = 1.0
        if trial % 3 == 0:
            image = ndimage.gaussian_filter(image, 1.0).astype(np.float32)
        uv = rng.uniform(-5, [cols + 5, rows + 5], (300, 2))
        if trial % 2:
            uv = np.round(2 * uv) / 2
        angle = rng.uniform(0, 2 * np.pi, 300)
        normal = np.column_stack([np.cos(angle), np.sin(angle)])
        if trial % 4 == 0:
            normal = np.round(normal)
        reach = np.clip(rng.uniform(0, 40, 300), 6.0, 384.0)
        got, reference = _both(lambda: _all_runs(image, uv, normal, reach, 0.5))
        for a, b in zip(got, reference):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
        assert got[0].any() and not got[0].all()


@pytest.mark.parametrize("seed", range(4))
def test_forest_states_equal_the_numpy_path(seed):
    """Random forests (levels of random sizes, parents in the level above, several children to a
    parent), random costs with infinities and ties (costs on a coarse grid): the pixel matching's
    states, compiled and NumPy, are the same."""
    from angiohull.reconstruction.model.matching import _forest_states

    rng = np.random.default_rng(seed)
    for trial in range(30):
        states = int(rng.integers(2, 9))
        sizes = rng.integers(1, 12, int(rng.integers(1, 15)))
        levels = list(np.split(rng.permutation(int(sizes.sum())), np.cumsum(sizes)[:-1]))
        parent = np.full(int(sizes.sum()), -1, dtype=np.int64)
        for above, level in zip(levels, levels[1:]):
            parent[level] = rng.choice(above, len(level))
        unary = rng.uniform(0, 5, (len(parent), states))
        every = rng.uniform(0, 5, (int(sizes[1:].sum()), states, states))
        if trial % 2:
            unary, every = np.round(unary), np.round(every)  # ties
        unary[rng.random(unary.shape) < 0.2] = np.inf
        offset = np.concatenate([[0], np.cumsum(sizes[1:])]).astype(np.int64)
        got, reference = _both(lambda: _forest_states(unary, every, offset, levels, parent))
        assert got.dtype == reference.dtype
        np.testing.assert_array_equal(got, reference)


@pytest.mark.parametrize("seed", range(4))
def test_spoiled_runs_equal_the_numpy_path(seed):
    """Random branches crossing in the image (polylines, some looping), random radii, scales and
    normals, with and without the image-path rule and the sides: the runs spoiled by other discs,
    compiled and NumPy (k-d tree pairs), are the same."""
    from angiohull.reconstruction.vessel_tree import TREE_SETTINGS, _Arrays, _overlaps, _Sections

    rng = np.random.default_rng(seed)
    for trial in range(12):
        counts = rng.integers(2, 60, int(rng.integers(1, 7)))
        points = np.concatenate([np.cumsum(rng.normal(0, 0.5, (c, 3)), axis=0) + rng.uniform(-5, 5, 3)
                                 for c in counts])
        n = len(points)
        arrays = _Arrays(points, rng.uniform(0.2, 2.5, n), np.cumsum(counts) - counts, counts,
                         [None] + [0] * (len(counts) - 1), [None] + [0] * (len(counts) - 1),
                         [f"b{b}" for b in range(len(counts))])
        views = int(rng.integers(1, 4))
        uv = rng.uniform(0, 6, (views, n, 2)) + np.cumsum(rng.normal(0, 1.0, (views, n, 2)), axis=1)
        if trial % 3 == 0:
            uv = np.round(2 * uv) / 2
        angle = rng.uniform(0, 2 * np.pi, (views, n))
        sections = _Sections(found=np.ones((views, n), dtype=bool), width_px=np.zeros((views, n)),
                             offset_px=np.zeros((views, n)),
                             normal_px=np.stack([np.cos(angle), np.sin(angle)], axis=-1),
                             gradient=np.zeros((views, n, 3)), px_per_mm=rng.uniform(1.0, 4.0, (views, n)),
                             foreshortening=np.ones((views, n)), uv=uv)
        for image_path in (False, True):
            for sides in (False, True):
                got, reference = _both(lambda: _overlaps(sections, arrays, TREE_SETTINGS, image_path=image_path,
                                                         sides=sides))
                for a, b in zip(got if sides else [got], reference if sides else [reference]):
                    np.testing.assert_array_equal(a, b)
                assert (got[0] if sides else got).any()


@pytest.mark.parametrize("seed", range(4))
def test_teasar_graph_equals_the_numpy_path(seed):
    """Random voxel sets (sparse and dense, touching the box's faces, a single voxel, none) with
    random depths, whole-number ones among them (equal costs): the TEASAR graph's CSR arrays,
    compiled and NumPy (``coo_matrix(...).tocsr()``), are the same, dtypes and flags included."""
    from angiohull.tree.voxels import path_cost_graph

    rng = np.random.default_rng(seed)
    for trial in range(12):
        shape = tuple(int(s) for s in rng.integers(1, 14, 3))
        volume = rng.random(shape) < rng.uniform(0.0, 1.0)
        if trial == 0:
            volume[:] = False
            volume[tuple(rng.integers(0, shape))] = True
        voxels = np.argwhere(volume)
        depth = rng.uniform(0.5, 6.0, len(voxels)) if trial % 2 else rng.integers(1, 4, len(voxels)).astype(float)
        got, reference = _both(lambda: path_cost_graph(voxels, shape, depth))
        assert got.shape == reference.shape
        for name in ("indptr", "indices", "data"):
            assert getattr(got, name).dtype == getattr(reference, name).dtype
            np.testing.assert_array_equal(getattr(got, name), getattr(reference, name))
        assert got.has_sorted_indices == reference.has_sorted_indices
        assert got.has_canonical_format == reference.has_canonical_format


@pytest.mark.parametrize("seed", range(4))
def test_teasar_cover_equals_the_numpy_path_and_its_definition(seed):
    """The TEASAR paths of random volumes (blobs of random voxels; whole-number depths among them,
    so that many path voxels lie at one distance with different reaches) are the same compiled
    and NumPy (the k-d tree); and the kernel's answer per voxel is the definition's where it
    gives one: every path voxel at the least distance reaches it (1), none does (0)."""
    from angiohull import _numba_kernels
    from angiohull.tree.teasar import teasar_skeleton

    rng = np.random.default_rng(seed)
    for trial in range(6):
        shape = tuple(int(s) for s in rng.integers(6, 24, 3))
        volume = rng.random(shape) < rng.uniform(0.3, 0.9)
        voxels = np.argwhere(volume)
        dbf = (rng.integers(1, 4, len(voxels)).astype(float) if trial % 2 else rng.uniform(0.5, 4.0, len(voxels)))
        got, reference = _both(lambda: teasar_skeleton(volume, dbf=dbf))
        np.testing.assert_array_equal(got[0], reference[0])
        np.testing.assert_array_equal(got[1], reference[1])
    for trial in range(20):
        path = rng.integers(0, 12, (int(rng.integers(1, 30)), 3))
        reach = rng.integers(1, 5, len(path)) * 1.5 + (0.0 if trial % 2 else rng.uniform(0, 1, len(path)))
        todo = rng.integers(-3, 15, (300, 3))
        status = _numba_kernels.teasar_cover_hits(path, reach, todo, float(reach.max()))
        squared = ((todo[:, None, :] - path[None, :, :]) ** 2).sum(axis=2)
        least = squared == squared.min(axis=1, keepdims=True)
        within = np.sqrt(squared) <= reach[None, :]
        assert np.all(within[least.nonzero()][np.repeat(status, least.sum(axis=1)) == 1])
        assert not np.any(within[least.nonzero()][np.repeat(status, least.sum(axis=1)) == 0])
        assert np.mean(status == 2) < 0.2


@pytest.mark.parametrize("seed", range(4))
def test_tube_silhouettes_and_a_slides_counts_equal_the_numpy_path(seed):
    """Thin and thick tubes (discs of 1 to 60 pixels, some past the image's edges): the tree
    method's silhouette pixel for pixel as the NumPy code draws it and as a test of every pixel
    centre against every disc finds it; the slide's per-pixel counts, a move's score and the
    counts after a move kept and a branch replaced, as the NumPy code counts them."""
    from angiohull.reconstruction.model import sliding
    from angiohull.reconstruction.model.agreement import _samples, tube_silhouette
    from angiohull.tree import Branch, VesselTree

    rng = np.random.default_rng(seed)
    projection = CArmGeometry(20.0 * seed, 10.0, 1200.0, 800.0, (0.35, 0.35), (96, 128)).projection()
    points = np.cumsum(rng.normal(0.0, 4.0, (12, 3)), axis=0) + rng.uniform(-20, 20, 3)
    tree = VesselTree((Branch(points, rng.uniform(0.1, 1.0 if seed % 2 else 12.0, len(points))),))
    got, reference = _both(lambda: tube_silhouette(tree, projection))
    np.testing.assert_array_equal(got, reference)
    samples, radii = _samples(tree, 0.25)
    uv = projection.project(samples)
    rho = radii * max(projection.focal_lengths_px) / projection.depth_mm(samples)
    v, u = np.indices(got.shape)
    inside = ((u.ravel()[:, None] - uv[:, 0]) ** 2 + (v.ravel()[:, None] - uv[:, 1]) ** 2 <= rho ** 2).any(axis=1)
    np.testing.assert_array_equal(got.ravel(), inside)
    assert got.any() and not got.all()

    mask = np.zeros(got.shape, dtype=bool)
    mask[20:70, 10:90] = True

    def slide():
        picture = sliding._Picture(tree.branches, projection, mask, 0.25)
        old = picture.samples[0].points_mm
        new = old + np.array([1.0, -0.5, 2.0])
        score, touched, change = picture.moved(old, new, picture.samples[0].radius_mm)
        dense = np.zeros(mask.size, dtype=np.int64)
        dense[touched] = change  # (a pixel whose count does not change may be listed or not)
        counts = [picture.count.copy()]
        picture.keep(touched, change)
        counts.append(picture.count.copy())
        picture.replace(0, Branch(new[::3], picture.samples[0].radius_mm[::3] * 0.5), new)
        return score, dense, counts + [picture.count.copy()]

    (score, dense, counts), (score_ref, dense_ref, counts_ref) = _both(slide)
    assert score == score_ref
    np.testing.assert_array_equal(dense, dense_ref)
    for a, b in zip(counts, counts_ref):
        np.testing.assert_array_equal(a, b)


def test_lattice_points_in_thick_tubes_equal_the_numpy_path():
    """Tubes 3 to 9 mm in radius on a 0.4 mm lattice: each lattice column's runs of many balls
    joined (the kernel marks each run's ends) as the NumPy code joins them."""
    from angiohull.reconstruction.model.tubes import lattice_points_in_tubes

    rng = np.random.default_rng(3)
    lattice = Lattice(20.0, 101)
    starts, ends = rng.uniform(-22, 22, (4, 3)), rng.uniform(-22, 22, (4, 3))
    r0, r1 = rng.uniform(3.0, 9.0, 4), rng.uniform(3.0, 9.0, 4)
    got, reference = _both(lambda: lattice_points_in_tubes(starts, ends, r0, r1, lattice, margin_mm=0.2))
    np.testing.assert_array_equal(got, reference)
    assert len(got) > 10_000
