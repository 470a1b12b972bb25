"""The vessel tree through the study folder, the command line and the reports."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

from angiohull.cli import main
from angiohull.errors import StudyError
from angiohull.exports import EXPORT_FILES, read_tree_json
from angiohull.study import load_study
from angiohull.workflow import ReconstructOptions, reconstruct_study, tree_evaluation_scores

TREE_KEYS = {"centerline_mean_mm", "centerline_p95_mm", "centerline_hausdorff_mm", "ot05mm", "ot1mm", "ot2mm",
             "ot1mm_reverse", "cldice", "radius_mae_mm", "radius_rmse_mm", "radius_bias_mm", "branch_recall",
             "branch_precision", "bifurcations_true", "bifurcation_error_mm", "tree_s"}


@pytest.fixture(scope="module")
def synthetic_study(tmp_path_factory):
    folder = tmp_path_factory.mktemp("synth") / "study"
    assert main(["synth", str(folder), "--seed", "11", "-q"]) == 0
    return folder


def test_synth_records_the_true_tree_in_the_study(synthetic_study):
    study = load_study(synthetic_study)
    assert study.ground_truth_tree_path.name == "gt_centerlines.npz"
    assert study.ground_truth_tree.n_branches == 4 and len(study.ground_truth_tree.bifurcations) == 3


def test_reconstruct_writes_the_tree_exports_and_reports_them(synthetic_study, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["reconstruct", str(synthetic_study), "-o", str(out), "--preset", "refined", "--no-figure"]) == 0
    for name in EXPORT_FILES.values():
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert not list(out.glob(".*"))  # no temporary left behind
    report = json.loads((out / "report.json").read_text())
    tree = read_tree_json(out / "tree.json")
    assert report["tree"]["built"] and report["tree"]["n_branches"] == tree.n_branches >= 4
    assert report["tree"]["length_mm"] == pytest.approx(tree.length_mm)
    assert report["tree"]["mesh"]["n_faces"] > 1000 and report["tree"]["lumen"]["volume_mm3"] > 0
    assert set(report["timings_s"]) >= {"tree", "mesh_and_lumen", "exports"}
    assert report["tree"]["build"]["view_sees_share"] and len(report["tree"]["build"]["view_sees_share"]) == 3
    assert f"vessel tree: {tree.n_branches} branches" in capsys.readouterr().out


def test_evaluate_adds_the_tree_scores_when_the_study_has_a_true_tree(synthetic_study, capsys):
    assert main(["evaluate", str(synthetic_study), "--preset", "refined", "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert TREE_KEYS <= set(scores)
    # a clean three-view case: the refined tree follows the truth closely (docs/vessel-tree.md)
    assert scores["centerline_mean_mm"] < 0.6 and scores["radius_mae_mm"] < 0.2
    assert scores["branch_recall"] >= 0.75 and scores["bifurcations_true"] == 3
    assert 0.0 <= scores["ot1mm"] <= 1.0 and 0.0 <= scores["cldice"] <= 1.0


def test_evaluate_takes_a_true_tree_from_the_command_line(synthetic_study, tmp_path, capsys):
    copy = tmp_path / "no-tree"
    shutil.copytree(synthetic_study, copy)
    text = (copy / "study.yaml").read_text().replace("ground_truth_tree: gt_centerlines.npz\n", "")
    (copy / "study.yaml").write_text(text)
    assert main(["evaluate", str(copy), "--json"]) == 0
    assert not TREE_KEYS & set(json.loads(capsys.readouterr().out))  # no true tree: no tree scores
    assert main(["evaluate", str(copy), "--json", "--ground-truth-tree", str(copy / "gt_centerlines.npz")]) == 0
    assert TREE_KEYS <= set(json.loads(capsys.readouterr().out))
    assert main(["evaluate", str(copy), "--ground-truth-tree", str(copy / "missing.npz")]) == 2
    assert "missing.npz: file not found" in capsys.readouterr().err


def test_tree_scores_without_a_true_tree_or_without_a_tree_are_an_error(synthetic_study):
    study = load_study(synthetic_study)
    result = reconstruct_study(study, ReconstructOptions(resolution=60))
    with pytest.raises(StudyError, match="no true vessel tree"):
        tree_evaluation_scores(replace(study, ground_truth_tree=None), result)
    with pytest.raises(StudyError, match="without its vessel tree"):
        tree_evaluation_scores(study, reconstruct_study(study, ReconstructOptions(resolution=60, tree=False)))
    # a reconstruction that asked for a tree and got none: undefined scores, the truth's counts, the reason
    failed = tree_evaluation_scores(study, replace(result, tree=None, tree_build=None, tree_error="the hull is empty"))
    assert failed["tree_error"] == "the hull is empty" and np.isnan(failed["centerline_mean_mm"])
    assert failed["bifurcations_true"] == 3 and failed["branches_found"] == 0


def test_a_bad_true_tree_in_study_yaml_names_the_field(synthetic_study, tmp_path):
    copy = tmp_path / "bad"
    shutil.copytree(synthetic_study, copy)
    np.save(copy / "tree.npy", np.zeros((2, 5)))
    text = (copy / "study.yaml").read_text().replace("gt_centerlines.npz", "tree.npy")
    (copy / "study.yaml").write_text(text)
    with pytest.raises(StudyError, match="ground_truth_tree: .*tree.npy: expected the authors' gt_centerlines.npy"):
        load_study(copy)


def test_an_output_folder_that_cannot_be_written_is_one_error_and_nothing_half_written(synthetic_study, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["reconstruct", str(synthetic_study), "-o", str(blocker / "out"), "-k", "60", "--no-figure", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and str(blocker) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_an_experiment_records_the_tree_scores_and_the_report_tabulates_them(tmp_path):
    config = tmp_path / "tree.yaml"
    config.write_text("""angiohull_experiment: 1
name: tree_scores
description: tree scores of the refined preset on two clinical RCA trees
seed: 5
generator: {kind: rca, rasteriser: exact, sid_mm: 1200, sod_mm: 800, pixel_mm: 0.35, size: 512}
design: {type: trees, tortuosity: [moderate], trees: 2, views: clinical}
reconstruction: {engine: octree, resolution: 256, threshold_px: 1.0, preset: refined}
metrics: [dice3d, centerline_mean_mm, ot1mm, radius_mae_mm, branch_recall]
""")
    run = tmp_path / "run"
    assert main(["experiment", str(config), "-o", str(run), "--workers", "1", "--quiet"]) == 0
    from angiohull.experiments.rows import read_rows

    header, rows = read_rows(run / "results.csv")
    assert {"centerline_mean_mm", "ot1mm", "radius_mae_mm", "branch_recall"} <= set(header)
    assert all(r["status"] == "ok" for r in rows) and len(rows) == 2
    assert all(r["centerline_mean_mm"] < 1.0 and 0.5 < r["ot1mm"] <= 1.0 for r in rows)
    assert main(["report", str(run), "-o", str(tmp_path / "report")]) == 0
    text = (tmp_path / "report" / "report.md").read_text()
    assert "centerline distance, mean (mm)" in text and "branch recall" in text


def test_a_part_the_tree_cannot_join_is_reported_not_lost_silently(tmp_path, capsys):
    from angiohull.geometry import CArmGeometry, parse_clinical_angles
    from angiohull.study import View, save_study
    from angiohull.synthetic import Tube, TubePhantom

    # two vessels 30 mm apart: the paper preset has no carving to bridge them through
    phantom = TubePhantom((Tube(np.linspace([-30, -15, 0], [30, -15, 5], 121), 1.5),
                           Tube(np.linspace([-20, 15, 0], [20, 15, -5], 81), 1.0)), "two")
    views = []
    for text in ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30"):
        carm = CArmGeometry(*parse_clinical_angles(text), 1200.0, 800.0, (0.35, 0.35), (512, 512))
        views.append(View.from_carm(text.replace(" ", ""), phantom.silhouette(carm.projection()), carm))
    study = save_study(tmp_path / "two", views)
    assert main(["reconstruct", str(study), "-o", str(tmp_path / "out"), "--no-figure", "-q"]) == 0
    err = capsys.readouterr().err
    assert "angiohull: warning: the vessel tree leaves out 1 part(s) of the hull" in err
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["tree"]["build"]["parts_dropped"] == 1 and report["tree"]["build"]["length_dropped_mm"] > 10
