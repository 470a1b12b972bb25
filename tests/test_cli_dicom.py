"""The DICOM commands of the command line: dicom-info, segment, study-from-dicom (in-process)."""

import json

import numpy as np
import pytest
from PIL import Image

from angiohull.cli import main
from angiohull.geometry import CArmGeometry
from angiohull.io import read_mask
from angiohull.synthetic import demo_phantom
from angiohull.synthetic.angiogram import AngiogramParameters, render_angiogram, to_counts

from _dicom_files import write_xa

CARMS = (CArmGeometry(31.3, -12.5, 1100.0, 760.0, (0.45, 0.45), (320, 320)),
         CArmGeometry(-40.0, 20.0, 1150.0, 780.0, (0.45, 0.45), (320, 320)))


def dice(a, b):
    return 2.0 * np.count_nonzero(a & b) / (np.count_nonzero(a) + np.count_nonzero(b))


@pytest.fixture(scope="module")
def angiograms(tmp_path_factory):
    """Two single-frame XA files of the rendered demo phantom, and their true masks."""
    folder = tmp_path_factory.mktemp("xa")
    out = []
    for i, carm in enumerate(CARMS):
        image = render_angiogram(demo_phantom(), carm, i, AngiogramParameters(collimator_px=6))
        path = write_xa(folder / f"view{i}.dcm", to_counts(image.image, bits=12), primary=carm.primary_deg,
                        secondary=carm.secondary_deg, sid=carm.sid_mm, sod=carm.sod_mm, spacing=carm.pixel_spacing_mm,
                        compressed=i == 1)
        out.append((path, image.mask))
    return out


def test_dicom_info_prints_one_line_per_file(tmp_path, angiograms, capsys):
    rotational = write_xa(tmp_path / "rot.dcm", np.zeros((3, 8, 8), np.uint8), primary=-10.0, secondary=0.0,
                          PositionerPrimaryAngleIncrement=[5.0], RWavePointer=[2])
    fallback = write_xa(tmp_path / "fov.dcm", np.zeros((8, 10), np.uint8), spacing=None, FieldOfViewDimensions=[4, 5])
    assert main(["dicom-info", str(angiograms[0][0]), str(rotational), str(fallback)]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert lines[0] == (f"{angiograms[0][0]}: XA, 1 frame, 320x320, primary 31.3 secondary -12.5 (LAO 31.3 CAU 12.5), "
                        "SID 1100 mm, SOD 760 mm, spacing 0.45 x 0.45 mm (from ImagerPixelSpacing (0018,1164))")
    assert lines[1].startswith(f"{rotational}: XA, 3 frames, 8x8, geometry varies by frame (angles from PositionerPrimaryAngle")
    assert lines[1].endswith("end-diastolic frames [1] (from RWavePointer (0028,6040))")
    assert lines[2:5] == [f"{rotational} frame {k}: primary {-10 + 5 * k:g} secondary 0 ({'RAO' if k < 2 else 'LAO'} "
                          f"{abs(-10 + 5 * k):g} CRA 0), SID 1100 mm, SOD 760 mm, spacing 0.3 x 0.3 mm" for k in range(3)]
    assert lines[5].endswith("spacing 0.5 x 0.5 mm (from FieldOfViewDimensions (0018,1149) = [4, 5] mm over 8 x 10 pixels)")
    assert captured.err == ""  # the fallback is stated in the line, not warned about


def test_dicom_info_reports_bad_files_and_goes_on(tmp_path, angiograms, capsys):
    bad = tmp_path / "bad.dcm"
    bad.write_text("text")
    assert main(["dicom-info", str(bad), str(angiograms[1][0]), "--frames"]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith(f"angiohull dicom-info: error: {bad}: is not a DICOM file")
    assert captured.out.splitlines()[1].startswith(f"{angiograms[1][0]} frame 0: primary -40 secondary 20 (RAO 40 CRA 20)")


def test_segment_a_dicom_file(tmp_path, angiograms, capsys):
    path, truth = angiograms[1]
    out = tmp_path / "mask.png"
    assert main(["segment", str(path), "-o", str(out)]) == 0
    assert dice(read_mask(out), truth) >= 0.85
    assert f"{path} frame 0 (single frame; RAO 40 CRA 20):" in capsys.readouterr().out
    assert main(["segment", str(path), "-o", str(tmp_path / "m2.npy"), "--method", "frangi", "--sigmas", "1.5,3",
                 "--min-object-px", "50"]) == 0
    assert dice(np.load(tmp_path / "m2.npy"), truth) >= 0.85


def test_segment_a_png_and_bad_requests(tmp_path, angiograms, capsys):
    png = tmp_path / "frame.png"
    image = render_angiogram(demo_phantom(), CARMS[0], 3)  # no collimator
    Image.fromarray(to_counts(image.image, bits=8)).save(png)
    assert main(["segment", str(png), "-o", str(tmp_path / "m.png"), "--no-collimator"]) == 0
    assert dice(read_mask(tmp_path / "m.png"), image.mask) >= 0.85
    assert main(["segment", str(png), "-o", str(tmp_path / "x.png"), "--frame", "1"]) == 2
    assert "--frame is only used with a DICOM file" in capsys.readouterr().err
    assert main(["segment", str(angiograms[0][0]), "-o", str(tmp_path / "x.png"), "--frame", "4"]) == 2
    assert "frame 4 does not exist; the run has 1 frame(s)" in capsys.readouterr().err
    assert main(["segment", str(angiograms[0][0]), "-o", str(tmp_path / "x.png"), "--min-object-px", "1000000"]) == 2
    assert "the segmentation found no vessel; nothing written" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
    assert main(["segment", str(png), "-o", str(tmp_path / "x.png"), "--low-threshold", "0.9"]) == 2
    assert "low_threshold must not exceed high_threshold" in capsys.readouterr().err
    tiny, flat = tmp_path / "tiny.png", tmp_path / "flat.png"
    Image.fromarray(np.full((4, 4), 90, np.uint8)).save(tiny)
    Image.fromarray(np.full((64, 64), 90, np.uint8)).save(flat)
    assert main(["segment", str(tiny), "-o", str(tmp_path / "x.png")]) == 2  # the file named, not just the rule
    assert f"{tiny}: image must be at least 8 x 8 pixels, got shape (4, 4)" in capsys.readouterr().err
    assert main(["segment", str(flat), "-o", str(tmp_path / "x.png")]) == 2  # no advice on thresholds there
    err = capsys.readouterr().err
    assert f"{flat}: the image is flat (every pixel 90): it shows no vessel to segment; nothing written" in err
    assert "--high-threshold" not in err and not (tmp_path / "x.png").exists()


def test_study_from_dicom_then_reconstruct(tmp_path, angiograms, capsys):
    study = tmp_path / "study"
    files = [str(path) for path, _ in angiograms]
    assert main(["study-from-dicom", *files, "-o", str(study), "--segment"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"view0: {files[0]} frame 0 (single frame), LAO 31.3 CAU 12.5, ") and out[0].endswith("vessel pixels")
    assert out[-1] == f"wrote {study / 'study.yaml'} (2 views)"
    assert main(["reconstruct", str(study), "-o", str(tmp_path / "out"), "--no-figure", "-q"]) == 0  # the tree method
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [v["geometry_source"] for v in report["views"]] == ["dicom", "dicom"]
    assert report["views"][0]["carm"]["clinical"] == "LAO 31.3 CAU 12.5"
    assert all(v["dice2d_reprojection"] > 70 for v in report["views"])  # two consistent synthetic views
    assert report["options"]["method"] == "tree" and report["tree_method"]["pairs"] == [["view0", "view1"],
                                                                                     ["view1", "view0"]]


def test_study_from_dicom_errors_exit_2(tmp_path, capsys):
    ct = write_xa(tmp_path / "ct.dcm", np.zeros((8, 8), np.uint8), modality="CT", sop_class="1.2.840.10008.5.1.4.1.1.2")
    assert main(["study-from-dicom", str(ct), "-o", str(tmp_path / "s")]) == 2
    assert "is not an X-ray angiogram" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["study-from-dicom", str(ct), "-o", str(tmp_path / "s"), "--frame", "0", "--all-frames"])


def test_dicom_info_on_the_real_phantom(ge_phantom_dir, capsys):
    assert main(["dicom-info", *(str(ge_phantom_dir / f"IM{i}.dcm") for i in (1, 2, 5))]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "14 frames, 512x512, primary 31.3 secondary 0.1 (LAO 31.3 CRA 0.1), SID 860 mm, SOD 720 mm, spacing 0.390625 x " \
           "0.390625 mm (from FieldOfViewDimensions (0018,1149) = [200, 200] mm over 512 x 512 pixels)" in lines[0]
    assert "12 frames, 512x512, primary -27.3 secondary -0.1 (RAO 27.3 CAU 0.1), SID 865 mm" in lines[1]
    assert "16 frames, 512x512, primary -26.5 secondary -32.7 (RAO 26.5 CAU 32.7), SID 931 mm, SOD 720 mm, spacing " \
           "0.390625 x 0.390625 mm (from ImagerPixelSpacing (0018,1164))" in lines[2]


def test_fallback_warnings_are_one_line_each_on_stderr(tmp_path, capsys):
    from angiohull.io import write_mask
    from angiohull.synthetic import demo_phantom as tree

    carm = CArmGeometry(20.0, 10.0, 1100.0, 760.0, (0.5, 0.5), (200, 200))
    write_xa(tmp_path / "fov.dcm", np.zeros((200, 200), np.uint8), primary=20.0, secondary=10.0, sid=1100.0, sod=760.0,
             spacing=None, FieldOfViewDimensions=[100, 100])
    write_mask(tmp_path / "m.png", tree().silhouette(carm))
    (tmp_path / "study.yaml").write_text("angiohull: 1\nviews:\n  - {name: a, mask: m.png, dicom: fov.dcm}\n"
                                         "  - {name: b, mask: m.png, dicom: fov.dcm}\n")
    assert main(["reconstruct", str(tmp_path), "-o", str(tmp_path / "out"), "-k", "30", "--method", "hull",
                 "--no-figure", "-q"]) == 0
    err = capsys.readouterr().err.splitlines()
    # the two views are one view twice: the views' angle has its own warning, one line too; the phantom runs
    # off this small detector, which the two-view edge warning says (one line)
    assert len(err) == 3 and err[1].startswith("angiohull: warning: the views look along nearly one line (degrees from "
                                               "it: a / b 0; under 25 for every pair)")
    assert err[2].startswith("angiohull: warning: vessel runs off the image's edge in a in ")
    assert err[:1] == [f"angiohull: warning: {tmp_path / 'fov.dcm'}: ImagerPixelSpacing (0018,1164) is missing; assumed 0.5 x 0.5 mm "
                       "from FieldOfViewDimensions (0018,1149) = [100, 100] mm over 200 x 200 pixels"]
