"""Reading XA DICOM files: geometry, fallbacks, multi-frame and rotational runs, Enhanced XA, ECG,
frame selection, broken files, and the real GE phantom runs (when ../shared is present)."""

import re
import warnings

import numpy as np
import pydicom
import pytest
from pydicom.uid import HTJ2KLossless

from angiohull import dicom
from angiohull.dicom import read_xa_frame, read_xa_frames, read_xa_header, read_xa_view, select_frame
from angiohull.errors import DicomError, DicomGeometryWarning
from angiohull.geometry import CArmGeometry
from angiohull.synthetic import demo_phantom
from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram, to_counts

from _dicom_files import CT, ENHANCED_XA, enhanced_groups, write_xa


def _frames(n=3, shape=(40, 60), dtype=np.uint8, seed=0):
    rng = np.random.default_rng(seed)
    top = 255 if dtype == np.uint8 else 4095
    return rng.integers(0, top + 1, size=(n, *shape)).astype(dtype)


# -- geometry of plain files -------------------------------------------------------------------
def test_single_frame_geometry_equals_the_header(tmp_path):
    image = _frames(1)[0]
    path = write_xa(tmp_path / "one.dcm", image, primary=-27.3, secondary=18.0, sid=1050.0, sod=745.5, spacing=(0.25, 0.3))
    header = read_xa_header(path)
    assert (header.modality, header.sop_class, header.n_frames, header.image_shape) == ("XA", "XA", 1, (40, 60))
    frame = header.frames[0]
    assert (frame.primary_deg, frame.secondary_deg, frame.sid_mm, frame.sod_mm) == (-27.3, 18.0, 1050.0, 745.5)
    assert frame.pixel_spacing_mm == (0.25, 0.3) and frame.clinical == "RAO 27.3 CRA 18"
    assert header.spacing_source == "ImagerPixelSpacing (0018,1164)" and not header.varying_geometry
    expected = CArmGeometry(-27.3, 18.0, 1050.0, 745.5, (0.25, 0.3), (40, 60)).projection().matrix
    np.testing.assert_array_equal(header.geometry().projection().matrix, expected)
    np.testing.assert_array_equal(read_xa_frame(path, 0), image)
    view = read_xa_view(path)
    assert view.frame == 0 and view.selection.reason == "single frame"
    np.testing.assert_array_equal(view.image, image)


def test_multi_frame_run_decodes_every_frame(tmp_path):
    frames = _frames(4, dtype=np.uint16)
    path = write_xa(tmp_path / "run.dcm", frames, FrameTime=66.7)
    header = read_xa_header(path)
    assert header.n_frames == 4 and len(header.frames) == 4 and not header.varying_geometry
    assert header.frame_times_ms == pytest.approx((0.0, 66.7, 133.4, 200.1))
    decoded = read_xa_frames(path)
    assert decoded.shape == (4, 40, 60) and decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, frames)
    np.testing.assert_array_equal(read_xa_frame(path, 2), frames[2])
    np.testing.assert_array_equal(read_xa_view(path, frame=3).image, frames[3])


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_jpeg_lossless_sv1_frames_decode_exactly(tmp_path, dtype):
    frames = _frames(3, shape=(33, 47), dtype=dtype, seed=4)
    path = write_xa(tmp_path / "jpeg.dcm", frames, compressed=True)
    header = read_xa_header(path)
    assert "JPEG Lossless, Non-Hierarchical, First-Order Prediction" in header.transfer_syntax
    np.testing.assert_array_equal(read_xa_frames(path, header), frames)
    np.testing.assert_array_equal(read_xa_frame(path, 1, header), frames[1])


def test_monochrome1_is_inverted(tmp_path):
    image = _frames(1)[0]
    path = write_xa(tmp_path / "m1.dcm", image, photometric="MONOCHROME1")
    np.testing.assert_array_equal(read_xa_frame(path, 0), 255 - image)


# -- pixel spacing fallbacks -------------------------------------------------------------------
def test_spacing_from_field_of_view_dimensions_warns(tmp_path):
    path = write_xa(tmp_path / "fov.dcm", _frames(1)[0], spacing=None, FieldOfViewDimensions=[20, 24], IntensifierSize=300)
    message = (f"{path}: ImagerPixelSpacing (0018,1164) is missing; assumed 0.5 x 0.4 mm from "
               "FieldOfViewDimensions (0018,1149) = [20, 24] mm over 40 x 60 pixels")
    with pytest.warns(DicomGeometryWarning, match=re.escape(message)):
        header = read_xa_header(path)
    assert header.frames[0].pixel_spacing_mm == (0.5, 0.4)
    assert header.spacing_source.startswith("FieldOfViewDimensions (0018,1149) = [20, 24] mm")


def test_round_field_of_view_is_a_diameter(tmp_path):
    path = write_xa(tmp_path / "round.dcm", _frames(1)[0], spacing=None, FieldOfViewDimensions=[18])
    with pytest.warns(DicomGeometryWarning, match=r"assumed 0\.3 x 0\.3 mm from FieldOfViewDimensions \(0018,1149\) = 18 mm \(diameter\) over 60 pixels"):
        assert read_xa_header(path).frames[0].pixel_spacing_mm == pytest.approx((0.3, 0.3))


def test_spacing_from_intensifier_size_warns(tmp_path):
    path = write_xa(tmp_path / "ii.dcm", _frames(1)[0], spacing=None, IntensifierSize=21.0)
    with pytest.warns(DicomGeometryWarning, match=r"ImagerPixelSpacing \(0018,1164\) is missing and so is FieldOfViewDimensions "
                                                  r"\(0018,1149\); assumed 0\.35 x 0\.35 mm from IntensifierSize \(0018,1162\) = 21 mm over 60 pixels"):
        header = read_xa_header(path)
    assert header.frames[0].pixel_spacing_mm == pytest.approx((0.35, 0.35))


def test_no_spacing_at_all_is_an_error(tmp_path):
    path = write_xa(tmp_path / "none.dcm", _frames(1)[0], spacing=None)
    with pytest.raises(DicomError, match=r"ImagerPixelSpacing \(0018,1164\) is missing, and neither FieldOfViewDimensions "
                                         r"\(0018,1149\) nor IntensifierSize \(0018,1162\)"):
        read_xa_header(path)


# -- rotational runs ---------------------------------------------------------------------------
def test_rotational_run_with_one_increment_per_frame(tmp_path):
    primary_inc = [0.0, 5.0, 12.5, 20.0]
    secondary_inc = [0.0, -1.0, -2.0, -3.5]
    path = write_xa(tmp_path / "rot.dcm", _frames(4), primary=-60.0, secondary=10.0, PositionerMotion="DYNAMIC",
                    PositionerPrimaryAngleIncrement=primary_inc, PositionerSecondaryAngleIncrement=secondary_inc)
    header = read_xa_header(path)
    assert header.varying_geometry
    assert [(f.primary_deg, f.secondary_deg) for f in header.frames] == [(-60.0, 10.0), (-55.0, 9.0), (-47.5, 8.0), (-40.0, 6.5)]
    assert "per-frame increments PositionerPrimaryAngleIncrement (0018,1520)" in header.angle_source
    np.testing.assert_array_equal(header.geometry(2).projection().matrix,
                                  CArmGeometry(-47.5, 8.0, 1100.0, 760.0, (0.3, 0.3), (40, 60)).projection().matrix)
    with pytest.raises(DicomError, match=r"the geometry changes from frame to frame .*give a frame index \(0 to 3\)"):
        header.geometry()


def test_rotational_run_with_a_constant_increment(tmp_path):
    path = write_xa(tmp_path / "rot1.dcm", _frames(5), primary=-90.0, secondary=0.0,
                    PositionerPrimaryAngleIncrement=[2.5])
    assert [f.primary_deg for f in read_xa_header(path).frames] == [-90.0, -87.5, -85.0, -82.5, -80.0]


def test_increment_vector_of_the_wrong_length_is_an_error(tmp_path):
    path = write_xa(tmp_path / "bad.dcm", _frames(3), PositionerPrimaryAngleIncrement=[0.0, 1.0])
    with pytest.raises(DicomError, match=r"PositionerPrimaryAngleIncrement \(0018,1520\) holds 2 values but the run has 3 frames"):
        read_xa_header(path)


def test_rotation_past_the_angle_range_is_reported(tmp_path):
    path = write_xa(tmp_path / "far.dcm", _frames(3), primary=170.0, PositionerPrimaryAngleIncrement=[0.0, 10.0, 20.0])
    with pytest.raises(DicomError, match=r"the primary angle PositionerPrimaryAngle \(0018,1510\) \(frame 2\) = 190 degrees "
                                         r"is not plausible; expected -180 to 180 degrees"):
        read_xa_header(path)


# -- Enhanced XA -------------------------------------------------------------------------------
def test_enhanced_xa_per_frame_groups_with_shared_fallback(tmp_path):
    per_frame = [{"primary": -30.0 + 10.0 * i, "secondary": 5.0 * i} for i in range(3)]
    per_frame[2]["sid"] = 1150.0  # overrides the shared SID for this frame only
    per_frame[1]["cycle"] = "END_DIASTOLE"
    groups = enhanced_groups(per_frame, shared={"sid": 1200.0, "sod": 780.0, "spacing": (0.2, 0.25)})
    path = write_xa(tmp_path / "enh.dcm", _frames(3), primary=None, secondary=None, sid=None, sod=None, spacing=None,
                    sop_class=ENHANCED_XA, **groups)
    header = read_xa_header(path)
    assert header.sop_class == "Enhanced XA" and header.varying_geometry
    got = [(f.primary_deg, f.secondary_deg, f.sid_mm, f.sod_mm, f.pixel_spacing_mm) for f in header.frames]
    assert got == [(-30.0, 0.0, 1200.0, 780.0, (0.2, 0.25)), (-20.0, 5.0, 1200.0, 780.0, (0.2, 0.25)),
                   (-10.0, 10.0, 1150.0, 780.0, (0.2, 0.25))]
    assert "per-frame functional groups" in header.angle_source
    assert "SharedFunctionalGroupsSequence.FramePixelDataPropertiesSequence" in header.spacing_source
    assert header.end_diastolic_frames == (1,)
    assert "CardiacCyclePosition (0018,9236)" in header.ecg_source


def test_enhanced_xa_without_angles_names_the_sequence(tmp_path):
    groups = enhanced_groups([{"primary": 10.0}, {"primary": 12.0}], shared={"sid": 1200.0, "sod": 780.0, "spacing": (0.2, 0.2)})
    path = write_xa(tmp_path / "enh.dcm", _frames(2), primary=None, secondary=None, sid=None, sod=None, spacing=None,
                    sop_class=ENHANCED_XA, **groups)
    with pytest.raises(DicomError, match=r"PositionerSecondaryAngle \(0018,1511\) is missing for frame 0 \(looked in the per-frame "
                                         r"and shared functional groups' PositionerPositionSequence \(0018,9405\)"):
        read_xa_header(path)


def test_enhanced_xa_without_isocentre_distance_is_an_error(tmp_path):
    groups = enhanced_groups([{"primary": 10.0, "secondary": 0.0}], shared={"sid": 1200.0, "spacing": (0.2, 0.2)})
    path = write_xa(tmp_path / "enh.dcm", _frames(1), primary=None, secondary=None, sid=None, sod=None, spacing=None,
                    sop_class=ENHANCED_XA, NumberOfFrames=1, **groups)
    with pytest.raises(DicomError, match=r"DistanceSourceToIsocenter \(0018,9402\) or DistanceSourceToPatient \(0018,1111\) is missing"):
        read_xa_header(path)


# -- ECG and frame selection -------------------------------------------------------------------
def test_r_wave_pointer_gives_end_diastolic_frames(tmp_path):
    path = write_xa(tmp_path / "ecg.dcm", _frames(6), RWavePointer=[2, 6])
    header = read_xa_header(path)
    assert header.end_diastolic_frames == (1, 5) and header.ecg_source == "RWavePointer (0028,6040)"


def test_r_wave_times_are_matched_to_frame_times(tmp_path):
    path = write_xa(tmp_path / "ecg.dcm", _frames(8), FrameTime=100.0, RWaveTimeVector=[130.0, 560.0, 2000.0])
    header = read_xa_header(path)
    assert header.end_diastolic_frames == (1, 6)  # 130 ms -> frame 1 (100 ms), 560 -> frame 6 (600); 2000 is after the run
    assert header.ecg_source == "RWaveTimeVector (0018,6060) and FrameTime (0018,1063)"
    steps = [0.0, 50.0, 50.0, 200.0, 50.0, 50.0, 50.0, 50.0]  # frame times 0, 50, 100, 300, 350, ...
    path = write_xa(tmp_path / "ecg2.dcm", _frames(8), FrameTimeVector=steps, RWaveTimeVector=[260.0])
    assert read_xa_header(path).end_diastolic_frames == (3,)


def test_r_wave_pointer_outside_the_run_is_an_error(tmp_path):
    path = write_xa(tmp_path / "ecg.dcm", _frames(3), RWavePointer=[2, 9])
    with pytest.raises(DicomError, match=r"RWavePointer \(0028,6040\) names frame number\(s\) \[9\] but the run has frames 1 to 3"):
        read_xa_header(path)


@pytest.fixture(scope="module")
def injection_run():
    """A cine run of the demo phantom in which the contrast arrives, peaks at frame 2, washes out."""
    carm = CArmGeometry(-30.0, 30.0, 1200.0, 800.0, (0.7, 0.7), (256, 256))
    fractions = (0.05, 0.4, 1.0, 0.7, 0.3)
    images = [render_angiogram(demo_phantom(), carm, seed, AngiogramParameters(vessel_attenuation_per_mm=0.25 * f, collimator_px=6)).image
              for seed, f in enumerate(fractions)]
    white = max(image.max() for image in images)
    return carm, np.stack([to_counts(image, bits=12, white=white) for image in images])


def test_automatic_frame_is_the_most_opacified(tmp_path, injection_run):
    carm, frames = injection_run
    path = write_xa(tmp_path / "cine.dcm", frames, primary=-30.0, secondary=30.0, sid=1200.0, sod=800.0, spacing=(0.7, 0.7))
    view = read_xa_view(path)
    assert view.frame == 2 and view.selection.most_contrast_frame == 2
    assert view.selection.reason == "most contrast (frame 2 of 5)"
    assert np.argmax(view.selection.scores) == 2
    np.testing.assert_array_equal(view.image, frames[2])
    np.testing.assert_array_equal(view.carm.projection().matrix, carm.projection().matrix)


def test_automatic_frame_prefers_the_nearest_end_diastole(tmp_path, injection_run):
    _, frames = injection_run
    path = write_xa(tmp_path / "cine.dcm", frames, RWavePointer=[1, 4])  # frames 0 and 3 are end-diastolic
    view = read_xa_view(path)
    assert view.frame == 3 and view.selection.most_contrast_frame == 2
    assert view.selection.reason == "end-diastolic frame nearest to the most-contrast frame 2 (end-diastolic: [0, 3])"
    assert select_frame(frames, end_diastolic_frames=[0, 4]).frame == 4  # tie at distance 2: frame 4 scores higher


# -- broken files ------------------------------------------------------------------------------
def test_not_a_dicom_file(tmp_path):
    path = tmp_path / "notes.dcm"
    path.write_text("not an image")
    with pytest.raises(DicomError, match=rf"^{re.escape(str(path))}: is not a DICOM file"):
        read_xa_header(path)
    with pytest.raises(DicomError, match="file not found"):
        read_xa_header(tmp_path / "missing.dcm")


def test_a_ct_image_is_not_an_angiogram(tmp_path):
    path = write_xa(tmp_path / "ct.dcm", _frames(1)[0], sop_class=CT, modality="CT")
    with pytest.raises(DicomError, match=r"is not an X-ray angiogram: Modality \(0008,0060\) is 'CT' and SOPClassUID \(0008,0016\) "
                                         r"is 'CT Image Storage'; expected Modality 'XA'"):
        read_xa_header(path)


@pytest.mark.parametrize("keyword, tag, what", [
    ("primary", r"PositionerPrimaryAngle \(0018,1510\)", "C-arm angle"),
    ("secondary", r"PositionerSecondaryAngle \(0018,1511\)", "C-arm angle"),
    ("sid", r"DistanceSourceToDetector \(0018,1110\)", r"source-to-detector distance \(SID\)"),
    ("sod", r"DistanceSourceToPatient \(0018,1111\)", r"source-to-isocentre distance \(SOD\)"),
])
def test_missing_geometry_names_the_tag_and_the_file(tmp_path, keyword, tag, what):
    path = write_xa(tmp_path / "x.dcm", _frames(1)[0], **{keyword: None})
    with pytest.raises(DicomError, match=rf"^{re.escape(str(path))}: {tag} is missing; it gives the {what}"):
        read_xa_header(path)


def test_empty_type2_angle_is_missing(tmp_path):
    path = write_xa(tmp_path / "x.dcm", _frames(1)[0], primary="")
    with pytest.raises(DicomError, match=r"PositionerPrimaryAngle \(0018,1510\) is missing"):
        read_xa_header(path)


@pytest.mark.parametrize("changes, message", [
    ({"sid": 5.0}, r"the SID DistanceSourceToDetector \(0018,1110\) = 5 mm is not plausible; expected 200 to 3000 mm"),
    ({"sod": 1200.0}, r"the SOD DistanceSourceToPatient \(0018,1111\) = 1200 mm is not plausible with the SID = 1100 mm"),
    ({"spacing": (50.0, 50.0)}, r"the pixel spacing \(from ImagerPixelSpacing \(0018,1164\)\) = 50 mm is not plausible"),
    ({"secondary": 120.0}, r"the secondary angle PositionerSecondaryAngle \(0018,1511\) = 120 degrees is not plausible"),
    ({"spacing": None, "FieldOfViewDimensions": [200, 200, 3]}, r"FieldOfViewDimensions \(0018,1149\) must hold 1 or 2 numbers"),
    ({"Rows": None}, r"Rows \(0028,0010\) is missing"),
    ({"SamplesPerPixel": 3}, r"SamplesPerPixel \(0028,0002\) is 3"),
])
def test_absurd_values_are_reported(tmp_path, changes, message):
    path = write_xa(tmp_path / "x.dcm", _frames(1)[0], **changes)
    with pytest.raises(DicomError, match=message):
        read_xa_header(path)


def test_frame_index_out_of_range(tmp_path):
    path = write_xa(tmp_path / "run.dcm", _frames(3))
    with pytest.raises(DicomError, match=r"frame 3 does not exist; the run has 3 frame\(s\), indices 0 to 2"):
        read_xa_view(path, frame=3)
    with pytest.raises(DicomError, match="frame must be an integer index from 0"):
        read_xa_frame(path, 1.5)


def test_truncated_pixel_data(tmp_path):
    path = write_xa(tmp_path / "cut.dcm", _frames(2))
    ds = pydicom.dcmread(path)
    ds.PixelData = ds.PixelData[:1000]
    ds.save_as(path)
    with pytest.raises(DicomError, match=r"cannot decode the pixel data \(transfer syntax Explicit VR Little Endian\)"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pydicom may warn about the short buffer before failing
            read_xa_frames(path)


def test_damaged_jpeg_stream(tmp_path):
    path = write_xa(tmp_path / "bad.dcm", _frames(1)[0], compressed=True)
    ds = pydicom.dcmread(path)
    from pydicom.encaps import encapsulate

    ds.PixelData = encapsulate([b"\xff\xd8\xff\xc3garbage-not-a-jpeg\xff\xd9"])
    ds["PixelData"].is_undefined_length = True
    ds.save_as(path)
    with pytest.raises(DicomError, match=r"cannot decode the pixel data \(transfer syntax JPEG Lossless.*the file may be damaged"):
        read_xa_frame(path, 0)


def test_missing_decoder_plugin_says_what_to_install(tmp_path, monkeypatch):
    # HTJ2K needs pylibjpeg-openjpeg, which angiohull does not install.
    path = write_xa(tmp_path / "htj2k.dcm", _frames(1)[0], compressed=True)
    ds = pydicom.dcmread(path)
    ds.file_meta.TransferSyntaxUID = HTJ2KLossless
    ds.save_as(path)
    with pytest.raises(DicomError, match=r"transfer syntax High-Throughput JPEG 2000 .* needs a decoder plugin that is not installed; "
                                         r"install one: pip install pylibjpeg pylibjpeg-openjpeg"):
        read_xa_frame(path, 0)
    # The phantom's JPEG Lossless on a machine without pylibjpeg-libjpeg:
    path = write_xa(tmp_path / "jpeg.dcm", _frames(1)[0], compressed=True)
    monkeypatch.setattr(dicom, "_decoder_status", lambda uid: (False, ["pylibjpeg - requires pylibjpeg-libjpeg"]))
    with pytest.raises(DicomError, match=r"JPEG Lossless, Non-Hierarchical, First-Order Prediction .*install one: "
                                         r"pip install pylibjpeg pylibjpeg-libjpeg \(or python-gdcm\)"):
        read_xa_frame(path, 0)


@pytest.mark.parametrize("compressed", [False, True])
def test_a_file_cut_inside_its_header_is_called_truncated(tmp_path, compressed):
    """pydicom reads a file cut short in its header quietly up to its end: Rows was then said to be
    missing (a cut at 600 bytes), or a value cut in two was 'damaged'."""
    path = write_xa(tmp_path / "run.dcm", _frames(2), compressed=compressed)
    data = path.read_bytes()
    pixels = data.index(b"\xe0\x7f\x10\x00")  # (7FE0,0010), little endian
    rows = data.index(b"\x28\x00\x10\x00US")  # Rows (0028,0010): tag, VR, 2-byte length, 2-byte value
    study = data.index(b"\x20\x00\x0d\x00UI")  # StudyInstanceUID (0020,000D), a generated UID: its length varies
    length = int.from_bytes(data[study + 6:study + 8], "little")
    cut = tmp_path / "cut.dcm"
    ends = "PixelData (7FE0,0010)): it is truncated; copy it again from its source"
    for size, where in [
            (140, "in or after FileMetaInformationGroupLength (0002,0000)"),  # in the file meta information
            (study + 12, f"in the value of StudyInstanceUID (0020,000D), {length - 4} byte(s) short of its length "
                         f"{length}"),
            (rows + 9, "in the value of Rows (0028,0010), 1 byte(s) short of its length 2"),
            (rows + 13, "in the element after Rows (0028,0010)"),  # a tag cut short
            (pixels + 6, "in the element after PixelRepresentation (0028,0103)")]:  # the pixel data's own tag
        cut.write_bytes(data[:size])
        with pytest.raises(DicomError, match=re.escape(f"{cut}: the file ends early, inside its header ({where}; "
                                                       f"{size} bytes, before any {ends}")):
            read_xa_header(cut)
    # cut right after an element: what a whole file without an image looks like too, so both are said
    for size, where in [(rows + 10, "after Rows (0028,0010)"), (pixels, "after PixelRepresentation (0028,0103)")]:
        cut.write_bytes(data[:size])
        with pytest.raises(DicomError, match=re.escape(f"{cut}: has no PixelData (7FE0,0010): the file ends "
                                                       f"{where} ({size} bytes), as a DICOM file without an image "
                                                       f"does, or one cut short right there")):
            read_xa_header(cut)
    cut.write_bytes(data[:600])  # (said "Rows (0028,0010) is missing")
    with pytest.raises(DicomError, match=re.escape(f"{cut}: the file ends early, inside its header (in ")):
        read_xa_header(cut)
    cut.write_bytes(data[:152])  # pydicom fails where a tag's length is cut in two: still the same verdict
    with pytest.raises(DicomError, match=re.escape(f"{cut}: the file ends early, inside its header (pydicom: error: "
                                                   f"unpack requires a buffer of 4 bytes; 152 bytes, before any {ends}")):
        read_xa_header(cut)
    cut.write_bytes(data[:pixels + 12])  # the pixel data's tag whole, its value gone: the header reads
    header = read_xa_header(cut)
    assert header.image_shape == (40, 60)
    with pytest.raises(DicomError, match=re.escape(str(cut))):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pydicom may warn about the short buffer before failing
            read_xa_frames(cut, header)
    np.testing.assert_array_equal(read_xa_frames(path), _frames(2))  # the whole file, for the record


def test_an_element_that_cannot_be_decoded_is_named_once(tmp_path):
    path = write_xa(tmp_path / "run.dcm", _frames(1)[0])
    data = path.read_bytes()
    at = data.index(b"\x18\x00\x10\x15DS")  # PositionerPrimaryAngle: its VR damaged
    path.write_bytes(data[:at + 4] + b"XX" + data[at + 6:])
    with pytest.raises(DicomError, match=rf"^{re.escape(str(path))}: PositionerPrimaryAngle \(0018,1510\) is damaged "
                                         r"and cannot be read \(NotImplementedError: Unknown Value Representation 'XX'"
                                         r".*\); the file's header is corrupt$"):  # was inside 'cannot read as DICOM (...)'
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pydicom may warn about the unknown VR first
            read_xa_header(path)


# -- the real phantom runs ---------------------------------------------------------------------
REAL = {  # file: frames, primary, secondary, SID, SOD, spacing, spacing from the fallback
    "IM1.dcm": (14, 31.3, 0.1, 860.0, 720.0, 0.390625, True),
    "IM2.dcm": (12, -27.3, -0.1, 865.0, 720.0, 0.390625, True),
    "IM5.dcm": (16, -26.5, -32.7, 931.0, 720.0, 0.390625, False),
}


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_ge_phantom_headers_and_pixels(ge_phantom_dir, name):
    n, primary, secondary, sid, sod, spacing, fallback = REAL[name]
    path = ge_phantom_dir / name
    raw = pydicom.dcmread(path, stop_before_pixels=True)
    assert (float(raw.PositionerPrimaryAngle), float(raw.DistanceSourceToDetector)) == (primary, sid)  # the README's table
    if fallback:
        with pytest.warns(DicomGeometryWarning, match=r"ImagerPixelSpacing \(0018,1164\) is missing; assumed 0\.390625 x 0\.390625 mm "
                                                      r"from FieldOfViewDimensions \(0018,1149\) = \[200, 200\] mm over 512 x 512 pixels"):
            header = read_xa_header(path)
    else:
        header = read_xa_header(path)
        assert header.spacing_source == "ImagerPixelSpacing (0018,1164)"
    assert (header.n_frames, header.image_shape, header.sop_class) == (n, (512, 512), "XA")
    assert not header.varying_geometry and header.end_diastolic_frames == ()
    for frame in header.frames:
        assert (frame.primary_deg, frame.secondary_deg, frame.sid_mm, frame.sod_mm) == (primary, secondary, sid, sod)
        assert frame.pixel_spacing_mm == (spacing, spacing)
    frames = read_xa_frames(path, header)
    assert frames.shape == (n, 512, 512) and frames.dtype == np.uint8
    assert 60 < frames.mean() < 140  # a bright field, not an undecoded buffer
    np.testing.assert_array_equal(read_xa_frame(path, n - 1, header), frames[-1])


def test_a_real_run_cut_short_is_called_truncated(ge_phantom_dir, tmp_path):
    """A copy that ends early (a transfer cut short) loses its compressed frames' end: pydicom stops
    there with a warning and no error, and the pixel data was then said to be missing."""
    data = (ge_phantom_dir / "IM2.dcm").read_bytes()
    cut = tmp_path / "cut.dcm"
    cut.write_bytes(data[:len(data) * 7 // 10])
    with pytest.warns(DicomGeometryWarning, match="FieldOfViewDimensions"):  # (IM2 has no ImagerPixelSpacing)
        header = read_xa_header(cut)  # the header is whole: dicom-info still reads it
    with pytest.raises(DicomError, match=r"cut\.dcm: the file ends early \(pydicom: End of file reached before "
                                         r"delimiter \(FFFE,E0DD\)\): it is truncated; copy it again"):
        read_xa_frames(cut, header)
