"""The input checks of reconstruct (angiohull.reconstruction.checks): hand-worked masks and views
whose problem is known, and a clean case that gives no warning (pytest turns any warning into an
error here)."""

import re
import warnings

import numpy as np
import pytest

from angiohull import CArmGeometry, parse_clinical_angles, reconstruct
from angiohull.errors import AgreementWarning, InputWarning
from angiohull.reconstruction.checks import edge_runs, edge_warning, input_warnings
from angiohull.synthetic.phantom import Tube, TubePhantom

TWO = ("RAO 30 CAU 25", "LAO 45 CRA 20")


def _views(angles=TWO):
    return [CArmGeometry(*parse_clinical_angles(v), 1200.0, 800.0, (0.35, 0.35), (512, 512)).projection()
            for v in angles]


def _y_masks(projections, shift=(0.0, 0.0, 0.0)):
    """A Y of tubes around the isocentre (inside every image), moved by ``shift`` mm."""
    lines = [((-30, 0, 0), (0, 0, 0), 2.0), ((0, 0, 0), (25, 15, 5), 1.4), ((0, 0, 0), (20, -20, -5), 1.1)]
    tubes = tuple(Tube(np.linspace(np.add(a, shift), np.add(b, shift), 60), r) for a, b, r in lines)
    return [TubePhantom(tubes, "y").silhouette(p) for p in projections]


def test_edge_runs_are_the_runs_of_vessel_along_each_side_by_hand():
    mask = np.zeros((10, 12), bool)
    mask[0, 2:6] = True      # top, columns 2-5: middle u 3.5, 4 px
    mask[9, 11] = True       # bottom-right corner pixel: runs of 1 on the bottom and the right, too short
    mask[3:8, 0] = True      # left, rows 3-7: middle v 5, 5 px
    mask[4:7, 11] = True     # right, rows 4-6: 3 px (the shortest counted)
    mask[5, 5] = True        # inside: not on an edge
    assert edge_runs(mask) == [(3.5, 0.0, 4), (0.0, 5.0, 5), (11.0, 5.0, 3)]
    assert edge_runs(mask, min_run_px=4) == [(3.5, 0.0, 4), (0.0, 5.0, 5)]
    assert edge_runs(np.zeros((5, 5), bool)) == []
    full = np.ones((4, 6), bool)  # every side one run, the corners counted on both sides they lie on
    assert edge_runs(full) == [(2.5, 0.0, 6), (2.5, 3.0, 6), (0.0, 1.5, 4), (5.0, 1.5, 4)]


def test_the_edge_warning_is_for_two_views_and_names_each_cut_view_and_its_places():
    inside = np.zeros((20, 20), bool)
    inside[5:15, 9:12] = True
    cut = inside.copy()
    cut[0:15, 9:12] = True  # reaches the top edge: columns 9-11, middle u 10
    assert edge_warning([inside, inside], ["a", "b"]) is None
    assert edge_warning([inside, cut, inside], ["a", "b", "c"]) is None  # three views: the agreement check's
    message = edge_warning([inside, cut], ["a", "b"])
    assert message.startswith("vessel runs off the image's edge in b in 1 place (u, v px: (10, 0); 3 pixels): beyond "
                              "an edge it is seen by the other view alone")
    many = cut.copy()
    many[19, ::3] = True  # seven single pixels: none a run of 3
    many[:, 0] = True
    many[:, 19] = True
    assert "b in 3 places (u, v px: (10, 0), (0, 10), (19, 10); 43 pixels)" in edge_warning([inside, many], ["a", "b"])


def test_reconstruct_gives_no_warning_for_views_that_agree_and_records_the_time_of_the_checks():
    projections = _views()
    result = reconstruct(projections, _y_masks(projections), method="hull", resolution=60)  # warnings are errors
    assert 0 < result.timings_s["checks"] < 5.0
    assert result.timings_s["total"] == pytest.approx(sum(v for k, v in result.timings_s.items()
                                                          if k not in ("reconstruction", "total", "checks")))
    quiet = reconstruct(projections, _y_masks(projections), method="hull", resolution=60, warn=False)
    assert "checks" not in quiet.timings_s
    np.testing.assert_array_equal(quiet.vessel_points_mm, result.vessel_points_mm)


def test_reconstruct_warns_for_views_along_one_line_a_mostly_vessel_mask_and_one_view():
    projections = _views(("RAO 30 CAU 25", "RAO 40 CAU 25"))  # 10 degrees apart (the check: 25)
    masks = _y_masks(projections)
    with pytest.warns(InputWarning, match=r"the views look along nearly one line \(degrees from it: "
                                          r"view0 / view1 9;") as caught:
        reconstruct(projections, masks, method="hull", resolution=40)
    assert len(caught) == 1 and caught[0].filename == __file__  # said where reconstruct was called
    inverted = [~masks[0], masks[1]]
    with pytest.warns(UserWarning) as caught:
        reconstruct(projections, inverted, method="hull", resolution=40, allow_empty=True)
    # in the checks' order: the mask, the views' angle (as above); not the views' agreement or the images' edges,
    # which the inverted mask's own warning explains
    assert [w.category for w in caught] == [InputWarning, InputWarning]
    said = [str(w.message) for w in caught]
    share = 100.0 * np.count_nonzero(inverted[0]) / inverted[0].size
    assert said[0] == (f"view 'view0': {share:.0f} % of the pixels are vessel; vessels cover a few percent of an "
                       f"angiogram, so the mask is probably inverted (vessel must be nonzero) or not a vessel mask, and "
                       f"the view removes almost nothing from the hull")
    with pytest.warns(InputWarning, match="^one view: the visual hull is the view's whole cone of rays"):
        reconstruct(projections[:1], masks[:1], method="hull", resolution=40)


def test_reconstruct_warns_when_a_view_disagrees_and_names_it():
    """Three views, the third's mask moved 20 pixels across (its geometry off by 20 pixels): the hull
    of all views covers far less of its mask than of the others'; 1 pixel is within the check."""
    projections = _views(("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30"))
    masks = _y_masks(projections)
    assert input_warnings(projections, masks[:2] + [np.roll(masks[2], 1, axis=1)], ["a", "b", "c"]) == []
    moved = masks[:2] + [np.roll(masks[2], 20, axis=1)]
    [(category, message)] = input_warnings(projections, moved, ["a", "b", "c"])
    assert category is AgreementWarning and message.startswith("the views disagree (")
    coverage = {name: float(value) / 100 for name, value in re.findall(r"(\w) (\d+) %", message.split(":")[1])}
    assert coverage["c"] < 0.95 and coverage["c"] == min(coverage.values())
    with pytest.warns(AgreementWarning, match=r"the views disagree \(.*view2.*\): the hull of all views covers .* of "
                                              r"each mask \(below 95 % means disagreement\); the geometry may be off "
                                              r"by pixels \(try the command line's --calibrate, "
                                              r"angiohull.workflow.calibrate_study in Python\)"):
        reconstruct(projections, moved, method="hull", resolution=60, allow_empty=True)


def test_the_tree_method_refuses_one_view_without_a_warning_first():
    projections = _views()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(Exception, match="two views or more"):
            reconstruct(projections[:1], _y_masks(projections)[:1], method="tree")


def test_two_views_whose_geometry_is_off_across_the_epipolar_lines_are_warned_about():
    """View 1's mask moved 20 px along u: the two masks' epipolar planes agree again with view 1
    moved back by the shift's component across its epipolar lines (worked out here from the
    epipole: the lines run through it), to about a pixel; the right geometry asks for under 0.5 px."""
    from angiohull.reconstruction.checks import (EPIPOLAR_WARN_PX, epipolar_check_applies, epipolar_offset_px,
                                                 epipolar_warning)

    projections = _views()
    masks = _y_masks(projections)
    assert epipolar_offset_px(projections, masks) < 0.5
    moved = [masks[0], np.roll(masks[1], 20, axis=1)]
    epipole = projections[1].project(projections[0].camera_centre_mm[None])[0]
    centre = projections[1].project(np.zeros((1, 3)))[0]  # the Y lies around the isocentre
    along = (centre - epipole) / np.linalg.norm(centre - epipole)
    across = abs(20.0 * along[1])  # |(20, 0) . normal|, the normal (-along_v, along_u)
    offset = epipolar_offset_px(projections, moved)
    assert across > 2 * EPIPOLAR_WARN_PX and abs(offset - across) <= 1.0
    [(category, message)] = input_warnings(projections, moved, ["a", "b"])
    assert category is AgreementWarning
    assert message.startswith(f"the two views' masks cover the same epipolar planes only with b moved by {offset:.1f} "
                              f"px across its epipolar lines")
    assert epipolar_offset_px(projections + projections[:1], masks + masks[:1]) == 0.0  # two views only
    # not where a mask is mostly vessel; where one runs off its image's edge (its vessel beyond moves the
    # estimate), from 3 px on
    assert epipolar_check_applies(moved) and not epipolar_check_applies([moved[0], ~moved[1]])
    cut = np.roll(masks[1], 4, axis=1)  # moved 4 px: about 1.9 px across, under both bars
    cut[:4, 0] = True  # a vessel leaving the image: a run of 4 on its left edge
    assert epipolar_check_applies([masks[0], cut])
    assert [c for c, _ in input_warnings(projections, [masks[0], cut], ["a", "b"])] == [InputWarning]  # the edge's
    cut = moved[1].copy()
    cut[:4, 0] = True
    said = [m for c, m in input_warnings(projections, [moved[0], cut], ["a", "b"]) if c is AgreementWarning]
    assert len(said) == 1 and "(up to 2.2 px on generated vessels that run off an image's edge whose" in said[0]
    assert epipolar_warning(2.5, ["a", "b"]) is not None and epipolar_warning(2.5, ["a", "b"], cut=True) is None



def test_the_command_line_gives_the_epipolar_warning_and_records_the_offset(tmp_path, capsys):
    import json

    from angiohull.cli import main
    from angiohull.study import View, save_study

    carms = [CArmGeometry(*parse_clinical_angles(v), 1200.0, 800.0, (0.35, 0.35), (512, 512)) for v in TWO]
    masks = _y_masks([c.projection() for c in carms])
    for shift, warned in ((0, False), (20, True)):
        views = [View.from_carm("a", masks[0], carms[0]), View.from_carm("b", np.roll(masks[1], shift, axis=1),
                                                                         carms[1])]
        study = save_study(tmp_path / f"study{shift}", views)
        out = tmp_path / f"out{shift}"
        assert main(["reconstruct", str(study), "-o", str(out), "--method", "hull", "-k", "40", "--no-figure",
                     "--no-viewer", "-q"]) == 0
        lines = [line for line in capsys.readouterr().err.splitlines() if "epipolar planes" in line]
        offset = json.loads((out / "report.json").read_text())["view_agreement"]["epipolar_offset_px"]
        assert (offset > 9.0) == warned and len(lines) == int(warned)
        if warned:
            assert lines[0].startswith(f"angiohull: warning: the two views' masks cover the same epipolar planes only "
                                       f"with b moved by {offset:.1f} px") and "try --calibrate" in lines[0]


def test_calibrating_two_views_notes_that_their_position_stays_open(tmp_path, capsys):
    from angiohull.cli import main
    from angiohull.study import View, save_study

    carms = [CArmGeometry(*parse_clinical_angles(v), 1200.0, 800.0, (0.35, 0.35), (512, 512)) for v in TWO]
    masks = _y_masks([c.projection() for c in carms])
    views = [View.from_carm("a", masks[0], carms[0]), View.from_carm("b", np.roll(masks[1], 20, axis=1), carms[1])]
    study = save_study(tmp_path / "study", views)
    assert main(["reconstruct", str(study), "-o", str(tmp_path / "out"), "--method", "hull", "-k", "40",
                 "--calibrate", "--no-figure", "--no-viewer"]) == 0
    err = capsys.readouterr().err
    assert "note: two views determine only the shift across the epipolar lines" in err
    assert "the two views' masks cover the same epipolar planes" not in err  # the calibration applied it



def test_reconstruct_with_check_view_order_warns_of_masks_given_for_the_wrong_views(tmp_path, capsys):
    """A study whose two masks are each given for the other view (generated RCA seed 7021, the two
    clinical views, exact masks; no other check warns of it): --check-view-order warns and writes
    both agreements to report.json; the study the right way round gets no warning; with the hull
    the flag is refused (the check reads the tree method's trees)."""
    import json

    from angiohull.cli import main
    from angiohull.reconstruction.checks import VIEW_ORDER_MARGIN
    from angiohull.study import View, save_study
    from angiohull.synthetic import SynthOptions, make_case

    case = make_case(SynthOptions(kind="rca", tortuosity="simple", views=TWO, seed=7021))
    names = [v.carm.clinical_name().replace(" ", "") for v in case.views]
    reports = {}
    for label, masks in (("right", [v.mask for v in case.views]), ("swapped", [v.mask for v in case.views][::-1])):
        study = save_study(tmp_path / label, [View.from_carm(n, m, v.carm) for n, m, v in zip(names, masks, case.views)])
        out = tmp_path / f"out_{label}"
        assert main(["reconstruct", str(study), "-o", str(out), "--check-view-order", "--no-figure", "--no-viewer",
                     "--no-centerlines", "-q"]) == 0
        warned = [line for line in capsys.readouterr().err.splitlines() if line.startswith("angiohull: warning:")]
        reports[label] = json.loads((out / "report.json").read_text())["view_order"]
        if label == "right":
            assert warned == []
        else:
            assert len(warned) == 1 and "the masks agree better with the views the other way round" in warned[0]
            assert f"{names[0]}'s and {names[1]}'s masks swapped" in warned[0]
    assert not reports["right"]["warned"] and reports["swapped"]["warned"]
    assert reports["right"]["warn_above"] == VIEW_ORDER_MARGIN
    assert reports["right"]["agreement_given"] == reports["swapped"]["agreement_swapped"]
    assert reports["right"]["agreement_swapped"] == reports["swapped"]["agreement_given"]
    assert main(["reconstruct", str(tmp_path / "right"), "-o", str(tmp_path / "hull"), "--check-view-order",
                 "--method", "hull"]) == 2
    assert "--check-view-order" in capsys.readouterr().err
