"""The refined preset's explanation step: phantom pieces where branches cross in projection.

Three straight tubes seen from three perpendicular C-arm views (AP, LAO 90, CRA 90), placed so
that each one, in one view, passes over the isocentre's pixel:

* a = (t, 20, t) crosses the AP view's central ray (the y axis) at (0, 20, 0);
* b = (20, s, -s) crosses the LAO 90 view's central ray (the x axis) at (20, 0, 0);
* c = (u, -u, 20) crosses the CRA 90 view's central ray (the z axis) at (0, 0, 20);

with t, s, u in [-12, 12] (the tubes do not touch: b and c would meet only at s = -20, u = 20).
The plane through the AP source and a's axis is x = z, through the LAO 90 source and b's axis
y + z = 0, through the CRA 90 source and c's axis x + y = 0. They share the line (k, -k, k), so the
visual hull holds a *phantom tube* along it, about |k| <= 12: it projects onto a's centreline in
AP, onto b's in LAO 90 and onto c's in CRA 90, i.e. onto vessel centreline in every view, and it
is 8 mm or more from every real tube. Each real tube, in contrast, has views where nothing else
lies on its pixels (a, for one: in LAO 90 and CRA 90 it projects onto the line y = 20, which no other tube follows).
"""

from dataclasses import replace

import numpy as np

from angiohull.geometry import CArmGeometry
from angiohull.reconstruction import reconstruct
from angiohull.reconstruction.refine import (REFINED, centreline_branches, clean_mask, drop_explained_pieces,
                                            refine_hull)
from angiohull.synthetic import Tube, TubePhantom

RADIUS = 1.5


def _segment(direction, through, half=12.0):
    direction = np.asarray(direction, float)
    through = np.asarray(through, float)
    return np.stack([through - half * direction, through + half * direction])


TUBES = {
    "a": _segment((1, 0, 1), (0, 20, 0)),
    "b": _segment((0, 1, -1), (20, 0, 0)),
    "c": _segment((1, -1, 0), (0, 0, 20)),
}
GHOST = np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0)  # the phantom's axis, through the origin


def _distance_to_segment(points, segment):
    start, end = segment
    axis = end - start
    t = np.clip((points - start) @ axis / (axis @ axis), 0.0, 1.0)
    return np.linalg.norm(points - (start + t[:, None] * axis), axis=1)


def _distance_to_ghost(points):
    return np.linalg.norm(points - np.outer(points @ GHOST, GHOST), axis=1)


def _three_tubes():
    phantom = TubePhantom(tuple(Tube(s, RADIUS) for s in TUBES.values()), "three tubes")
    carms = [CArmGeometry(a, b, 1200.0, 800.0, (0.35, 0.35), (512, 512)) for a, b in ((0, 0), (90, 0), (0, 90))]
    projections = [c.projection() for c in carms]
    masks = [clean_mask(phantom.silhouette(p)) for p in projections]
    carved = reconstruct(projections, masks, resolution=REFINED.resolution, centerlines=False, tree=False)
    return carved, projections, masks


def test_the_phantom_tube_where_three_branches_cross_in_projection_is_removed_and_the_tubes_kept():
    carved, projections, masks = _three_tubes()
    before, _ = refine_hull(carved.vessel_points_mm, carved.lattice, projections, masks,
                            replace(REFINED, unique_fraction=0.0))
    after, info = refine_hull(carved.vessel_points_mm, carved.lattice, projections, masks, REFINED)

    def ghost_points(points):
        far = np.min([_distance_to_segment(points, s) for s in TUBES.values()], axis=0) > 6.0
        return points[far & (_distance_to_ghost(points) < 2 * RADIUS)]

    # The oracle's phantom is there without the step (radius consistency alone keeps it: it has
    # axis points all along) ...
    assert len(ghost_points(before)) > 500
    # a tube along (1, -1, 1) as long as the hand computation says: |k| <= 12, i.e. 12 sqrt 3 mm
    # from the origin along its axis (plus the radius and a little perspective)
    extent = np.abs(ghost_points(before) @ GHOST).max()
    assert 12 * np.sqrt(3.0) - 1.0 < extent < 12 * np.sqrt(3.0) + 2 * RADIUS
    # ... and nothing of it is left with the step, nor anything else far from the real tubes.
    assert len(ghost_points(after)) == 0
    assert info["pieces_removed"] >= 1
    near_tube = np.min([_distance_to_segment(after, s) for s in TUBES.values()], axis=0)
    assert near_tube.max() <= RADIUS + (REFINED.slack_cells + 2) * carved.lattice_spacing_mm
    # Every real tube is kept whole: each sample of its axis has a kept point within its radius.
    for name, (start, end) in TUBES.items():
        samples = start + np.linspace(0.05, 0.95, 60)[:, None] * (end - start)
        gaps = [np.linalg.norm(after - p, axis=1).min() for p in samples]
        assert max(gaps) < RADIUS, name
        kept_before = (_distance_to_segment(before, (start, end)) < RADIUS).sum()
        kept_after = (_distance_to_segment(after, (start, end)) < RADIUS).sum()
        assert kept_after >= 0.98 * kept_before, name


def test_the_refined_preset_runs_the_explanation_step():
    carved, projections, masks = _three_tubes()
    refined = reconstruct(projections, masks, preset="refined", centerlines=False, tree=False).vessel_points_mm
    expected, _ = refine_hull(carved.vessel_points_mm, carved.lattice, projections, masks, REFINED)
    np.testing.assert_array_equal(refined, expected)


def test_the_most_redundant_piece_goes_first():
    # Pieces 0 and 1 are real vessels, piece 2 a phantom: in view 0 it lies on the rays of piece 0,
    # in view 1 on those of piece 1, so every one of its points has a rival in both views. Piece 0's
    # points are rivalled by the phantom in view 0 only, piece 1's in view 1 only.
    piece = np.repeat([0, 1, 2], 4)
    a, b, phantom = np.arange(0, 4), np.arange(4, 8), np.arange(8, 12)
    rivals = [
        (np.concatenate([phantom, a]), np.concatenate([np.full(4, 0), np.full(4, 2)])),
        (np.concatenate([phantom, b]), np.concatenate([np.full(4, 1), np.full(4, 2)])),
    ]
    np.testing.assert_array_equal(drop_explained_pieces(piece, rivals, 0.5), [True, True, False])
    # Once the phantom is gone, nothing rivals the real pieces: they stay even at a strict threshold.
    np.testing.assert_array_equal(drop_explained_pieces(piece, rivals, 1.0), [True, True, False])
    # 0 turns the step off.
    np.testing.assert_array_equal(drop_explained_pieces(piece, rivals, 0.0), [True, True, True])
    # A piece rivalled on half of its points in its best view is not "mostly explained".
    half = [(np.array([8, 9]), np.array([0, 0])), (np.array([10, 11]), np.array([1, 1]))]
    np.testing.assert_array_equal(drop_explained_pieces(piece, half, 0.5), [True, True, True])


def test_centreline_branches_cut_at_junctions():
    plus = np.zeros((11, 11), dtype=bool)
    plus[5, 1:10] = True
    plus[1:10, 5] = True
    labels = centreline_branches(plus)
    arms = [labels[5, 2], labels[5, 8], labels[2, 5], labels[8, 5]]
    assert len(set(arms)) == 4 and 0 not in arms
    assert labels[5, 5] not in arms and labels[5, 5] > 0
    assert (labels > 0).sum() == plus.sum() and (labels[~plus] == 0).all()
