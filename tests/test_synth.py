"""Synthetic studies: seeded, replayable, written in the study format; ``angiohull synth``."""

import json

import numpy as np
import pytest

from angiohull.cli import main
from angiohull.errors import AngiohullError
from angiohull.geometry import CArmGeometry
from angiohull.metrics import scores_3d
from angiohull.reconstruction import reconstruct
from angiohull.study import load_study
from angiohull.synthetic import SynthOptions, make_case, parse_views, replay_case, write_case
from angiohull.synthetic.render import render_mask


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    folder = tmp_path_factory.mktemp("case")
    options = SynthOptions(tortuosity="tortuous", views="perpendicular", rasteriser="paper", seed=42,
                           corruptions=("translate=6,-3", "fp=0.002", "missing=1@1", "blob=1@2"))
    case = make_case(options)
    write_case(folder, case)
    return folder, case


def test_same_seed_same_case_and_other_seed_differs():
    a = make_case(SynthOptions(seed=5, corruptions=("fn=0.1",)))
    b = make_case(SynthOptions(seed=5, corruptions=("fn=0.1",)))
    c = make_case(SynthOptions(seed=6, corruptions=("fn=0.1",)))
    assert all(np.array_equal(x.mask, y.mask) for x, y in zip(a.views, b.views))
    assert np.array_equal(a.surface_points_mm, b.surface_points_mm)
    assert not np.array_equal(a.views[0].mask, c.views[0].mask)


def test_corruptions_do_not_change_the_tree_of_a_seed():
    clean = make_case(SynthOptions(seed=9))
    noisy = make_case(SynthOptions(seed=9, corruptions=("fp=0.01", "translate=5,5")))
    assert clean.tree.params == noisy.tree.params
    assert all(np.array_equal(x, y) for x, y in zip(clean.clean_masks, noisy.clean_masks))


def test_written_case_loads_as_a_study_with_its_ground_truth(written):
    folder, case = written
    study = load_study(folder)
    assert study.names == ("AP", "LAO90", "CRA90")
    assert [v.carm.clinical_name() for v in study.views] == ["LAO 0 CRA 0", "LAO 90 CRA 0", "LAO 0 CRA 90"]
    assert np.array_equal(study.ground_truth_mm, case.surface_points_mm)
    for view, mine in zip(study.views, case.views):
        assert np.array_equal(view.mask, mine.mask)
        assert np.allclose(view.projection.matrix, mine.projection.matrix, rtol=0, atol=1e-9)
    lumen = np.load(folder / "gt_lumen.npy")
    assert case.tree.phantom.contains(lumen).all()
    centerlines = np.load(folder / "gt_centerlines.npz")
    names = list(centerlines["branch_names"])
    assert names == [b.name for b in case.tree.branches]
    assert list(centerlines["parents"]) == [-1, 0, 0, 0]
    for branch in case.tree.branches:
        assert np.array_equal(centerlines[branch.name][:, :3], branch.centerline_mm)
        assert np.array_equal(centerlines[branch.name][:, 3], branch.radius_mm)


def test_record_says_what_each_corruption_changed(written):
    folder, case = written
    record = json.loads((folder / "synthetic.json").read_text())
    assert record["seed"] == 42
    kinds = [[r["kind"] for r in entry["records"]] for entry in record["corruptions"]]
    assert kinds == [["translate", "fp"], ["fp", "missing"], ["fp", "blob"]]
    for index, entry in enumerate(record["corruptions"]):
        # Replaying the records one by one on the clean mask gives the recorded change counts.
        current = case.clean_masks[index]
        for recorded, changed in zip(case.corruptions[index], entry["changed_pixels"]):
            after = recorded.apply(current)
            assert int((after != current).sum()) == changed
            current = after
        assert np.array_equal(current, case.views[index].mask)
    assert record["tree"]["tortuosity"] == "tortuous"


def test_replay_from_the_records_alone_gives_the_same_masks(written):
    folder, case = written
    replayed = replay_case(folder)
    for a, b in zip(replayed.views, load_study(folder).views):
        assert np.array_equal(a.mask, b.mask)
    assert replayed.tree.params == case.tree.params


def test_paper_rasteriser_and_exact_silhouette_agree_to_within_its_closing():
    case = make_case(SynthOptions(seed=3, views="LAO 45"))
    view = case.views[0]
    paper = render_mask(case.tree.phantom, view.projection, "paper")
    exact = view.mask
    # The paper's rasteriser truncates (half a pixel shift) and closes/blurs (about a pixel of growth).
    union = (paper | exact).sum()
    assert (paper & exact).sum() / union > 0.8
    assert paper.sum() > exact.sum()


def test_reconstruction_of_a_generated_case_contains_the_tree():
    # The visual hull of exact silhouettes contains the solid: nearly every deep lumen point's
    # lattice cell survives (K=100 lattice, threshold 1 px), and Dice3D is in the paper's range.
    case = make_case(SynthOptions(seed=11, views="clinical"))
    result = reconstruct([v.projection for v in case.views], [v.mask for v in case.views], engine="octree",
                         centerlines=False, tree=False)
    scores = scores_3d(result.vessel_points_mm, case.surface_points_mm)
    assert 60.0 < scores.dice3d < 95.0
    assert scores.chamfer_mm < 2.0


def test_views_syntax():
    assert [v[0] for v in parse_views("clinical")] == ["RAO30_CRA30", "LAO60_CRA30", "RAO30_CAU30"]
    assert parse_views("RAO 30 CRA 30; LAO 60") == [("RAO30_CRA30", -30.0, 30.0), ("LAO60", 60.0, 0.0)]
    with pytest.raises(AngiohullError, match="repeats"):
        parse_views("LAO 30; LAO 30 CRA 0")
    with pytest.raises(AngiohullError, match="at least one view"):
        parse_views(" ; ")
    with pytest.raises(AngiohullError, match="cannot read clinical angles"):
        parse_views("sideways")


@pytest.mark.parametrize("kwargs, message", [
    (dict(tortuosity="wild"), "tortuosity must be one of"),
    (dict(kind="aorta"), "tree must be one of"),
    (dict(views=""), "at least one view"),
    (dict(size=-3), "size must be a positive integer"),
    (dict(pixel_mm=-0.35), "pixel_mm must be a positive"),
    (dict(sod_mm=1300.0), "sod_mm must be smaller than sid_mm"),
    (dict(corruptions=("fp=2",)), r"p must lie in \[0, 1\]"),
    (dict(rasteriser="pencil"), "rasteriser must be one of"),
    (dict(seed=-1), "seed must be a non-negative integer"),
])
def test_bad_options_are_clear_errors(kwargs, message):
    with pytest.raises(AngiohullError, match=message):
        SynthOptions(**kwargs)


def test_a_detector_too_small_for_the_tree_is_an_error():
    with pytest.raises(AngiohullError, match="cube of interest"):
        make_case(SynthOptions(seed=1, size=128))
    # pixels so coarse that the vessels draw none: said so (it was put on corruptions that were not asked for)
    with pytest.raises(AngiohullError, match=r"the tree draws no vessel pixel on a detector of 4 x 4 pixels of 50 x 50 mm"):
        make_case(SynthOptions(seed=1, size=4, pixel_mm=50.0, views=("RAO 30 CRA 30", "LAO 60 CRA 30")))


def test_synth_command_writes_a_study_that_evaluates(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["synth", str(out), "--seed", "4", "--views", "RAO 30 CRA 30; LAO 60 CRA 30", "--corrupt",
                 "fn=0.01", "-q"]) == 0
    assert {p.name for p in out.iterdir()} >= {"study.yaml", "masks", "gt.npy", "gt_lumen.npy",
                                               "gt_centerlines.npz", "tree.json", "synthetic.json"}
    assert main(["evaluate", str(out), "--json"]) == 0
    scores = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert scores["dice3d"] > 40


@pytest.mark.parametrize("argv, message", [
    (["--tortuosity", "wild"], "tortuosity must be one of"),
    (["--corrupt", "fp=1.5"], "p must lie in [0, 1]"),
    (["--views", ""], "at least one view"),
    (["--size", "-3"], "size must be a positive integer"),
])
def test_synth_command_bad_options(tmp_path, capsys, argv, message):
    assert main(["synth", str(tmp_path / "s"), *argv]) == 2
    assert message in capsys.readouterr().err


def test_carm_views_respect_the_geometry_options():
    case = make_case(SynthOptions(seed=2, views="AP", sid_mm=1000.0, sod_mm=700.0, pixel_mm=0.3, size=600))
    carm = case.views[0].carm
    assert carm == CArmGeometry(0.0, 0.0, 1000.0, 700.0, (0.3, 0.3), (600, 600))
