"""Exports of a vessel tree for other tools, and readers of true (ground-truth) trees.

Writers (each through the format's own library; nothing hand-formatted but SWC, a plain table):

=====================  ===================================================================================
``centerlines.vtp``    VTK XML PolyData (:func:`write_centerlines_vtp`): one polyline cell per branch;
                       point data ``MaximumInscribedSphereRadius`` (radius, mm) and cell data
                       ``CenterlineIds`` (branch index), VMTK's names, plus ``ParentIds`` and
                       ``ParentPointIds`` (-1 for the root); field data ``BranchNames``, ``Units``,
                       ``Frame``, ``Generator``
``tree.swc``           SWC, 7 columns ``n T x y z R P`` (:func:`write_swc`), structure type
                       :data:`SWC_TYPE` on every point, no soma
``tree.json``          :meth:`VesselTree.to_dict <angiohull.tree.model.VesselTree.to_dict>` as JSON
                       (:func:`write_tree_json`, read back by :func:`read_tree_json`)
``vessel.stl``         binary STL of a :class:`~angiohull.tree.solid.SurfaceMesh` (:func:`write_mesh_stl`)
``lumen.nii.gz``       NIfTI-1 of a :class:`~angiohull.tree.solid.LumenVolume`'s uint16 labels
                       (:func:`write_lumen_nifti`), affine in NIfTI's RAS world frame
=====================  ===================================================================================

:func:`write_tree_exports` writes the set into a folder, all or nothing.

Units and frame: millimetres, DICOM patient coordinates (LPS: +x patient left, +y posterior, +z
head) everywhere except the NIfTI affine, which NIfTI defines in RAS (+x right, +y anterior):
``affine_ras = diag(-1, -1, 1, 1) @ affine_lps``.

Every file is first written under a hidden temporary name in its destination folder and then
renamed into place (:func:`os.replace`), so a failed write never leaves a partial file under the
final name. A file that cannot be written raises :class:`~angiohull.errors.TreeError` naming the
path and the operating system's reason; a bad input file raises
:class:`~angiohull.errors.StudyError` starting with the file's path.

Heavy libraries (VTK, nibabel) are imported inside the functions that need them.
"""

from __future__ import annotations

import errno
import json
import os
import secrets
import zipfile
from pathlib import Path
from typing import Any, Callable, Union

import numpy as np

from . import _validation as _v
from .errors import StudyError, TreeError
from .io import load_numpy_file
from .tree.model import Branch, VesselTree
from .tree.solid import LumenVolume, SurfaceMesh

__all__ = ["write_centerlines_vtp", "write_swc", "write_tree_json", "read_tree_json", "write_mesh_stl", "read_mesh_stl",
           "write_lumen_nifti", "read_true_tree", "write_tree_exports", "SWC_TYPE", "EXPORT_FILES",
           "TRUE_TREE_SUFFIXES", "LPS_TO_RAS"]

PathLike = Union[str, "os.PathLike[str]"]

SWC_TYPE = 7
"""SWC structure type written on every point: 7, the code the SWC specification (Cannon et al.
1998) reserves for a "custom" structure. A vessel is none of the neuron compartments 1-4 (soma,
axon, dendrite, apical dendrite), and 0 ("undefined") is refused by some readers (earlier MorphIO
releases, hence NeuroM: "Unsupported section type: 0"); MorphIO reads 7 as ``SectionType.custom7``
(its custom types 5-19)."""

EXPORT_FILES: dict[str, str] = {"centerlines_vtp": "centerlines.vtp", "swc": "tree.swc", "tree_json": "tree.json",
                                "mesh_stl": "vessel.stl", "lumen_nifti": "lumen.nii.gz"}
"""File name of each export of :func:`write_tree_exports`, by its key in the returned dict."""

TRUE_TREE_SUFFIXES: tuple[str, ...] = (".npz", ".npy", ".json")
"""File extensions :func:`read_true_tree` understands (lower case)."""

LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])
"""4x4 change of world frame from DICOM patient coordinates (LPS) to NIfTI's RAS."""

_FRAME = "DICOM patient coordinates (LPS: +x patient left, +y posterior, +z head)"
_TRUE_TREE_EXPECTED = ("a true tree as gt_centerlines.npz (angiohull synth), gt_centerlines.npy "
                       "(the authors' (B, M, 4) x, y, z, radius array) or tree.json (angiohull)")
_JSON_EXPECTED = "an angiohull vessel tree JSON (tree.json)"


def _version() -> str:
    from . import __version__

    return __version__


# -- argument checks --------------------------------------------------------------------------
def _check_tree(tree: Any) -> VesselTree:
    if not isinstance(tree, VesselTree):
        raise TreeError(f"tree must be a VesselTree, got {type(tree).__name__}")
    return tree


def _check_mesh(mesh: Any) -> SurfaceMesh:
    if not isinstance(mesh, SurfaceMesh):
        raise TreeError(f"mesh must be a SurfaceMesh (angiohull.tree.solid.surface_mesh), got {type(mesh).__name__}")
    vertices, faces = np.asarray(mesh.vertices_mm), np.asarray(mesh.faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.isfinite(vertices).all():
        raise TreeError(f"mesh.vertices_mm must be a finite (V, 3) array in mm, got shape {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or faces.dtype.kind not in "iu":
        raise TreeError(f"mesh.faces must be a non-empty (F, 3) integer array, got shape {faces.shape}, "
                        f"dtype {faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise TreeError(f"mesh.faces index vertices {int(faces.min())}..{int(faces.max())}, but the mesh has "
                        f"{len(vertices)} vertices")
    return mesh


def _lumen_labels(lumen: Any) -> np.ndarray:
    if not isinstance(lumen, LumenVolume):
        raise TreeError(f"lumen must be a LumenVolume (angiohull.tree.solid.lumen_labels), got {type(lumen).__name__}")
    labels = np.asarray(lumen.labels)
    if labels.ndim != 3 or labels.size == 0:
        raise TreeError(f"lumen.labels must be a non-empty 3D array, got shape {labels.shape}")
    if labels.dtype != np.uint16:
        if labels.dtype.kind not in "iub" or labels.min() < 0 or labels.max() > np.iinfo(np.uint16).max:
            raise TreeError(f"lumen.labels must be uint16 labels (0 outside, b + 1 in branch b), got dtype "
                            f"{labels.dtype}" + (f" with values {labels.min()}..{labels.max()}" if labels.dtype.kind in "iuf" else ""))
        labels = labels.astype(np.uint16)
    affine = np.asarray(lumen.affine_lps, dtype=np.float64)
    if affine.shape != (4, 4) or not np.isfinite(affine).all() or abs(np.linalg.det(affine[:3, :3])) == 0:
        raise TreeError(f"lumen affine must be a finite invertible 4x4 matrix, got {affine.tolist()}")
    return labels


# -- writing through a temporary file ---------------------------------------------------------
def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__


def _open_temporary(path: Path) -> Path:
    """Create an empty, hidden, unique file beside ``path`` (mode from the umask, as for any new
    file) ending in the same extension(s), and return its path; OSError if the folder is unusable."""
    suffix = "".join(path.suffixes[-2:])
    for _ in range(100):
        temporary = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp{suffix}")
        try:
            os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        return temporary
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(path))  # pragma: no cover


def _check_written(path: Path) -> None:
    """Library writers that report failure only on the console: the file must exist and be non-empty."""
    try:
        size = path.stat().st_size
    except OSError:
        raise OSError("the writer did not produce the file") from None
    if size == 0:
        raise OSError("the writer produced an empty file")


def _remove(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass


def _write_atomically(path: PathLike, write: Callable[[Path], None]) -> Path:
    """Write ``path`` through ``write(temporary)`` and rename it into place; TreeError on failure."""
    path = Path(path)
    temporary = None
    try:
        temporary = _open_temporary(path)
        write(temporary)
        _check_written(temporary)
        os.replace(temporary, path)
    except BaseException as exc:
        if temporary is not None:
            _remove(temporary)
        if isinstance(exc, OSError):
            raise TreeError(f"cannot write {path}: {_reason(exc)}") from None
        raise
    return path


# -- the writers proper (to a given path, no temporary) ---------------------------------------
def _vtk_write(writer: Any, path: Path) -> None:
    from vtkmodules.vtkCommonMisc import vtkErrorCode

    writer.SetFileName(str(path))
    ok = writer.Write()
    code = writer.GetErrorCode()
    if ok != 1 or code != 0:
        reason = vtkErrorCode.GetStringFromErrorCode(code) if code else "the VTK writer failed"
        raise OSError(f"{type(writer).__name__}: {reason}")


def _string_array(name: str, values: list[str]) -> Any:
    from vtkmodules.vtkCommonCore import vtkStringArray

    array = vtkStringArray()
    array.SetName(name)
    for value in values:
        array.InsertNextValue(value)
    return array


def _write_vtp(path: Path, tree: VesselTree) -> None:
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
    from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

    points_mm, radius_mm, _ = tree.points()
    counts = np.array([b.n_points for b in tree.branches], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    points = vtkPoints()
    points.SetData(numpy_to_vtk(np.ascontiguousarray(points_mm, dtype=np.float64), deep=True))
    cells = vtkCellArray()
    cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                  numpy_to_vtkIdTypeArray(np.arange(offsets[-1], dtype=np.int64), deep=True))
    polydata = vtkPolyData()
    polydata.SetPoints(points)
    polydata.SetLines(cells)

    radius = numpy_to_vtk(np.ascontiguousarray(radius_mm, dtype=np.float64), deep=True)
    radius.SetName("MaximumInscribedSphereRadius")
    polydata.GetPointData().AddArray(radius)
    cell_arrays = {
        "CenterlineIds": np.arange(tree.n_branches),
        "ParentIds": [-1 if b.parent is None else b.parent for b in tree.branches],
        "ParentPointIds": [-1 if b.parent_point is None else b.parent_point for b in tree.branches],
    }
    for name, values in cell_arrays.items():
        array = numpy_to_vtk(np.asarray(values, dtype=np.int32), deep=True)
        array.SetName(name)
        polydata.GetCellData().AddArray(array)
    field = polydata.GetFieldData()
    field.AddArray(_string_array("BranchNames", [b.name for b in tree.branches]))
    field.AddArray(_string_array("Units", ["mm"]))
    field.AddArray(_string_array("Frame", [_FRAME]))
    field.AddArray(_string_array("Generator", [f"angiohull {_version()}"]))

    writer = vtkXMLPolyDataWriter()
    writer.SetInputData(polydata)
    _vtk_write(writer, path)


def _swc_table(tree: VesselTree) -> np.ndarray:
    """(N, 7) rows ``n T x y z R P``: ids from 1, branch after branch, parents before children."""
    first_id = np.cumsum([0] + [b.n_points for b in tree.branches[:-1]]) + 1
    rows = []
    for b, branch in enumerate(tree.branches):
        m = branch.n_points
        ids = first_id[b] + np.arange(m)
        parents = ids - 1
        parents[0] = -1 if branch.parent is None else first_id[branch.parent] + branch.parent_point
        rows.append(np.column_stack([ids, np.full(m, SWC_TYPE), branch.points_mm, branch.radius_mm, parents]))
    return np.concatenate(rows)


def _write_swc(path: Path, tree: VesselTree) -> None:
    table = _swc_table(tree)
    first_id = np.cumsum([0] + [b.n_points for b in tree.branches[:-1]]) + 1
    header = [
        f"vessel tree written by angiohull {_version()}",
        "units: mm (x, y, z and the radius R)",
        f"frame: {_FRAME}",
        f"structure type T = {SWC_TYPE} (SWC 'custom') on every point: a vessel centreline point; no soma",
        "P = -1 for the root's first point; a branch's first point has the parent's point it leaves from as parent",
        f"{tree.n_branches} branches, {tree.n_points} points; each branch's points are consecutive ids:",
    ]
    for b, branch in enumerate(tree.branches):
        where = "root" if branch.parent is None else f"parent branch {branch.parent} at its point {branch.parent_point}"
        header.append(f"branch {b} {json.dumps(branch.name)}: ids {first_id[b]}-{first_id[b] + branch.n_points - 1}, "
                      f"{where}")
    header.append("n T x y z R P")
    np.savetxt(path, table, fmt=["%d", "%d", "%.17g", "%.17g", "%.17g", "%.17g", "%d"], delimiter=" ",
               header="\n".join(header), comments="# ", encoding="utf-8")


def _write_json(path: Path, tree: VesselTree) -> None:
    text = json.dumps(tree.to_dict(), indent=1, allow_nan=False)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(text + "\n")


def _write_stl(path: Path, mesh: SurfaceMesh) -> None:
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
    from vtkmodules.vtkIOGeometry import vtkSTLWriter

    faces = np.asarray(mesh.faces, dtype=np.int64)
    points = vtkPoints()
    points.SetData(numpy_to_vtk(np.ascontiguousarray(mesh.vertices_mm, dtype=np.float64), deep=True))
    triangles = vtkCellArray()
    triangles.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(faces) + 1, 3, dtype=np.int64), deep=True),
                      numpy_to_vtkIdTypeArray(np.ascontiguousarray(faces.ravel()), deep=True))
    polydata = vtkPolyData()
    polydata.SetPoints(points)
    polydata.SetPolys(triangles)
    writer = vtkSTLWriter()
    writer.SetInputData(polydata)
    writer.SetFileTypeToBinary()
    # 80 bytes at most; a binary header must not start with "solid" (readers take it for ASCII STL)
    writer.SetHeader(f"angiohull {_version()} vessel surface, mm, DICOM patient frame LPS"[:80])
    _vtk_write(writer, path)


def _labelled(labels: np.ndarray) -> np.ndarray:
    """Flat (C order) indices of the nonzero labels, ascending: the grid is scanned 8 bytes at a
    time (a label volume is mostly empty), then the words that hold a label are looked into."""
    flat = np.ascontiguousarray(labels).reshape(-1)
    per_word = 8 // flat.itemsize if 8 % flat.itemsize == 0 else 0
    whole = len(flat) - len(flat) % per_word if per_word else 0
    if whole == 0:
        return np.flatnonzero(flat)
    words = np.flatnonzero(flat[:whole].view(np.uint64) != 0)  # nonzero is faster on bools
    candidates = (words[:, None] * per_word + np.arange(per_word)).reshape(-1)
    candidates = np.concatenate([candidates, np.arange(whole, len(flat))])
    return candidates[flat[candidates] != 0]


def _label_dtype(values: np.ndarray, labels: np.ndarray) -> np.dtype:
    """uint8 when every label fits (half the bytes to compress), else the labels' own dtype."""
    return np.dtype(np.uint8) if len(values) == 0 or values.max() <= np.iinfo(np.uint8).max else labels.dtype


def _in_nifti_order(labels: np.ndarray) -> np.ndarray:
    """The labels in NIfTI's order (first index fastest: Fortran order) and data type
    (:func:`_label_dtype`), as one array, built from the few labelled voxels into a fresh zeroed
    one (no copy of the whole grid)."""
    flat = _labelled(labels)
    values = labels.reshape(-1)[flat]
    out = np.zeros(labels.size, dtype=_label_dtype(values, labels))
    out[np.ravel_multi_index(np.unravel_index(flat, labels.shape), labels.shape, order="F")] = values
    return out.reshape(labels.shape, order="F")


def _nifti_image(lumen: LumenVolume, data: np.ndarray) -> Any:
    """The NIfTI image of a lumen with ``data`` (the labels in NIfTI order, or an array of their
    shape and data type)."""
    import nibabel

    affine = LPS_TO_RAS @ np.asarray(lumen.affine_lps, dtype=np.float64)
    header = nibabel.Nifti1Header()
    header.set_data_dtype(data.dtype)
    image = nibabel.Nifti1Image(data, affine, header)
    image.set_sform(affine, code=1)
    image.set_qform(affine, code=1)
    image.header.set_xyzt_units(xyz="mm")
    image.header.set_intent("label")
    image.header["descrip"] = b"angiohull lumen: 0 outside, b+1 branch b; RAS = diag(-1,-1,1) LPS"
    return image


def _write_nifti_whole(path: Path, lumen: LumenVolume) -> None:
    """nibabel.save of the whole label map: the reference of :func:`_write_nifti`."""
    import nibabel

    nibabel.save(_nifti_image(lumen, _in_nifti_order(_lumen_labels(lumen))), str(path))


def _nifti_prepared(lumen: LumenVolume) -> tuple[Any, np.ndarray]:
    """The header and the data of the label map's file (:func:`_write_nifti`): the header updated
    from the image and given the slope and intercept of nibabel's array writer (none: the labels
    are written in their own data type), the data :func:`_in_nifti_order` as one flat array."""
    from nibabel.arraywriters import get_slope_inter, make_array_writer

    data = _in_nifti_order(_lumen_labels(lumen))
    image = _nifti_image(lumen, data)
    image.update_header()
    header = image.header
    stand_in = np.broadcast_to(np.zeros((), dtype=data.dtype), data.shape)  # the writer need not scan the data
    writer = make_array_writer(stand_in, header.get_data_dtype(), header.has_data_slope, header.has_data_intercept)
    header.set_slope_inter(*get_slope_inter(writer))
    return header, data.ravel(order="F")  # a view: the array is in Fortran order


def _write_nifti(path: Path, lumen: LumenVolume, prepared: tuple[Any, np.ndarray] | None = None) -> None:
    """The file ``nibabel.save`` writes (:func:`_write_nifti_whole`, byte for byte; a test holds
    them equal), written as ``Nifti1Image.to_file_map`` does it: the header, then the data
    (:func:`_nifti_prepared`, or ``prepared`` when given), through nibabel's opener (gzip at
    nibabel's level, no time stamp), in one write: zlib compresses it in one call, which takes
    Python's GIL only now and then (for a new output block), so other threads run meanwhile."""
    from nibabel.openers import ImageOpener
    from nibabel.volumeutils import seek_tell

    header, data = _nifti_prepared(lumen) if prepared is None else prepared
    with ImageOpener(str(path), "wb") as handle:
        header.write_to(handle)
        seek_tell(handle, header.get_data_offset(), write0=True)
        handle.write(memoryview(data).cast("B"))


# -- public writers ---------------------------------------------------------------------------
def write_centerlines_vtp(path: PathLike, tree: VesselTree) -> Path:
    """Write the centerlines as VTK XML PolyData (``.vtp``), readable by VTK, ParaView and VMTK.

    One polyline cell per branch (its points in order, tree order); points in mm, DICOM patient
    frame (LPS). Point data ``MaximumInscribedSphereRadius`` (float64, the radius in mm); cell data
    ``CenterlineIds`` (the branch index), ``ParentIds`` (parent branch, -1 for the root) and
    ``ParentPointIds`` (index of the parent's point the branch leaves from, -1 for the root), all
    int32; field data ``BranchNames``, ``Units``, ``Frame``, ``Generator`` (strings). The writer's
    default settings (binary, appended, compressed).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    TreeError
        If ``tree`` is not a VesselTree or the file cannot be written (the message names the path
        and the reason).
    """
    tree = _check_tree(tree)
    return _write_atomically(path, lambda temporary: _write_vtp(temporary, tree))


def write_swc(path: PathLike, tree: VesselTree) -> Path:
    """Write the tree as SWC: 7 columns ``n T x y z R P`` (radius R in mm), after ``#`` comment
    lines giving the units (mm), the frame (DICOM patient, LPS), the angiohull version, the type
    code and each branch's id range.

    Ids start at 1 and run branch after branch, each branch's points in order; the root's first
    point has P = -1, every later point of a branch has the previous point as parent, and a child
    branch's first point has the id of its parent's point ``parent_point`` (so parents always come
    before their children). Every point has the structure type :data:`SWC_TYPE` (7, "custom"); no
    soma is written (SWC readers of neurons warn that there is none). Numbers are written with 17
    significant digits (float64 survives a round trip).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    TreeError
        If ``tree`` is not a VesselTree or the file cannot be written.
    """
    tree = _check_tree(tree)
    return _write_atomically(path, lambda temporary: _write_swc(temporary, tree))


def write_tree_json(path: PathLike, tree: VesselTree) -> Path:
    """Write :meth:`VesselTree.to_dict <angiohull.tree.model.VesselTree.to_dict>` as JSON (UTF-8,
    indent 1); :func:`read_tree_json` reads it back.

    Raises
    ------
    TreeError
        If ``tree`` is not a VesselTree or the file cannot be written.
    """
    tree = _check_tree(tree)
    return _write_atomically(path, lambda temporary: _write_json(temporary, tree))


def write_mesh_stl(path: PathLike, mesh: SurfaceMesh) -> Path:
    """Write a surface mesh as binary STL (VTK's writer; coordinates in mm, DICOM patient frame,
    stored as float32 as binary STL requires; facet normals from the right-hand rule, outward).

    Raises
    ------
    TreeError
        If ``mesh`` is not a usable SurfaceMesh or the file cannot be written.
    """
    mesh = _check_mesh(mesh)
    return _write_atomically(path, lambda temporary: _write_stl(temporary, mesh))


def write_lumen_nifti(path: PathLike, lumen: LumenVolume) -> Path:
    """Write a lumen label volume as NIfTI-1 (nibabel; gzip-compressed when ``path`` ends in ``.gz``).

    The data are the labels (0 outside, ``b + 1`` inside branch ``b``; uint8 when there are fewer than
    256 branches, uint16 otherwise), intent "label".
    NIfTI's world frame is RAS (+x right, +y anterior, +z head) while angiohull's is LPS, so the
    affine written is ``diag(-1, -1, 1, 1) @ lumen.affine_lps`` (:data:`LPS_TO_RAS`): voxel ``(i, j,
    k)`` maps to ``(-x, -y, z)`` of its LPS centre ``origin_mm + spacing_mm * (i, j, k)``. sform and
    qform both hold it with code 1 (scanner), xyz units mm; the header's ``descrip`` says so.
    NIfTI-1 stores the affine in float32 (about 1e-7 relative).

    Raises
    ------
    TreeError
        If ``lumen`` is not a usable LumenVolume or the file cannot be written.
    """
    _lumen_labels(lumen)
    return _write_atomically(path, lambda temporary: _write_nifti(temporary, lumen))


def _make_folder(folder: Path) -> list[Path]:
    """Create ``folder`` and missing parents; return the folders created, outermost first."""
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(folder))
    missing = []
    current = folder
    while not current.exists() and current != current.parent:
        missing.append(current)
        current = current.parent
    created = []
    try:
        for path in reversed(missing):
            path.mkdir()
            created.append(path)
    except BaseException:
        for path in reversed(created):
            path.rmdir()
        raise
    return created


def write_tree_exports(out_dir: PathLike, tree: VesselTree, *, mesh: SurfaceMesh | None = None,
                       lumen: LumenVolume | None = None) -> dict[str, Path]:
    """Write the exports of a tree into ``out_dir`` (created if missing), all or nothing.

    Files (:data:`EXPORT_FILES`): ``centerlines.vtp`` (:func:`write_centerlines_vtp`), ``tree.swc``
    (:func:`write_swc`), ``tree.json`` (:func:`write_tree_json`), and ``vessel.stl``
    (:func:`write_mesh_stl`) when ``mesh`` is given, ``lumen.nii.gz`` (:func:`write_lumen_nifti`)
    when ``lumen`` is given. Existing files of those names are replaced.

    Every file is first written under a hidden temporary name in ``out_dir`` (the label map,
    prepared first, compressed on a second thread while the others are written: zlib lets other
    threads run while it compresses); only when all are written are they renamed into place. If anything fails, every file this call wrote (the
    temporaries and any already renamed) and every folder it created is removed before the error
    is raised.

    Returns
    -------
    dict of str to Path
        Keys ``"centerlines_vtp"``, ``"swc"``, ``"tree_json"``, and ``"mesh_stl"`` /
        ``"lumen_nifti"`` when written.

    Raises
    ------
    TreeError
        If an argument is not of its type, or a file cannot be written: the message names the path
        and the operating system's reason, e.g. ``cannot write /x/centerlines.vtp: Not a directory``.
    """
    out_dir = Path(out_dir)
    tree = _check_tree(tree)
    jobs: list[tuple[str, Callable[[Path], None]]] = [
        ("centerlines_vtp", lambda p: _write_vtp(p, tree)),
        ("swc", lambda p: _write_swc(p, tree)),
        ("tree_json", lambda p: _write_json(p, tree)),
    ]
    if mesh is not None:
        checked_mesh = _check_mesh(mesh)
        jobs.append(("mesh_stl", lambda p: _write_stl(p, checked_mesh)))
    if lumen is not None:
        _lumen_labels(lumen)
        prepared = _nifti_prepared(lumen)  # here: the second thread then only compresses and writes
        jobs.append(("lumen_nifti", lambda p: _write_nifti(p, lumen, prepared)))  # last: written on a second thread

    finals = {key: out_dir / EXPORT_FILES[key] for key, _ in jobs}
    created: list[Path] = []
    temporaries: dict[str, Path] = {}
    placed: list[Path] = []
    current = finals["centerlines_vtp"]
    background = None  # the label map, compressed on a second thread while the others are written
    pool = None
    try:
        created = _make_folder(out_dir)
        if lumen is not None:
            from concurrent.futures import ThreadPoolExecutor

            # zlib lets other threads run while it compresses the label map (the largest file by
            # far) in one call; it still waits for Python's GIL now and then (a new output block),
            # which VTK's writers hold while they write, so the two overlap only in part
            key, write = jobs.pop()
            current = finals[key]
            temporaries[key] = _open_temporary(current)
            pool = ThreadPoolExecutor(1, thread_name_prefix="angiohull-nifti")
            background = (key, pool.submit(write, temporaries[key]))
        for key, write in jobs:
            current = finals[key]
            temporaries[key] = _open_temporary(current)
            write(temporaries[key])
            _check_written(temporaries[key])
        if background is not None:
            key, future = background
            current = finals[key]
            future.result()
            _check_written(temporaries[key])
        for key, temporary in temporaries.items():
            current = finals[key]
            os.replace(temporary, current)
            placed.append(current)
    except BaseException as exc:
        if pool is not None:
            pool.shutdown(wait=True)  # nothing may still be writing when the temporaries go
        for temporary in temporaries.values():
            _remove(temporary)
        for path in placed:
            _remove(path)
        for folder in reversed(created):
            try:
                folder.rmdir()
            except OSError:
                pass
        if isinstance(exc, OSError):
            raise TreeError(f"cannot write {current}: {_reason(exc)}") from None
        raise
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
    return finals


# -- readers ----------------------------------------------------------------------------------
def _require_file(path: Path, expected: str) -> None:
    if not path.exists():
        raise StudyError(f"{path}: file not found; expected {expected}")
    if not path.is_file():
        raise StudyError(f"{path}: is not a regular file; expected {expected}")


def read_tree_json(path: PathLike) -> VesselTree:
    """Read a tree written by :func:`write_tree_json` (the ``tree.json`` of an export).

    Raises
    ------
    StudyError
        If the file is missing or unreadable, is not JSON, or is not a valid angiohull vessel tree;
        the message starts with the path.
    """
    path = Path(path)
    _require_file(path, _JSON_EXPECTED)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise StudyError(f"{path}: cannot read as UTF-8 text ({_reason(exc)}); expected {_JSON_EXPECTED}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StudyError(f"{path}: not JSON ({exc.msg} at line {exc.lineno}, column {exc.colno}); "
                         f"expected {_JSON_EXPECTED}") from None
    try:
        return VesselTree.from_dict(data, str(path))
    except TreeError as exc:
        raise StudyError(str(exc)) from None


_STL_EXPECTED = "a binary STL mesh (the vessel.stl of angiohull reconstruct)"


def read_mesh_stl(path: PathLike) -> SurfaceMesh:
    """Read a binary STL (:func:`write_mesh_stl`) as a :class:`SurfaceMesh`: the facets' corners
    welded where they are equal (float32 as stored), faces in the file's order; ``step_mm`` is nan
    (a file does not say it).

    Raises
    ------
    StudyError
        If the file is missing or unreadable, is ASCII STL, or its size does not match its facet
        count; the message starts with the path.
    """
    path = Path(path)
    _require_file(path, _STL_EXPECTED)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StudyError(f"{path}: cannot read it ({_reason(exc)}); expected {_STL_EXPECTED}") from None
    if len(data) < 84:
        raise StudyError(f"{path}: {len(data)} bytes, shorter than a binary STL header (84); expected {_STL_EXPECTED}")
    count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
    if len(data) != 84 + 50 * count:
        ascii_hint = " (it looks like ASCII STL, which is not read)" if data[:5].lower() == b"solid" else ""
        raise StudyError(f"{path}: {len(data)} bytes but the header announces {count} facets ({84 + 50 * count} "
                         f"bytes){ascii_hint}; expected {_STL_EXPECTED}")
    facet = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    corners = np.frombuffer(data, dtype=facet, count=count, offset=84)["corners"].reshape(-1, 3)
    if not np.isfinite(corners).all():
        raise StudyError(f"{path}: a facet corner is not finite; expected {_STL_EXPECTED}")
    vertices, inverse = np.unique(corners, axis=0, return_inverse=True)
    return SurfaceMesh(vertices.astype(np.float64), inverse.reshape(-1, 3).astype(np.int64), float("nan"))


def _numeric_rows(array: np.ndarray, where: str, expected: str) -> np.ndarray:
    if array.dtype.kind not in "iuf":
        raise StudyError(f"{where}: expected {expected}, got an array of dtype {array.dtype}")
    array = array.astype(np.float64)
    bad = ~np.isfinite(array)
    if bad.any():
        first = np.argwhere(bad)[0].tolist()
        raise StudyError(f"{where}: holds {int(bad.sum())} non-finite value(s) (the first at index {first}); "
                         f"expected {expected}")
    return array


def _member(archive: Any, path: Path, key: str, expected: str) -> np.ndarray:
    try:
        return archive[key]
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:  # object arrays need pickle; damaged archives
        raise StudyError(f"{path}: cannot load its array {key!r} ({exc}); expected {expected}") from None


def _read_npz(path: Path) -> VesselTree:
    expected = ("gt_centerlines.npz as written by angiohull synth: branch_names, parents (-1 root), "
                "origin_vertices (-1 root) and an (M, 4) x, y, z, radius array per branch name")
    archive = load_numpy_file(path, expected, "a NumPy .npz archive")
    if isinstance(archive, np.ndarray):
        raise StudyError(f"{path}: is a single .npy array, not an .npz archive; expected {expected}")
    with archive:
        keys = set(archive.files)
        missing = [k for k in ("branch_names", "parents", "origin_vertices") if k not in keys]
        if missing:
            raise StudyError(f"{path}: lacks the array(s) {missing} (has {sorted(keys)}); expected {expected}")
        names, parents, origins = (_member(archive, path, key, expected)
                                   for key in ("branch_names", "parents", "origin_vertices"))
        if names.ndim != 1 or names.dtype.kind != "U" or len(names) == 0:
            raise StudyError(f"{path}: branch_names must be a non-empty 1D array of strings, got shape "
                             f"{names.shape}, dtype {names.dtype}")
        for key, values in (("parents", parents), ("origin_vertices", origins)):
            if values.shape != names.shape or values.dtype.kind not in "iu":
                raise StudyError(f"{path}: {key} must be {len(names)} integers (one per branch name, -1 for the "
                                 f"root), got shape {values.shape}, dtype {values.dtype}")
        if len(set(names.tolist())) != len(names):
            raise StudyError(f"{path}: branch_names repeat a name ({names.tolist()}); each names its own array")
        branches = []
        for b, name in enumerate(names.tolist()):
            if name not in keys:
                raise StudyError(f"{path}: branch_names[{b}] = {name!r} has no array of that name; expected {expected}")
            where = f"{path}: {name}"
            rows = _numeric_rows(_member(archive, path, name, expected), where,
                                 "an (M, 4) array of x, y, z, radius in mm")
            if rows.ndim != 2 or rows.shape[1] != 4:
                raise StudyError(f"{where}: expected an (M, 4) array of x, y, z, radius in mm, got shape {rows.shape}")
            parent, origin = int(parents[b]), int(origins[b])
            if (parent < 0) != (origin < 0) or min(parent, origin) < -1:
                raise StudyError(f"{path}: branch {b} ({name!r}) has parents[{b}] = {parent} and origin_vertices[{b}] = "
                                 f"{origin}; expected both -1 (the root) or both indices >= 0")
            try:
                branches.append(Branch(rows[:, :3], rows[:, 3], None if parent < 0 else parent,
                                       None if origin < 0 else origin, name))
            except TreeError as exc:
                raise StudyError(f"{path}: {exc}") from None
    for b, branch in enumerate(branches):
        if branch.parent is not None and branch.parent >= len(branches):
            raise StudyError(f"{path}: branch {b} ({branch.name!r}) has parent {branch.parent}, but there are "
                             f"{len(branches)} branches")
    try:
        if all(branch.parent is None or branch.parent < b for b, branch in enumerate(branches)):
            return VesselTree(tuple(branches))
        return VesselTree.reordered(branches)  # a valid tree listed in another order: parents first
    except TreeError as exc:
        raise StudyError(f"{path}: {exc}") from None


def _read_authors_npy(path: Path, nonpositive_radius_mm: float | None) -> VesselTree:
    expected = "the authors' gt_centerlines.npy: a (B, M, 4) array of x, y, z, radius in mm, main vessel first"
    loaded = load_numpy_file(path, expected)
    if not isinstance(loaded, np.ndarray):
        loaded.close()
        raise StudyError(f"{path}: is an .npz archive, not a single .npy array; expected {expected}")
    if loaded.ndim != 3 or loaded.shape[2] != 4 or loaded.shape[0] < 1 or loaded.shape[1] < 2:
        raise StudyError(f"{path}: expected {expected} (B >= 1, M >= 2), got an array of shape {loaded.shape}")
    array = _numeric_rows(loaded, str(path), expected)
    polylines, radii = [], []
    for b, rows in enumerate(array):
        # exact repeats of a whole row (x, y, z and radius) carry nothing: keep the first
        repeat = np.concatenate([[False], (rows[1:] == rows[:-1]).all(axis=1)])
        rows = rows[~repeat]
        same_place = np.flatnonzero((rows[1:, :3] == rows[:-1, :3]).all(axis=1))
        if same_place.size:
            i = int(same_place[0])
            raise StudyError(f"{path}: branch {b}, points {i} and {i + 1} (after dropping exact repeats) have the same "
                             f"x, y, z {rows[i, :3].tolist()} but radii {rows[i, 3]!r} and {rows[i + 1, 3]!r}; "
                             f"expected distinct consecutive points")
        if len(rows) < 2:
            raise StudyError(f"{path}: branch {b} has a single distinct point {rows[0, :3].tolist()}; expected a "
                             f"centerline of 2 or more points")
        radius = rows[:, 3].copy()
        bad = np.flatnonzero(radius <= 0)
        if bad.size:
            if nonpositive_radius_mm is None:
                raise StudyError(
                    f"{path}: branch {b} has {bad.size} radius value(s) <= 0 mm at points {bad.tolist()} "
                    f"(down to {radius[bad].min():.6g} mm); expected radii > 0 mm. A stenosis of the authors' "
                    f"generator can overshoot below zero; pass nonpositive_radius_mm=<radius in mm> to "
                    f"read_true_tree to replace such radii explicitly")
            radius[bad] = nonpositive_radius_mm
        polylines.append(rows[:, :3])
        radii.append(radius)
    names = ["main"] + [f"side{b}" for b in range(1, len(polylines))]
    try:
        return VesselTree.attached_to_nearest(polylines, radii, names)
    except TreeError as exc:
        raise StudyError(f"{path}: {exc}") from None


def read_true_tree(path: PathLike, *, nonpositive_radius_mm: float | None = None) -> VesselTree:
    """Read a true (ground-truth) vessel tree.

    Parameters
    ----------
    path : str or path-like
        One of (:data:`TRUE_TREE_SUFFIXES`):

        * ``.npz``: ``gt_centerlines.npz`` as written by ``angiohull synth``
          (:func:`~angiohull.synthetic.case.write_case`): ``branch_names``, ``parents`` (-1 for the
          root), ``origin_vertices`` (the parent's point each branch leaves from, -1 for the root)
          and one ``(M, 4)`` array ``x, y, z, radius`` (mm) per branch name. Read as stored (no
          point is dropped or changed); branches listed in another order than parents first are
          brought into it (:meth:`VesselTree.reordered`).
        * ``.npy``: the paper authors' ``gt_centerlines.npy``, a ``(B, M, 4)`` array ``x, y, z,
          radius`` (mm; float32 in their files, converted exactly to float64): the main vessel,
          then side branches, without topology. Each side branch is attached to the point, among
          the branches before it, nearest to its first point
          (:meth:`VesselTree.attached_to_nearest`); in the authors' 48 studies that point is the
          side branch's own first point (distance 0). Names ``main``, ``side1``, ... Two things
          are handled explicitly: a row equal in all four values to the row before it is dropped
          (an exact repeat; none occur in the authors' 48 files), and radii <= 0 raise an error
          unless ``nonpositive_radius_mm`` is given (one of the authors' 48 files,
          ``perpendicular_moderate_002``, has 7 consecutive radii down to -0.45 mm mid-way along
          the main vessel, a stenosis of their generator overshooting below zero). Anything else
          unusable (non-finite values, repeated positions with different radii) raises.
        * ``.json``: an angiohull ``tree.json`` (:func:`read_tree_json`).

        Files are loaded with ``allow_pickle=False``.
    nonpositive_radius_mm : float, optional, keyword-only
        For ``.npy`` only: replace every radius <= 0 by this radius (mm, > 0) instead of raising.
        Only those radii change.

    Returns
    -------
    VesselTree

    Raises
    ------
    StudyError
        If the file is missing or unreadable, has another extension, or does not hold a usable tree;
        the message starts with the path and says what was expected.
    """
    path = Path(path)
    if nonpositive_radius_mm is not None:
        nonpositive_radius_mm = _v.positive_finite(nonpositive_radius_mm, "nonpositive_radius_mm", error=StudyError)
    suffix = path.suffix.lower()
    if suffix not in TRUE_TREE_SUFFIXES:
        raise StudyError(f"{path}: unsupported file extension {path.suffix!r}; expected {_TRUE_TREE_EXPECTED} "
                         f"(extension one of {', '.join(TRUE_TREE_SUFFIXES)})")
    _require_file(path, _TRUE_TREE_EXPECTED)
    if suffix == ".json":
        return read_tree_json(path)
    if suffix == ".npz":
        return _read_npz(path)
    return _read_authors_npy(path, nonpositive_radius_mm)
