"""What a reconstruction's inputs say about its result before it runs (arrays and projections in,
warning texts out): one view, views that look along nearly one line, views that disagree, masks
that are mostly vessel, and, with two views, masks whose epipolar planes disagree (a geometry off
by pixels, which the hull's agreement hardly sees with two views) and vessel cut off by an image's
edge.

Each check returns the text of its warning, or None when it does not apply. :func:`input_warnings`
runs them all; :func:`angiohull.reconstruction.reconstruct` gives them as Python warnings
(``warn=True``, its default) and the command line as ``angiohull: warning:`` lines.
"""

from __future__ import annotations

import itertools
from typing import Sequence

import numpy as np

from .. import _validation as _v
from ..errors import AgreementWarning, InputWarning
from ..geometry import Projection, degrees_from_one_line
from .calibration import AGREEMENT_MIN_COVERAGE, view_coverage
from .epipolar import two_view_shift

__all__ = ["MIN_VIEW_SEPARATION_DEG", "EDGE_MIN_RUN_PX", "EPIPOLAR_WARN_PX", "EPIPOLAR_WARN_CUT_PX", "view_separation_deg",
           "view_angle_warning", "one_view_warning", "agreement_warning", "epipolar_offset_px", "epipolar_warning",
           "epipolar_check_applies", "vessel_share_warning", "edge_runs", "edge_pixels", "edge_warning",
           "VIEW_ORDER_MARGIN", "view_order_warning", "input_warnings"]

MIN_VIEW_SEPARATION_DEG = 25.0
"""Views whose central rays are closer than this to parallel (or to opposite) give a warning."""

EPIPOLAR_WARN_PX = 2.0
"""Two views whose masks agree best with one moved this far or more across its epipolar lines
(pixels) give a warning: the geometry is probably off (the estimate is 0.0-0.4 px on generated
trees whose geometry is right, exact or segmented masks; an image moved by d px reads as the part of
d across the epipolar lines, about half of it for the clinical pair RAO 30 CAU 25 / LAO 45 CRA 20)."""

EPIPOLAR_WARN_CUT_PX = 3.0
"""The bar of :data:`EPIPOLAR_WARN_PX` where a mask runs off its image's edge: the vessel beyond the
edge covers epipolar planes the other mask does not, which moves the estimate with the geometry
right (a lone vessel leaving one image: 2.2 px; six generated trees with up to half of one view's
centerline off its detector: 0.05-1.1 px)."""

_EPIPOLAR_MIN_DEG = 5.0  # views nearer one line than this: their epipolar planes say nothing (the tree method's)

EDGE_MIN_RUN_PX = 3
"""A run of at least this many vessel pixels along an image's border is a vessel cut off by the edge
(shorter runs are a vessel's rim grazing it)."""

_CALIBRATE = "the command line's --calibrate, angiohull.workflow.calibrate_study in Python"


def view_separation_deg(projections: Sequence[Projection], names: Sequence[str]) -> dict[str, float]:
    """Per pair of views ("a / b"), how far their central rays are from lying along one line:
    the angle between them, or 180 less it where that is smaller (degrees, 0-90)."""
    out = {}
    for i, j in itertools.combinations(range(len(projections)), 2):
        out[f"{names[i]} / {names[j]}"] = round(degrees_from_one_line(projections[i], projections[j]), 2)
    return out


def view_angle_warning(separation_deg: dict[str, float]) -> str | None:
    """The warning to give when no pair of views is MIN_VIEW_SEPARATION_DEG apart (None when one is,
    or with a single view)."""
    if not separation_deg or max(separation_deg.values()) >= MIN_VIEW_SEPARATION_DEG:
        return None
    pairs = list(separation_deg.items())
    listed = ", ".join(f"{pair} {value:.0f}" for pair, value in pairs[:6])
    listed += f" and {len(pairs) - 6} more pairs" if len(pairs) > 6 else ""
    return (f"the views look along nearly one line (degrees from it: {listed}; under "
            f"{MIN_VIEW_SEPARATION_DEG:.0f} for every pair): the depth along it is poorly determined, and the result "
            f"with it (docs/tree-method.md measures how much); use views 30 degrees apart or more, and not nearly "
            f"opposite (report.json: view_separation_deg)")


def one_view_warning(n_views: int) -> str | None:
    """The warning to give for a single view (None otherwise): its visual hull is its whole cone of
    rays, so the points say where the vessels may lie along each ray, not where they are."""
    if n_views != 1:
        return None
    return ("one view: the visual hull is the view's whole cone of rays through the mask, which holds no depth "
            "(the points say where along each ray a vessel may lie, not where it is; no vessel tree is built); "
            "reconstruct from two views or more, 30 degrees apart or more")


def edge_runs(mask: np.ndarray, min_run_px: int = EDGE_MIN_RUN_PX) -> list[tuple[float, float, int]]:
    """The places where the mask's vessel meets its image's border: per run of at least
    ``min_run_px`` vessel pixels along one side, ``(u, v, length)``, the run's middle in pixel
    coordinates (u column, v row) and its length in pixels; in the order top, bottom, left, right."""
    mask = np.asarray(mask, dtype=bool)
    rows, cols = mask.shape
    sides = ((mask[0, :], lambda i: (i, 0.0)), (mask[-1, :], lambda i: (i, rows - 1.0)),
             (mask[:, 0], lambda i: (0.0, i)), (mask[:, -1], lambda i: (cols - 1.0, i)))
    runs = []
    for line, place in sides:
        edges = np.flatnonzero(np.diff(np.concatenate(([0], line.astype(np.int8), [0]))))
        for first, end in zip(edges[::2], edges[1::2]):
            if end - first >= min_run_px:
                runs.append((*place((first + end - 1) / 2.0), int(end - first)))
    return runs


def edge_pixels(masks: Sequence[np.ndarray], names: Sequence[str]) -> dict[str, int]:
    """Per view name, its mask's vessel pixels in runs along its image's border (:func:`edge_runs`;
    0 for a mask that is mostly vessel, which has a warning of its own)."""
    return {name: 0 if _v.vessel_share_problem(mask) else sum(n for _, _, n in edge_runs(mask))
            for mask, name in zip(masks, names)}


def edge_warning(masks: Sequence[np.ndarray], names: Sequence[str]) -> str | None:
    """With two views, the warning to give when a view's vessel is cut off by its image's edge
    (None otherwise): the vessel beyond the edge is seen by the other view alone, which cannot place
    it in depth; the hull carves it away, and the tree method may pair the other view's part of it
    with another vessel (a branch where there is none). With three views or more the hull keeps
    what every view sees and the agreement check measures what is lost."""
    if len(masks) != 2:
        return None
    cut = []
    for mask, name in zip(masks, names):
        if _v.vessel_share_problem(mask):  # a mask that is mostly vessel has its own warning
            continue
        runs = edge_runs(mask)
        if runs:
            places = ", ".join(f"({u:.0f}, {v:.0f})" for u, v, _ in runs[:4])
            places += f" and {len(runs) - 4} more" if len(runs) > 4 else ""
            cut.append(f"{name} in {len(runs)} place{'s' if len(runs) > 1 else ''} "
                       f"(u, v px: {places}; {sum(n for _, _, n in runs)} pixels)")
    if not cut:
        return None
    return (f"vessel runs off the image's edge in {'; '.join(cut)}: beyond an edge it is seen by the other view "
            f"alone, which cannot place it in depth; the reconstruction leaves it out, and the tree method may pair "
            f"the other view's part of it with another vessel (a branch where there is none): check the tree near "
            f"those places, or add a view that shows them")


def epipolar_offset_px(projections: Sequence[Projection], masks: Sequence[np.ndarray]) -> float:
    """With two views, how far (pixels) view 1's image must move across its epipolar lines for the
    two masks to cover the same epipolar planes (:func:`.epipolar.two_view_shift`, the two-view
    calibration's estimate; 0.0-0.4 px on generated trees with exact or segmented masks); 0.0 for
    other numbers of views, an empty mask, or views within 5 degrees of one line (the angle's own
    warning is given there)."""
    if len(masks) != 2 or not all(np.any(m) for m in masks):
        return 0.0
    if degrees_from_one_line(*projections) < _EPIPOLAR_MIN_DEG:  # no baseline to turn planes about
        return 0.0
    return float(np.hypot(*two_view_shift(*projections, *masks)))


def epipolar_check_applies(masks: Sequence[np.ndarray]) -> bool:
    """Whether :func:`epipolar_warning` reads :func:`epipolar_offset_px` on these masks: two views,
    neither mostly vessel (its own warning explains it)."""
    return len(masks) == 2 and not any(_v.vessel_share_problem(m) for m in masks)


def epipolar_warning(offset_px: float, names: Sequence[str], *, calibrate: str = "--calibrate",
                     cut: bool = False) -> str | None:
    """The warning to give when two views' masks agree best with one of them moved by
    :data:`EPIPOLAR_WARN_PX` or more across its epipolar lines, :data:`EPIPOLAR_WARN_CUT_PX` where
    ``cut`` (a mask runs off its image's edge), None otherwise."""
    bar = EPIPOLAR_WARN_CUT_PX if cut else EPIPOLAR_WARN_PX
    if len(names) != 2 or offset_px < bar:
        return None
    right = ("up to 2.2 px on generated vessels that run off an image's edge" if cut else
             "0.0-0.4 px on generated trees")
    return (f"the two views' masks cover the same epipolar planes only with {names[1]} moved by {offset_px:.1f} px "
            f"across its epipolar lines ({right} whose geometry is right): the geometry is "
            f"probably off by pixels (or the masks do not show the same vessels, or one is mirrored), which moves the "
            f"tree's points and can pair the wrong vessels (generated trees, "
            f"one view moved 20 px, 9 px of it across: the tree's shape 1.1-2.7 mm off); try {calibrate}, which "
            f"corrects the shift across the epipolar lines (the shape comes back to 0.3-1.3 mm there; the rest of the "
            f"shift moves the whole object by millimetres, which two views cannot tell)")


def agreement_warning(coverage: dict[str, float], *, calibrated: bool, calibrate: str = "--calibrate",
                      edges: dict[str, int] | None = None) -> str | None:
    """The warning to give when some view's coverage is below AGREEMENT_MIN_COVERAGE (None if none).
    ``calibrate`` names the calibration to try; ``edges`` (view name -> vessel pixels on its image's
    border), where given, names the views whose image cuts off vessel (a cause of disagreement
    that no calibration corrects)."""
    poor = [name for name, value in coverage.items() if value < AGREEMENT_MIN_COVERAGE]
    if not poor or not any(coverage.values()):  # none, or an empty hull, which the reconstruction reports itself
        return None
    listed = ", ".join(f"{name} {100 * value:.0f} %" for name, value in coverage.items())
    which = ", ".join(poor)
    cut = [f"{name} ({count} pixels)" for name, count in (edges or {}).items() if count]
    edge_note = (f"; vessel runs off the image's edge in {', '.join(cut)}: what another view shows beyond it is "
                 f"lost" if cut else "")
    if calibrated:
        return (f"the views still disagree after calibration ({which}): the hull of all views covers {listed} of each "
                f"mask (below {100 * AGREEMENT_MIN_COVERAGE:.0f} % means disagreement){edge_note}; the result is "
                f"unreliable: check that the masks show the same vessels, that no view's image cuts off vessel the "
                f"others show (it is lost), and the geometry (report.json: calibration)")
    return (f"the views disagree ({which}): the hull of all views covers {listed} of each mask (below "
            f"{100 * AGREEMENT_MIN_COVERAGE:.0f} % means disagreement){edge_note}; the geometry may be off by pixels "
            f"(try {calibrate}), or the masks may not show the same vessels")


def vessel_share_warning(mask: np.ndarray, where: str) -> str | None:
    """The warning to give for a mask whose vessel covers more than half its pixels (probably
    inverted; :data:`angiohull.study.MAX_VESSEL_SHARE`), None otherwise; ``where`` says which mask."""
    problem = _v.vessel_share_problem(mask)
    return f"{where}: {problem}" if problem else None


VIEW_ORDER_MARGIN = 0.005
""":func:`view_order_warning` warns where the masks swapped between the views agree better than as
given by more than this (mean Dice). On the 180 two-view cases of benchmarks/view_order.py (30 + 30
generated trees; the clinical pair with exact masks and segmented angiograms, random pairs;
2026-12-07) the right way round agreed better by -0.012 to +0.43 (median +0.021): with this
margin 3 of the 180 would warn the right way round, and 166 of 180 swaps are caught (170 with the
input checks, which alone warn of 65); with no margin 7 and 173, with 0.01 1 and 138. On 180 cases
of 60 other trees (seeds 7200-7229, 8200-8229): none, 167 and 172 (docs/results/view-order.md)."""


def view_order_warning(given: float, swapped: float | None, names: Sequence[str],
                       margin: float = VIEW_ORDER_MARGIN) -> str | None:
    """The warning to give when the tree method's trees agree better with two views' masks swapped
    between the views than as given, by more than ``margin``
    (:func:`angiohull.reconstruction.view_order_agreement`; mean Dice of the trees' silhouettes and
    the masks), None otherwise (or where no tree could be built the other way round)."""
    if swapped is None or len(names) != 2 or swapped - given <= margin:
        return None
    return (f"the masks agree better with the views the other way round: the tree method's trees explain them with "
            f"mean Dice {swapped:.3f} with {names[0]}'s and {names[1]}'s masks swapped, {given:.3f} as given; is each "
            f"mask the image of its own view? (the other checks catch few swaps, since two views' masks of one tree "
            f"cover nearly the same epipolar planes either way round; of 360 generated two-view cases given the "
            f"right way round, 3 agreed better swapped by more than 0.005, by at most 0.012)")


def input_warnings(projections: Sequence[Projection], masks: Sequence[np.ndarray], names: Sequence[str], *,
                   threshold_px: float = 1.0) -> list[tuple[type[Warning], str]]:
    """Every check of this module on checked inputs: ``(category, text)`` per warning to give, in
    the order masks, views (one view, or their angles), agreement (with two views, of the epipolar
    planes too; not where a mask is mostly vessel: its hull fills the cube, 10 s and more), edges.
    The agreement check carves the paper's hull of all views (K = 256), the epipolar one bins every
    mask pixel's plane: together 0.08-0.13 s for two 512 x 512 views
    (12 generated trees, 2026-12-07, this 2-core machine)."""
    found: list[tuple[type[Warning], str]] = []
    for mask, name in zip(masks, names):
        message = vessel_share_warning(mask, f"view {name!r}")
        if message:
            found.append((InputWarning, message))
    mostly_vessel = bool(found)  # (then the hull of all views is most of the cube: its agreement says nothing new)
    message = one_view_warning(len(masks)) or view_angle_warning(view_separation_deg(projections, names))
    if message:
        found.append((InputWarning, message))
    if len(masks) >= 2 and all(np.any(m) for m in masks) and not mostly_vessel:
        coverage = dict(zip(names, view_coverage(projections, masks, threshold_px=threshold_px)))
        edges = edge_pixels(masks, names)
        message = agreement_warning(coverage, calibrated=False, calibrate=_CALIBRATE, edges=edges)
        if message:
            found.append((AgreementWarning, message))
        if epipolar_check_applies(masks):
            message = epipolar_warning(epipolar_offset_px(projections, masks), names, calibrate=_CALIBRATE,
                                       cut=any(edges.values()))  # (no mask mostly vessel here: edges counts all)
            if message:
                found.append((AgreementWarning, message))
    message = edge_warning(masks, names)
    if message:
        found.append((InputWarning, message))
    return found
