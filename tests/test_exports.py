"""Exports of a vessel tree (VTP, SWC, JSON, STL, NIfTI) and the readers of true trees.

Every file is read back with its own library (VTK, MorphIO, numpy, trimesh, nibabel), never with
angiohull's writer code.
"""

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from angiohull import __version__
from angiohull import exports
from angiohull.errors import StudyError, TreeError
from angiohull.exports import (EXPORT_FILES, LPS_TO_RAS, SWC_TYPE, read_true_tree, read_tree_json,
                               write_centerlines_vtp, write_lumen_nifti, write_mesh_stl, write_swc,
                               write_tree_exports, write_tree_json)
from angiohull.tree.model import Branch, VesselTree
from angiohull.tree.solid import lumen_labels, surface_mesh


def _three_branch_tree() -> VesselTree:
    """Root of 20 points; ``side1`` (12 points) leaves it at point 8 starting exactly there (as
    built trees do); ``side2`` (6 points) leaves side1 at point 5 starting 0.5 mm away (a connector)."""
    t = np.linspace(0.0, 1.0, 20)
    root = Branch(np.column_stack([30 * t, 2 * np.sin(3 * t), 0.25 * t]), 1.5 - 0.5 * t, name="main")
    s = np.linspace(0.0, 1.0, 12)
    side1 = Branch(root.points_mm[8] + np.column_stack([0 * s, 15 * s, 3 * s]), 1.0 - 0.3 * s, 0, 8, "side1")
    u = np.linspace(0.0, 1.0, 6)
    side2 = Branch(side1.points_mm[5] + np.column_stack([8 * u + 0.5, 0 * u, 8 * u]), 0.8 - 0.2 * u, 1, 5, "side2")
    return VesselTree((root, side1, side2))


TREE = _three_branch_tree()


@pytest.fixture(scope="module")
def mesh():
    return surface_mesh(TREE, step_mm=0.4)


@pytest.fixture(scope="module")
def lumen():
    return lumen_labels(TREE, spacing_mm=0.6)


def _files_under(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*"))


# -- VTP ----------------------------------------------------------------------------------------
def test_vtp_reads_back_with_vtk(tmp_path):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    path = write_centerlines_vtp(tmp_path / "centerlines.vtp", TREE)
    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    assert reader.GetErrorCode() == 0
    poly = reader.GetOutput()
    assert poly.GetNumberOfCells() == TREE.n_branches
    assert poly.GetNumberOfPoints() == TREE.n_points

    point_data, cell_data = poly.GetPointData(), poly.GetCellData()
    assert [point_data.GetArrayName(i) for i in range(point_data.GetNumberOfArrays())] == ["MaximumInscribedSphereRadius"]
    assert {cell_data.GetArrayName(i) for i in range(cell_data.GetNumberOfArrays())} == {
        "CenterlineIds", "ParentIds", "ParentPointIds"}
    points = vtk_to_numpy(poly.GetPoints().GetData())
    radius = vtk_to_numpy(point_data.GetArray("MaximumInscribedSphereRadius"))
    assert radius.dtype == np.float64
    centerline_ids = vtk_to_numpy(cell_data.GetArray("CenterlineIds"))
    np.testing.assert_array_equal(centerline_ids, np.arange(TREE.n_branches))
    np.testing.assert_array_equal(vtk_to_numpy(cell_data.GetArray("ParentIds")), [-1, 0, 1])
    np.testing.assert_array_equal(vtk_to_numpy(cell_data.GetArray("ParentPointIds")), [-1, 8, 5])

    for c in range(poly.GetNumberOfCells()):
        cell_ids = poly.GetCell(c).GetPointIds()
        ids = [cell_ids.GetId(k) for k in range(cell_ids.GetNumberOfIds())]
        branch = TREE.branches[int(centerline_ids[c])]
        np.testing.assert_allclose(points[ids], branch.points_mm, rtol=0, atol=1e-12)
        np.testing.assert_allclose(radius[ids], branch.radius_mm, rtol=0, atol=1e-12)

    names = poly.GetFieldData().GetAbstractArray("BranchNames")
    assert [names.GetValue(i) for i in range(names.GetNumberOfValues())] == ["main", "side1", "side2"]
    assert poly.GetFieldData().GetAbstractArray("Units").GetValue(0) == "mm"


# -- SWC ----------------------------------------------------------------------------------------
def test_swc_structure_exact_with_numpy(tmp_path):
    path = write_swc(tmp_path / "tree.swc", TREE)
    table = np.loadtxt(path, comments="#")
    assert table.shape == (38, 7)
    np.testing.assert_array_equal(table[:, 0], np.arange(1, 39))
    np.testing.assert_array_equal(table[:, 1], SWC_TYPE)
    expected_parents = ([-1] + list(range(1, 20))          # root: ids 1-20
                        + [9] + list(range(21, 32))         # side1: ids 21-32, leaves root point 8 (id 9)
                        + [26] + list(range(33, 38)))       # side2: ids 33-38, leaves side1 point 5 (id 26)
    np.testing.assert_array_equal(table[:, 6], expected_parents)
    assert (table[1:, 6] < table[1:, 0]).all()  # parents before children
    points, radius, _ = TREE.points()
    np.testing.assert_array_equal(table[:, 2:5], points)  # 17 digits: float64 survives
    np.testing.assert_array_equal(table[:, 5], radius)

    header = [line for line in path.read_text(encoding="utf-8").splitlines() if line.startswith("#")]
    text = "\n".join(header)
    assert "mm" in text and "LPS" in text and f"angiohull {__version__}" in text and f"T = {SWC_TYPE}" in text


def test_swc_reads_back_with_morphio(tmp_path):
    morphio = pytest.importorskip("morphio")
    path = write_swc(tmp_path / "tree.swc", TREE)
    collector = morphio.WarningHandlerCollector()
    morphology = morphio.Morphology(str(path), warning_handler=collector)
    # a vessel tree has no soma: MorphIO says so, and nothing else
    assert {type(w.warning).__name__ for w in collector.get_all()} <= {"NoSomaFound", "DisconnectedNeurite"}
    assert len(morphology.soma.points) == 0

    sections = list(morphology.iter())
    # MorphIO splits a branch at every point that others leave from: B + (interior bifurcations)
    assert len(sections) == TREE.n_branches + len(TREE.bifurcations)
    assert all(s.type == getattr(morphio.SectionType, f"custom{SWC_TYPE}") for s in sections)
    assert sum(s.is_root for s in sections) == 1

    # MorphIO starts each child section with a copy of its parent section's last point (unless the
    # file's own first point of the child is there): drop those copies, the rest are the file's points
    rows = []
    for s in sections:
        block = np.column_stack([s.points, s.diameters])
        if not s.is_root and np.array_equal(block[0], np.append(s.parent.points[-1], s.parent.diameters[-1])):
            block = block[1:]
        rows.append(block)
    theirs = np.concatenate(rows)
    points, radius, _ = TREE.points()
    ours = np.column_stack([points, 2.0 * radius])  # MorphIO reports diameters
    assert len(theirs) == TREE.n_points
    order = lambda a: a[np.lexsort(a.T[::-1])]  # noqa: E731
    np.testing.assert_allclose(order(theirs), order(ours), rtol=1e-6, atol=1e-5)  # MorphIO holds float32


# -- JSON ---------------------------------------------------------------------------------------
def test_json_round_trip_is_exact(tmp_path):
    back = read_tree_json(write_tree_json(tmp_path / "tree.json", TREE))
    assert back.n_branches == TREE.n_branches
    for a, b in zip(back.branches, TREE.branches):
        np.testing.assert_array_equal(a.points_mm, b.points_mm)
        np.testing.assert_array_equal(a.radius_mm, b.radius_mm)
        assert (a.parent, a.parent_point, a.name) == (b.parent, b.parent_point, b.name)


def test_read_tree_json_rejects_non_json_and_non_tree(tmp_path):
    bad = tmp_path / "broken.json"
    bad.write_text("{not json", encoding="utf-8")
    with pytest.raises(StudyError, match=r"broken\.json: not JSON"):
        read_tree_json(bad)
    other = tmp_path / "other.json"
    other.write_text('{"format": "something else"}', encoding="utf-8")
    with pytest.raises(StudyError, match=r"other\.json: not an angiohull vessel tree"):
        read_tree_json(other)
    with pytest.raises(StudyError, match=r"absent\.json: file not found"):
        read_tree_json(tmp_path / "absent.json")


# -- STL ----------------------------------------------------------------------------------------
def test_stl_reads_back_with_trimesh(tmp_path, mesh):
    trimesh = pytest.importorskip("trimesh")
    path = write_mesh_stl(tmp_path / "vessel.stl", mesh)
    assert path.read_bytes()[:5] != b"solid"  # binary, and not mistaken for ASCII
    loaded = trimesh.load(str(path), force="mesh")
    assert len(loaded.faces) == len(mesh.faces)
    assert loaded.is_watertight
    assert loaded.volume == pytest.approx(mesh.volume_mm3, rel=1e-6)


# -- NIfTI --------------------------------------------------------------------------------------
def test_nifti_reads_back_with_nibabel(tmp_path, lumen):
    import nibabel

    path = write_lumen_nifti(tmp_path / "lumen.nii.gz", lumen)
    image = nibabel.load(str(path))
    data = np.asarray(image.dataobj)
    assert data.dtype == np.uint8  # fewer than 256 branches
    np.testing.assert_array_equal(data, lumen.labels)
    assert set(np.unique(data)) == {0, 1, 2, 3}
    # NIfTI-1 stores the affine as float32
    np.testing.assert_allclose(image.affine, np.diag([-1.0, -1.0, 1.0, 1.0]) @ lumen.affine_lps, rtol=1e-6, atol=1e-6)
    sform, sform_code = image.header.get_sform(coded=True)
    qform, qform_code = image.header.get_qform(coded=True)
    assert int(sform_code) == 1 and int(qform_code) == 1
    np.testing.assert_allclose(qform, image.affine, atol=1e-6)
    assert image.header.get_xyzt_units()[0] == "mm"

    index = np.argwhere(data == 2)[0]
    ras = image.affine @ np.append(index, 1.0)
    lps = np.diag([-1.0, -1.0, 1.0]) @ ras[:3]
    np.testing.assert_allclose(lps, lumen.origin_mm + lumen.spacing_mm * index, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(LPS_TO_RAS, np.diag([-1.0, -1.0, 1.0, 1.0]))


def test_nifti_is_what_nibabel_save_writes(tmp_path, lumen):
    """Byte for byte nibabel.save of the whole label map in NIfTI order, whether the labels fit
    uint8 or not, empty or not."""
    from angiohull.tree.solid import LumenVolume

    rng = np.random.default_rng(9)
    many = np.zeros((30, 20, 40), dtype=np.uint16)
    many.reshape(-1)[rng.choice(many.size, 500, replace=False)] = rng.integers(1, 700, 500)
    cases = [lumen, LumenVolume(many, np.array([1.5, -2.0, 3.25]), 0.3),
             LumenVolume(np.zeros((4, 5, 6), dtype=np.uint16), np.zeros(3), 1.0)]
    for case in cases:
        exports._write_nifti(tmp_path / "ours.nii.gz", case)
        exports._write_nifti_whole(tmp_path / "whole.nii.gz", case)
        assert (tmp_path / "ours.nii.gz").read_bytes() == (tmp_path / "whole.nii.gz").read_bytes()


# -- the set ------------------------------------------------------------------------------------
def test_write_tree_exports_writes_the_set(tmp_path, mesh, lumen):
    out = tmp_path / "new" / "exports"
    files = write_tree_exports(out, TREE, mesh=mesh, lumen=lumen)
    assert set(files) == {"centerlines_vtp", "swc", "tree_json", "mesh_stl", "lumen_nifti"}
    assert {p.name for p in files.values()} == set(EXPORT_FILES.values())
    assert sorted(p.name for p in out.iterdir()) == sorted(EXPORT_FILES.values())  # no temporary left
    assert all(p.stat().st_size > 0 for p in files.values())

    only_tree = write_tree_exports(tmp_path / "plain", TREE)
    assert set(only_tree) == {"centerlines_vtp", "swc", "tree_json"}
    assert len(list((tmp_path / "plain").iterdir())) == 3


def test_write_tree_exports_under_a_regular_file(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x", encoding="utf-8")
    target = blocker / "out"
    with pytest.raises(TreeError, match=r"cannot write .*file\.txt/out/centerlines\.vtp: Not a directory"):
        write_tree_exports(target, TREE)
    assert _files_under(tmp_path) == [blocker]
    with pytest.raises(TreeError, match=r"Not a directory"):
        write_tree_exports(blocker, TREE)  # the folder itself is a file
    assert _files_under(tmp_path) == [blocker]
    with pytest.raises(TreeError, match=r"cannot write .*file\.txt/tree\.swc: Not a directory"):
        write_swc(blocker / "tree.swc", TREE)


def test_write_tree_exports_failure_in_the_middle_leaves_nothing(tmp_path, monkeypatch, mesh):
    def full_disk(path, tree):
        Path(path).write_bytes(b"partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(exports, "_write_json", full_disk)
    new = tmp_path / "new" / "deeper"
    with pytest.raises(TreeError, match=r"cannot write .*tree\.json: No space left on device"):
        write_tree_exports(new, TREE, mesh=mesh)
    assert _files_under(tmp_path) == []  # no file, no temporary, and the folders it made are gone

    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "centerlines.vtp").write_bytes(b"old")
    with pytest.raises(TreeError, match=r"tree\.json"):
        write_tree_exports(existing, TREE, mesh=mesh)
    assert _files_under(existing) == [existing / "centerlines.vtp"]  # earlier exports untouched
    assert (existing / "centerlines.vtp").read_bytes() == b"old"


def test_the_label_map_written_beside_the_others_fails_as_cleanly(tmp_path, monkeypatch, mesh, lumen):
    # the label map is written on a second thread: its failure names its file, a failure of
    # another file waits for it, and either way nothing is left behind
    import threading

    def slow_full_disk(path, lumen, prepared=None):
        Path(path).write_bytes(b"partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(exports, "_write_nifti", slow_full_disk)
    with pytest.raises(TreeError, match=r"cannot write .*lumen\.nii\.gz: No space left on device"):
        write_tree_exports(tmp_path / "a", TREE, mesh=mesh, lumen=lumen)
    assert _files_under(tmp_path) == []

    started, finished = threading.Event(), threading.Event()

    def late_nifti(path, lumen, prepared=None):
        started.set()
        threading.Event().wait(0.3)
        Path(path).write_bytes(b"late")
        finished.set()

    def failing_json(path, tree):
        assert started.wait(5)
        raise OSError(errno.EIO, os.strerror(errno.EIO), str(path))

    monkeypatch.setattr(exports, "_write_nifti", late_nifti)
    monkeypatch.setattr(exports, "_write_json", failing_json)
    with pytest.raises(TreeError, match=r"cannot write .*tree\.json: Input/output error"):
        write_tree_exports(tmp_path / "b", TREE, mesh=mesh, lumen=lumen)
    assert finished.is_set() and _files_under(tmp_path) == []


def test_a_writer_that_writes_nothing_is_a_failure(tmp_path, monkeypatch):
    # VTK writers report failure on the console only; an empty or absent output must still fail
    monkeypatch.setattr(exports, "_write_vtp", lambda path, tree: None)
    with pytest.raises(TreeError, match=r"cannot write .*centerlines\.vtp: the writer produced an empty file"):
        write_tree_exports(tmp_path / "out", TREE)
    with pytest.raises(TreeError, match=r"c\.vtp: the writer produced an empty file"):
        write_centerlines_vtp(tmp_path / "c.vtp", TREE)
    assert _files_under(tmp_path) == []


def test_vtk_writer_failure_is_detected(tmp_path):
    from vtkmodules.vtkCommonCore import vtkObject
    from vtkmodules.vtkCommonDataModel import vtkPolyData
    from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

    writer = vtkXMLPolyDataWriter()
    writer.SetInputData(vtkPolyData())
    shown = vtkObject.GetGlobalWarningDisplay()
    vtkObject.GlobalWarningDisplayOff()  # VTK prints its error on the console
    try:
        with pytest.raises(OSError, match="vtkXMLPolyDataWriter"):
            exports._vtk_write(writer, tmp_path / "missing" / "c.vtp")
    finally:
        vtkObject.SetGlobalWarningDisplay(shown)


def test_writers_reject_wrong_types(tmp_path, mesh):
    with pytest.raises(TreeError, match="VesselTree"):
        write_swc(tmp_path / "t.swc", "not a tree")
    with pytest.raises(TreeError, match="SurfaceMesh"):
        write_mesh_stl(tmp_path / "m.stl", TREE)
    with pytest.raises(TreeError, match="LumenVolume"):
        write_tree_exports(tmp_path / "out", TREE, lumen=mesh)
    assert _files_under(tmp_path) == []


# -- true trees ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def synthetic_case(tmp_path_factory):
    from angiohull.synthetic.case import SynthOptions, make_case, write_case

    folder = tmp_path_factory.mktemp("synth")
    case = make_case(SynthOptions(seed=3, size=128, pixel_mm=1.4, views="perpendicular"))
    write_case(folder, case)
    return case, folder / "gt_centerlines.npz"


def test_read_true_tree_synthetic_npz(synthetic_case):
    case, path = synthetic_case
    tree = read_true_tree(path)
    truth = case.tree.branches
    assert tree.n_branches == len(truth)
    assert [b.parent for b in tree.branches] == [b.parent for b in truth]
    assert [b.parent_point for b in tree.branches] == [b.origin_vertex for b in truth]
    assert [b.name for b in tree.branches] == [b.name for b in truth]
    for ours, theirs in zip(tree.branches, truth):
        np.testing.assert_array_equal(ours.points_mm, theirs.centerline_mm)
        np.testing.assert_array_equal(ours.radius_mm, theirs.radius_mm)
    for b in tree.branches[1:]:
        anchor = tree.branches[b.parent].points_mm[b.parent_point]
        assert np.linalg.norm(b.points_mm[0] - anchor) <= 1e-9


def test_read_true_tree_json(tmp_path):
    back = read_true_tree(write_tree_json(tmp_path / "tree.JSON", TREE))
    assert [b.parent for b in back.branches] == [None, 0, 1]


def test_read_true_tree_authors_npy(peer_synthetic_dir):
    path = peer_synthetic_dir / "clinical_moderate_000" / "gt_centerlines.npy"
    array = np.load(path, allow_pickle=False)
    tree = read_true_tree(path)
    assert tree.n_branches == array.shape[0] == 4
    assert [b.parent for b in tree.branches] == [None, 0, 0, 0]
    assert [b.name for b in tree.branches] == ["main", "side1", "side2", "side3"]
    for b, branch in enumerate(tree.branches):
        np.testing.assert_array_equal(branch.points_mm, array[b, :, :3].astype(np.float64))
        np.testing.assert_array_equal(branch.radius_mm, array[b, :, 3].astype(np.float64))
    for b in tree.branches[1:]:  # the side branches start on a point of the main vessel
        assert np.linalg.norm(b.points_mm[0] - tree.branches[b.parent].points_mm[b.parent_point]) == 0


def test_read_true_tree_authors_npy_nonpositive_radius(peer_synthetic_dir):
    path = peer_synthetic_dir / "perpendicular_moderate_002" / "gt_centerlines.npy"
    with pytest.raises(StudyError, match=r"perpendicular_moderate_002.*branch 0 has 7 radius value\(s\) <= 0 mm"):
        read_true_tree(path)
    array = np.load(path, allow_pickle=False).astype(np.float64)
    tree = read_true_tree(path, nonpositive_radius_mm=0.05)
    radius = array[0, :, 3]
    np.testing.assert_array_equal(tree.root.radius_mm, np.where(radius <= 0, 0.05, radius))


def test_read_true_tree_npy_repeats(tmp_path):
    t = np.linspace(0.0, 1.0, 20)
    main = np.column_stack([20 * t, 0 * t, 0 * t, 1.5 - 0.5 * t])
    side = np.column_stack([main[10, 0] + 0 * t, 10 * t, 0 * t, 0.8 + 0 * t])
    array = np.stack([main, side])
    repeated = np.stack([np.insert(main, 5, main[5], axis=0), np.insert(side, 19, side[19], axis=0)])
    np.save(tmp_path / "repeats.npy", repeated, allow_pickle=False)
    tree = read_true_tree(tmp_path / "repeats.npy")
    np.testing.assert_array_equal(tree.root.points_mm, main[:, :3])  # the exact repeats are dropped
    np.testing.assert_array_equal(tree.branches[1].radius_mm, side[:, 3])
    assert (tree.branches[1].parent, tree.branches[1].parent_point) == (0, 10)

    moved = np.stack([np.insert(main, 5, main[5] + [0, 0, 0, 0.1], axis=0), np.insert(side, 0, side[0], axis=0)])
    np.save(tmp_path / "ambiguous.npy", moved, allow_pickle=False)
    with pytest.raises(StudyError, match=r"ambiguous\.npy: branch 0, points 5 and 6 .* same x, y, z"):
        read_true_tree(tmp_path / "ambiguous.npy")

    nan = array.copy()
    nan[1, 3, 2] = np.nan
    np.save(tmp_path / "nan.npy", nan, allow_pickle=False)
    with pytest.raises(StudyError, match=r"nan\.npy: holds 1 non-finite value"):
        read_true_tree(tmp_path / "nan.npy")
    np.save(tmp_path / "flat.npy", array[0], allow_pickle=False)
    with pytest.raises(StudyError, match=r"flat\.npy: expected .*\(B, M, 4\).* shape \(20, 4\)"):
        read_true_tree(tmp_path / "flat.npy")


def test_read_true_tree_bad_inputs(tmp_path, synthetic_case):
    with pytest.raises(StudyError, match=r"missing\.npz: file not found"):
        read_true_tree(tmp_path / "missing.npz")
    text = tmp_path / "tree.txt"
    text.write_text("1 2 3", encoding="utf-8")
    with pytest.raises(StudyError, match=r"tree\.txt: unsupported file extension '\.txt'.*\.npz, \.npy, \.json"):
        read_true_tree(text)

    _, good = synthetic_case
    with np.load(good, allow_pickle=False) as archive:
        arrays = {key: archive[key] for key in archive.files if key != "parents"}
    np.savez(tmp_path / "no_parents.npz", **arrays)
    with pytest.raises(StudyError, match=r"no_parents\.npz: lacks the array\(s\) \['parents'\]"):
        read_true_tree(tmp_path / "no_parents.npz")

    np.save(tmp_path / "array.npy", np.zeros(3), allow_pickle=False)
    (tmp_path / "array.npy").rename(tmp_path / "array.npz")
    with pytest.raises(StudyError, match=r"array\.npz: is a single \.npy array"):
        read_true_tree(tmp_path / "array.npz")
    with pytest.raises(StudyError, match="nonpositive_radius_mm"):
        read_true_tree(good, nonpositive_radius_mm=-1.0)

    data = good.read_bytes()  # a copy cut short: a zip archive without its directory
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 3])
    with pytest.raises(StudyError, match=r"cut\.npz: cannot read as a NumPy \.npz archive \(.*zip.*\); expected gt_centerlines"):
        read_true_tree(tmp_path / "cut.npz")
    (tmp_path / "picture.npy").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(32))  # a PNG under an .npy name
    with pytest.raises(StudyError, match=r"picture\.npy: cannot read as a NumPy \.npy file \(it is none: .*begins with b'\\x89PNG"):
        read_true_tree(tmp_path / "picture.npy")
