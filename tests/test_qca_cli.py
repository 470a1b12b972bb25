"""The quantitative coronary analysis on the command line (``angiohull qca``, ``reconstruct --qca``),
its files (``qca.json``, ``lesions.csv``, ``branches.csv``) and its figures, in-process through
``main(argv)``.

One small case per module: the demo's synthetic RCA study (``synth --seed 2025``: 4 true branches,
2 lesions in its reconstructed tree) reconstructed once with ``--qca``; ``qca`` then runs on that
result folder.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import shutil
from dataclasses import replace

import numpy as np
import pytest
from matplotlib.image import imread

from angiohull import workflow
from angiohull.cli import main
from angiohull.errors import OutputError, QcaError
from angiohull.qca import BRANCH_COLUMNS, LESION_COLUMNS, QcaSettings, analyse_tree, segment_view_map
from angiohull.tree import Branch, VesselTree

REQUIRED_LESION_COLUMNS = ("branch", "x_mm", "y_mm", "z_mm", "mld_mm", "reference_diameter_mm",
                           "diameter_stenosis_pct", "lesion_length_mm")
REQUIRED_BRANCH_COLUMNS = ("branch", "parent", "length_mm", "mean_diameter_mm")


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """``{"study", "result", "qca"}``: a reconstructed study (with ``--qca``) and ``qca RESULT``'s
    folder (figures, one lesion map per lesion, two segment maps), plus that run's stdout."""
    root = tmp_path_factory.mktemp("qca-cli")
    study, result, qca = root / "study", root / "result", root / "qca"
    assert main(["synth", str(study), "--seed", "2025", "-q"]) == 0
    assert main(["reconstruct", str(study), "-o", str(result), "--no-figure", "--qca", "-q"]) == 0
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["qca", str(result), "-o", str(qca), "--segment", "1:5-25", "--segment", "2", "-q"]) == 0
    assert stdout.getvalue() == ""  # -q
    with contextlib.redirect_stdout(stdout):
        assert main(["qca", str(result), "-o", str(root / "printed"), "--no-figures"]) == 0
    return {"root": root, "study": study, "result": result, "qca": qca, "stdout": stdout.getvalue()}


def _json(path):
    return json.loads(path.read_text(encoding="utf-8"))


def _csv(path):
    with path.open(encoding="utf-8", newline="") as handle:
        reader = csv.DictReader(handle)
        return list(reader.fieldnames), list(reader)


def _number(cell: str):
    return None if cell == "" else float(cell)


def _same(cell: str, value) -> bool:
    """A CSV cell against the JSON value: numbers to 1e-9 relative, None as an empty cell."""
    if value is None:
        return cell == ""
    if isinstance(value, bool):
        return cell == str(value).lower()
    if isinstance(value, (int, float)):
        return math.isclose(float(cell), float(value), rel_tol=1e-9, abs_tol=1e-12)
    return cell == str(value)


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    return err


# -- the files ---------------------------------------------------------------------------------------
def test_qca_writes_the_three_files(case):
    out = case["qca"]
    for name in ("qca.json", "lesions.csv", "branches.csv"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    content = _json(out / "qca.json")
    assert content["format"] == "angiohull-qca"
    assert len(content["lesions"]) == len(content["lesion_views"]) > 0  # the case has lesions
    assert [v["view"] for v in content["views"]] == ["RAO30_CRA30", "LAO60_CRA30", "RAO30_CAU30"]
    assert not list(out.glob(".angiohull-partial-*"))  # the staging folder is gone


def test_lesions_csv_rows_equal_qca_json(case):
    columns, rows = _csv(case["qca"] / "lesions.csv")
    assert tuple(columns) == LESION_COLUMNS and set(REQUIRED_LESION_COLUMNS) <= set(columns)
    lesions = _json(case["qca"] / "qca.json")["lesions"]
    assert len(rows) == len(lesions) > 0
    for row, lesion in zip(rows, lesions):
        for column in columns:
            assert _same(row[column], lesion[column]), (column, row[column], lesion[column])
        assert [float(row[k]) for k in ("x_mm", "y_mm", "z_mm")] == lesion["mld_point_mm"]  # repr precision
        assert row["best_view"] and float(row["diameter_stenosis_pct"]) >= 20.0


def test_branches_csv_lengths_equal_tree_json(case):
    columns, rows = _csv(case["qca"] / "branches.csv")
    assert tuple(columns) == BRANCH_COLUMNS and set(REQUIRED_BRANCH_COLUMNS) <= set(columns)
    tree = _json(case["result"] / "tree.json")
    assert [int(r["branch"]) for r in rows] == [b["index"] for b in tree["branches"]]
    assert [_number(r["parent"]) for r in rows] == [b["parent"] for b in tree["branches"]]
    for row, branch in zip(rows, tree["branches"]):
        assert math.isclose(float(row["length_mm"]), branch["length_mm"], rel_tol=1e-12)
        diameter = 2.0 * np.asarray(branch["radius_mm"])
        assert diameter.min() - 1e-12 <= float(row["mean_diameter_mm"]) <= diameter.max() + 1e-12
    branches = _json(case["qca"] / "qca.json")["branches"]
    for row, branch in zip(rows, branches):
        for column in columns:
            assert _same(row[column], branch[column]), (column, row[column], branch[column])


def test_lesions_csv_without_lesions_is_the_header_only(tmp_path):
    s = np.linspace(0.0, 40.0, 81)
    tree = VesselTree((Branch(np.column_stack([s, np.zeros_like(s), np.zeros_like(s)]), 1.5, name="straight"),))
    result = analyse_tree(tree, settings=QcaSettings(lesion_views=False))
    assert result.lesions == ()
    paths = workflow.write_qca_outputs(tmp_path / "out", result)
    assert set(paths) == {"qca", "lesions", "branches"}
    assert paths["lesions"].read_text(encoding="utf-8") == ",".join(LESION_COLUMNS) + "\n"
    columns, rows = _csv(paths["branches"])
    assert len(rows) == 1 and rows[0]["name"] == "straight" and rows[0]["parent"] == ""
    assert "segment_views" not in _json(paths["qca"])


def test_write_qca_outputs_is_all_or_nothing(tmp_path):
    s = np.linspace(0.0, 40.0, 81)
    tree = VesselTree((Branch(np.column_stack([s, np.zeros_like(s), np.zeros_like(s)]), 1.5),))
    result = analyse_tree(tree, settings=QcaSettings(lesion_views=False))
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(OutputError, match="cannot write the outputs into"):
        workflow.write_qca_outputs(blocker / "out", result)
    with pytest.raises(QcaError, match="QcaResult"):
        workflow.write_qca_outputs(tmp_path / "out", {"lesions": []})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


# -- the figures -------------------------------------------------------------------------------------
def test_figures_are_pngs(case):
    out = case["qca"]
    n_lesions = len(_json(out / "qca.json")["lesions"])
    length_2 = _json(case["result"] / "tree.json")["branches"][2]["length_mm"]
    names = (["profiles.png"] + [f"view_map_lesion_{i}.png" for i in range(n_lesions)]
             + ["view_map_segment_1_5-25.png", f"view_map_segment_2_0-{f'{length_2:.1f}'.removesuffix('.0')}.png"])
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == sorted(names)
    for name in names:
        path = out / name
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        image = imread(path)
        assert image.ndim == 3 and image.shape[2] in (3, 4) and image.shape[0] > 200 and image.shape[1] > 300, name
        assert image[..., :3].std() > 0.05, name  # something is drawn


def test_segment_maps_go_to_qca_json(case):
    content = _json(case["qca"] / "qca.json")
    segments = content["segment_views"]
    assert [(s["branch"], s["start_mm"]) for s in segments] == [(1, 5.0), (2, 0.0)]
    assert segments[0]["end_mm"] == 25.0
    assert segments[1]["end_mm"] == pytest.approx(_json(case["result"] / "tree.json")["branches"][2]["length_mm"])
    for s in segments:
        assert s["best_view"].split()[0] in ("LAO", "RAO") and len(s["foreshortening"]) == len(s["secondary_deg"])


def test_qca_prints_one_line_per_lesion_and_the_outputs(case):
    lines = case["stdout"].splitlines()
    lesions = _json(case["qca"] / "qca.json")["lesions"]
    lesion_lines = [line for line in lines if line.startswith("lesion ")]
    assert len(lesion_lines) == len(lesions)
    for line, lesion in zip(lesion_lines, lesions):
        assert f"{lesion['diameter_stenosis_pct']:.1f} % DS" in line and f"MLD {lesion['mld_mm']:.2f} mm" in line
        assert line.endswith(f"best view {lesion['best_view']}")
    n_branches = len(_json(case["result"] / "tree.json")["branches"])
    assert any(line.startswith(f"{len(lesions)} lesions in {n_branches} branches") for line in lines)
    assert lines[-1].startswith("outputs in ") and lines[-1].endswith("qca.json, lesions.csv, branches.csv")


def test_figures_with_panels_left_out_and_a_map_without_overlap(tmp_path, monkeypatch):
    from angiohull import viz

    # a comb of 6 side branches, more than the (here) 4 panels drawn; one too short for a panel
    s = np.linspace(0.0, 80.0, 161)
    trunk = Branch(np.column_stack([s, np.zeros_like(s), np.zeros_like(s)]), 2.0 - s / 200.0, name="trunk")
    branches = [trunk]
    for k in range(6):
        t = np.linspace(0.0, 6.0 if k == 0 else 14.0 + 3 * k, 40)
        at = 20 * k + 10
        points = np.column_stack([np.full_like(t, s[at]), t * (1 if k % 2 else -1), 3.0 * np.sin(t / 4.0 + k)])
        branches.append(Branch(points, 0.8, 0, at, f"side{k}"))
    result = analyse_tree(VesselTree(tuple(branches)), settings=QcaSettings(lesion_views=False))
    assert sum(b.profile.reference is not None for b in result.branches) == 6
    monkeypatch.setattr(viz, "QCA_MAX_PANELS", 4)
    image = imread(viz.qca_profiles_figure(result, tmp_path / "profiles.png"))
    assert image.ndim == 3 and image.shape[1] > 2 * image.shape[0]  # one row of 4 panels
    # a thin straight vessel seen at least 45 degrees from its axis overlaps nowhere
    lone = VesselTree((Branch(trunk.points_mm, 0.2),))
    settings = QcaSettings(view_map=replace(QcaSettings().view_map, primary_range_deg=(-45.0, 45.0), step_deg=15.0,
                                            refine_step_deg=0.0))
    vm = segment_view_map(lone, 0, 20.0, 60.0, settings)
    assert not vm.overlap.any()
    assert imread(viz.qca_view_map_figure(vm, tmp_path / "map.png")).ndim == 3
    with pytest.raises(ValueError, match="ViewMap"):
        viz.qca_view_map_figure(result, tmp_path / "bad.png")
    with pytest.raises(ValueError, match="QcaResult"):
        viz.qca_profiles_figure(vm, tmp_path / "bad.png")
    assert not (tmp_path / "bad.png").exists()


# -- errors ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("segment, words", [("99", ["branch 99", "does not exist"]),
                                            ("1:50-10", ["segment 50-10 mm", "branch 1"])])
def test_a_segment_that_does_not_exist_is_one_line(case, tmp_path, capsys, segment, words):
    out = tmp_path / "out"
    assert main(["qca", str(case["result"]), "-o", str(out), "--segment", segment, "--no-figures", "-q"]) == 2
    line = _error_line(capsys)
    assert line.startswith("angiohull qca: error: ") and all(w in line for w in words), line
    assert not out.exists()  # checked before the analysis


@pytest.mark.parametrize("segment", ["x", "1:10", "1:10-", "-1", "1:-5-10", "1:a-b"])
def test_a_malformed_segment_is_an_argparse_error(case, capsys, segment):
    with pytest.raises(SystemExit) as exc:
        main(["qca", str(case["result"]), f"--segment={segment}"])
    assert exc.value.code == 2
    assert "BRANCH:START-END" in capsys.readouterr().err


def test_a_result_without_tree_json_is_one_clear_error(case, tmp_path, capsys):
    folder = tmp_path / "no-tree"
    folder.mkdir()
    shutil.copy(case["result"] / "report.json", folder / "report.json")
    assert main(["qca", str(folder)]) == 2
    line = _error_line(capsys)
    assert "tree.json" in line and "without --no-tree" in line, line
    assert main(["qca", str(tmp_path / "missing")]) == 2
    assert "no such folder" in _error_line(capsys)
    assert main(["qca", str(case["study"])]) == 2  # a study folder: its tree.json is the synthetic record
    assert "reconstruct it first" in _error_line(capsys)


def test_a_report_with_a_bad_view_is_named(case, tmp_path, capsys):
    folder = tmp_path / "bad-view"
    folder.mkdir()
    shutil.copy(case["result"] / "tree.json", folder / "tree.json")
    report = _json(case["result"] / "report.json")
    report["views"][1]["projection_matrix"] = [[1.0, 0.0], [0.0, 1.0]]
    (folder / "report.json").write_text(json.dumps(report), encoding="utf-8")
    assert main(["qca", str(folder)]) == 2
    line = _error_line(capsys)
    assert "report.json: views[1] ('LAO60_CRA30').projection_matrix" in line and "(3, 4)" in line, line
    (folder / "report.json").write_text("{not json", encoding="utf-8")
    assert main(["qca", str(folder)]) == 2
    assert "report.json: not JSON" in _error_line(capsys)


def test_without_report_json_there_is_no_view_section(case, tmp_path):
    folder = tmp_path / "tree-only"
    folder.mkdir()
    shutil.copy(case["result"] / "tree.json", folder / "tree.json")
    tree, projections, names = workflow.load_result_for_qca(folder)
    assert tree.n_branches == len(_json(folder / "tree.json")["branches"]) and projections == [] and names == []
    assert main(["qca", str(folder), "--no-views", "--no-figures", "-q"]) == 0
    content = _json(folder / "qca" / "qca.json")
    assert content["views"] == [] and content["lesion_views"] == []
    assert all(row["best_view"] == "" for row in _csv(folder / "qca" / "lesions.csv")[1])


# -- reconstruct --qca, help -------------------------------------------------------------------------
def test_reconstruct_qca_writes_the_same_analysis(case):
    inline = case["result"] / "qca"
    assert sorted(p.name for p in inline.iterdir()) == ["branches.csv", "lesions.csv", "qca.json"]  # --no-figure
    alone = _json(case["qca"] / "qca.json")
    del alone["segment_views"]
    assert _json(inline / "qca.json") == alone  # the tree in memory = tree.json; the views from report.json
    report = _json(case["result"] / "report.json")
    assert "qca" not in report  # report.json's schema is unchanged


def test_reconstruct_qca_needs_a_tree(case, tmp_path, capsys, monkeypatch):
    assert main(["reconstruct", str(case["study"]), "-o", str(tmp_path / "a"), "--qca", "--no-tree"]) == 2
    assert "--no-tree" in _error_line(capsys)
    assert not (tmp_path / "a").exists()

    real = workflow.reconstruct_study

    def without_tree(study, options, **kwargs):
        return replace(real(study, options, **kwargs), tree=None, tree_build=None, tree_error="no skeleton (test)")

    monkeypatch.setattr(workflow, "reconstruct_study", without_tree)
    out = tmp_path / "b"
    assert main(["reconstruct", str(case["study"]), "-o", str(out), "-k", "40", "--no-figure", "--qca", "-q"]) == 2
    err = capsys.readouterr().err
    assert "error: --qca: the reconstruction built no vessel tree (no skeleton (test))" in err
    assert (out / "report.json").is_file() and not (out / "qca").exists()


def test_qca_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["qca", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "RESULT_DIR" in text and "--segment BRANCH[:START-END]" in text and "--no-views" in text
    assert "% diameter stenosis" in text and "%%" not in text
    with pytest.raises(SystemExit):
        main(["reconstruct", "--help"])
    assert "--qca" in capsys.readouterr().out


def test_reconstruct_qca_puts_the_lesions_in_the_viewer(case):
    """``reconstruct --qca`` writes viewer.html again with a marker per lesion of qca.json."""
    from test_viewer import decode, figure_of, trace

    lesions = _json(case["result"] / "qca" / "qca.json")["lesions"]
    figure = figure_of((case["result"] / "viewer.html").read_text(encoding="utf-8"))
    markers = trace(figure, f"lesions ({len(lesions)})")
    positions = np.column_stack([decode(markers[k]) for k in "xyz"])
    np.testing.assert_allclose(positions, [[row["x_mm"], row["y_mm"], row["z_mm"]] for row in lesions], atol=1e-4)
    for text, row in zip(markers["hovertext"], lesions):
        assert f"MLD {row['mld_mm']:.2f} mm" in text and f"best view {row['best_view']}" in text
    assert "truth_points" in figure["angiohull"] and figure["angiohull"]["tree"]["branches"] >= 4


def test_qca_replaces_its_own_earlier_analysis_and_nothing_else(case, tmp_path, capsys):
    """`qca RESULT_DIR` again replaces RESULT_DIR/qca (an earlier run's extra lesion map goes with
    it); a folder holding anything else needs --overwrite; RESULT_DIR itself is never an output."""
    result = tmp_path / "result"
    shutil.copytree(case["result"], result)
    own = result / "qca"
    (own / "view_map_lesion_9.png").write_bytes(b"an earlier run's map")
    assert main(["qca", str(result), "--no-views", "--no-figures", "-q"]) == 0
    assert sorted(p.name for p in own.iterdir()) == ["branches.csv", "lesions.csv", "qca.json"]
    (own / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main(["qca", str(result), "--no-views", "--no-figures", "-q"]) == 2
    assert "not empty" in capsys.readouterr().err and (own / "notes.txt").is_file()
    assert main(["qca", str(result), "-o", str(result), "--overwrite", "--no-views", "--no-figures", "-q"]) == 2
    assert "an input of this command" in capsys.readouterr().err and (result / "tree.json").is_file()


# -- lesions measured on the angiograms (image: views) ------------------------------------------------
@pytest.fixture(scope="module")
def angiogram_case(case):
    """The demo's tree rendered as angiograms (seeded; angiohull.synthetic.angiogram) in the study's
    own views, a study of ``image:`` views beside it, reconstructed with ``--qca``."""
    import yaml

    from angiohull.synthetic import SynthOptions, make_case
    from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram

    root = case["root"] / "angiograms"
    (root / "images").mkdir(parents=True)
    document = yaml.safe_load((case["study"] / "study.yaml").read_text(encoding="utf-8"))
    synth = make_case(SynthOptions(kind="rca", seed=2025))
    for i, (entry, view) in enumerate(zip(document["views"], synth.views)):
        image = render_angiogram(synth.tree.phantom, view.carm, 2025 * 10 + i, AngiogramParameters(collimator_px=8)).image
        np.save(root / "images" / f"{entry['name']}.npy", image)
        del entry["mask"]
        entry["image"] = f"images/{entry['name']}.npy"
    for key in ("ground_truth", "ground_truth_tree"):
        document.pop(key, None)
    (root / "study.yaml").write_text(yaml.safe_dump(document, sort_keys=False), encoding="utf-8")
    result = case["root"] / "angiograms-result"
    assert main(["reconstruct", str(root), "-o", str(result), "--no-figure", "--no-viewer", "--qca", "-q"]) == 0
    return {"study": root, "result": result}


def test_reconstruct_qca_measures_lesions_on_the_angiograms(angiogram_case, case, tmp_path):
    result = angiogram_case["result"]
    analysis = _json(result / "qca" / "qca.json")
    assert analysis["lesions"], "the demo tree's lesions were found from the segmented angiograms"
    assert {les["mld_source"] for les in analysis["lesions"]} == {"images"}
    calibrations = analysis["attenuation_calibrations"]
    assert len(calibrations) == 3 and all(c["points"] >= 8 and c["attenuation_per_px"] > 0 for c in calibrations)
    header, rows = _csv(result / "qca" / "lesions.csv")
    assert "mld_source" in header and {row["mld_source"] for row in rows} == {"images"}
    for row, les in zip(rows, analysis["lesions"]):  # %DS from the measured MLD over the profile's reference
        assert float(row["diameter_stenosis_pct"]) == pytest.approx(
            100.0 * (1.0 - les["mld_mm"] / les["reference_diameter_mm"]), rel=1e-9)
    # `qca RESULT --study` gives the same analysis; without the study, the tree's own diameters
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["qca", str(result), "-o", str(tmp_path / "again"), "--study", str(angiogram_case["study"]),
                     "--no-figures"]) == 0
    assert _json(tmp_path / "again" / "qca.json") == analysis
    n = len(analysis["lesions"])
    assert f"; {n} of {n} MLDs measured on the angiograms\n" in stdout.getvalue()
    assert stdout.getvalue().count("(angiograms), ref") == n
    assert main(["qca", str(result), "-o", str(tmp_path / "tree"), "--no-figures", "-q"]) == 0
    plain = _json(tmp_path / "tree" / "qca.json")
    assert {les["mld_source"] for les in plain["lesions"]} == {"tree"} and plain["attenuation_calibrations"] == []
    assert [les["start_mm"] for les in plain["lesions"]] == [les["start_mm"] for les in analysis["lesions"]]


def test_qca_study_must_hold_the_results_views(angiogram_case, case, tmp_path, capsys):
    # the mask study (same view names) has no angiograms: said, and the tree's diameters are used
    assert main(["qca", str(angiogram_case["result"]), "-o", str(tmp_path / "masks"), "--study", str(case["study"]),
                 "--no-figures"]) == 0
    assert "lesions measured on the tree's diameters: views RAO30_CRA30, LAO60_CRA30, RAO30_CAU30 are masks" in \
        capsys.readouterr().err
    other = tmp_path / "other"
    shutil.copytree(angiogram_case["study"], other)
    text = (other / "study.yaml").read_text(encoding="utf-8").replace("name: RAO30_CRA30", "name: first")
    (other / "study.yaml").write_text(text, encoding="utf-8")
    assert main(["qca", str(angiogram_case["result"]), "-o", str(tmp_path / "bad"), "--study", str(other), "-q"]) == 2
    assert "the study has no view named 'RAO30_CRA30'" in _error_line(capsys)
