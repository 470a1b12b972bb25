"""Parity with the authors' own code on their 48 peer-synthetic studies (issue: core, must show).

``angiohull evaluate --method hull --engine kdtree --resolution 100 --json`` must reproduce the authors' scores
case by case: Dice3D and IoU3D within 0.05 points, Chamfer within 0.005 mm, the paper-protocol
Dice2D within 0.1 points.
"""

import csv
import json

import numpy as np
import pytest

from angiohull.cli import main


def _cases(folder):
    with open(folder / "peer_results.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def _kdtree_reproduces_the_authors_scores(folder, capsys, every: int):
    rows = _cases(folder)
    assert len(rows) == 48
    failures = []
    for row in rows[::every]:
        code = main(["evaluate", str(folder / row["case"]), "--method", "hull", "--engine", "kdtree", "--resolution",
                     "100", "--json"])
        out = capsys.readouterr().out
        assert code == 0
        scores = json.loads(out)
        checks = [("dice3d", "peer_dice3d", 0.05), ("iou3d", "peer_iou3d", 0.05),
                  ("chamfer_mm", "peer_chamfer_mm", 0.005), ("dice2d_paper", "peer_dice2d", 0.1)]
        for ours, theirs, tolerance in checks:
            if abs(scores[ours] - float(row[theirs])) > tolerance:
                failures.append(f"{row['case']}: {ours} {scores[ours]:.4f} vs {theirs} {float(row[theirs]):.4f}")
    assert not failures, "\n".join(failures)


def test_kdtree_reproduces_the_authors_scores_on_a_quarter_of_the_peer_studies(peer_synthetic_dir, capsys):
    """Every fourth study: 000 and 004 of each view set and tortuosity level (12 of 48, about 10 s);
    all 48 behind the slow marker (about 40 s on an idle 2-core machine: the suite's 5-minute budget).
    By default every study's hull still meets theirs through its centerline points (the test below)."""
    _kdtree_reproduces_the_authors_scores(peer_synthetic_dir, capsys, 4)


@pytest.mark.slow
def test_kdtree_reproduces_the_authors_scores_on_every_peer_study(peer_synthetic_dir, capsys):
    _kdtree_reproduces_the_authors_scores(peer_synthetic_dir, capsys, 1)


def test_set_means_match_the_readme_of_the_benchmark(peer_synthetic_dir):
    rows = _cases(peer_synthetic_dir)
    for angleset, expected in (("perpendicular", 78.4), ("clinical", 76.2)):
        values = [float(r["peer_dice3d"]) for r in rows if r["angleset"] == angleset]
        assert sum(values) / len(values) == pytest.approx(expected, abs=0.05)


def _some_tie_resolution_gives(target, points, projections, masks, max_ties=12):
    """Whether resolving the centerline step's ties (candidates equally near a skeleton pixel, to
    1e-9 px) in some way gives the distinct point set ``target``: every combination of choices, view
    after view (a search over at most 2**max_ties branches per view)."""
    import itertools

    from scipy.spatial import cKDTree

    from angiohull.reconstruction import skeletonise

    pixels_per_view = []
    for mask in masks:
        rows, cols = np.nonzero(skeletonise(mask))
        pixels_per_view.append(np.stack([cols, rows], axis=1).astype(float))

    def search(view, candidates):
        if view == len(masks):
            return {tuple(p) for p in np.round(candidates, 6)} == target
        pixels = pixels_per_view[view]
        tree = cKDTree(projections[view].project(candidates))
        distance, nearest = tree.query(pixels)
        options = [sorted(tree.query_ball_point(pixels[i], distance[i] + 1e-9)) for i in range(len(pixels))]
        tied = [i for i, o in enumerate(options) if len(o) > 1]
        if len(tied) > max_ties:
            return False
        for choice in itertools.product(*(options[i] for i in tied)):
            picked = nearest.copy()
            picked[tied] = choice
            if search(view + 1, candidates[np.unique(picked)]):
                return True
        return False

    return search(0, points)


def test_centerline_step_reproduces_the_authors_centerlines(peer_synthetic_dir, kernel_backend):
    """Skeletons are theirs pixel for pixel (test_thinning); the distinct centerline points are their
    set on 46 of 48 studies; on the other two (perpendicular views, where lattice points mirror each
    other about a view's central ray) every difference is a tie that their k-d tree resolved the other
    way. Their duplicate-keeping output (one row per skeleton pixel of the last view) is reproduced
    row for row on the same 46."""
    from angiohull.reconstruction import extract_centerlines, reconstruct
    from angiohull.study import load_study

    same_set, same_rows, ties_only = [], [], []
    for folder in sorted(p for p in peer_synthetic_dir.iterdir() if p.is_dir()):
        theirs = np.load(folder / "peer_reconstruction.npz", allow_pickle=False)
        study = load_study(folder)
        result = reconstruct(study.projections, study.masks, resolution=100, tree=False)
        ours_set = {tuple(p) for p in np.round(result.centerline_points_mm, 6)}
        their_set = {tuple(p) for p in np.round(theirs["centerlines_mm"], 6)}
        rows = extract_centerlines(result.vessel_points_mm, study.projections, study.masks, keep_duplicates=True)
        if ours_set == their_set:
            same_set.append(folder.name)
            if rows.shape == theirs["centerlines_mm"].shape and np.allclose(rows, theirs["centerlines_mm"]):
                same_rows.append(folder.name)
        else:
            if _some_tie_resolution_gives(their_set, result.vessel_points_mm, study.projections, study.masks):
                ties_only.append(folder.name)
    assert len(same_set) == 46, sorted(same_set)
    assert same_rows == same_set
    assert sorted(ties_only) == ["perpendicular_simple_002", "perpendicular_simple_006"]
