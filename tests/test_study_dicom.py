"""Study views from DICOM (dicom:, frame:) and from raw images (image:, segmentation:), save/load
round trips of such views, and study_from_dicom."""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from angiohull.errors import DicomError, DicomGeometryWarning, InputWarning, StudyError
from angiohull.geometry import CArmGeometry
from angiohull.io import write_mask
from angiohull.reconstruction import reconstruct
from angiohull.segmentation import SegmentationParameters
from angiohull.study import View, load_study, save_study, study_from_dicom
from angiohull.synthetic import demo_phantom
from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram, to_counts

from _dicom_files import write_xa

SHAPE = (300, 300)
CARMS = {"lao": CArmGeometry(40.0, 20.0, 1200.0, 800.0, (0.5, 0.5), SHAPE),
         "rao": CArmGeometry(-35.0, -25.0, 1150.0, 790.0, (0.5, 0.5), SHAPE)}


def dice(a, b):
    return 2.0 * np.count_nonzero(a & b) / (np.count_nonzero(a) + np.count_nonzero(b))


def _header(carm):
    return dict(primary=carm.primary_deg, secondary=carm.secondary_deg, sid=carm.sid_mm, sod=carm.sod_mm,
                spacing=carm.pixel_spacing_mm)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Per view: a 3-frame cine XA file of the rendered demo phantom (contrast peaks at frame 1) and the true mask."""
    folder = tmp_path_factory.mktemp("runs")
    phantom = demo_phantom()
    out = {}
    for seed, (name, carm) in enumerate(CARMS.items()):
        images = [render_angiogram(phantom, carm, 10 * seed + k, AngiogramParameters(vessel_attenuation_per_mm=0.25 * f,
                                                                                     collimator_px=6)).image
                  for k, f in enumerate((0.2, 1.0, 0.5))]
        white = max(image.max() for image in images)
        frames = np.stack([to_counts(image, bits=12, white=white) for image in images])
        out[name] = (write_xa(folder / f"{name}.dcm", frames, compressed=seed == 1, **_header(carm)), phantom.silhouette(carm),
                     frames)
    return out


def _write(folder: Path, views: list[dict]) -> Path:
    """A study.yaml naming the runs where the fixtures wrote them (outside the folder: opted in)."""
    path = folder / "study.yaml"
    path.write_text(yaml.safe_dump({"angiohull": 1, "views": views, "allow_outside_paths": True}, sort_keys=False))
    return path


def _raises(folder: Path, views: list[dict], pattern: str) -> StudyError:
    yaml_path = _write(folder, views)
    with pytest.raises(StudyError, match=rf"^{re.escape(str(yaml_path))}: {pattern}") as info:
        load_study(folder)
    return info.value


def test_dicom_geometry_with_masks(tmp_path, runs):
    (tmp_path / "masks").mkdir()
    views = []
    for name, (path, truth, _) in runs.items():
        write_mask(tmp_path / "masks" / f"{name}.png", truth)
        views.append({"mask": f"masks/{name}.png", "dicom": str(path)})  # absolute path, no frame: a static run
    _write(tmp_path, views)
    study = load_study(tmp_path)
    assert study.names == ("lao", "rao")
    for view, name in zip(study.views, CARMS):
        assert view.source == "dicom" and view.frame is None and view.dicom_path == runs[name][0]
        assert view.carm == CARMS[name]
        np.testing.assert_array_equal(view.projection.matrix, CARMS[name].projection().matrix)
    masks = [runs[name][1] for name in CARMS]
    expected = reconstruct([c.projection() for c in CARMS.values()], masks, resolution=60, centerlines=False)
    got = reconstruct(study.projections, study.masks, resolution=60, centerlines=False)
    np.testing.assert_array_equal(got.vessel_points_mm, expected.vessel_points_mm)


def test_dicom_image_is_segmented_on_the_automatic_frame(tmp_path, runs):
    path, truth, _ = runs["lao"]
    _write(tmp_path, [{"name": "lao", "image": str(path), "dicom": str(path)}])
    view = load_study(tmp_path).views[0]
    assert view.frame == 1  # the most opacified frame; its geometry is used
    assert view.image_path == path and view.mask_path is None
    assert dice(view.mask, truth) >= 0.85


def test_explicit_frame_and_segmentation_overrides(tmp_path, runs):
    path, truth, _ = runs["rao"]
    _write(tmp_path, [{"name": "rao", "image": str(path), "dicom": str(path), "frame": 2,
                       "segmentation": {"method": "frangi", "sigmas_px": [1.5, 3]}}])
    view = load_study(tmp_path).views[0]
    assert view.frame == 2 and dice(view.mask, truth) >= 0.85
    error = _raises(tmp_path, [{"name": "rao", "image": str(path), "dicom": str(path), "segmentation": {"sigma": 2}}],
                    r"views\[0\]\.segmentation: view 'rao': unknown segmentation parameter\(s\) \['sigma'\]")
    assert "known: vessels, smoothing_px" in str(error)
    _raises(tmp_path, [{"name": "rao", "image": str(path), "dicom": str(path), "segmentation": {"min_object_px": 10 ** 6}}],
            r"views\[0\]\.image: view 'rao': .*rao\.dcm: the segmentation found no vessel")


def test_png_image_with_carm_geometry(tmp_path, runs):
    _, truth, frames = runs["lao"]
    Image.fromarray(frames[1]).save(tmp_path / "lao.png")  # 16-bit grey PNG
    carm = CARMS["lao"]
    entry = {"image": "lao.png", "carm": {"primary_deg": carm.primary_deg, "secondary_deg": carm.secondary_deg,
                                          "sid_mm": carm.sid_mm, "sod_mm": carm.sod_mm, "pixel_spacing_mm": list(carm.pixel_spacing_mm)}}
    _write(tmp_path, [entry])
    view = load_study(tmp_path).views[0]
    assert view.name == "lao" and view.source == "carm" and dice(view.mask, truth) >= 0.85
    _raises(tmp_path, [dict(entry, frame=1)], r"views\[0\]\.frame: view 'lao': frame: is only used with dicom: or a DICOM image:, "
                                               r"but lao\.png is not a DICOM file")
    Image.fromarray(frames[1][:4, :4]).save(tmp_path / "tiny.png")  # too small to segment: the file is named
    _raises(tmp_path, [dict(entry, image="tiny.png")],
            r"views\[0\]\.image: view 'tiny': .*tiny\.png: image must be at least 8 x 8 pixels, got shape \(4, 4\)")
    Image.fromarray(np.full((64, 64), 900, np.uint16)).save(tmp_path / "flat.png")
    _raises(tmp_path, [dict(entry, image="flat.png")],
            r"views\[0\]\.image: view 'flat': .*flat\.png: the image is flat \(every pixel 900\): it shows no vessel")


def test_view_sources_are_checked(tmp_path, runs):
    path = str(runs["lao"][0])
    _raises(tmp_path, [{"name": "v", "mask": "m.png", "image": path, "dicom": path}],
            r"views\[0\]: view 'v' has both mask: and image:; give exactly one of mask:")
    _raises(tmp_path, [{"name": "v", "mask": "m.png", "dicom": path, "segmentation": {"method": "sato"}}],
            r"views\[0\]: view 'v': segmentation: is only used with image:")
    _raises(tmp_path, [{"name": "v", "image": path, "dicom": path, "frame": -1}],
            r"views\[0\]\.frame: Input should be greater than or equal to 0")
    _raises(tmp_path, [{"name": "v", "image": path, "dicom": path, "frame": 7}],
            r"views\[0\]\.image: view 'v': .*lao\.dcm: frame 7 does not exist; the run has 3 frame\(s\), indices 0 to 2")


def test_rotational_run_needs_a_frame(tmp_path):
    carm = CARMS["lao"]
    frames = np.full((3, *SHAPE), 200, np.uint8)
    write_xa(tmp_path / "rot.dcm", frames, PositionerPrimaryAngleIncrement=[0.0, 4.0, 8.0], **_header(carm))
    mask = np.zeros(SHAPE, bool)
    mask[100:110, 50:250] = True
    write_mask(tmp_path / "m.png", mask)
    _raises(tmp_path, [{"mask": "m.png", "dicom": "rot.dcm"}],
            r"views\[0\]\.dicom: view 'm': .*rot\.dcm: the geometry changes from frame to frame .*give a frame index \(0 to 2\)")
    _raises(tmp_path, [{"mask": "m.png", "dicom": "rot.dcm", "frame": 5}],
            r"views\[0\]\.frame: view 'm': .*rot\.dcm: frame 5 does not exist; the run has 3 frame\(s\)")
    _write(tmp_path, [{"mask": "m.png", "dicom": "rot.dcm", "frame": 2}])
    view = load_study(tmp_path).views[0]
    assert view.carm.primary_deg == carm.primary_deg + 8.0 and view.frame == 2


def test_mask_of_another_shape_than_the_detector(tmp_path, runs):
    write_mask(tmp_path / "small.png", np.ones((20, 30), bool))
    _raises(tmp_path, [{"mask": "small.png", "dicom": str(runs["lao"][0])}],
            r"views\[0\]\.dicom: view 'small': .*lao\.dcm: the image is 300 x 300 pixels \(Rows, Columns\) but the mask is 20 x 30")


def test_fallback_spacing_warns_when_loading(tmp_path):
    mask = np.zeros((40, 60), bool)
    mask[10:20, 5:50] = True
    write_mask(tmp_path / "m.png", mask)
    write_xa(tmp_path / "fov.dcm", np.zeros((40, 60), np.uint8), spacing=None, FieldOfViewDimensions=[20, 30])
    _write(tmp_path, [{"mask": "m.png", "dicom": "fov.dcm"}])
    with pytest.warns(DicomGeometryWarning, match=r"fov\.dcm: ImagerPixelSpacing \(0018,1164\) is missing; assumed 0\.5 x 0\.5 mm"):
        view = load_study(tmp_path).views[0]
    assert view.carm.pixel_spacing_mm == (0.5, 0.5)


def test_save_and_load_dicom_views(tmp_path, runs):
    path, truth, _ = runs["rao"]
    view = View.from_dicom("rao", truth, path, frame=1)
    assert view.source == "dicom" and view.carm == CARMS["rao"]
    yaml_path = save_study(tmp_path / "saved", [view])
    entry = yaml.safe_load(yaml_path.read_text())["views"][0]
    relative = Path(os.path.relpath(path, tmp_path / "saved")).as_posix()
    assert entry == {"name": "rao", "mask": "masks/rao.png", "dicom": relative, "frame": 1}
    loaded = load_study(tmp_path / "saved").views[0]
    assert loaded.source == "dicom" and loaded.frame == 1
    np.testing.assert_array_equal(loaded.projection.matrix, view.projection.matrix)
    np.testing.assert_array_equal(loaded.mask, truth)
    with pytest.raises(DicomError, match=r"the image is 300 x 300 pixels \(Rows, Columns\) but view 'x''s mask is \(5, 5\)"):
        View.from_dicom("x", np.ones((5, 5)), path)
    with pytest.raises(StudyError, match=r"dicom_path is given exactly for source 'dicom'"):
        View("x", truth, view.projection, carm=view.carm, source="carm", dicom_path=path)


def test_study_from_dicom_segmented_and_not(tmp_path, runs):
    files = [runs[name][0] for name in CARMS]
    yaml_path, summaries = study_from_dicom(files, tmp_path / "seg", segment=True)
    assert [(s.name, s.frame) for s in summaries] == [("lao", 1), ("rao", 1)]
    assert all(s.selection == "most contrast (frame 1 of 3)" and s.mask_pixels > 0 for s in summaries)
    document = yaml.safe_load(yaml_path.read_text())
    assert document["views"][0] == {"name": "lao", "mask": "masks/lao.png", "dicom": "dicom/lao.dcm", "frame": 1}
    assert (tmp_path / "seg" / "dicom" / "rao.dcm").read_bytes() == files[1].read_bytes()
    study = load_study(yaml_path)
    for view, name in zip(study.views, CARMS):
        assert view.source == "dicom" and dice(view.mask, runs[name][1]) >= 0.85

    lazy, _ = study_from_dicom(files[:1], tmp_path / "lazy", copy=False, frame=2, parameters=SegmentationParameters(edge_snr=2.5))
    document = yaml.safe_load(lazy.read_text())
    entry = document["views"][0]
    relative = Path(os.path.relpath(files[0], tmp_path / "lazy")).as_posix()
    assert entry == {"name": "lao", "image": relative, "dicom": relative, "frame": 2, "segmentation": {"edge_snr": 2.5}}
    assert document["allow_outside_paths"] is True  # the runs stay where they are, outside the study: opted in
    assert load_study(tmp_path / "lazy").views[0].frame == 2


def test_study_from_dicom_all_frames_of_a_rotational_run(tmp_path, runs):
    _, _, frames = runs["lao"]
    path = write_xa(tmp_path / "rot.dcm", frames, PositionerPrimaryAngleIncrement=[0.0, 3.0, 6.0], **_header(CARMS["lao"]))
    yaml_path, summaries = study_from_dicom([path], tmp_path / "study", all_frames=True)
    assert [s.name for s in summaries] == ["rot_f000", "rot_f001", "rot_f002"]
    assert [s.carm.primary_deg for s in summaries] == [40.0, 43.0, 46.0]
    assert [v["frame"] for v in yaml.safe_load(yaml_path.read_text())["views"]] == [0, 1, 2]
    with pytest.raises(StudyError, match="give either a frame or all_frames, not both"):
        study_from_dicom([path], tmp_path / "x", frame=0, all_frames=True)
    with pytest.raises(StudyError, match="needs at least one DICOM file"):
        study_from_dicom([], tmp_path / "x")


def test_the_same_image_given_twice_becomes_two_views_with_a_warning(tmp_path, runs):
    path = runs["lao"][0]
    with pytest.warns(InputWarning, match=r"lao\.dcm: the same image as .*lao\.dcm \(SOP Instance UID .+\): both become "
                                          r"views, which look along one line"):
        _, summaries = study_from_dicom([path, path], tmp_path / "twice", frame=1)
    assert [s.name for s in summaries] == ["lao", "lao_2"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # two different runs: nothing said
        study_from_dicom([runs["lao"][0], runs["rao"][0]], tmp_path / "two", frame=1)
