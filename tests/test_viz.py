"""Tests of angiohull.viz: the overlay colour code and the reconstruction figure (PNG)."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.image import imread

from angiohull import viz
from angiohull.errors import AngiohullError
from angiohull.viz import OVERLAY_COLOURS, overlay_rgb, reconstruction_figure

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _helix(n: int = 400) -> np.ndarray:
    t = np.linspace(0.0, 4.0 * np.pi, n)
    return np.column_stack([30.0 * np.cos(t), 20.0 * np.sin(t), np.linspace(-40.0, 40.0, n)])


def _views(n_views: int, shape: tuple[int, int] = (64, 80)):
    masks, reprojections, names = [], [], []
    rows, cols = shape
    for i in range(n_views):
        mask = np.zeros(shape, dtype=bool)
        mask[rows // 2 - 2:rows // 2 + 2, 5:cols - 5] = True  # a horizontal "vessel"
        mask[5:rows - 5, (i * 7) % (cols - 10) + 5] = True  # a vertical branch that moves per view
        reproj = np.zeros(shape, dtype=bool)
        reproj[rows // 2 - 3:rows // 2 + 1, 10:cols - 3] = True  # shifted: both, missed and spurious
        masks.append(mask)
        reprojections.append(reproj)
        names.append(f"view {i}")
    return masks, reprojections, names


def _read_png(path) -> np.ndarray:
    with open(path, "rb") as handle:
        assert handle.read(8) == PNG_SIGNATURE
    image = imread(path)
    assert image.ndim == 3 and image.shape[2] in (3, 4)
    return image


# --------------------------------------------------------------------------------------------------
# overlay_rgb
# --------------------------------------------------------------------------------------------------


def test_overlay_colours_per_class():
    mask = np.array([[True, True, False, False]])
    reproj = np.array([[True, False, True, False]])
    rgb = overlay_rgb(mask, reproj)
    assert rgb.shape == (1, 4, 3)
    assert rgb.dtype == np.uint8
    assert tuple(rgb[0, 0]) == OVERLAY_COLOURS["both"]
    assert tuple(rgb[0, 1]) == OVERLAY_COLOURS["missed"]
    assert tuple(rgb[0, 2]) == OVERLAY_COLOURS["spurious"]
    assert tuple(rgb[0, 3]) == OVERLAY_COLOURS["background"]


def test_overlay_colour_code_is_the_documented_one():
    # Pin the palette: agreement light, background black, the two error classes distinct colours.
    assert OVERLAY_COLOURS["background"] == (0, 0, 0)
    assert OVERLAY_COLOURS["both"] == (235, 235, 235)
    assert OVERLAY_COLOURS["missed"] == (213, 94, 0)
    assert OVERLAY_COLOURS["spurious"] == (86, 180, 233)
    assert len(set(OVERLAY_COLOURS.values())) == 4


def test_overlay_2d_case_and_numeric_masks():
    rows, cols = 5, 6
    mask = np.zeros((rows, cols), dtype=np.uint8)
    mask[1:4, 1:4] = 255  # nonzero counts as vessel
    reproj = np.zeros((rows, cols), dtype=bool)
    reproj[2:5, 2:6] = True
    rgb = overlay_rgb(mask, reproj)
    m, r = mask != 0, reproj
    expected = np.zeros((rows, cols, 3), dtype=np.uint8)
    expected[m & r] = OVERLAY_COLOURS["both"]
    expected[m & ~r] = OVERLAY_COLOURS["missed"]
    expected[~m & r] = OVERLAY_COLOURS["spurious"]
    np.testing.assert_array_equal(rgb, expected)
    # Spot checks against hand-worked pixels.
    assert tuple(rgb[2, 2]) == OVERLAY_COLOURS["both"]
    assert tuple(rgb[1, 1]) == OVERLAY_COLOURS["missed"]
    assert tuple(rgb[4, 5]) == OVERLAY_COLOURS["spurious"]
    assert tuple(rgb[0, 0]) == OVERLAY_COLOURS["background"]


def test_overlay_rejects_bad_shapes():
    with pytest.raises(ValueError, match="same"):
        overlay_rgb(np.zeros((4, 4), bool), np.zeros((4, 5), bool))
    with pytest.raises(ValueError, match="2-D"):
        overlay_rgb(np.zeros((4, 4, 3), bool), np.zeros((4, 4, 3), bool))


# --------------------------------------------------------------------------------------------------
# reconstruction_figure
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n_views", [1, 3, 5])
def test_figure_written_for_several_view_counts(tmp_path, n_views):
    masks, reprojections, names = _views(n_views)
    out = tmp_path / "sub" / "dir" / f"fig_{n_views}.png"  # parents do not exist yet
    result = reconstruction_figure(
        out,
        vessel_points_mm=_helix(),
        masks=masks,
        reprojections=reprojections,
        view_names=names,
        centerline_points_mm=_helix(60),
        ground_truth_mm=_helix(300) + 1.0,
        title=f"{n_views} views",
        view_scores=[80.0 + i for i in range(n_views)],
        dpi=60,
    )
    assert result == out and out.is_file()
    image = _read_png(out)
    height, width = image.shape[:2]
    assert 600 <= width <= 900  # about 13 in at 60 dpi
    assert 300 <= height <= 1500
    if n_views == 5:  # two rows of views make the figure taller than one
        masks1, rep1, names1 = _views(1)
        one = reconstruction_figure(tmp_path / "one.png", vessel_points_mm=_helix(), masks=masks1,
                                    reprojections=rep1, view_names=names1, dpi=60)
        assert height > _read_png(one).shape[0]
    # Not a blank canvas: the overlays and points put plenty of non-white pixels on it.
    rgb = image[..., :3]
    assert np.mean(np.any(rgb < 0.9, axis=-1)) > 0.02


def test_figure_accepts_str_path_and_no_optional_layers(tmp_path):
    masks, reprojections, names = _views(2)
    result = reconstruction_figure(str(tmp_path / "plain.png"), vessel_points_mm=_helix(),
                                   masks=masks, reprojections=reprojections, view_names=names, dpi=50)
    assert result == tmp_path / "plain.png"
    _read_png(result)


@pytest.mark.parametrize("empty", [np.empty((0, 3)), []])
def test_empty_cloud_draws_a_figure(tmp_path, empty):
    masks, reprojections, names = _views(2)
    reprojections = [np.zeros_like(m) for m in masks]  # an empty reconstruction re-projects to nothing
    out = reconstruction_figure(tmp_path / "empty.png", vessel_points_mm=empty, masks=masks,
                                reprojections=reprojections, view_names=names, view_scores=[0.0, float("nan")],
                                dpi=50)
    image = _read_png(out)
    assert image.shape[1] > 500


def test_empty_cloud_with_ground_truth(tmp_path):
    masks, reprojections, names = _views(1)
    out = reconstruction_figure(tmp_path / "empty_gt.png", vessel_points_mm=np.zeros((0, 3)), masks=masks,
                                reprojections=reprojections, view_names=names, ground_truth_mm=_helix(),
                                centerline_points_mm=np.zeros((0, 3)), dpi=50)
    _read_png(out)


def test_large_cloud_is_subsampled_for_drawing(tmp_path, monkeypatch):
    monkeypatch.setattr(viz, "_MAX_DRAWN_POINTS", 500)
    masks, reprojections, names = _views(1)
    out = reconstruction_figure(tmp_path / "big.png", vessel_points_mm=_helix(5000), masks=masks,
                                reprojections=reprojections, view_names=names, dpi=50)
    _read_png(out)


def test_single_point_cloud(tmp_path):
    masks, reprojections, names = _views(1)
    out = reconstruction_figure(tmp_path / "one_point.png", vessel_points_mm=[[1.0, 2.0, 3.0]], masks=masks,
                                reprojections=reprojections, view_names=names, dpi=50)
    _read_png(out)


def _kwargs(n_views: int = 2):
    masks, reprojections, names = _views(n_views)
    return dict(vessel_points_mm=_helix(), masks=masks, reprojections=reprojections, view_names=names)


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda kw: kw.update(reprojections=kw["reprojections"][:1]), "one entry per view"),
        (lambda kw: kw.update(masks=kw["masks"] + kw["masks"][:1]), "one entry per view"),
        (lambda kw: kw.update(view_names=["only one"]), "one entry per view"),
        (lambda kw: kw.update(view_scores=[1.0, 2.0, 3.0]), "one entry per view"),
        (lambda kw: kw.update(reprojections=[kw["reprojections"][0], np.zeros((10, 10), bool)]), "shape"),
        (lambda kw: kw.update(vessel_points_mm=np.zeros((5, 2))), r"\(N, 3\)"),
        (lambda kw: kw.update(vessel_points_mm=np.zeros(6)), r"\(N, 3\)"),
        (lambda kw: kw.update(centerline_points_mm=np.zeros((4, 4))), "centerline_points_mm"),
        (lambda kw: kw.update(ground_truth_mm=np.zeros((2, 3, 1))), "ground_truth_mm"),
        (lambda kw: kw.update(vessel_points_mm=np.array([[0.0, np.nan, 0.0]])), "NaN"),
        (lambda kw: kw.update(masks=[np.zeros((4, 4, 3)), np.zeros((4, 4, 3))]), "2-D"),
        (lambda kw: kw.update(masks=kw["masks"][0]), "sequence"),
        (lambda kw: kw.update(view_names="ab"), "sequence"),
        (lambda kw: kw.update(view_scores=["high", 1.0]), "view_scores"),
        (lambda kw: kw.update(dpi=0), "dpi"),
    ],
)
def test_invalid_inputs_raise_value_error(tmp_path, change, match):
    kwargs = _kwargs()
    change(kwargs)
    out = tmp_path / "bad.png"
    with pytest.raises(ValueError, match=match) as info:
        reconstruction_figure(out, **kwargs)
    assert isinstance(info.value, AngiohullError)
    assert not out.exists()  # validation happens before anything is written


# --------------------------------------------------------------------------------------------------
# the rasterised cloud, the error colouring, angiograms under the overlay
# --------------------------------------------------------------------------------------------------


def test_splat_image_nearest_point_wins_each_pixel():
    u = np.array([2.2, 2.7, 6.0])
    v = np.array([3.1, 3.9, 0.5])
    depth = np.array([1.0, 5.0, 0.0])  # the second point is nearer than the first
    image = viz.splat_image(u, v, depth, np.array([10.0, 20.0, 30.0]), (6, 8), 1)
    expected = np.full((6, 8), np.nan)
    expected[3, 2] = 20.0  # both points fall in pixel (row 3, col 2): the nearer one
    expected[0, 6] = 30.0
    np.testing.assert_array_equal(image, expected)
    square = viz.splat_image(np.array([4.5]), np.array([2.5]), np.zeros(1), np.array([7.0]), (6, 8), 3)
    assert np.argwhere(np.isfinite(square)).tolist() == [[r, c] for r in (1, 2, 3) for c in (3, 4, 5)]
    clipped = viz.splat_image(np.array([0.2]), np.array([0.2]), np.zeros(1), np.array([1.0]), (4, 4), 3)
    assert np.isfinite(clipped).sum() == 4  # the square's part inside the image


def test_nearest_distance_is_the_brute_force_minimum():
    rng = np.random.default_rng(5)
    points, reference = rng.normal(size=(300, 3)) * 10, rng.normal(size=(400, 3)) * 10
    brute = np.sqrt(((points[:, None] - reference[None]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_allclose(viz.nearest_distance_mm(points, reference), brute, rtol=1e-12)
    assert np.isnan(viz.nearest_distance_mm(points, np.zeros((0, 3)))).all()


def test_view_rgb_blends_the_angiogram_under_the_classes():
    mask = np.array([[True, True, False, False]])
    reproj = np.array([[True, False, True, False]])
    image = np.array([[0.0, 100.0, 50.0, 25.0]])
    rgb = viz.view_rgb(mask, reproj, image)
    grey = np.clip((image - np.percentile(image, 1)) / (np.percentile(image, 99) - np.percentile(image, 1)), 0, 1)[0]
    for col, key, alpha in ((0, "both", 0.35), (1, "missed", 0.85), (2, "spurious", 0.85)):
        expected = (1 - alpha) * grey[col] + alpha * np.asarray(OVERLAY_COLOURS[key]) / 255.0
        np.testing.assert_allclose(rgb[0, col], expected, atol=1e-12)
    np.testing.assert_allclose(rgb[0, 3], [grey[3]] * 3)  # neither: the angiogram alone
    np.testing.assert_array_equal(viz.view_rgb(mask, reproj), overlay_rgb(mask, reproj) / 255.0)


def test_figure_with_truth_scores_and_angiograms(tmp_path):
    masks, reprojections, names = _views(2)
    images = [np.random.default_rng(i).normal(size=masks[0].shape) for i in range(2)]
    out = reconstruction_figure(tmp_path / "truth.png", vessel_points_mm=_helix(), masks=masks,
                                reprojections=reprojections, view_names=names, centerline_points_mm=_helix(50),
                                ground_truth_mm=_helix(900) + 0.5, images=[images[0], None],
                                scores=["Dice3D 80.0 % · IoU3D 66.7 %", "tree: centerline 0.2 mm"], dpi=50)
    image = _read_png(out)
    alone = reconstruction_figure(tmp_path / "plain.png", vessel_points_mm=_helix(), masks=masks,
                                  reprojections=reprojections, view_names=names, dpi=50)
    assert image.shape[0] > _read_png(alone).shape[0]  # the truth row and the score lines
    with pytest.raises(AngiohullError, match=r"images\[1\]"):
        reconstruction_figure(tmp_path / "bad.png", vessel_points_mm=_helix(), masks=masks,
                              reprojections=reprojections, view_names=names, images=[None, np.zeros((3, 3))])
    with pytest.raises(AngiohullError, match="one entry per view"):
        reconstruction_figure(tmp_path / "bad.png", vessel_points_mm=_helix(), masks=masks,
                              reprojections=reprojections, view_names=names, images=[None])
