"""Experiment cases: seeds, directions, expansion at the paper's sizes, and run_case against make_case."""

import math

import numpy as np
import pytest

import angiohull.experiments.cases as cases_module
from angiohull.experiments.cases import (angle_matrix_sigma_min, case_inputs, clear_caches, derive_seed,
                                         direction_angles, expand_cases, row_columns, run_case, sphere_directions,
                                         sweep_values, tree_seed)
from angiohull.experiments.config import config_from_dict, config_to_dict, load_config
from angiohull.geometry import CArmGeometry
from angiohull.metrics import scores_3d
from angiohull.reconstruction import reconstruct
from angiohull.synthetic import SynthOptions, make_case, render_mask
from angiohull.synthetic.render import PAPER_SURFACE_SPACING_MM
from angiohull.synthetic.tree import build_tree, draw_tree_params


def _with(name, path, value, quick=False):
    data = config_to_dict(load_config(name, quick=quick))
    node = data
    keys = path.split(".")
    for key in keys[:-1]:
        node = node[key]
    node[keys[-1]] = value
    return config_from_dict(data)


def test_derived_seeds_are_fixed_distinct_and_non_negative():
    assert derive_seed(2025, 1, 0, 1, 7) == derive_seed(2025, 1, 0, 1, 7)
    seeds = {derive_seed(2025, 1, 0, level, i) for level in range(3) for i in range(200)}
    assert len(seeds) == 600 and min(seeds) >= 0 and max(seeds) < 2 ** 63
    assert derive_seed(2025, 1) != derive_seed(2026, 1)


def test_direction_angles_invert_the_carm_frame():
    rng = np.random.default_rng(0)
    directions = sphere_directions(500, rng)
    assert np.allclose(np.linalg.norm(directions, axis=1), 1.0)
    for d in directions:
        primary, secondary = direction_angles(d)
        assert -180.0 < primary <= 180.0 and -90.0 <= secondary <= 90.0
        carm = CArmGeometry(primary, secondary, 1200.0, 800.0, (0.35, 0.35), (512, 512))
        assert np.allclose(carm.detector_direction(), d, atol=1e-12)
    assert direction_angles([0.0, -1.0, 0.0]) == (0.0, 0.0)  # AP: detector anterior
    assert direction_angles([1.0, 0.0, 0.0]) == (90.0, 0.0)  # LAO 90
    assert direction_angles([0.0, 0.0, 1.0])[1] == 90.0  # CRA 90


def test_sphere_directions_are_uniform():
    """Archimedes: z is uniform on [-1, 1]; the azimuth is uniform; the mean vector is ~0."""
    from scipy import stats

    d = sphere_directions(20000, np.random.default_rng(1))
    assert stats.kstest(d[:, 2], "uniform", args=(-1, 2)).pvalue > 1e-3
    azimuth = np.arctan2(d[:, 1], d[:, 0])
    assert stats.kstest(azimuth, "uniform", args=(-np.pi, 2 * np.pi)).pvalue > 1e-3
    assert np.linalg.norm(d.mean(axis=0)) < 0.03
    # a prefix of a larger draw is the smaller draw (quick runs use the first directions)
    assert np.array_equal(sphere_directions(10, np.random.default_rng(5)), sphere_directions(50, np.random.default_rng(5))[:10])


def test_smallest_singular_value_of_the_angle_matrix():
    assert angle_matrix_sigma_min([(0, 0), (90, 0), (0, 90)]) == pytest.approx(1.0)  # perpendicular
    assert angle_matrix_sigma_min([(0, 0), (90, 0), (45, 0)]) == pytest.approx(0.0, abs=1e-12)  # coplanar
    assert angle_matrix_sigma_min([(0, 0), (180, 0), (90, 0)]) == pytest.approx(0.0, abs=1e-12)  # opposite = same line
    # two directions 10 degrees apart and a third perpendicular to both: sigma_min = sqrt(1 - cos 10)
    assert angle_matrix_sigma_min([(0, 0), (10, 0), (0, 90)]) == pytest.approx(math.sqrt(1 - math.cos(math.radians(10))))


def test_sweep_values_follow_the_configs():
    fp = sweep_values(load_config("false_positives"))
    assert np.allclose(fp, np.arange(11) / 100) and len(fp) == 11
    fn = sweep_values(load_config("false_negatives"))
    assert np.allclose(fn, np.arange(10) / 10)
    scale = np.array(sweep_values(load_config("scaling")))
    assert len(scale) == 150 and scale.min() == 0.1 and scale.max() < 2.0 and np.all(np.diff(scale) > 0)
    shifts = np.array(sweep_values(load_config("translation")))
    assert shifts.shape == (100, 2) and shifts.min() >= -100 and shifts.max() < 100
    assert len({tuple(v) for v in shifts}) == 100


def test_paired_and_unpaired_trees_and_shared_seeds():
    fp = expand_cases(load_config("false_positives"))
    by_tree = {}
    for case in fp:
        by_tree.setdefault(case["tree_index"], set()).add(case["columns"]["p"])
    assert len(by_tree) == 100 and all(len(ps) == 11 for ps in by_tree.values())  # the same trees at every p
    assert [c["tree_index"] for c in fp[:12]] == [0] * 11 + [1]  # tree-major order
    translation = expand_cases(load_config("translation"))
    assert len({c["tree_seed"] for c in translation}) == 100  # a tree per vector
    general = expand_cases(load_config("general"))
    n_views = expand_cases(load_config("n_views"))
    moderate0 = next(c for c in general if c["tortuosity"] == "moderate" and c["tree_index"] == 0)
    assert {c["tree_seed"] for c in n_views} == {moderate0["tree_seed"]} == {tree_seed(2025, "rca", "moderate", 0)}
    assert len({c["tree_seed"] for c in general}) == 600


def test_n_views_selections_and_angles_triplets():
    cases = expand_cases(load_config("n_views"))
    assert [len(c["views"]) for c in cases[::100]] == list(range(1, 16))
    for case in cases[::37]:
        ids = case["view_ids"]
        assert len(set(ids)) == len(ids) and all(0 <= i < 1000 for i in ids)
    table = {}
    for case in cases:
        for i, (_, primary, secondary) in zip(case["view_ids"], case["views"]):
            assert table.setdefault(i, (primary, secondary)) == (primary, secondary)  # one table of directions
    assert len(table) > 900
    angles = expand_cases(load_config("angles"))
    sigmas = np.array([c["columns"]["sigma_min"] for c in angles])
    assert len(angles) == 150 and sigmas.min() >= 0 and sigmas.max() <= 1
    assert sigmas.max() - sigmas.min() > 0.5  # the draws span near-coplanar to near-perpendicular triplets


@pytest.mark.parametrize("config, index", [("general", 0), ("false_positives", 5), ("translation", 3),
                                           ("general_clinical", 250)])
def test_a_trees_case_is_make_case_of_its_tree_seed(config, index):
    """Independent oracle: angiohull.synthetic.make_case with the row's tree seed and corruption."""
    params = expand_cases(load_config(config))[index]
    design = load_config(config).design
    corruptions = ()
    if design.sweep is not None:
        spec = params["corruptions"][-1]
        views = "" if spec["views"] is None else "@" + (spec["views"] if spec["views"] == "all" else ",".join(map(str, spec["views"])))
        corruptions = (f"{spec['kind']}={','.join(repr(v) for v in spec['values'])}{views}",)
    case = make_case(SynthOptions(kind="rca", tortuosity=params["tortuosity"], views=design.views, rasteriser="paper",
                                  corruptions=corruptions, seed=params["tree_seed"]))
    clear_caches()
    for _ in range(2):  # fresh, then from this process's caches
        inputs = case_inputs(params)
        assert len(inputs.masks) == len(case.views)
        for mine, view in zip(inputs.masks, case.views):
            assert np.array_equal(mine, view.mask)
        assert np.array_equal(inputs.ground_truth_mm, case.surface_points_mm)
        assert [p.matrix.tolist() for p in inputs.projections] == [v.projection.matrix.tolist() for v in case.views]


def test_run_case_scores_like_the_library():
    params = expand_cases(load_config("general"))[401]
    row = run_case(params)
    assert set(row) == set(row_columns(load_config("general")))
    assert row["status"] == "ok" and row["reason"] == "" and row["tortuosity"] == "tortuous"
    inputs = case_inputs(params)
    result = reconstruct(list(inputs.projections), list(inputs.masks), engine="kdtree", centerlines=False, tree=False)
    s3 = scores_3d(result.vessel_points_mm, inputs.ground_truth_mm)
    assert row["n_points"] == len(result.vessel_points_mm)  # octree keeps exactly the kdtree's points
    assert (row["dice3d"], row["iou3d"], row["chamfer_mm"]) == (s3.dice3d, s3.iou3d, s3.chamfer_mm)
    assert 60 < row["dice3d"] < 95 and 0 < row["time_s"] < row["case_s"]
    assert row["views"] == "LAO 0 CRA 0;LAO 90 CRA 0;LAO 0 CRA 90"


def test_n_views_masks_come_from_the_cache_unchanged():
    config = load_config("n_views", quick=True)
    cases = expand_cases(config)
    clear_caches()
    params = cases[-1]  # 15 views
    inputs = case_inputs(params)
    tree = build_tree(draw_tree_params("rca", "moderate", np.random.default_rng(
        np.random.SeedSequence(params["tree_seed"]).spawn(2)[0])))
    splat = tree.phantom.surface_points_mm(PAPER_SURFACE_SPACING_MM)
    for carm, mask in zip(inputs.carms, inputs.masks):
        assert np.array_equal(mask, render_mask(tree.phantom, carm.projection(), "paper", surface_points_mm=splat))
    misses = cases_module._MASKS.misses
    case_inputs(params)
    assert cases_module._MASKS.misses == misses  # the second time every view came from the cache


def test_case_failures_become_rows():
    empty = _with("translation", "design.sweep.values", {"list": [[250.0, 250.0]]})
    row = run_case(expand_cases(empty)[0])
    assert row["status"] == "empty" and row["n_points"] == 0
    assert row["dice3d"] == 0.0 and math.isnan(row["chamfer_mm"])
    assert row["reason"].startswith("empty visual hull: view")
    erased = _with("false_negatives", "design.sweep.values", {"list": [1.0]})
    row = run_case(expand_cases(erased)[0])
    assert row["status"] == "failed" and "erased every vessel pixel" in row["reason"]
    assert all(math.isnan(row[m]) for m in ("dice3d", "iou3d", "chamfer_mm", "dice2d_paper", "time_s"))


def test_an_unexpected_exception_becomes_an_error_row(monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(cases_module, "reconstruct", broken)
    row = run_case(expand_cases(load_config("general", quick=True))[0])
    assert row["status"] == "error" and row["reason"] == "RuntimeError: disk on fire"
    assert math.isnan(row["dice3d"])
