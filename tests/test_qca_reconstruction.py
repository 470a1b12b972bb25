"""The quantitative analysis of a reconstruction against the generator's truth, end to end.

One generated right coronary tree with two stenoses (seed 15: RCA 57.8 % cosine, acute marginal
71.3 % cosine), three clinical views, exact masks, the refined preset: every true stenosis is found
within 5 mm of its true point of least radius, and measured within the bars of issue 22 (%DS within
5 points, MLD within 0.15 mm, reference diameter within 0.1 mm, lesion length within 1.5 mm), with
no other lesion reported. The truth comes from the generator's own radii and taper, the lesion
length from the window's closed form (:func:`angiohull.qca.window_lesion_length_mm`).
"""

from __future__ import annotations

import numpy as np
import pytest

from angiohull.qca import QcaSettings, analyse_tree, window_lesion_length_mm
from angiohull.reconstruction import reconstruct
from angiohull.synthetic import SynthOptions, make_case


@pytest.fixture(scope="module")
def analysed():
    case = make_case(SynthOptions(kind="rca", seed=15))
    result = reconstruct([v.carm.projection() for v in case.views], [v.mask for v in case.views], preset="refined")
    return case, analyse_tree(result.tree, [v.carm.projection() for v in case.views], [v.name for v in case.views],
                              QcaSettings(lesion_views=False))


def _true_lesions(case):
    out = []
    for b in case.tree.branches:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(b.centerline_mm, axis=0), axis=1))])
        for s in b.stenoses:
            inside = np.flatnonzero(np.abs(arc - s.centre_mm) <= 0.5 * s.length_mm)
            k = int(inside[np.argmin(b.radius_mm[inside])])
            mld, ref = 2 * float(b.radius_mm[k]), 2 * float(b.reference_radius_mm[k])
            out.append((b.centerline_mm[k], mld, ref, 100 * (1 - mld / ref), window_lesion_length_mm(s.profile, s.length_mm)))
    return out


def test_every_stenosis_found_and_measured_within_the_bars(analysed):
    case, qca = analysed
    truth = _true_lesions(case)
    assert len(truth) == 2
    found = list(qca.lesions)
    assert len(found) == len(truth)  # and no false lesion
    for point, mld, ref, ds, length in truth:
        distance = [np.linalg.norm(np.asarray(les.mld_point_mm) - point) for les in found]
        les = found[int(np.argmin(distance))]
        assert min(distance) <= 5.0
        assert abs(les.diameter_stenosis_pct - ds) <= 5.0
        assert abs(les.mld_mm - mld) <= 0.15
        assert abs(les.reference_diameter_mm - ref) <= 0.1
        assert abs(les.length_mm - length) <= 1.5


def test_each_view_reports_every_branch(analysed):
    case, qca = analysed
    assert [v["view"] for v in qca.views] == [v.name for v in case.views]
    for view in qca.views:
        assert len(view["branches"]) == qca.tree.n_branches
        for b in view["branches"]:
            assert 0.0 < b["foreshortening"] <= 1.0 and 0.0 <= b["overlapped_share"] <= 1.0
