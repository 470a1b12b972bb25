"""The interactive viewer (``viewer.html``): the scene it embeds, checked against the inputs and
brute-force oracles; ``angiohull view`` and ``reconstruct``'s staging; and the page itself in
headless Chromium (skipped where Chromium is missing)."""

from __future__ import annotations

import base64
import json
import re
import time

import numpy as np
import pytest

from angiohull import viewer
from angiohull.cli import main
from angiohull.errors import StudyError, ViewerError
from angiohull.exports import read_mesh_stl, write_mesh_stl
from angiohull.geometry import CArmGeometry
from angiohull.tree import Branch, VesselTree
from angiohull.tree.solid import surface_mesh
from angiohull.viewer import ViewerView, decimate_mesh, even_subset, viewer_html

from test_cli import ball_study


# -- a tiny scene ---------------------------------------------------------------------------------------
def _tree(shift=0.0) -> VesselTree:
    """A Y of three branches (40 mm trunk along z, two 25 mm arms), radii 1.6 -> 0.8 mm."""
    s = np.linspace(0.0, 1.0, 21)
    trunk = np.column_stack([4.0 * np.sin(3.0 * s), 0.0 * s, -20.0 + 40.0 * s]) + shift
    top = trunk[-1]
    left = top + np.column_stack([-18.0 * s, 6.0 * s, 17.0 * s])
    right = top + np.column_stack([18.0 * s, -4.0 * s, 15.0 * s])
    return VesselTree((Branch(trunk, np.linspace(1.6, 1.2, 21), name="main"),
                       Branch(left, np.linspace(1.1, 0.8, 21), 0, 20, "left"),
                       Branch(right, np.linspace(1.0, 0.8, 21), 0, 20, "right")))


def _views():
    out = []
    for name, primary, secondary in (("RAO 30 CRA 20", -30.0, 20.0), ("LAO 50", 50.0, 0.0)):
        carm = CArmGeometry(primary, secondary, 1100.0, 750.0, (0.3, 0.3), (200, 240))
        out.append(ViewerView(name, carm.projection(), carm.sid_mm))
    return out


LESION = {"branch": 0, "branch_name": "main", "x_mm": 1.0, "y_mm": 0.0, "z_mm": -2.0, "mld_mm": 1.41,
          "reference_diameter_mm": 2.9, "diameter_stenosis_pct": 51.4, "lesion_length_mm": 7.25,
          "best_view": "LAO 20 CRA 35"}


@pytest.fixture(scope="module")
def scene():
    tree = _tree()
    mesh = surface_mesh(tree, step_mm=0.6)
    rng = np.random.default_rng(1)
    points = mesh.vertices_mm[::7] + rng.normal(scale=0.4, size=(len(mesh.vertices_mm[::7]), 3))
    truth_tree = _tree(shift=np.array([0.3, 0.0, 0.0]))
    truth = surface_mesh(truth_tree, step_mm=0.8).vertices_mm
    kwargs = dict(vessel_points_mm=points, mesh_vertices_mm=mesh.vertices_mm, mesh_faces=mesh.faces, tree=tree,
                  views=_views(), ground_truth_mm=truth, ground_truth_tree=truth_tree, lesions=[LESION],
                  title="tiny Y </script><script>window.bad = 1</script>", subtitle=["Dice3D 91.0 %", "tree: <b>x</b>"])
    return {"kwargs": kwargs, "html": viewer_html(**kwargs), "mesh": mesh, "points": points, "truth": truth,
            "truth_tree": truth_tree, "tree": tree}


def figure_of(page: str) -> dict:
    """The scene JSON embedded in a viewer page."""
    match = re.search(r'<script type="application/json" id="angiohull-figure">(.*?)</script>', page, re.S)
    assert match, "no scene element"
    return json.loads(match.group(1))


def decode(value) -> np.ndarray:
    """A plotly typed array ({"dtype", "bdata"}) or a plain list as a NumPy array."""
    if isinstance(value, dict):
        dtype = {"f4": "<f4", "i4": "<i4", "u2": "<u2"}[value["dtype"]]
        return np.frombuffer(base64.b64decode(value["bdata"]), dtype=dtype)
    return np.asarray(value, dtype=float)


def trace(figure: dict, name_start: str) -> dict:
    data = [t for t in figure["data"] if t.get("meta") != "legend entry"]  # (a layer's stand-in in the legend)
    found = [t for t in data if t["name"] == name_start] or [t for t in data if t["name"].startswith(name_start)]
    assert len(found) == 1, [t["name"] for t in figure["data"]]
    return found[0]


def xyz(t: dict) -> np.ndarray:
    return np.column_stack([decode(t[k]) for k in "xyz"])


# -- the embedded scene ----------------------------------------------------------------------------------
def test_page_is_self_contained_and_its_scene_parses(scene):
    page = scene["html"]
    assert page.startswith("<!DOCTYPE html>")
    assert "Plotly.newPlot" in page and "window.angiohullReady = true" in page
    assert not re.search(r"<script[^>]+src=", page)  # nothing fetched: plotly.js is inline
    assert "https://cdn" not in page.split('id="angiohull-figure"')[1]
    # a name with "</script>" cannot end the JSON element early (it is escaped as <\/script>)
    assert page.count("<script") == 3 and "window.bad = 1</script>" not in page
    figure = figure_of(page)
    assert "window.bad = 1" in figure["layout"]["title"]["text"]
    assert figure["layout"]["title"]["subtitle"]["text"] == "Dice3D 91.0 %<br>tree: &lt;b&gt;x&lt;/b&gt;"


def test_mesh_points_and_tree_are_the_inputs(scene):
    figure = figure_of(scene["html"])
    mesh = trace(figure, "vessel surface")
    assert len(scene["mesh"].faces) < viewer.MAX_MESH_FACES  # small: not decimated
    np.testing.assert_array_equal(xyz(mesh), scene["mesh"].vertices_mm.astype(np.float32))
    faces = np.column_stack([decode(mesh[k]) for k in "ijk"])
    np.testing.assert_array_equal(faces, scene["mesh"].faces)
    assert figure["angiohull"]["mesh"]["shown_faces"] == len(scene["mesh"].faces)
    points = trace(figure, "lumen points")
    np.testing.assert_array_equal(xyz(points), scene["points"].astype(np.float32))
    assert points["visible"] == "legendonly"  # under a mesh the points start hidden
    centerlines = trace(figure, "centerlines: radius")
    line = xyz(centerlines)
    radius = decode(centerlines["line"]["color"])
    gaps = np.isnan(line[:, 0])
    assert gaps.sum() == 2 and np.isnan(radius[gaps]).all()  # three branches, two gaps
    # branch after branch, each with its radii (the side branches start on their parent's point here)
    cuts = np.flatnonzero(gaps)
    for branch, part, part_radius in zip(scene["tree"].branches, np.split(line, cuts), np.split(radius, cuts)):
        part, part_radius = part[~np.isnan(part[:, 0])], part_radius[~np.isnan(part_radius)]
        np.testing.assert_allclose(part, branch.points_mm, atol=1e-5)
        np.testing.assert_allclose(part_radius, branch.radius_mm, atol=1e-6)
    assert centerlines["line"]["cmin"] == pytest.approx(0.8) and centerlines["line"]["cmax"] == pytest.approx(1.6)


def test_error_colouring_is_the_nearest_truth_distance(scene):
    figure = figure_of(scene["html"])
    errors = trace(figure, "error: lumen points")
    shown = xyz(errors)
    np.testing.assert_array_equal(shown, scene["points"].astype(np.float32))
    # brute force: every pair
    brute = np.sqrt(((scene["points"][:, None, :] - scene["truth"][None, :, :]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_allclose(decode(errors["marker"]["color"]), brute, rtol=1e-6, atol=1e-5)
    # the tree's points against the true centerline: brute force on a 0.01 mm resampling of it
    line_errors = trace(figure, "error: centerline")
    points = xyz(line_errors).astype(np.float64)
    dense = np.concatenate([b.resampled(0.01).points_mm for b in scene["truth_tree"].branches])
    brute = np.array([np.linalg.norm(dense - p, axis=1).min() for p in points])
    np.testing.assert_allclose(decode(line_errors["marker"]["color"]), brute, atol=2e-3)
    assert brute.max() < 0.3 + 1e-3 and brute.mean() > 0.15  # the truth is the same Y moved by 0.3 mm
    assert errors["visible"] == "legendonly" and "truth" in figure["angiohull"]["groups"]


def test_views_sit_where_their_projection_says(scene):
    figure = figure_of(scene["html"])
    for view in scene["kwargs"]["views"]:
        frame = xyz(trace(figure, f"{view.name}: source, detector")).astype(np.float64)
        source = xyz(trace(figure, f"{view.name}: source")).astype(np.float64)[0]
        np.testing.assert_allclose(source, view.projection.camera_centre_mm, atol=1e-3)
        corners = frame[:4]
        rows, cols = view.projection.image_shape
        np.testing.assert_allclose(view.projection.project(corners),
                                   [[-0.5, -0.5], [cols - 0.5, -0.5], [cols - 0.5, rows - 0.5], [-0.5, rows - 0.5]],
                                   atol=1e-2)
        # the detector plane lies SID from the source, along the principal ray
        centre = frame[-1]
        assert np.linalg.norm(centre - source) == pytest.approx(view.sid_mm, abs=1e-2)
        cone = xyz(trace(figure, f"{view.name}: X-ray cone"))
        assert np.isnan(cone[:, 0]).sum() == 3  # four rays
    assert len(figure["angiohull"]["groups"]["views"]) == 4 and len(figure["angiohull"]["groups"]["cones"]) == 2


def test_lesion_marker_and_its_hover_text(scene):
    figure = figure_of(scene["html"])
    lesions = trace(figure, "lesions (1)")
    np.testing.assert_allclose(xyz(lesions)[0], [1.0, 0.0, -2.0])
    text = lesions["hovertext"][0]
    for part in ("MLD 1.41 mm", "%DS 51 %", "length 7.2 mm", "best view LAO 20 CRA 35", "branch 0 (main)"):
        assert part in text, (part, text)
    with pytest.raises(ViewerError, match=r"lesions\[0\].*mld_mm"):
        viewer_html(vessel_points_mm=scene["points"], lesions=[{"x_mm": 0, "y_mm": 0, "z_mm": 0}])


def test_points_only_scene_without_truth():
    points = np.random.default_rng(2).normal(size=(500, 3)) * 10.0
    figure = figure_of(viewer_html(vessel_points_mm=points))
    names = [t["name"] for t in figure["data"]]
    assert names == ["lumen points (500)"]
    assert figure["data"][0].get("visible", True) is True  # the main layer without a mesh
    assert figure["layout"]["updatemenus"] == []
    empty = figure_of(viewer_html(vessel_points_mm=np.zeros((0, 3))))
    assert empty["data"] == []


def test_big_inputs_are_cut_to_the_budgets(monkeypatch):
    monkeypatch.setattr(viewer, "MAX_POINTS", 1000)
    points = np.random.default_rng(3).normal(size=(25_000, 3))
    figure = figure_of(viewer_html(vessel_points_mm=points))
    shown = xyz(figure["data"][0])
    assert len(shown) == 1000 and figure["angiohull"]["vessel_points"] == 25_000
    # an even subset of the rows, in order
    index = even_subset(25_000, 1000)
    np.testing.assert_array_equal(shown, points[index].astype(np.float32))
    assert index[0] == 0 and index[-1] == 24_999 and (np.diff(index) > 0).all()


def test_decimated_mesh_keeps_its_shape():
    tree = VesselTree((Branch(np.array([[0.0, 0.0, -15.0], [0.0, 0.0, 15.0]]), 4.0),))
    mesh = surface_mesh(tree, step_mm=0.25)
    vertices, faces, cell = decimate_mesh(mesh.vertices_mm, mesh.faces, 3000)
    assert 1000 < len(faces) <= 3000 and cell > 0
    assert faces.min() == 0 and faces.max() == len(vertices) - 1
    assert (faces[:, 0] != faces[:, 1]).all() and (faces[:, 1] != faces[:, 2]).all() and (faces[:, 0] != faces[:, 2]).all()
    volume = np.einsum("ij,ij->i", vertices[faces[:, 0]], np.cross(vertices[faces[:, 1]], vertices[faces[:, 2]])).sum() / 6
    exact = np.pi * 16.0 * 30.0 + 4.0 / 3.0 * np.pi * 64.0  # the capsule
    assert volume == pytest.approx(exact, rel=0.05)
    # vertices stay on the surface: |distance to the axis segment| - 4 within one cell
    closest_z = np.clip(vertices[:, 2], -15.0, 15.0)
    distance = np.linalg.norm(vertices - np.column_stack([0 * closest_z, 0 * closest_z, closest_z]), axis=1)
    assert np.abs(distance - 4.0).max() < cell
    same = decimate_mesh(mesh.vertices_mm, mesh.faces, len(mesh.faces))
    assert same[2] == 0.0 and same[1] is not None and len(same[1]) == len(mesh.faces)


@pytest.mark.parametrize("kwargs, match", [
    ({"vessel_points_mm": np.zeros((4, 2))}, r"vessel_points_mm.*\(N, 3\)"),
    ({"vessel_points_mm": [[0.0, np.nan, 0.0]]}, "non-finite"),
    ({"vessel_points_mm": np.zeros((3, 3)), "mesh_vertices_mm": np.zeros((3, 3)), "mesh_faces": [[0, 1, 3]]},
     "mesh_faces index"),
    ({"vessel_points_mm": np.zeros((3, 3)), "views": ["front"]}, r"views\[0\]"),
])
def test_bad_inputs_are_viewer_errors(kwargs, match):
    with pytest.raises(ViewerError, match=match):
        viewer_html(**kwargs)


# -- STL read back ----------------------------------------------------------------------------------------
def test_stl_round_trip_and_bad_files(tmp_path):
    mesh = surface_mesh(_tree(), step_mm=0.8)
    path = write_mesh_stl(tmp_path / "vessel.stl", mesh)
    back = read_mesh_stl(path)
    assert len(back.faces) == len(mesh.faces) and len(back.vertices_mm) == len(mesh.vertices_mm)
    np.testing.assert_allclose(back.vertices_mm[back.faces], mesh.vertices_mm[mesh.faces], atol=1e-5)
    assert back.volume_mm3 == pytest.approx(mesh.volume_mm3, rel=1e-5)
    (tmp_path / "short.stl").write_bytes(path.read_bytes()[:-10])
    with pytest.raises(StudyError, match="short.stl.*facets"):
        read_mesh_stl(tmp_path / "short.stl")
    (tmp_path / "ascii.stl").write_text("solid x\nendsolid x\n")
    with pytest.raises(StudyError, match="ascii.stl.*"):
        read_mesh_stl(tmp_path / "ascii.stl")


# -- the command line --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ball_result(tmp_path_factory):
    root = tmp_path_factory.mktemp("viewer-cli")
    study = ball_study(root / "study").parent
    out = root / "out"
    assert main(["reconstruct", str(study), "-o", str(out), "-k", "30", "--method", "hull", "--no-figure", "-q"]) == 0
    return {"root": root, "study": study, "out": out}


def test_reconstruct_writes_the_viewer_with_the_truth(ball_result):
    out = ball_result["out"]
    figure = figure_of((out / "viewer.html").read_text(encoding="utf-8"))
    report = json.loads((out / "report.json").read_text())
    assert figure["angiohull"]["vessel_points"] == report["n_vessel_points"]
    assert figure["angiohull"]["truth_points"] == 4000  # the ball study's ground truth
    assert "Dice3D" in figure["layout"]["title"]["subtitle"]["text"]  # a study with a truth is scored
    assert report["scores"]["dice3d"] > 50
    assert [v for v in figure["angiohull"]["views"]] == ["ap", "lao90"]
    if (out / "vessel.stl").is_file():
        stl = read_mesh_stl(out / "vessel.stl")
        assert figure["angiohull"]["mesh"]["vertices"] == len(stl.vertices_mm)


def test_view_rebuilds_the_page_with_lesions(ball_result, capsys, monkeypatch):
    out = ball_result["out"]
    (out / "qca").mkdir(exist_ok=True)
    (out / "qca" / "qca.json").write_text(json.dumps({"lesions": [LESION, {**LESION, "z_mm": 3.0}]}))
    opened = []
    monkeypatch.setattr("webbrowser.open", lambda url: opened.append(url) or True)
    page = ball_result["root"] / "elsewhere.html"
    assert main(["view", str(out), "-o", str(page), "--open"]) == 0
    assert opened == [page.resolve().as_uri()]
    figure = figure_of(page.read_text(encoding="utf-8"))
    np.testing.assert_allclose(xyz(trace(figure, "lesions (2)"))[:, 2], [-2.0, 3.0])
    assert figure["angiohull"]["truth_points"] == 4000  # from the study report.json names
    before = figure_of((out / "viewer.html").read_text(encoding="utf-8"))
    assert [t["name"] for t in before["data"] if not t["name"].startswith("lesions")] == \
           [t["name"] for t in figure["data"] if not t["name"].startswith("lesions")]
    assert "wrote" in capsys.readouterr().out


def test_view_of_a_folder_that_is_no_result_exits_2(ball_result, tmp_path, capsys):
    assert main(["view", str(ball_result["study"])]) == 2
    err = capsys.readouterr().err
    assert "report.json: not found" in err and "reconstruct it first" in err and "Traceback" not in err
    assert main(["view", str(tmp_path / "nothing")]) == 2
    assert "no such folder" in capsys.readouterr().err
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "report.json").write_text("{not json")
    assert main(["view", str(tmp_path / "r")]) == 2
    assert "report.json: not JSON" in capsys.readouterr().err


def test_view_without_the_study_notes_it(ball_result, tmp_path, capsys):
    import shutil

    copy = tmp_path / "moved"
    shutil.copytree(ball_result["out"], copy)
    report = json.loads((copy / "report.json").read_text())
    report["study"] = str(tmp_path / "gone")
    (copy / "report.json").write_text(json.dumps(report))
    assert main(["view", str(copy), "-q"]) == 0
    err = capsys.readouterr().err
    assert "no ground truth" in err and "cannot be loaded" in err and "--study" in err
    assert "truth_points" not in figure_of((copy / "viewer.html").read_text(encoding="utf-8"))["angiohull"]
    assert main(["view", str(copy), "--study", str(ball_result["study"]), "-q"]) == 0
    assert figure_of((copy / "viewer.html").read_text(encoding="utf-8"))["angiohull"]["truth_points"] == 4000


def test_a_failing_viewer_leaves_no_output(ball_result, tmp_path, monkeypatch, capsys):
    def broken(**kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(viewer, "viewer_html", broken)
    out = tmp_path / "out"
    assert main(["reconstruct", str(ball_result["study"]), "-o", str(out), "-k", "20", "--no-figure", "--no-tree",
                 "-q"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert not out.exists()  # all or nothing, the folder it created removed again


# -- the page in a real browser ----------------------------------------------------------------------------
def _browser():
    try:
        from _browser import Browser, BrowserMissing
    except ImportError as exc:  # pragma: no cover
        pytest.skip(f"browser driver not importable: {exc}")
    try:
        return Browser(width=1000, height=700, timeout_s=40.0)
    except BrowserMissing as exc:
        pytest.skip(f"{exc}: the viewer's browser test needs headless Chromium")


def vessel_box_share(png: bytes, width: int, height: int) -> tuple[float, float]:
    """(share of the scene area covered by the bounding box of the coloured pixels, share of
    coloured pixels): the scene area leaves out the legend (left), colour bars (right), title and
    help line; a pixel is coloured when its channels differ by more than 40 (grey UI is not)."""
    from io import BytesIO

    from matplotlib.image import imread

    image = (imread(BytesIO(png), format="png")[..., :3] * 255).astype(int)
    assert image.shape[:2] == (height, width)
    region = image[70:height - 30, int(0.2 * width):int(0.86 * width)]
    coloured = (region.max(axis=-1) - region.min(axis=-1)) > 40
    if not coloured.any():
        return 0.0, 0.0
    rows, cols = np.nonzero(coloured)
    box = (rows.max() - rows.min() + 1) * (cols.max() - cols.min() + 1)
    return float(box / coloured.size), float(coloured.mean())


def test_the_page_renders_the_vessel_in_headless_chromium(scene, tmp_path):
    page_path = tmp_path / "viewer.html"
    page_path.write_text(scene["html"], encoding="utf-8")
    start = time.monotonic()
    browser = _browser()
    with browser, browser.page(page_path.as_uri(), ready="window.angiohullReady === true") as page:
        shot = page.shot()
        # the same scene seen from 10 m away: what a lost vessel (or an empty canvas) looks like
        page.evaluate("Plotly.relayout('angiohull-plot', {'scene.camera.eye': {x: 0, y: -60, z: 0}}).then(() => true)",
                      wait=True)
        far = page.shot()
    elapsed = time.monotonic() - start
    (tmp_path / "viewer.png").write_bytes(shot.png)
    assert shot.errors == [] and far.errors == [], far.errors
    box, share = vessel_box_share(shot.png, 1000, 700)
    # measured: the Y's bounding box covers about 0.6 of the scene area, 7 % of its pixels coloured;
    # seen from 10 m the box covers under 0.001: a blank canvas or a lost vessel fails
    assert box > 0.25 and share > 0.01, (box, share)
    far_box, _ = vessel_box_share(far.png, 1000, 700)
    assert far_box < 0.02, far_box
    print(f"browser: {elapsed:.1f} s (page ready after {shot.seconds:.1f} s); vessel box {box:.2f}, coloured "
          f"{share:.3f}; from 10 m {far_box:.4f}")
