"""Tests of angiohull.study: reading, checking and writing study folders."""

from __future__ import annotations

import copy
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from angiohull.errors import GeometryError, StudyError
from angiohull.geometry import CArmGeometry, Projection
from angiohull.io import write_mask, write_points_ply
from angiohull.study import Study, View, load_study, save_study

SHARED = Path(__file__).resolve().parents[2] / "shared"
PEER_STUDY = SHARED / "benchmarks" / "peer-synthetic" / "perpendicular_simple_000"

SHAPE = (6, 8)  # (rows, cols) of the masks of the hand-made studies
MATRIX = [
    [1000.0, 0.0, 3.5, 2800.0],
    [0.0, 1000.0, 2.5, 2000.0],
    [0.0, 0.0, 1.0, 800.0],
]
CARM = {"primary_deg": -30, "secondary_deg": 30.0, "sid_mm": 1200, "sod_mm": 800, "pixel_spacing_mm": [0.35, 0.3]}


def _mask(seed: int = 0) -> np.ndarray:
    mask = np.zeros(SHAPE, dtype=bool)
    mask[2 + seed % 3, :] = True
    mask[:, 4] = True
    return mask


def _document() -> dict[str, Any]:
    """A valid study.yaml: one C-arm view, one matrix view (named by the mask stem)."""
    return {
        "angiohull": 1,
        "views": [
            {"name": "a", "mask": "masks/a.png", "carm": dict(CARM)},
            {"mask": "masks/b.png", "projection_matrix": copy.deepcopy(MATRIX)},
        ],
    }


def _study_folder(folder: Path, document: dict[str, Any] | None = None) -> Path:
    """Write masks a.png, b.png (and a study.yaml when a document is given); return study.yaml."""
    (folder / "masks").mkdir(exist_ok=True)
    write_mask(folder / "masks" / "a.png", _mask(0))
    write_mask(folder / "masks" / "b.png", _mask(1))
    yaml_path = folder / "study.yaml"
    if document is not None:
        yaml_path.write_text(yaml.safe_dump(document, sort_keys=False))
    return yaml_path


def _raises_at(folder: Path, document: dict[str, Any] | str, pattern: str) -> StudyError:
    """Load a study with this document and check the error names study.yaml, then ``pattern``."""
    yaml_path = _study_folder(folder)
    yaml_path.write_text(document if isinstance(document, str) else yaml.safe_dump(document, sort_keys=False))
    with pytest.raises(StudyError, match=rf"^{re.escape(str(yaml_path))}: {pattern}") as info:
        load_study(folder)
    return info.value


# -- loading --------------------------------------------------------------------------------
def test_load_valid_study(tmp_path: Path) -> None:
    yaml_path = _study_folder(tmp_path, _document())
    study = load_study(tmp_path)
    assert isinstance(study, Study)
    assert study.root == tmp_path
    assert study.names == ("a", "b")  # b defaults to its mask's stem
    assert [view.source for view in study.views] == ["carm", "projection_matrix"]
    np.testing.assert_array_equal(study.masks[0], _mask(0))
    np.testing.assert_array_equal(study.masks[1], _mask(1))
    assert all(mask.dtype == bool and not mask.flags.writeable for mask in study.masks)
    carm = study.views[0].carm
    assert carm == CArmGeometry(-30.0, 30.0, 1200.0, 800.0, (0.35, 0.3), SHAPE)
    assert np.array_equal(study.projections[0].matrix, carm.projection().matrix)
    assert study.views[1].carm is None
    assert np.array_equal(study.projections[1].matrix, np.array(MATRIX))
    assert all(p.image_shape == SHAPE for p in study.projections)
    assert study.views[1].mask_path == tmp_path / "masks" / "b.png"
    assert study.ground_truth_mm is None and study.ground_truth_path is None
    assert load_study(yaml_path).names == ("a", "b")  # the YAML file itself works too


def test_principal_offset(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["carm"]["principal_offset_px"] = [1.5, -2]
    _study_folder(tmp_path, document)
    assert load_study(tmp_path).views[0].carm.principal_offset_px == (1.5, -2.0)


@pytest.mark.parametrize("name", ["gt.npy", "gt.ply"])
def test_ground_truth(tmp_path: Path, name: str) -> None:
    points = np.array([[1.0, 2.0, 3.0], [-4.0, 5.5, 0.0]])
    if name.endswith(".npy"):
        np.save(tmp_path / name, points)
    else:
        write_points_ply(tmp_path / name, points)
    document = _document()
    document["ground_truth"] = name
    _study_folder(tmp_path, document)
    study = load_study(tmp_path)
    np.testing.assert_array_equal(study.ground_truth_mm, points)
    assert study.ground_truth_path == tmp_path / name


def test_real_peer_study() -> None:
    if not PEER_STUDY.is_dir():
        pytest.skip(f"benchmark study not present at {PEER_STUDY} (the shared/ benchmarks are not checked out)")
    study = load_study(PEER_STUDY)
    assert len(study.views) == 3
    assert study.names == ("view0", "view1", "view2")
    for mask, projection in zip(study.masks, study.projections):
        assert mask.shape == (512, 512) and mask.dtype == bool and mask.any()
        assert projection.image_shape == (512, 512)
        assert projection.is_mirrored
    assert study.ground_truth_mm.ndim == 2 and study.ground_truth_mm.shape[1] == 3
    assert len(study.ground_truth_mm) > 0


# -- saving and round trips -----------------------------------------------------------------
def _awkward_views() -> list[View]:
    rng = np.random.default_rng(7)
    carm = CArmGeometry(-31.7, 12.345678901234567, 1187.3, 791.1, (0.308, 0.3125), SHAPE, (0.25, -1.0 / 3.0))
    matrix = rng.normal(size=(3, 4)) * np.array([1e3, 1e-2, 3.0, 1e5])
    return [
        View.from_carm("LAO", _mask(0), carm),
        View.from_matrix("odd matrix", _mask(1), matrix),
        View.from_carm("plain", _mask(2), CArmGeometry(0, 0, 1200, 800, (0.35, 0.35), SHAPE)),
    ]


def _assert_same_views(loaded: Study, views: list[View]) -> None:
    assert loaded.names == tuple(view.name for view in views)
    for got, want in zip(loaded.views, views):
        assert got.projection.matrix.tobytes() == want.projection.matrix.tobytes()
        assert got.mask.tobytes() == want.mask.tobytes()
        assert got.carm == want.carm
        assert got.source == want.source


@pytest.mark.parametrize("mask_format", ["png", "tiff", "npy"])
def test_save_load_round_trip_is_bitwise(tmp_path: Path, mask_format: str) -> None:
    views = _awkward_views()
    points = np.array([[0.1, 0.2, 0.3], [1e-12, -5.0, 7.0 / 3.0]])
    yaml_path = save_study(tmp_path / "study", views, ground_truth_mm=points, mask_format=mask_format)
    assert yaml_path == tmp_path / "study" / "study.yaml"
    assert (tmp_path / "study" / "masks" / f"LAO.{mask_format}").is_file()
    loaded = load_study(yaml_path)
    _assert_same_views(loaded, views)
    assert loaded.ground_truth_mm.tobytes() == points.tobytes()
    assert loaded.ground_truth_path == tmp_path / "study" / "gt.npy"


def test_saved_yaml_layout(tmp_path: Path) -> None:
    document = yaml.safe_load(save_study(tmp_path, _awkward_views()).read_text())
    assert document["angiohull"] == 1 and "ground_truth" not in document
    first, second, third = document["views"]
    assert first["carm"]["principal_offset_px"] == [0.25, -1.0 / 3.0]
    assert "principal_offset_px" not in third["carm"]
    assert all(type(value) is float for value in third["carm"].values() if not isinstance(value, list))
    assert set(second) == {"name", "mask", "projection_matrix"}
    assert second["mask"] == "masks/odd matrix.png"


def test_save_then_load_then_save_is_stable(tmp_path: Path) -> None:
    first = save_study(tmp_path / "one", _awkward_views())
    second = save_study(tmp_path / "two", load_study(first).views)
    assert first.read_text() == second.read_text()


def test_peer_study_round_trip(tmp_path: Path) -> None:
    if not PEER_STUDY.is_dir():
        pytest.skip(f"benchmark study not present at {PEER_STUDY} (the shared/ benchmarks are not checked out)")
    study = load_study(PEER_STUDY)
    loaded = load_study(save_study(tmp_path, study.views, ground_truth_mm=study.ground_truth_mm))
    _assert_same_views(loaded, list(study.views))
    assert loaded.ground_truth_mm.tobytes() == study.ground_truth_mm.tobytes()


_finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=20, deadline=None)
@given(
    angles=st.tuples(st.floats(-180, 180), st.floats(-90, 90)),
    sod_mm=st.floats(100, 1000),
    extra_mm=st.floats(1e-3, 1000),
    spacing=st.tuples(st.floats(0.05, 1.0), st.floats(0.05, 1.0)),
    matrix=st.lists(_finite, min_size=12, max_size=12),
)
def test_round_trip_property(angles: tuple[float, float], sod_mm: float, extra_mm: float,
                             spacing: tuple[float, float], matrix: list[float]) -> None:
    try:
        projection = Projection(np.reshape(matrix, (3, 4)), SHAPE)
    except GeometryError:
        assume(False)
        return
    assume(matrix[11] >= 0)  # the isocentre in front of the source (behind it: refused, test_bad_projection_matrix)
    views = [
        View.from_carm("c", _mask(0), CArmGeometry(*angles, sod_mm + extra_mm, sod_mm, spacing, SHAPE)),
        View("m", _mask(1), projection),
    ]
    with tempfile.TemporaryDirectory() as folder:
        _assert_same_views(load_study(save_study(folder, views, mask_format="npy")), views)


def test_save_study_bad_arguments(tmp_path: Path) -> None:
    view = _awkward_views()[0]
    with pytest.raises(StudyError, match=r"save_study: needs at least one view"):
        save_study(tmp_path, [])
    with pytest.raises(StudyError, match=r"view names must be unique, got duplicates \['LAO'\]"):
        save_study(tmp_path, [view, view])
    with pytest.raises(StudyError, match=r"mask_format must be one of .*got 'jpg'"):
        save_study(tmp_path, [view], mask_format="jpg")
    with pytest.raises(StudyError, match=r"view name 'a/b' cannot be a file name"):
        save_study(tmp_path, [View.from_carm("a/b", view.mask, view.carm)])
    with pytest.raises(StudyError, match=r"view 'LAO' has an empty mask"):
        save_study(tmp_path, [View.from_carm("LAO", np.zeros(SHAPE), view.carm)])
    with pytest.raises(StudyError, match=r"ground_truth_mm: expected an \(N, 3\) array .*shape \(2, 2\)"):
        save_study(tmp_path, [view], ground_truth_mm=np.zeros((2, 2)))
    behind = View("m", view.mask, Projection(-np.array(MATRIX), view.mask.shape))
    with pytest.raises(StudyError, match=r"view 'm': the isocentre .* depth w = -800 < 0, behind the source"):
        save_study(tmp_path, [behind])


def test_view_checks_its_fields() -> None:
    carm = CArmGeometry(0, 0, 1200, 800, (0.35, 0.35), SHAPE)
    with pytest.raises(StudyError, match=r"view 'v': mask shape \(6, 7\) differs from the projection's image_shape \(6, 8\)"):
        View("v", np.ones((6, 7)), carm.projection())
    with pytest.raises(StudyError, match=r"view 'v': projection is not carm.projection\(\)"):
        View("v", _mask(), Projection(MATRIX, SHAPE), carm=carm)
    with pytest.raises(StudyError, match=r"view 'v': source 'carm' needs carm given"):
        View("v", _mask(), carm.projection(), source="carm")
    with pytest.raises(StudyError, match=r"view 'v': projection matrix must have shape \(3, 4\)"):
        View.from_matrix("v", _mask(), np.eye(3))
    assert View("v", _mask(), carm.projection(), carm=carm).source == "carm"


# -- the study file itself ------------------------------------------------------------------
def test_missing_study_file(tmp_path: Path) -> None:
    with pytest.raises(StudyError, match=r"study\.yaml: study file not found; expected a study folder"):
        load_study(tmp_path)
    with pytest.raises(StudyError, match=r"other\.yaml: study file not found"):
        load_study(tmp_path / "other.yaml")


def test_yaml_syntax_error(tmp_path: Path) -> None:
    _raises_at(tmp_path, "angiohull: 1\nviews: [\n  {mask: a.png\n", r"invalid YAML at line \d+, column \d+: ")
    # a control character: PyYAML's reader refuses it as the loader starts (a traceback before)
    _raises_at(tmp_path, "angiohull: 1\nviews: []\x07\n", r"invalid YAML: unacceptable character #x0007")


@pytest.mark.parametrize(("text", "got"), [("", "an empty file"), ("- 1\n- 2\n", "a list"), ("just text\n", "a str")])
def test_yaml_not_a_mapping(tmp_path: Path, text: str, got: str) -> None:
    _raises_at(tmp_path, text, rf"expected a YAML mapping with keys angiohull, views .*got {got}")


def test_unsupported_version(tmp_path: Path) -> None:
    document = _document()
    document["angiohull"] = 2
    _raises_at(tmp_path, document, r"angiohull: unsupported study format version 2; .*reads version 1")


def test_missing_version_and_views(tmp_path: Path) -> None:
    error = _raises_at(tmp_path, {"ground_truth": "gt.npy"}, r"angiohull: required key is missing")
    assert "study.yaml: views: required key is missing" in str(error)


def test_unknown_keys_list_allowed_keys(tmp_path: Path) -> None:
    document = _document()
    document["colour"] = "red"
    document["views"][0]["carm"]["sid"] = 1200
    error = _raises_at(tmp_path, document, r"views\[0\]\.carm\.sid: unknown key; allowed keys here: primary_deg, secondary_deg, sid_mm")
    assert "study.yaml: colour: unknown key; allowed keys here: angiohull, views, ground_truth" in str(error)


def test_unknown_view_key(tmp_path: Path) -> None:
    document = _document()
    document["views"][1]["shape"] = [6, 8]
    _raises_at(tmp_path, document, r"views\[1\]\.shape: unknown key; allowed keys here: name, mask, carm, projection_matrix, dicom, frame")


def test_every_problem_is_listed_once(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["carm"]["sid_mm"] = "far"
    document["views"][1]["projection_matrix"][2] = [0.0, 0.0, 1.0]
    document["views"][1]["mask"] = 5
    error = _raises_at(tmp_path, document, r"views\[0\]\.carm\.sid_mm: Input should be a valid number, got 'far' \(str\)")
    lines = str(error).splitlines()
    assert len(lines) == 3
    assert all(line.startswith(str(tmp_path / "study.yaml") + ": views[") for line in lines)
    assert "views[1].mask: Input should be a valid string, got 5 (int)" in str(error)


@pytest.mark.parametrize("views", [[], "masks/a.png", None])
def test_views_must_be_a_non_empty_list(tmp_path: Path, views: Any) -> None:
    _raises_at(tmp_path, {"angiohull": 1, "views": views}, r"views: ")


def test_number_written_as_text(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["carm"]["sid_mm"] = "1e3"
    _raises_at(tmp_path, document, r"views\[0\]\.carm\.sid_mm: .*YAML read this as text; write the number as 1000\.0")


def test_bool_is_not_a_number(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["carm"]["primary_deg"] = True
    _raises_at(tmp_path, document, r"views\[0\]\.carm\.primary_deg: Input should be a valid number, got True")


# -- geometry sources -----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("key", "value", "pattern"),
    [
        ("sod_mm", 1300, r"views\[0\]\.carm: sod_mm must be smaller than sid_mm"),
        ("sid_mm", -5, r"views\[0\]\.carm: sid_mm must be a positive"),
        ("secondary_deg", 95, r"views\[0\]\.carm: secondary_deg must be within \[-90, 90\]"),
        ("pixel_spacing_mm", [0.3, 0], r"views\[0\]\.carm: pixel_spacing_mm\[1\] must be a positive"),
        ("pixel_spacing_mm", [0.3, 0.3, 0.3], r"views\[0\]\.carm\.pixel_spacing_mm: List should have at most 2 items"),
        ("principal_offset_px", [1.0], r"views\[0\]\.carm\.principal_offset_px: List should have at least 2 items"),
    ],
)
def test_bad_carm(tmp_path: Path, key: str, value: Any, pattern: str) -> None:
    document = _document()
    document["views"][0]["carm"][key] = value
    _raises_at(tmp_path, document, pattern)


def test_carm_missing_key(tmp_path: Path) -> None:
    document = _document()
    del document["views"][0]["carm"]["sod_mm"]
    _raises_at(tmp_path, document, r"views\[0\]\.carm\.sod_mm: required key is missing")


@pytest.mark.parametrize(
    ("matrix", "pattern"),
    [
        ([[1.0, 0.0, 0.0]] * 3, r"expected a 3x4 matrix \(3 rows of 4 numbers\), got 3 rows of lengths \[3, 3, 3\]"),
        (MATRIX[:2], r"expected a 3x4 matrix .*got 2 rows"),
        ([MATRIX[0], MATRIX[1], [0.0, 0.0, float("nan"), 800.0]], r"expected 12 finite numbers, got non-finite"),
        ([MATRIX[0], MATRIX[1], [0.0, 0.0, float("inf"), 800.0]], r"expected 12 finite numbers, got non-finite"),
        ([[0.0] * 4] * 3, r"projection matrix is degenerate"),
        ([[-x for x in row] for row in MATRIX], r"the isocentre \(the world origin, .*\) has depth w = -800 < 0, "
                                                r"behind the source; .*multiply it by -1"),
    ],
)
def test_bad_projection_matrix(tmp_path: Path, matrix: Any, pattern: str) -> None:
    document = _document()
    document["views"][1]["projection_matrix"] = matrix
    _raises_at(tmp_path, document, rf"views\[1\]\.projection_matrix: {pattern}")


def test_projection_matrix_entry_not_a_number(tmp_path: Path) -> None:
    document = _document()
    document["views"][1]["projection_matrix"][1][3] = "x"
    _raises_at(tmp_path, document, r"views\[1\]\.projection_matrix\[1\]\[3\]: Input should be a valid number, got 'x'")


def test_no_geometry_source(tmp_path: Path) -> None:
    document = _document()
    del document["views"][1]["projection_matrix"]
    _raises_at(tmp_path, document, r"views\[1\]: view 'b' has no geometry source; give exactly one of carm:, projection_matrix:, dicom:")


def test_two_geometry_sources(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["projection_matrix"] = MATRIX
    _raises_at(tmp_path, document, r"views\[0\]: view 'a' has 2 geometry sources \(carm, projection_matrix\); give exactly one")


def test_missing_dicom_file(tmp_path: Path) -> None:
    document = _document()
    document["views"][1] = {"mask": "masks/b.png", "dicom": "dicom/run3.dcm", "frame": 12}
    _raises_at(tmp_path, document, r"views\[1\]\.dicom: view 'b': .*run3\.dcm: file not found; expected an X-ray angiography DICOM file")


def test_frame_without_dicom(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["frame"] = 3
    _raises_at(tmp_path, document, r"views\[0\]: view 'a': frame: is only used with dicom: or a DICOM image:, got frame: 3")


def test_duplicate_names(tmp_path: Path) -> None:
    document = _document()
    document["views"][1]["name"] = "a"
    _raises_at(tmp_path, document, r"views: view names must be unique: 'a' is used by views \[0, 1\]")


def test_duplicate_default_names(tmp_path: Path) -> None:
    document = _document()
    document["views"][0] = {"mask": "masks/b.png", "carm": dict(CARM)}
    _raises_at(tmp_path, document, r"views: view names must be unique: 'b' is used by views \[0, 1\].*give name:")


# -- masks named by the study ---------------------------------------------------------------
def test_missing_mask(tmp_path: Path) -> None:
    document = _document()
    document["views"][1]["mask"] = "masks/nothere.png"
    _raises_at(tmp_path, document, r"views\[1\]\.mask: view 'nothere': .*nothere\.png: file not found")


def test_unreadable_mask(tmp_path: Path) -> None:
    document = _document()
    document["views"][1]["mask"] = "masks/bad.png"
    _study_folder(tmp_path)
    (tmp_path / "masks" / "bad.png").write_bytes(b"garbage")
    _raises_at(tmp_path, document, r"views\[1\]\.mask: view 'bad': .*bad\.png: cannot read as an image")


def test_unsupported_mask_extension(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["mask"] = "masks/a.jpg"
    _raises_at(tmp_path, document, r"views\[0\]\.mask: view 'a': .*a\.jpg: unsupported file extension")


def test_empty_mask(tmp_path: Path) -> None:
    document = _document()
    document["views"][0]["mask"] = "masks/blank.npy"
    _study_folder(tmp_path)
    np.save(tmp_path / "masks" / "blank.npy", np.zeros(SHAPE, dtype=bool))
    _raises_at(tmp_path, document, r"views\[0\]\.mask: view 'a': .*blank\.npy: the mask has no vessel pixel")


def test_missing_mask_key(tmp_path: Path) -> None:
    document = _document()
    del document["views"][0]["mask"]
    _raises_at(tmp_path, document, r"views\[0\]: view 'a' has neither mask: nor image:; give exactly one of mask: \(a binary "
                                   r"vessel mask\) or image: \(a raw angiogram")


def test_bad_ground_truth(tmp_path: Path) -> None:
    document = _document()
    document["ground_truth"] = "gt.npy"
    error = _raises_at(tmp_path, document, r"ground_truth: .*gt\.npy: file not found")
    np.save(tmp_path / "gt.npy", np.zeros((4, 2)))
    with pytest.raises(StudyError, match=r"study\.yaml: ground_truth: .*gt\.npy: expected an \(N, 3\) array .*shape \(4, 2\)"):
        load_study(tmp_path)
    assert str(error).count("\n") == 0


def test_view_entry_not_a_mapping(tmp_path: Path) -> None:
    document = _document()
    document["views"].append(7)
    document["views"][0]["carm"] = [1, 2]
    error = _raises_at(tmp_path, document, r"views\[0\]\.carm: expected a mapping with keys from: primary_deg, .*got \[1, 2\] \(list\)")
    assert ("views[2]: expected a mapping with keys from: name, mask, carm, projection_matrix, dicom, frame, image, "
            "segmentation; got 7 (int)") in str(error)


def test_key_that_is_not_text(tmp_path: Path) -> None:
    _raises_at(tmp_path, "angiohull: 1\nviews:\n  - {mask: masks/a.png, 3: 4}\n", r"views\[0\]: key 3 is not text; allowed keys here: name, mask")
