"""Tests of angiohull.io: masks (PNG, TIFF, NPY) and points (NPY, PLY)."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from PIL import Image
from plyfile import PlyData, PlyElement

from angiohull.errors import StudyError
from angiohull.io import read_mask, read_points, write_mask, write_points_ply


def _cross_mask(rows: int = 7, cols: int = 9) -> np.ndarray:
    """A small asymmetric mask: a row and a column of vessel plus one corner pixel."""
    mask = np.zeros((rows, cols), dtype=bool)
    mask[2, :] = True
    mask[:, 5] = True
    mask[0, 0] = True
    return mask


# -- masks: round trips ---------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".png", ".tif", ".tiff", ".npy", ".PNG"])
def test_mask_round_trip(tmp_path: Path, suffix: str) -> None:
    mask = _cross_mask()
    path = tmp_path / f"mask{suffix}"
    write_mask(path, mask)
    back = read_mask(path)
    assert back.dtype == bool
    assert back.shape == (7, 9)
    np.testing.assert_array_equal(back, mask)


def test_png_and_tiff_are_written_as_uint8_0_255(tmp_path: Path) -> None:
    for name in ("m.png", "m.tif"):
        write_mask(tmp_path / name, _cross_mask())
        with Image.open(tmp_path / name) as image:
            assert image.mode == "L"
            assert set(np.unique(np.asarray(image)).tolist()) == {0, 255}


def test_npy_is_written_as_bool(tmp_path: Path) -> None:
    write_mask(tmp_path / "m.npy", _cross_mask().astype(np.uint8) * 7)
    stored = np.load(tmp_path / "m.npy")
    assert stored.dtype == bool
    np.testing.assert_array_equal(stored, _cross_mask())


@settings(max_examples=25, deadline=None)
@given(mask=hnp.arrays(bool, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12)),
       suffix=st.sampled_from([".png", ".tiff", ".npy"]))
def test_mask_round_trip_property(mask: np.ndarray, suffix: str) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"m{suffix}"
        write_mask(path, mask)
        np.testing.assert_array_equal(read_mask(path), mask)


# -- masks: pixel formats -------------------------------------------------------------------
def test_rgb_png_vessel_where_any_channel_nonzero(tmp_path: Path) -> None:
    rgb = np.zeros((3, 4, 3), dtype=np.uint8)
    rgb[0, 0, 0] = 200  # red only
    rgb[1, 1, 1] = 1  # green only, faint
    rgb[2, 2, 2] = 255  # blue only
    rgb[0, 3] = (10, 20, 30)
    Image.fromarray(rgb).save(tmp_path / "rgb.png")
    expected = np.zeros((3, 4), dtype=bool)
    expected[0, 0] = expected[1, 1] = expected[2, 2] = expected[0, 3] = True
    np.testing.assert_array_equal(read_mask(tmp_path / "rgb.png"), expected)


def test_rgba_and_la_ignore_alpha(tmp_path: Path) -> None:
    rgba = np.zeros((2, 3, 4), dtype=np.uint8)
    rgba[..., 3] = 255  # opaque black: background
    rgba[0, 1] = (0, 0, 9, 0)  # transparent but coloured: vessel
    Image.fromarray(rgba).save(tmp_path / "rgba.png")
    la = np.zeros((2, 3, 2), dtype=np.uint8)
    la[..., 1] = 255
    la[1, 2] = (4, 0)
    Image.fromarray(la).convert("LA").save(tmp_path / "la.png")  # fromarray gives LA for (.., 2) uint8
    expected_rgba = np.zeros((2, 3), dtype=bool)
    expected_rgba[0, 1] = True
    expected_la = np.zeros((2, 3), dtype=bool)
    expected_la[1, 2] = True
    np.testing.assert_array_equal(read_mask(tmp_path / "rgba.png"), expected_rgba)
    np.testing.assert_array_equal(read_mask(tmp_path / "la.png"), expected_la)


def test_sixteen_bit_png_and_float_tiff(tmp_path: Path) -> None:
    values = np.array([[0, 1, 0], [60000, 0, 256]], dtype=np.uint16)
    Image.fromarray(values).save(tmp_path / "deep.png")
    Image.fromarray(values.astype(np.float32) / 7).save(tmp_path / "float.tif")
    for name in ("deep.png", "float.tif"):
        np.testing.assert_array_equal(read_mask(tmp_path / name), values != 0)


def test_palette_png(tmp_path: Path) -> None:
    image = Image.new("P", (2, 2))
    image.putdata([0, 1, 1, 0])
    image.putpalette([0, 0, 0, 255, 255, 255] + [0] * (3 * 254))
    image.save(tmp_path / "pal.png")
    np.testing.assert_array_equal(read_mask(tmp_path / "pal.png"), [[False, True], [True, False]])


def test_npy_numeric_dtypes(tmp_path: Path) -> None:
    for dtype in (np.uint8, np.int16, np.float64, bool):
        np.save(tmp_path / "m.npy", np.array([[0, 1], [2, 0]]).astype(dtype))
        np.testing.assert_array_equal(read_mask(tmp_path / "m.npy"), [[False, True], [True, False]])


# -- masks: bad input -----------------------------------------------------------------------
def test_missing_mask_file(tmp_path: Path) -> None:
    with pytest.raises(StudyError, match=r"^.*nothere\.png: file not found; expected a 2D binary mask"):
        read_mask(tmp_path / "nothere.png")


@pytest.mark.parametrize("name", ["mask.jpg", "mask.bmp", "mask"])
def test_unsupported_mask_extension(tmp_path: Path, name: str) -> None:
    (tmp_path / name).write_bytes(b"whatever")
    with pytest.raises(StudyError, match=rf"^.*{re.escape(name)}: unsupported file extension.*\.png, \.tif, \.tiff, \.npy"):
        read_mask(tmp_path / name)


@pytest.mark.parametrize("name", ["bad.png", "bad.tif", "bad.npy"])
def test_unreadable_mask(tmp_path: Path, name: str) -> None:
    (tmp_path / name).write_bytes(b"this is not an image at all")
    with pytest.raises(StudyError, match=rf"^.*{re.escape(name)}: cannot read as .*expected a 2D binary mask"):
        read_mask(tmp_path / name)


def test_truncated_png(tmp_path: Path) -> None:
    write_mask(tmp_path / "full.png", np.ones((64, 64), dtype=bool) & (np.arange(64) % 3 == 0))
    data = (tmp_path / "full.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(StudyError, match=r"cut\.png: cannot read as an image"):
        read_mask(tmp_path / "cut.png")


def test_mask_folder_instead_of_file(tmp_path: Path) -> None:
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(StudyError, match=r"dir\.png: is not a regular file"):
        read_mask(tmp_path / "dir.png")


def test_3d_npy_mask(tmp_path: Path) -> None:
    np.save(tmp_path / "vol.npy", np.ones((2, 3, 4), dtype=bool))
    with pytest.raises(StudyError, match=r"vol\.npy: expected a 2D binary mask .*shape \(2, 3, 4\)"):
        read_mask(tmp_path / "vol.npy")


def test_multi_frame_tiff(tmp_path: Path) -> None:
    frames = [Image.fromarray(np.full((4, 4), value, dtype=np.uint8)) for value in (0, 255)]
    frames[0].save(tmp_path / "stack.tif", save_all=True, append_images=frames[1:])
    with pytest.raises(StudyError, match=r"stack\.tif: has 2 frames; expected a 2D binary mask"):
        read_mask(tmp_path / "stack.tif")


@pytest.mark.parametrize(
    ("array", "pattern"),
    [
        (np.zeros((0, 5)), r"empty array of shape \(0, 5\)"),
        (np.array([[1.0, np.nan]]), r"1 non-finite values"),
        (np.array([[1 + 1j, 0]]), r"dtype complex128"),
        (np.array([["a", "b"]]), r"dtype <U1"),
    ],
)
def test_bad_npy_mask_contents(tmp_path: Path, array: np.ndarray, pattern: str) -> None:
    np.save(tmp_path / "m.npy", array)
    with pytest.raises(StudyError, match=rf"m\.npy: .*{pattern}"):
        read_mask(tmp_path / "m.npy")


def test_pickled_npy_is_refused(tmp_path: Path) -> None:
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(StudyError, match=r"obj\.npy: cannot read as a NumPy \.npy file"):
        read_mask(tmp_path / "obj.npy")


def test_npz_behind_npy_name(tmp_path: Path) -> None:
    with open(tmp_path / "arch.npy", "wb") as handle:
        np.savez(handle, a=np.ones((2, 2)))
    with pytest.raises(StudyError, match=r"arch\.npy: is an \.npz archive"):
        read_mask(tmp_path / "arch.npy")


def test_write_mask_bad_input(tmp_path: Path) -> None:
    with pytest.raises(StudyError, match=r"m\.png: cannot write mask: .*shape \(2, 2, 2\)"):
        write_mask(tmp_path / "m.png", np.ones((2, 2, 2)))
    with pytest.raises(StudyError, match=r"m\.gif: unsupported file extension"):
        write_mask(tmp_path / "m.gif", np.ones((2, 2)))
    with pytest.raises(StudyError, match=r"m\.png: cannot write mask \("):
        write_mask(tmp_path / "no" / "such" / "m.png", np.ones((2, 2)))


# -- points ---------------------------------------------------------------------------------
def _points() -> np.ndarray:
    return np.array([[0.0, 1.5, -2.25], [1e-300, -0.0, 123456.789], [np.pi, -np.e, 1 / 3]])


def test_ply_round_trip_is_bitwise(tmp_path: Path) -> None:
    path = tmp_path / "cloud.ply"
    write_points_ply(path, _points())
    back = read_points(path)
    assert back.dtype == np.float64 and back.shape == (3, 3)
    assert back.tobytes() == _points().tobytes()


def test_ply_empty_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "empty.ply"
    write_points_ply(path, np.empty((0, 3)))
    back = read_points(path)
    assert back.shape == (0, 3) and back.dtype == np.float64


def test_ply_header_is_binary_le_doubles_with_units(tmp_path: Path) -> None:
    path = tmp_path / "cloud.ply"
    write_points_ply(path, _points(), comment="made by a test\nsecond line")
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    ply = PlyData.read(str(path))
    assert ply.comments == ["units mm", "frame DICOM patient LPS", "made by a test", "second line"]
    assert [(p.name, p.val_dtype) for p in ply["vertex"].properties] == [("x", "f8"), ("y", "f8"), ("z", "f8")]


@settings(max_examples=25, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 20), st.just(3)), elements=st.floats(allow_nan=False, allow_infinity=False)))
def test_ply_round_trip_property(points: np.ndarray) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "p.ply"
        write_points_ply(path, points)
        assert read_points(path).tobytes() == points.tobytes()


def test_read_points_npy(tmp_path: Path) -> None:
    np.save(tmp_path / "p.npy", np.arange(12, dtype=np.int32).reshape(4, 3))
    back = read_points(tmp_path / "p.npy")
    assert back.dtype == np.float64
    np.testing.assert_array_equal(back, np.arange(12).reshape(4, 3))


def test_read_points_extra_ply_properties_ignored(tmp_path: Path) -> None:
    vertex = np.array([(1.0, 2.0, 3.0, 9)], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("label", "i4")])
    PlyData([PlyElement.describe(vertex, "vertex")], text=True).write(str(tmp_path / "t.ply"))
    np.testing.assert_array_equal(read_points(tmp_path / "t.ply"), [[1.0, 2.0, 3.0]])


@pytest.mark.parametrize("shape", [(5, 4), (5, 2), (3,), (2, 3, 3)])
def test_read_points_wrong_shape(tmp_path: Path, shape: tuple[int, ...]) -> None:
    np.save(tmp_path / "p.npy", np.zeros(shape))
    with pytest.raises(StudyError, match=rf"p\.npy: expected an \(N, 3\) array .*shape {re.escape(str(shape))}"):
        read_points(tmp_path / "p.npy")


def test_read_points_non_finite(tmp_path: Path) -> None:
    np.save(tmp_path / "p.npy", np.array([[0.0, np.inf, 1.0], [np.nan, 0, 0]]))
    with pytest.raises(StudyError, match=r"p\.npy: contains 2 non-finite values"):
        read_points(tmp_path / "p.npy")
    vertex = np.array([(1.0, np.nan, 3.0)], dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(tmp_path / "p.ply"))
    with pytest.raises(StudyError, match=r"p\.ply: contains 1 non-finite values"):
        read_points(tmp_path / "p.ply")


def test_read_points_bad_files(tmp_path: Path) -> None:
    with pytest.raises(StudyError, match=r"gone\.ply: file not found; expected an \(N, 3\) array"):
        read_points(tmp_path / "gone.ply")
    (tmp_path / "p.xyz").write_text("1 2 3\n")
    with pytest.raises(StudyError, match=r"p\.xyz: unsupported file extension.*\.npy, \.ply"):
        read_points(tmp_path / "p.xyz")
    (tmp_path / "junk.ply").write_bytes(b"not a ply file\n")
    with pytest.raises(StudyError, match=r"junk\.ply: cannot read as a PLY file"):
        read_points(tmp_path / "junk.ply")


def test_read_points_ply_without_vertex_xyz(tmp_path: Path) -> None:
    faces = np.array([(1,)], dtype=[("a", "i4")])
    PlyData([PlyElement.describe(faces, "face")]).write(str(tmp_path / "novertex.ply"))
    with pytest.raises(StudyError, match=r"novertex\.ply: has no 'vertex' element \(elements: \['face'\]\)"):
        read_points(tmp_path / "novertex.ply")
    planar = np.array([(1.0, 2.0)], dtype=[("x", "f8"), ("y", "f8")])
    PlyData([PlyElement.describe(planar, "vertex")]).write(str(tmp_path / "noz.ply"))
    with pytest.raises(StudyError, match=r"noz\.ply: the 'vertex' element lacks properties \['z'\]"):
        read_points(tmp_path / "noz.ply")


def test_write_points_bad_input(tmp_path: Path) -> None:
    with pytest.raises(StudyError, match=r"p\.ply: cannot write points: .*shape \(2, 4\)"):
        write_points_ply(tmp_path / "p.ply", np.zeros((2, 4)))
    with pytest.raises(StudyError, match=r"p\.ply: cannot write points: contains 1 non-finite"):
        write_points_ply(tmp_path / "p.ply", [[0.0, 0.0, np.nan]])
    with pytest.raises(StudyError, match=r"p\.ply: cannot write points: comment must be ASCII"):
        write_points_ply(tmp_path / "p.ply", np.zeros((1, 3)), comment="µm")
    with pytest.raises(StudyError, match=r"p\.ply\.gz: unsupported file extension '\.gz'"):
        read_points(tmp_path / "p.ply.gz")
