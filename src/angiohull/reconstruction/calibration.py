"""Self-calibration: in-plane shifts of the views estimated from the masks alone.

The header geometry of real C-arm runs disagrees by tens of pixels between views (table and
isocentre offsets the header does not carry); a misplaced view carves the true vessel away. The
shift of one view is observable from the others: the visual hull of the *other* views, projected
into it, should land on its mask. :func:`calibrate_shifts` estimates a shift ``(du, dv)`` per view
that maximises that agreement (three views or more; two views: see the end):

1. **Support score.** For view ``v`` with the current corrections, carve the hull of the other
   views (a coarse lattice; the threshold widened to the lattice spacing so that thin vessels are
   not missed), project its points into ``v`` and count, for every candidate shift ``s`` at once,
   how many land on the mask (dilated by the same threshold): a cross-correlation of the point
   density with the mask, by FFT. ``f_v(s)`` is that count over the number of points: the fraction
   of the other views' hull that view ``v`` supports when shifted by ``s``.
2. **Greedy, fewest views first.** Each round computes the best shift of every view and applies
   only the one with the largest gain ``f_v(s*) - f_v(current)``; rounds stop when no view gains
   more than ``min_gain`` or when the mean support of all views would drop. With one view off and
   the others right, the first round moves just that view (the hull of the right views is the
   true vessel, so its gain is the largest), which is the correction the usual failure needs.
   A move is undone, and the level ends, if it lowers the *coverage*: the mean fraction of each
   mask that the hull of all views covers when projected back (1 when the views agree; a view out
   of place carves vessel away in every view). When several views gain almost as much in the first
   round (within 20 %), each is tried as the first move and the outcome with the highest final
   coverage is kept.
3. **Coarse to fine.** The same rounds on finer lattices with a smaller search window.
4. **Centreline fit** (:mod:`.centreline_fit`). The support score is flat over a pixel or two and
   leans towards phantom volume; the last step fits each view's shift to the 2D centrelines of the
   others, triangulated along epipolar planes, to a fraction of a pixel.
5. **Gauge.** Shifting every view by the projection of one common 3D translation changes nothing
   but where the object sits (``J_v t`` with ``J_v`` the Jacobian of view ``v`` at the isocentre).
   Of the equivalent corrections, the one that moves the fewest views by a pixel or more, then the
   shortest in total, is reported (candidates: no translation, and the translations that leave
   one view or a pair of views unmoved); its translation is then refitted by least squares to all
   the views it leaves unmoved, so that the answer does not depend on where the estimate started
   and their small leftovers show the views' own disagreement.
6. **Joint fit and ties.** The sweeps of step 4 fit one view at a time against the others, which
   is not a descent on their summed cost: along a direction the cost barely sees they wander by a
   pixel or more. Up to JOINT_FIT_MAX_VIEWS views, the summed cost
   (:func:`.centreline_fit.consistency_cost`, matches farther than ``_JOINT_CUTOFF_PX`` counted as
   misses) is then minimised over all views at once (:func:`.centreline_fit.fit_jointly`), and the
   gauge is applied again. Views that share an image axis (the paper's perpendicular views share
   one axis pairwise) leave a shift along that axis nearly undetermined: moving either view, with
   the object translated, explains the masks about equally well, and the gauge sees a near-tie (as
   many views moved, in total within ``_TIE_PX``). The translation between the alternatives changes
   the object's depth in the other views, and so its magnification there (about 0.6 % for 20 px):
   each alternative is fitted jointly (whatever the number of views) and the one with the lowest
   summed cost is kept.
6b. **Fewer views.** The summed cost can be nearly flat between corrections that are not
   equivalent: with one view off, the fit may end with a second view moved by two or three pixels
   and the first one off by as much. While the correction moves two views or more (up to
   JOINT_FIT_MAX_VIEWS views), each moved view in turn is held in place with the unmoved ones and
   the others are refitted (:func:`.centreline_fit.fit_jointly` on the moved views only, from the
   best integer offsets within ``_FEWER_VIEWS_REACH_PX``); the best of these is kept when it costs
   at most ``_FEWER_VIEWS_TOLERANCE`` times the mean cost per view more (1.5 % of the total with
   three views). Measured on the authors' clinical studies with view 0 moved by 20 px: in the two
   that ended with a second view moved, holding it cost 1.0-1.2 % more and brought view 0 from
   0.9 / 4.7 px to 1.1 / 0.5 px of the truth (geometry error 1.7 / 2.3 px to 0.5 / 0.2 px); with a
   second view truly moved by 2-3 px, holding it cost 1.7-13 % more in 26 of 28 studies, and the
   other 2 (0.0 %, 1.0 %) came out closer to the truth.
7. **Scales** (``estimate_scale``, three views or more): a magnification the header has wrong
   (source-to-image distance, pixel spacing) scales a view's image about its principal point.
   A scale and a shift of a view trade against each other when its vessels lie off the principal
   point, so the scales are fitted together with all views' shifts
   (:func:`.centreline_fit.fit_scales_jointly`, which moves a scale about the vessels' centroid).
   Per round: the candidate views are those whose own centreline cost some factor within
   ``1 -+ SCALE_RANGE`` lowers by ``_MIN_SCALE_GAIN`` (a quick screen,
   :func:`.centreline_fit.fit_view_scale`); each is fitted jointly from the factor of
   ``_SCALE_STARTS`` nearest the screen's (starting from every one of them took twice the time
   and found the same scales on 5 of 6 test cases, and on the sixth 1.0496 instead of 1.0490 for
   a true 1.05), starting from the shift-only outcome and from the header's shifts (a
   wrongly scaled view can mislead the shift search into moving other views), each start only where
   the screen saw that view's scale from it (fitting from both doubled the fits). The lowest summed
   cost wins the round, followed by the gauge and step 6 (near-ties), if it lowers the summed cost
   by ``_MIN_SCALE_EVIDENCE`` against the shifts alone (first round) or by ``_MIN_SCALE_GAIN``
   against the previous round; a true 10 % scale lowered it by 10-16 % (4 trees), while spurious
   scales on the authors' studies lowered it by 0.5 %. With more than ``JOINT_FIT_MAX_VIEWS``
   views the joint fits would take minutes: the scales are then chosen view by view
   (:func:`_scale_views`), both after the shift search and at the header's shifts followed by
   steps 1-6, and the route whose views agree best is kept under the same evidence rule.

8. **Silhouette fit** (three to JOINT_FIT_MAX_VIEWS views; :mod:`.silhouette_fit`). Where the tree overlaps
   itself, a mask's centreline runs through the merged silhouette and the centreline cost is
   biased; the outline of the merged silhouette is not. The axis points of the refined hull at the
   current shifts, with their radii (:func:`.refine.tube_axis`), are fitted as a union of balls to
   the masks' outlines together with every view's shift (:func:`.silhouette_fit.fit_silhouettes`),
   and the gauge is applied with the same views moved. A correction the fit would change by more
   than ``_SILHOUETTE_REACH_PX`` (common translation taken out) is left as it was: the step
   polishes. On the authors' 48 studies with view 0 moved by 20 px it brought view 0 from up to
   1.48 px to within 0.26 px of the truth. With more views the refined hull has many more axis
   points (15 900 with 15 views against 1 900 with 3: more views put a point on the centreline in
   three of them) and the sparse solve grows too fast (13 s per iteration with 15 views, 0.6 s with
   6, 0.03 s with 3), so it is not run there; the sweeps alone are accurate with many views.

9. **Outcome.** The agreement of the views is measured before and after (:func:`view_coverage`: per
   view, the fraction of its mask the paper's hull of all views covers, K = COVERAGE_RESOLUTION).
   When the estimate makes the views agree less than the header's geometry did, it is not applied
   (``outcome`` "reverted"), so calibration never ends worse than no calibration by that measure;
   views still below AGREEMENT_MIN_COVERAGE after it are reported (``disagreeing_views``), and the
   command line warns.

10. **Ambiguity.** Two views seen from nearly the same direction (e.g. RAO 30 CRA 30 and RAO 30
    CAU 30) leave it nearly open which of them moved: a shift of one equals a shift of the other
    and a translation of the object, up to a pixel. When the correction moves one view, the
    correction moving another one instead (the translation that leaves the rest unmoved taken out,
    then that view fitted) is tried, before the silhouette fit. One that explains the centrelines
    clearly better (cost below SWITCH_COST_RATIO times the chosen one's) replaces it; one within
    AMBIGUITY_COST_RATIO makes the calibration ambiguous (``ambiguous_with``): the masks agree
    either way, but the object's position differs by the translation between the two (on one of
    the authors' studies 7.5 mm, Dice3D 75 % -> 44 %), and the command line warns.

**Two views** determine one number only (four shift components, three of them a common 3D
translation): view 1's shift across its epipolar lines. The hull of one view is a whole cone, so
the support score above has no meaning there; :func:`.epipolar.two_view_shift` instead makes the
two masks cover the same planes of the pencil around the baseline, and the gauge step follows;
an estimate under :data:`TWO_VIEW_NOISE_PX` is noise and is not applied.

A view's correction is applied as ``P' = T(du, dv) P`` (``T`` shifts pixel coordinates), so the
returned shifts are what was done to the masks: a mask whose content moved by ``(+20, 0)`` px
comes back as ``du = +20``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.fft import irfft2, next_fast_len, rfft2

from ..compiled import kernels
from ..errors import ReconstructionError
from ..geometry import Projection, cube_half_edge_mm
from ..thinning import pixel_box
from .cube import Lattice
from .centreline_fit import (Centreline, consistency_cost, fit_jointly, fit_scales_jointly, fit_view_scale,
                             polish_shifts)
from .refine import REFINED, clean_mask, tube_axis
from .silhouette_fit import fit_silhouettes, largest_off_gauge_px, mask_edge_points
from .epipolar import two_view_shift
from .engines import ENGINES

__all__ = ["Calibration", "calibrate_shifts", "shift_projection", "view_coverage", "CALIBRATION_LEVELS",
           "JOINT_FIT_MAX_VIEWS", "AGREEMENT_MIN_COVERAGE"]

CALIBRATION_LEVELS: tuple[tuple[int, float], ...] = ((64, 1.0), (112, 0.25), (160, 0.1))
"""(lattice resolution K, search window as a fraction of max_shift_px) of the coarse-to-fine levels."""

COVERAGE_RESOLUTION = 256
"""Lattice resolution at which the reported coverage before and after is measured."""

SCALE_RANGE = 0.15
"""With ``estimate_scale``, a view's image scale is screened within ``1 -+ SCALE_RANGE`` in steps of
``_SCALE_STEP`` (0.02) and then fitted jointly with the shifts from the factor in ``_SCALE_STARTS`` nearest the screen's
(view by view, in steps of 0.005 and 0.0025 around the best, with more than JOINT_FIT_MAX_VIEWS
views)."""

JOINT_FIT_MAX_VIEWS = 6
"""Up to this many views the shifts from the view-by-view sweeps are refined by minimising the summed
centreline cost over all views at once (:func:`.centreline_fit.fit_jointly`); its work grows with
the square of the number of views (measured on one generated tree, 2 cores: 0.2 s at 3 views, 1.2 s
at 4, 2.9 s at 6, 53 s at 15). A near-tie of the gauge is always decided that way. The silhouette
fit (step 8) runs up to this many views too."""


AGREEMENT_MIN_COVERAGE = 0.95
"""A view whose mask the hull of all views covers less than this (:func:`view_coverage`) disagrees
with the others: measured on the authors' and generated studies, the paper hull covers 0.99-1.00
of every exact mask when the views agree, 0.97-1.00 of the masks segmented from 20 generated
clinical angiograms (3 views, uncalibrated), 0.98-0.99 of the calibrated phantom DICOM views, and
a view moved by 5-40 px drops it to 0.39-0.97. 0.9 until 2026-12-02: it let pass, after a right
calibration, an authors' study whose moved view had pushed 4 % of its vessel past the image's
edge (the others' masks then 0.94 covered; 3.8 Dice3D points lost, refined preset)."""

SWITCH_COST_RATIO = 0.95
"""Such an alternative whose cost is below this times the chosen one's replaces it (the greedy
search can settle on the wrong one of two views seen from nearly the same direction: measured on
generated trees, the right view explained the centrelines 11-12 % better)."""
AMBIGUITY_COST_RATIO = 1.05
"""An alternative correction (another view moved instead of the one calibration moved) whose summed
centreline cost is at most this times the chosen one's makes the calibration ambiguous."""
_AMBIGUITY_RESIDUAL_PX = 2.0  # the alternative leaves every other view within this of unmoved
_OUTCOME_TOLERANCE = 0.002  # mean coverage changes smaller than this leave the views' agreement "unchanged"
_MOVED_PX = 1.0  # a view whose correction is shorter than this counts as unmoved (gauge choice)
TWO_VIEW_NOISE_PX = 0.5
"""Two views: an estimate across view 1's epipolar lines (:func:`.epipolar.two_view_shift`) shorter
than this is not applied. With the right geometry it reads 0.0-0.4 px (36 generated cases, exact
masks, segmented angiograms and the paper's rasteriser; 2026-12-07): noise, and applying it moved
both views by a few hundredths of a pixel, which can change which of two near-equal readings the
tree method keeps (the demo's tree in its two views: centerline 0.35 -> 1.71 mm from the truth)."""
_TIE_PX = 2.0  # gauge alternatives moving as many views and at most this much longer in total are near-ties
_JOINT_CUTOFF_PX = 1.0  # after the sweeps the views agree within about a pixel: farther matches are wrong ones
_MIN_COVERAGE_GAIN = 0.001  # a move must raise the mean mask coverage by more than this
_FEWER_VIEWS_TOLERANCE = 0.045  # of the mean cost per view: what moving one view fewer may cost (step 6b)
_FEWER_VIEWS_REACH_PX = 4  # integer search around a refitted view's start (step 6b)
_SILHOUETTE_REACH_PX = 2.0  # step 8 polishes: a correction it would change by more than this is left as it was
_SILHOUETTE_MIN_BALLS = 10  # step 8 needs a tube model of at least this many axis points
_SCALE_STEP = 0.02  # coarse step of the scale search
_MIN_SCALE_GAIN = 0.02  # a scale change must lower the view's own and the summed centreline cost by this fraction
_MIN_SCALE_EVIDENCE = 0.05  # the scaled outcome must lower the summed cost by this fraction against shifts alone
# starting factors of the joint scale fits (each converges from about 0.05 away; SCALE_RANGE is covered)
_SCALE_STARTS = (0.9, 0.95, 1.05, 1.1)


def shift_projection(projection: Projection, du_px: float, dv_px: float) -> Projection:
    """The projection whose image is moved by ``(du, dv)`` pixels: ``T(du, dv) P``."""
    return projection.shifted(du_px, dv_px)


@dataclass(frozen=True)
class Calibration:
    """Estimated per-view image shifts and how well the views agree before and after."""

    shifts_px: tuple[tuple[float, float], ...]  # (du, dv) per view, in the order given, after the gauge
    scales: tuple[float, ...]  # image scale per view about its principal point, applied before the shift (1: none)
    gauge_translation_mm: tuple[float, float, float]  # 3D translation the gauge steps moved the object by, in total
    coverage_before: tuple[float, ...]  # per view: fraction of its mask the hull of all views covers, uncorrected
    coverage_after: tuple[float, ...]  # the same, corrected (K = COVERAGE_RESOLUTION, reconstruction threshold)
    rounds: int  # greedy rounds that changed a view, over all levels
    # step 8: "applied (RMS ... px)", or why it was not run or not kept
    silhouette_fit: str = "not run"
    # "improved", "unchanged" (the views agreed as well before), or "reverted: ..." (the estimate made
    # the views agree less than the header's geometry did, so none was applied)
    outcome: str = "improved"
    time_s: float = 0.0  # seconds the calibration took
    # alternatives as good as the correction found: (view moved instead, its shift (du, dv), cost
    # relative to the chosen correction's, how far the object moves between the two, mm)
    ambiguous_with: tuple[tuple[int, tuple[float, float], float, float], ...] = ()
    history: list[tuple[int, int, float, float, float]] = field(default_factory=list, repr=False)

    @property
    def disagreeing_views(self) -> tuple[int, ...]:
        """The views whose mask the calibrated hull covers less than AGREEMENT_MIN_COVERAGE."""
        return tuple(i for i, c in enumerate(self.coverage_after) if c < AGREEMENT_MIN_COVERAGE)
    # (level K, view, du, dv, gain) of every applied update

    def corrected(self, projections: Sequence[Projection]) -> list[Projection]:
        """The projections with the scales and then the shifts applied: ``T(du, dv) S(f) P``."""
        return [shift_projection(p.magnified(f), du, dv) for p, f, (du, dv) in zip(projections, self.scales, self.shifts_px)]

    def to_dict(self, names: Sequence[str] | None = None) -> dict:
        names = list(names) if names is not None else [f"view{i}" for i in range(len(self.shifts_px))]
        return {
            "method": ("greedy leave-one-out support maximisation, coarse to fine, then a fit to the other views' "
                       "triangulated centrelines, view by view and then all views at once; gauge: fewest views "
                       "moved, then least total shift; of corrections that explain the views almost as well, the "
                       "one moving fewer views; near-ties: the alternative whose centrelines agree best; "
                       "then (three views or more) the shifts polished against a tube model fitted to the masks' "
                       "outlines (silhouette fit); two views: agreement of the masks' epipolar planes; scales (when estimated): each view's "
                       "image scale fitted to the centrelines, kept when it lowers their summed cost by "
                       f"{_MIN_SCALE_EVIDENCE:.0%} against shifts alone"),
            "shifts_px": {n: {"du": s[0], "dv": s[1]} for n, s in zip(names, self.shifts_px)},
            "scales": dict(zip(names, self.scales)),
            "gauge_translation_mm": list(self.gauge_translation_mm),
            "coverage_before": dict(zip(names, self.coverage_before)),
            "coverage_after": dict(zip(names, self.coverage_after)),
            "rounds": self.rounds,
            "silhouette_fit": self.silhouette_fit,
            "outcome": self.outcome,
            "ambiguous_with": [{"view": names[v], "shift_px": {"du": d[0], "dv": d[1]}, "cost_ratio": r,
                                "object_moves_mm": t} for v, d, r, t in self.ambiguous_with],
            "agreement_min_coverage": AGREEMENT_MIN_COVERAGE,
            "disagreeing_views": [names[i] for i in self.disagreeing_views],
            "time_s": self.time_s,
        }


def _px_per_mm(projection: Projection) -> float:
    """Pixels per mm at the isocentre (the larger of the two axes)."""
    fu, fv = projection.focal_lengths_px
    return max(fu, fv) / float(np.linalg.norm(projection.camera_centre_mm))


def _jacobian(projection: Projection) -> np.ndarray:
    """d(u, v)/dX at the isocentre, (2, 3)."""
    return projection.jacobian(np.zeros((1, 3)))[0]


def _hull(projections: Sequence[Projection], masks: Sequence[np.ndarray], lattice: Lattice, threshold_px: float) -> np.ndarray:
    return ENGINES["octree"](lattice, list(projections), list(masks), threshold_px=threshold_px).points_mm


def _support_map(points: np.ndarray, projection: Projection, mask_near: np.ndarray, window: int,
                 spectra: dict | None = None) -> np.ndarray:
    """``f(s)`` for integer shifts ``|s| <= window``: fraction of points landing on ``mask_near``.

    Returns an array ``(2 window + 1, 2 window + 1)`` indexed ``[dv + window, du + window]``.
    ``spectra`` remembers the padded mask's transform by window (it does not change between calls).
    """
    spectra = {} if spectra is None else spectra
    if window not in spectra:
        spectra[window] = _MaskSpectrum(mask_near, window)
    spectrum = spectra[window]
    h = projection.homogeneous(points)
    front = h[:, 2] > 0
    uv = h[front, :2] / h[front, 2:3]
    # canvas coordinates: the box of the mask padded by the window (a point outside it lands on
    # the mask for no shift within the window)
    iu = np.floor(uv[:, 0] + 0.5).astype(np.int64) - spectrum.col0 + window
    iv = np.floor(uv[:, 1] + 0.5).astype(np.int64) - spectrum.row0 + window
    rows, cols = spectrum.box
    ok = (iu >= 0) & (iu < cols + 2 * window) & (iv >= 0) & (iv < rows + 2 * window)
    # C(s) = sum_x D(x) M(x + s) on the padded canvas: as a circular correlation it wraps only into
    # the padding, where the mask is empty, for |s| <= window.
    shape = spectrum.shape
    density = np.bincount(iv[ok] * shape[1] + iu[ok], minlength=shape[0] * shape[1]).astype(np.float64)
    correlation = irfft2(np.conj(rfft2(density.reshape(shape))) * spectrum.transform, s=shape)
    offsets = np.arange(-window, window + 1)
    block = correlation[np.ix_(offsets % shape[0], offsets % shape[1])]
    return np.clip(np.round(block), 0, None) / max(1, len(points))


class _MaskSpectrum:
    """The transform of a view's near-mask on the canvas of :func:`_support_map`: the box of its
    pixels (the whole image when it has none) padded by the window on every side."""

    def __init__(self, mask_near: np.ndarray, window: int):
        r0, r1, c0, c1 = pixel_box(mask_near) or (0, mask_near.shape[0], 0, mask_near.shape[1])
        self.row0, self.col0, self.box = r0, c0, (r1 - r0, c1 - c0)
        rows, cols = self.box
        self.shape = (next_fast_len(rows + 2 * window, real=True), next_fast_len(cols + 2 * window, real=True))
        canvas = np.zeros(self.shape)
        canvas[window:window + rows, window:window + cols] = mask_near[self.row0:self.row0 + rows,
                                                                       self.col0:self.col0 + cols]
        self.transform = rfft2(canvas)


def _disc(radius: float, *, strict: bool = False) -> np.ndarray:
    """The offsets ``(dy, dx)`` with ``sqrt(dx**2 + dy**2) <= radius`` (``< radius`` if ``strict``),
    as a boolean footprint: a dilation with it marks the pixels whose Euclidean distance transform
    to the input is within ``radius`` (the same square roots of whole numbers)."""
    r = int(np.floor(radius))
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    distance = np.sqrt((dx * dx + dy * dy).astype(float))
    return distance < radius if strict else distance <= radius


_MAX_DISC = 64  # a larger disc is quicker as a distance transform (the coarsest level's, about 120 offsets)


def _dilated(image: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """``image`` (bool) dilated by a small symmetric ``footprint`` (nothing beyond the border): one
    shifted OR per offset, much quicker than a general dilation for a footprint of a few dozen (the
    compiled kernel sets each set pixel's offsets instead: the same pixels)."""
    compiled = kernels()
    if compiled is not None:
        offsets = np.argwhere(footprint) - footprint.shape[0] // 2
        return compiled.dilate_by_offsets(np.ascontiguousarray(image, dtype=bool), offsets.astype(np.int64))
    out = image.copy()
    rows, cols = image.shape
    r = footprint.shape[0] // 2
    for dy, dx in np.argwhere(footprint) - r:
        if (dy == 0 and dx == 0) or abs(dy) >= rows or abs(dx) >= cols:
            continue
        out[max(dy, 0):rows + min(dy, 0), max(dx, 0):cols + min(dx, 0)] |= \
            image[max(-dy, 0):rows + min(-dy, 0), max(-dx, 0):cols + min(-dx, 0)]
    return out


class _Level:
    """One coarse-to-fine level: a lattice, a widened threshold and the masks dilated by it."""

    def __init__(self, projections, masks, half_edge_mm, resolution, threshold_px):
        self.projections = list(projections)
        self.masks = list(masks)
        self.lattice = Lattice(half_edge_mm, resolution)
        spacing_px = self.lattice.spacing_mm * max(_px_per_mm(p) for p in projections)
        self.threshold = max(threshold_px, 0.75 * spacing_px)
        self.sharp_threshold = threshold_px  # the coverage is judged with the reconstruction's own threshold
        self.cell_reach_px = threshold_px + 0.5 * np.sqrt(3.0) * spacing_px  # a lattice point's cell, projected
        near = _disc(self.threshold, strict=True)  # distance transform < threshold, as a dilation when small
        self.near = [_dilated(m, near) if np.count_nonzero(near) <= _MAX_DISC else
                     ndi.distance_transform_edt(~m) < self.threshold for m in masks]
        self._spectra: list[dict] = [{} for _ in masks]  # per view: the transform of its padded mask, by window
        self._reach_disc = _disc(self.cell_reach_px)
        self._hulls: dict[tuple, np.ndarray] = {}

    def hull(self, views: Sequence[int], shifts: np.ndarray, threshold: float) -> np.ndarray:
        """The hull of ``views`` with their ``shifts`` (remembered: the greedy rounds move one view
        at a time, so most hulls they ask for were carved before)."""
        key = (tuple(views), np.asarray(shifts, dtype=float)[list(views)].tobytes(), threshold)
        if key not in self._hulls:
            if len(self._hulls) >= 64:
                self._hulls.clear()
            current = [shift_projection(self.projections[v], *shifts[v]) for v in views]
            self._hulls[key] = _hull(current, [self.masks[v] for v in views], self.lattice, threshold)
        return self._hulls[key]

    def agreement(self, shifts: np.ndarray) -> int:
        """Lattice points that every view keeps with the reconstruction's own threshold."""
        return len(self.hull(range(len(self.masks)), shifts, self.sharp_threshold))

    def coverage(self, shifts: np.ndarray) -> float:
        """Mean over views of :meth:`coverage_per_view`."""
        return float(np.mean(self.coverage_per_view(shifts)))

    def coverage_per_view(self, shifts: np.ndarray) -> list[float]:
        """Per view, the fraction of mask pixels that the hull of all views, projected back (each
        lattice point standing for its cell), covers: 1 when the views agree."""
        current = [shift_projection(p, *s) for p, s in zip(self.projections, shifts)]
        points = self.hull(range(len(self.masks)), shifts, self.sharp_threshold)
        if len(points) == 0:
            return [0.0] * len(self.masks)
        values = []
        for projection, mask in zip(current, self.masks):
            uv = projection.project(points)
            rows, cols = mask.shape
            iu = np.floor(uv[:, 0] + 0.5).astype(np.int64)
            iv = np.floor(uv[:, 1] + 0.5).astype(np.int64)
            ok = (iu >= 0) & (iu < cols) & (iv >= 0) & (iv < rows)
            if not ok.any():
                values.append(0.0)
                continue
            # on the box of the hit pixels grown by the reach: every mask pixel a hit reaches is in it
            margin = int(np.ceil(self.cell_reach_px)) + 1
            r0, r1 = max(int(iv[ok].min()) - margin, 0), min(int(iv[ok].max()) + margin + 1, rows)
            c0, c1 = max(int(iu[ok].min()) - margin, 0), min(int(iu[ok].max()) + margin + 1, cols)
            hit = np.zeros((r1 - r0, c1 - c0), dtype=bool)
            hit[iv[ok] - r0, iu[ok] - c0] = True
            # the pixels within the reach of a hit (the distance transform's test, as a dilation)
            reach = _dilated(hit, self._reach_disc)
            values.append(float(np.count_nonzero(reach & mask[r0:r1, c0:c1]) / np.count_nonzero(mask)))
        return values

    def support_maps(self, shifts: np.ndarray, window: int) -> list[np.ndarray | None]:
        """Per view, f(s) of the other views' hull over integer shifts within ``window`` (None: empty hull)."""
        maps: list[np.ndarray | None] = []
        for v in range(len(self.masks)):
            others = [i for i in range(len(self.masks)) if i != v]
            points = self.hull(others, shifts, self.threshold)
            maps.append(_support_map(points, shift_projection(self.projections[v], *shifts[v]), self.near[v], window,
                                     self._spectra[v]) if len(points) else None)
        return maps


def _here(support: np.ndarray | None, window: int) -> float:
    return float(support[window, window]) if support is not None else 0.0


def _best(support: np.ndarray | None, window: int) -> tuple[float, int, int]:
    """(gain over no move, du, dv) of the best integer shift in a support map."""
    if support is None:
        return (0.0, 0, 0)
    r, c = np.unravel_index(int(np.argmax(support)), support.shape)
    return (float(support[r, c] - support[window, window]), int(c) - window, int(r) - window)


def _greedy(level: "_Level", window: int, shifts: np.ndarray, history: list, needed: float, rounds: int) -> None:
    """Move one view per round (the largest gain) while the gain exceeds ``needed`` and the move
    neither lowers the masks' coverage by the hull of all views nor the number of lattice points all
    views keep (no drifting along directions the data do not fix)."""
    maps = level.support_maps(shifts, window)
    score = (level.coverage(shifts), level.agreement(shifts))
    for _ in range(rounds):
        gains = [_best(m, window) for m in maps]
        v = int(np.argmax([g[0] for g in gains]))
        gain, du, dv = gains[v]
        if gain < needed:
            return
        shifts[v] += (du, dv)
        new = (level.coverage(shifts), level.agreement(shifts))
        if new[0] < score[0] - _MIN_COVERAGE_GAIN or new[1] <= score[1] and new[0] <= score[0] + _MIN_COVERAGE_GAIN:
            shifts[v] -= (du, dv)
            return
        score = new
        maps = level.support_maps(shifts, window)
        history.append((level.lattice.resolution, v, float(du), float(dv), gain))


def _keeping(shifts: np.ndarray, jacobians: Sequence[np.ndarray], views: Sequence[int]) -> np.ndarray:
    """The 3D translation whose image shifts ``J_v t`` best match ``shifts`` of ``views`` (least
    squares): taken out, it leaves those views as nearly unmoved as a translation can."""
    return np.linalg.lstsq(np.vstack([jacobians[v] for v in views]), np.concatenate([shifts[v] for v in views]),
                           rcond=None)[0]


def _gauge_candidates(shifts: np.ndarray, jacobians: Sequence[np.ndarray]) -> list[tuple[tuple, np.ndarray, np.ndarray]]:
    """The corrections equivalent to ``shifts`` up to a common 3D translation ``t``, as
    ``(key, corrected shifts, t)`` with key = (views moved by _MOVED_PX or more, total shift, |t|).

    Candidates: no translation, and for every view and every pair of views the translation that
    (in the least-squares sense) leaves them unmoved.
    """
    n = len(jacobians)
    translations = [np.zeros(3)]
    for v in range(n):
        translations.append(np.linalg.pinv(jacobians[v]) @ shifts[v])
        for w in range(v + 1, n):
            translations.append(_keeping(shifts, jacobians, (v, w)))
    out = []
    for t in translations:
        corrected = shifts - np.stack([j @ t for j in jacobians])
        lengths = np.linalg.norm(corrected, axis=1)
        key = (int(np.count_nonzero(lengths >= _MOVED_PX)), round(float(lengths.sum()), 6), float(np.linalg.norm(t)))
        out.append((key, corrected, t))
    return out


def _moved(shifts: np.ndarray) -> frozenset[int]:
    return frozenset(np.flatnonzero(np.linalg.norm(shifts, axis=1) >= _MOVED_PX).tolist())


def _gauge(shifts: np.ndarray, jacobians: Sequence[np.ndarray],
           moved: frozenset[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Of the corrections equivalent up to a common 3D translation, the one that moves the fewest
    views (corrections of at least _MOVED_PX), then the shortest in total; with ``moved``, the
    shortest of those that move exactly these views (if any). Returns ``(corrected, translation)``.
    """
    candidates = _gauge_candidates(shifts, jacobians)
    if moved is not None:
        candidates = [c for c in candidates if _moved(c[1]) == moved] or candidates
    _, corrected, t = min(candidates, key=lambda c: c[0])
    # The translation that best leaves the unmoved views in place (least squares over all of them),
    # so that the result does not depend on where the estimate started (equivariance); their small
    # leftovers are the views' own disagreement.
    unmoved = sorted(set(range(len(jacobians))) - _moved(corrected))
    if unmoved:
        fitted = _keeping(shifts, jacobians, unmoved)
        refitted = shifts - np.stack([j @ fitted for j in jacobians])
        if _moved(refitted) == _moved(corrected):
            return refitted, fitted
    return corrected, t


def _tied(shifts: np.ndarray, jacobians: Sequence[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The gauge's near-ties: equivalent corrections that move as few views as the best one, in
    total at most _TIE_PX longer, and differ from each other by _MOVED_PX or more in some view.
    Returns ``[(corrected, translation)]``, the best first."""
    candidates = sorted(_gauge_candidates(shifts, jacobians), key=lambda c: c[0])
    best = candidates[0][0]
    tied: list[tuple[np.ndarray, np.ndarray]] = []
    for key, corrected, t in candidates:
        if key[0] == best[0] and key[1] <= best[1] + _TIE_PX and \
                all(np.abs(corrected - other).max() >= _MOVED_PX for other, _ in tied):
            tied.append((corrected, t))
    return tied


def _fit_jointly(projections: Sequence[Projection], centre_lines: Sequence[Centreline], shifts: np.ndarray,
                 jacobians: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Step 6 of the module notes: the summed centreline cost minimised over all views at once,
    from the gauge's choice and from each of its near-ties (views that share an image axis); the
    outcome with the lowest cost is kept. The object's translation between near-tied alternatives
    changes its depth, and so its magnification, in the other views, which the summed cost sees
    once every alternative has been fitted. Without a near-tie and with more than
    JOINT_FIT_MAX_VIEWS views, the sweeps' shifts are kept. Returns the shifts and the further 3D
    translation of the object."""
    options = _tied(shifts, jacobians)
    if len(options) < 2:
        if len(projections) > JOINT_FIT_MAX_VIEWS:
            return shifts, np.zeros(3)
        options = [(shifts, np.zeros(3))]
    scored = []
    for corrected, t in options:
        fitted, cost = fit_jointly(projections, centre_lines, corrected, np.vstack(jacobians),
                                   cutoff_px=_JOINT_CUTOFF_PX)
        again, further = _gauge(fitted, jacobians, moved=_moved(corrected))
        scored.append((cost, again, t + further))
    _, chosen, translation = min(scored, key=lambda o: o[0])
    return chosen, translation


def _fewer_moved(projections: Sequence[Projection], centre_lines: Sequence[Centreline], shifts: np.ndarray,
                 jacobians: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Step 6b of the module notes: while the correction moves two views or more, try holding one
    of them in place as well (with the others left in place; the translation that best keeps all
    of them is taken out first) and refitting the rest (:func:`.centreline_fit.fit_jointly` on the
    moved views, from the best integer offsets within _FEWER_VIEWS_REACH_PX). The best of these is
    kept when its summed cost exceeds that of the correction given by at most
    _FEWER_VIEWS_TOLERANCE times the mean cost per view (the allowance is not spent twice: every
    further view held is judged against the same cost). Up to JOINT_FIT_MAX_VIEWS views. Returns
    the shifts and the further 3D translation of the object."""
    n = len(projections)
    translation = np.zeros(3)
    if n > JOINT_FIT_MAX_VIEWS:
        return shifts, translation
    gauge = np.vstack(jacobians)
    cost = consistency_cost(projections, centre_lines, shifts, cutoff_px=_JOINT_CUTOFF_PX)
    allowed = cost + _FEWER_VIEWS_TOLERANCE * cost / n
    while len(_moved(shifts)) >= 2:
        trials = []
        for dropped in sorted(_moved(shifts)):
            kept = sorted(_moved(shifts) - {dropped})
            held = [v for v in range(n) if v not in kept]
            t = _keeping(shifts, jacobians, held)
            start = shifts - np.stack([j @ t for j in jacobians])
            start[held] = 0.0
            fitted, fitted_cost = fit_jointly(projections, centre_lines, start, gauge, cutoff_px=_JOINT_CUTOFF_PX,
                                              views=kept, reach_px=_FEWER_VIEWS_REACH_PX)
            trials.append((fitted_cost, fitted, t))
        fitted_cost, fitted, t = min(trials, key=lambda trial: trial[0])
        if fitted_cost > allowed:
            break
        fitted, further = _gauge(fitted, jacobians)
        if len(_moved(fitted)) >= len(_moved(shifts)):
            break
        shifts, translation = fitted, translation + t + further
    return shifts, translation


def _moved_view(n: int, view: int, shift) -> np.ndarray:
    """Shifts of ``n`` views, all zero but ``view``'s."""
    shifts = np.zeros((n, 2))
    shifts[view] = shift
    return shifts


def calibrate_shifts(projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                     max_shift_px: float = 60.0, threshold_px: float = 1.0, min_gain: float = 0.01,
                     max_rounds: int | None = None, estimate_scale: bool = False,
                     progress: Callable[[str], None] | None = None) -> Calibration:
    """Estimate an in-plane image shift per view that makes the views agree (see the module notes).

    Parameters
    ----------
    projections : sequence of Projection
        The header geometry, at least 2 views.
    masks : sequence of (rows, cols) bool arrays
    max_shift_px : float, keyword-only
        Largest shift searched per view, pixels (default 60).
    threshold_px : float, keyword-only
        The carving threshold the final reconstruction will use (the levels widen it to their
        lattice spacing).
    min_gain : float, keyword-only
        On the coarsest level a view is moved only if it then supports at least this much more of
        the other views' hull (a fraction; default 0.01); finer levels accept a tenth of it.
    max_rounds : int, optional
        Greedy rounds per level (default: 2 x the number of views).
    estimate_scale : bool, keyword-only
        Also estimate an image scale per view (within ``1 -+ SCALE_RANGE``), for a magnification the
        header has wrong (step 7 of the module notes; three views or more). Default False.
    progress : callable, optional, keyword-only
        Called with a short message as each step starts (the command line prints them on stderr).

    Returns
    -------
    Calibration
        With the agreement of the views before and after (``coverage_before``, ``coverage_after``);
        when the estimate makes the views agree less than the header's geometry, no correction is
        applied (``outcome`` says "reverted").
    """
    start = time.perf_counter()

    def say(message: str) -> None:
        if progress is not None:
            progress(f"calibration: {message}")

    n = len(projections)
    if n < 2:
        raise ReconstructionError(f"calibration needs at least 2 views, got {n}")
    if len(masks) != n:
        raise ReconstructionError(f"got {n} projections but {len(masks)} masks")
    masks = [np.asarray(m, dtype=bool) for m in masks]
    if not all(m.any() for m in masks):
        raise ReconstructionError("calibration needs a vessel pixel in every mask")
    if not np.isfinite(max_shift_px) or max_shift_px < 1:
        raise ReconstructionError(f"max_shift_px must be >= 1, got {max_shift_px!r}")
    rounds = max_rounds if max_rounds is not None else 2 * n
    half_edge = cube_half_edge_mm(projections)  # the lattice stays where the headers put it
    jacobians = [_jacobian(p) for p in projections]
    if estimate_scale and n < 3:
        raise ReconstructionError(f"scale estimation needs at least 3 views, got {n}")
    scales = np.ones(n)
    ambiguous: list = []
    if n == 2:
        say("two views: matching the masks' epipolar planes")
        # one number is observable: view 1's shift across its epipolar lines (see .epipolar)
        estimate = two_view_shift(*projections, *masks, max_shift_px=max_shift_px)
        if float(np.linalg.norm(estimate)) < TWO_VIEW_NOISE_PX:
            say(f"two views: the masks agree best {np.linalg.norm(estimate):.2f} px across the epipolar lines, "
                f"less than the {TWO_VIEW_NOISE_PX:g} px of a right geometry's noise: nothing to correct")
            estimate = np.zeros(2)
        moved = _moved_view(2, 1, estimate)
        history: list[tuple[int, int, float, float, float]] = []
        final, translation = _gauge(moved, jacobians)
        silhouette = "not run: two views"
    else:
        centre_lines = [Centreline(m) for m in masks]
        final, translation, history = _support_then_centrelines(
            projections, masks, centre_lines, jacobians, half_edge, threshold_px, max_shift_px, min_gain, rounds, say)
        if estimate_scale:
            say("image scales")
            scales, final, translation, history = _with_scales(
                projections, masks, centre_lines, (final, translation, history), half_edge, threshold_px, max_shift_px,
                min_gain, rounds)
        silhouette = f"not run: more than {JOINT_FIT_MAX_VIEWS} views"
        scaled = [p.magnified(f) for p, f in zip(projections, scales)]
        say("looking for other views' corrections")
        alternatives = _alternatives(scaled, centre_lines, final)
        better = [a for a in alternatives if a[2] < SWITCH_COST_RATIO]
        if better:  # another view moved instead explains the centrelines clearly better: take it
            view, shifts, ratio, t = min(better, key=lambda a: a[2])
            final, translation = shifts, translation + t
            history.append((0, view, float(shifts[view][0]), float(shifts[view][1]), 1.0 - ratio))
        if n <= JOINT_FIT_MAX_VIEWS:
            say("fitting a tube model to the masks' outlines")
            final, further, silhouette = _silhouette_step(scaled, masks, final, half_edge, threshold_px)
            translation = translation + further
        if better:
            alternatives = _alternatives(scaled, centre_lines, final)
        ambiguous = [(v, (float(a[v][0]), float(a[v][1])), r, float(np.linalg.norm(t)))
                     for v, a, r, t in alternatives if r <= AMBIGUITY_COST_RATIO]
    say("measuring how well the views agree before and after")
    level = _Level(projections, masks, half_edge, COVERAGE_RESOLUTION, threshold_px)
    before = level.coverage_per_view(np.zeros((n, 2)))
    if np.any(scales != 1.0):
        level = _Level([p.magnified(f) for p, f in zip(projections, scales)], masks, half_edge, COVERAGE_RESOLUTION,
                       threshold_px)
    after = level.coverage_per_view(final)
    outcome = "improved"
    if np.mean(after) < np.mean(before) - _OUTCOME_TOLERANCE:
        # never worse than the header's geometry: the estimate is reported but not applied
        outcome = (f"reverted: the estimated correction made the views agree less (mean mask coverage "
                   f"{np.mean(after):.3f}) than the header's geometry ({np.mean(before):.3f}); none applied")
        final, scales, translation, after, ambiguous = np.zeros((n, 2)), np.ones(n), np.zeros(3), before, []
    elif np.mean(after) <= np.mean(before) + _OUTCOME_TOLERANCE:
        outcome = "unchanged"
    return Calibration(
        shifts_px=tuple((float(a), float(b)) for a, b in final),
        scales=tuple(float(f) for f in scales),
        gauge_translation_mm=tuple(float(x) for x in translation),
        coverage_before=tuple(before),
        coverage_after=tuple(after),
        rounds=len(history),
        silhouette_fit=silhouette,
        outcome=outcome,
        time_s=time.perf_counter() - start,
        ambiguous_with=tuple(ambiguous),
        history=history,
    )


def _alternatives(projections: Sequence[Projection], centre_lines: Sequence[Centreline],
                  shifts: np.ndarray) -> list[tuple[int, np.ndarray, float, np.ndarray]]:
    """Step 10 of the module notes: when the correction moves one view, the corrections that move
    another view instead (two views seen from nearly the same direction trade a shift of one for a
    shift of the other and a translation of the object), each fitted. Returns ``[(view, shifts (N,
    2), summed centreline cost relative to the given correction's, 3D translation of the object
    between the two (3,))]`` for those within AMBIGUITY_COST_RATIO."""
    jacobians = [_jacobian(p) for p in projections]
    moved = _moved(shifts)
    if len(moved) != 1 or len(projections) > JOINT_FIT_MAX_VIEWS:
        return []
    gauge = np.vstack(jacobians)
    cost = consistency_cost(projections, centre_lines, shifts, cutoff_px=_JOINT_CUTOFF_PX)
    found = []
    for view in range(len(projections)):
        if view in moved:
            continue
        held = [v for v in range(len(projections)) if v != view]
        t = _keeping(shifts, jacobians, held)
        alternative = shifts - np.stack([j @ t for j in jacobians])
        if max(np.linalg.norm(alternative[v]) for v in held) > _AMBIGUITY_RESIDUAL_PX:
            continue
        alternative[held] = 0.0
        fitted, fitted_cost = fit_jointly(projections, centre_lines, alternative, gauge, cutoff_px=_JOINT_CUTOFF_PX,
                                          views=[view], reach_px=2)
        if cost > 0 and fitted_cost <= AMBIGUITY_COST_RATIO * cost:
            found.append((view, fitted, float(fitted_cost / cost), t))
    return found


def view_coverage(projections: Sequence[Projection], masks: Sequence[np.ndarray], *, threshold_px: float = 1.0,
                  resolution: int = COVERAGE_RESOLUTION) -> list[float]:
    """How well the views agree: per view, the fraction of its mask that the paper's hull of all views
    (K = ``resolution``, the given threshold), projected back with each lattice point standing for
    its cell, covers. 1 when the views agree; below AGREEMENT_MIN_COVERAGE a view disagrees with
    the others (a geometry off by pixels, or masks that do not show the same vessels)."""
    masks = [np.asarray(m, dtype=bool) for m in masks]
    level = _Level(projections, masks, cube_half_edge_mm(projections), resolution, threshold_px)
    return level.coverage_per_view(np.zeros((len(projections), 2)))


def _silhouette_step(projections: Sequence[Projection], masks: Sequence[np.ndarray], shifts: np.ndarray,
                     half_edge: float, threshold_px: float) -> tuple[np.ndarray, np.ndarray, str]:
    """Step 8 of the module notes: ``(shifts, further 3D translation of the object, outcome)``."""
    unchanged = np.asarray(shifts, dtype=float), np.zeros(3)
    cleaned = [clean_mask(m, REFINED.min_neighbours, REFINED.fill_neighbours) for m in masks]
    if not all(m.any() for m in cleaned):
        return *unchanged, "not run: a mask is empty after speck removal"
    current = [shift_projection(p, *s) for p, s in zip(projections, shifts)]
    lattice = Lattice(half_edge, REFINED.resolution)
    points = _hull(current, cleaned, lattice, threshold_px)
    centres, radius = tube_axis(points, lattice, current, cleaned, REFINED)
    if len(centres) < _SILHOUETTE_MIN_BALLS:
        return *unchanged, f"not run: {len(centres)} axis points in the refined hull"
    fit = fit_silhouettes(projections, [mask_edge_points(m) for m in cleaned], centres, radius, shifts)
    largest = largest_off_gauge_px(projections, fit.shifts_px - shifts)
    if not np.isfinite(largest) or largest > _SILHOUETTE_REACH_PX:
        return *unchanged, f"not kept: it would change a view by {largest:.2f} px"
    jacobians = [_jacobian(p) for p in projections]
    final, further = _gauge(fit.shifts_px, jacobians, moved=_moved(shifts))
    fewer, fewer_further = _gauge(fit.shifts_px, jacobians)
    if len(_moved(fewer)) < len(_moved(final)):
        # the outlines say that fewer views moved than the centrelines did (a view's error along
        # an axis it shares with another had gone to both): the simpler correction
        final, further = fewer, fewer_further
    rms = ", ".join(f"{r:.2f}" for r in fit.residual_rms_px)
    return final, further, f"applied: outline RMS {rms} px per view, {fit.iterations} iterations"


def _support_then_centrelines(projections, masks, centre_lines, jacobians, half_edge, threshold_px, max_shift_px,
                              min_gain, rounds, say=lambda message: None) -> tuple[np.ndarray, np.ndarray, list]:
    """Steps 1-6 of the module notes (three views or more): the shifts in the gauge, the 3D
    translation the gauge steps moved the object by, and the greedy history."""
    n = len(projections)
    levels = [(_Level(projections, masks, half_edge, k, threshold_px), max(2, int(np.ceil(max_shift_px * f))))
              for k, f in CALIBRATION_LEVELS]
    coarse, coarse_window = levels[0]
    maps = coarse.support_maps(np.zeros((n, 2)), coarse_window)
    # The first move decides which views carry the correction; near-ties (e.g. two views that share
    # an image axis) are all followed to the end and the most consistent outcome is kept.
    gains = [_best(m, coarse_window) for m in maps]
    top = max(g[0] for g in gains)
    starts = [v for v, g in enumerate(gains) if top >= min_gain and g[0] >= 0.8 * top]
    # the first move obeys the greedy rounds' rule too: none that lowers the masks' coverage
    coverage_now = coarse.coverage(np.zeros((n, 2)))
    starts = [v for v in starts
              if coarse.coverage(_moved_view(n, v, gains[v][1:])) >= coverage_now - _MIN_COVERAGE_GAIN] or [None]
    outcomes = []
    for first in starts:
        shifts = np.zeros((n, 2))
        history: list[tuple[int, int, float, float, float]] = []
        if first is not None:
            shifts = _moved_view(n, first, gains[first][1:])
            history.append((coarse.lattice.resolution, first, *map(float, gains[first][1:]), gains[first][0]))
        for index, (level, window) in enumerate(levels):
            say(f"support search on a {level.lattice.resolution}^3 lattice, shifts within {window} px"
                + (f" (start {starts.index(first) + 1} of {len(starts)})" if len(starts) > 1 else ""))
            needed = min_gain if index == 0 else 0.1 * min_gain
            _greedy(level, window, shifts, history, needed, rounds)
        outcomes.append((shifts, history))
    last = levels[-1][0]
    shifts, history = max(outcomes, key=lambda o: last.coverage(o[0]))
    final, translation = _gauge(shifts, jacobians)
    say("fitting the shifts to the views' centrelines")
    final = polish_shifts(projections, centre_lines, final)
    final, further = _gauge(final, jacobians)  # again, after the fit; the object moved by both
    translation = translation + further
    say("fitting all views' shifts at once")
    final, further = _fit_jointly(projections, centre_lines, final, jacobians)
    final, fewer = _fewer_moved(projections, centre_lines, final, jacobians)
    return final, translation + further + fewer, history


def _scaled_cost(projections, centre_lines, scales, shifts) -> float:
    """The summed centreline cost (cutoff _JOINT_CUTOFF_PX) of the views scaled and shifted."""
    return consistency_cost([p.magnified(f) for p, f in zip(projections, scales)], centre_lines, shifts,
                            cutoff_px=_JOINT_CUTOFF_PX)


def _with_scales(projections, masks, centre_lines, shifts_only, half_edge, threshold_px, max_shift_px, min_gain,
                 rounds) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Step 7 of the module notes: ``(scales, shifts, translation, history)``, given the shift-only
    outcome ``(shifts, translation, history)`` of steps 1-6."""
    if len(projections) <= JOINT_FIT_MAX_VIEWS:
        return _scales_jointly(projections, centre_lines, shifts_only)
    return _scales_view_by_view(projections, masks, centre_lines, shifts_only, half_edge, threshold_px, max_shift_px,
                                min_gain, rounds)


def _coarse_factors() -> np.ndarray:
    """The scale factors 1 -+ SCALE_RANGE in steps of _SCALE_STEP."""
    return 1.0 + np.arange(-SCALE_RANGE, SCALE_RANGE + _SCALE_STEP / 2, _SCALE_STEP)


def _scale_candidates(current: Sequence[Projection], centre_lines: Sequence[Centreline], starts,
                      views) -> list[tuple[int, int, float]]:
    """The views among ``views`` whose own centreline cost some image scale within SCALE_RANGE lowers
    by _MIN_SCALE_GAIN at least, from any of the ``starts`` (shifts): a quick screen, one view at a
    time against the others as they stand. Returns ``(view, start index, the screen's factor)`` for
    every view and start where it does."""
    found = []
    for v in views:
        for index, shifts in enumerate(starts):
            factor, _, cost, cost_here = fit_view_scale(current, centre_lines, shifts, v, _coarse_factors())
            if cost <= (1.0 - _MIN_SCALE_GAIN) * cost_here:
                found.append((v, index, float(factor)))
    return found


def _nearest_start(factor: float) -> float:
    """The factor of _SCALE_STARTS nearest the screen's (the first of two as near)."""
    return min(_SCALE_STARTS, key=lambda start: abs(start - factor))


def _scales_jointly(projections, centre_lines, shifts_only) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Step 7 with up to JOINT_FIT_MAX_VIEWS views: per round, every candidate view's scale is
    fitted together with all views' shifts (:func:`.centreline_fit.fit_scales_jointly`) from the
    factor of _SCALE_STARTS nearest the screen's, starting from the shift-only outcome and from the header's shifts (a
    wrong scale can mislead the shift search into moving other views), each start only where the
    screen (:func:`_scale_candidates`) saw that view's scale from it. The lowest summed cost wins
    the round if it lowers the cost by _MIN_SCALE_EVIDENCE against shifts alone (first round) or by
    _MIN_SCALE_GAIN against the previous round."""
    n = len(projections)
    shifts, translation, history = shifts_only
    scales = np.ones(n)
    best_cost = _scaled_cost(projections, centre_lines, scales, shifts)
    starts = [(np.asarray(shifts, dtype=float), np.asarray(translation, dtype=float)), (np.zeros((n, 2)), np.zeros(3))]
    needed = 1.0 - _MIN_SCALE_EVIDENCE
    while True:
        current = [p.magnified(f) for p, f in zip(projections, scales)]
        scaled = [v for v in range(n) if scales[v] != 1.0]
        candidates = _scale_candidates(current, centre_lines, [s for s, _ in starts],
                                       [v for v in range(n) if v not in scaled])
        trials = []
        for v, index, screened in candidates:  # from the starts where the screen saw the scale only
            start, start_translation = starts[index]
            trial = scales.copy()
            trial[v] *= _nearest_start(screened)
            gauge = np.vstack([_jacobian(p.magnified(f)) for p, f in zip(projections, trial)])
            fitted_scales, fitted, cost = fit_scales_jointly(projections, centre_lines, trial, start,
                                                             scaled + [v], gauge, cutoff_px=_JOINT_CUTOFF_PX)
            trials.append((cost, fitted_scales, fitted, start_translation))
        if not trials:
            break
        cost, fitted_scales, fitted, start_translation = min(trials, key=lambda t: t[0])
        if cost > needed * best_cost:
            break
        rescaled = [p.magnified(f) for p, f in zip(projections, fitted_scales)]
        jacobians = [_jacobian(p) for p in rescaled]
        fitted, further = _gauge(fitted, jacobians)
        fitted, more = _fit_jointly(rescaled, centre_lines, fitted, jacobians)  # near-ties, as in step 6
        scales, shifts, translation = fitted_scales, fitted, start_translation + further + more
        best_cost = _scaled_cost(projections, centre_lines, scales, shifts)
        starts = [(shifts, translation)]
        needed = 1.0 - _MIN_SCALE_GAIN
    return scales, shifts, translation, history


def _scales_view_by_view(projections, masks, centre_lines, shifts_only, half_edge, threshold_px, max_shift_px,
                         min_gain, rounds) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Step 7 with more than JOINT_FIT_MAX_VIEWS views (the joint fits would take minutes): scales
    one view at a time (:func:`_scale_views`), by two routes."""
    n = len(projections)

    def cost(outcome) -> float:
        return _scaled_cost(projections, centre_lines, outcome[0], outcome[1])

    plain = (np.ones(n), *shifts_only)
    # Route 1: scales after the shifts.
    scales, shifts, further = _scale_views(projections, centre_lines, shifts_only[0])
    routes = [(scales, shifts, shifts_only[1] + further, shifts_only[2])]
    # Route 2: a wrong scale can mislead the shift search (another view moved instead), so the
    # scales are also estimated at the header's shifts first, and the shifts searched again.
    first, _, _ = _scale_views(projections, centre_lines, np.zeros((n, 2)))
    if np.any(first != 1.0):
        rescaled = [p.magnified(f) for p, f in zip(projections, first)]
        shifts, translation, history = _support_then_centrelines(
            rescaled, masks, centre_lines, [_jacobian(p) for p in rescaled], half_edge, threshold_px, max_shift_px,
            min_gain, rounds)
        more, shifts, further = _scale_views(rescaled, centre_lines, shifts)
        routes.append((first * more, shifts, translation + further, history))
    routes = [r for r in routes if np.any(r[0] != 1.0)]
    if not routes:
        return plain
    costs = [cost(r) for r in routes]
    best = routes[int(np.argmin(costs))]
    # a scale is kept only when it explains the views clearly better than shifts alone
    return best if min(costs) <= (1.0 - _MIN_SCALE_EVIDENCE) * cost(plain) else plain


def _scale_views(projections: Sequence[Projection], centre_lines: Sequence[Centreline],
                 shifts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 7 of the module notes: per-view image scales, one view per round, each followed by the
    shift fits again. Returns ``(scales, shifts, further 3D translation of the object)``."""
    n = len(projections)
    scales = np.ones(n)
    shifts = np.array(shifts, dtype=float)
    translation = np.zeros(3)
    coarse = _coarse_factors()
    for _ in range(n):
        current = [p.magnified(f) for p, f in zip(projections, scales)]
        cost_now = _scaled_cost(projections, centre_lines, scales, shifts)
        best = None
        for v in range(n):
            factor, shift, cost, cost_here = fit_view_scale(current, centre_lines, shifts, v, coarse / scales[v])
            for offsets in ((-2, -1, 1, 2), (-0.5, 0.5)):  # steps of a quarter and an eighth around the best
                fine = factor + _SCALE_STEP / 4 * np.array(offsets)
                factor_fine, shift_fine, cost_fine, _ = fit_view_scale(current, centre_lines, shifts, v, fine)
                if cost_fine < cost:
                    factor, shift, cost = factor_fine, shift_fine, cost_fine
            if factor == 1.0 or cost >= (1.0 - _MIN_SCALE_GAIN) * cost_here:
                continue
            # judged by all views: a wrong view's scale also corrupts the points the others are fitted to
            trial_scales, trial_shifts = scales.copy(), shifts.copy()
            trial_scales[v] *= factor
            trial_shifts[v] = shift
            total = _scaled_cost(projections, centre_lines, trial_scales, trial_shifts)
            if best is None or total < best[0]:
                best = (total, v, factor, shift)
        if best is None or best[0] > (1.0 - _MIN_SCALE_GAIN) * cost_now:
            break
        _, v, factor, shift = best
        scales[v] *= factor
        shifts[v] = shift
        current = [p.magnified(f) for p, f in zip(projections, scales)]
        jacobians = [_jacobian(p) for p in current]
        shifts = polish_shifts(current, centre_lines, shifts)
        shifts, further = _gauge(shifts, jacobians)
        translation = translation + further
        shifts, further = _fit_jointly(current, centre_lines, shifts, jacobians)
        translation = translation + further
    return scales, shifts, translation
