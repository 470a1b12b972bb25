"""Lumen diameters read from the angiograms' attenuation: a blurred round lumen fitted across the vessel.

A mask's width is where a threshold cuts the vessel's blurred profile. Where the lumen is a few
pixels wide or less, that cut depends on the blur, the contrast and the noise more than on the
lumen (on the QCA benchmark's segmented angiograms a lumen 1.6 px wide comes out 3 px wide), so
the minimal lumen diameter of a severe stenosis read from masks carries an error no 3D fit of them
can take out. The attenuation itself carries the lumen: by Beer–Lambert, the flattened attenuation
``A`` of a segmentation (:attr:`angiohull.segmentation.SegmentationResult.lumen_attenuation`) across a
round lumen of radius ``R`` (px at the lumen's depth) is

    A(x) = b0 + b1 x + (mu / f) 2 sqrt(R^2 - (x - c)^2)   (0 outside the lumen), blurred by G(sigma)

``x`` along the normal of the projected centreline (px), ``c`` the axis, ``mu`` the attenuation
per pixel of chord, ``f`` the vessel's foreshortening in the view (a ray crosses a lumen seen at
a slant over ``1 / f`` times its chord), ``G(sigma)`` a Gaussian (the detector's blur and the
segmentation's smoothing), ``b0 + b1 x`` the local background. Fitting the whole profile, not only
where it crosses a level, reads ``R`` without the threshold's bias and with less noise.

1. **Calibration, per view.** ``mu`` and ``sigma`` are the medians of free fits (``R``, ``c``,
   ``mu``, ``sigma``, background) at up to ``calibration_points`` points of the tree where the
   vessel is 2.5-6 px in radius (by the tree's radii), seen side on (foreshortening at least
   ``calibration_foreshortening``), clear of every other vessel in the view (below), at least
   ``calibration_clearance_mm`` from a branch's ends and from every lesion. The contrast is taken
   to be the same in every vessel of a view (one ``mu``), as videodensitometry does; with fewer
   than ``min_calibration`` such points the view measures nothing.
2. **Diameters.** At a point of the tree, in each calibrated view that sees it side on enough
   (foreshortening at least ``min_foreshortening``) and clear of other vessels, ``A`` is sampled
   along the projected normal (bilinear, every ``step_px``, out to ``reach_px`` beyond the
   reference radius) and ``R`` and ``c`` fitted with ``mu / f`` and ``sigma`` held (a grid over ``R``
   and ``c``, the background solved in closed form for each, the best ``R`` refined by a parabola);
   the diameter is ``2 R`` over the view's magnification there. The point's diameter is the median
   over the views that measure it.
3. **Lesions.** A lesion found on the tree's diameter profile (:mod:`.profile`) is measured again
   on the points of its branch within its span (start to end): the least image diameter there is
   its MLD (and that point its MLD point), over the same reference; its span and length stay the
   profile's. Where no view measures any of those points the lesion keeps the profile's values.
4. **Agreement.** A view measures a lesion only where the model reads the vessel beside it as the
   tree does: at the lesion's flanks (its branch from ``flank_gap_mm`` to ``flank_mm`` beyond either
   end of its span), the median of the view's image diameter over the tree's is within
   ``flank_agreement`` (20 %) of 1, over at least ``min_flank_points`` points. On the benchmark's
   renders every view agrees (the ratio's median 0.95); where the images break the model (on the
   real GE phantom's 8-bit runs, whose attenuation is not linear in the chord, the image diameters
   read 0.3-0.7 of the tree's everywhere, and the first version reported a 25 % narrowing of the
   main vessel as 84 %) the lesion keeps the tree's values. So does a lesion whose least image
   diameter is not below its reference diameter: the images show no narrowing there, so what they
   measure is not the lesion (since 2026-12-06: on one lattice of the benchmark a conus lesion
   whose reconstructed branch lies 2-3 mm off the vessel read -19.6 % against a true 38.8 %; from 3
   views the rule acts on no other lesion of the benchmark's four lattices or of 60 other trees,
   from 2 views with the tree method on one lesion on each of three lattices).

"Clear of other vessels": no other point of the tree (of another branch, or of the same branch
farther along it than the two radii and 1 mm) has a projected disc, widened by
``overlap_margin_px``, that reaches the sampled line.

Measured (QCA benchmark's renders, 3 segmented views, 2026-12-06; docs/qca.md): at the true lesion
point, one view at a time (trees 0-19, a least-squares version of the same model), MLD error
-0.005 ± 0.091 mm, against the densitometric integral (:mod:`angiohull.densitometry`) +0.071 ±
0.146 mm; calibration ``sigma`` 1.2 px (the renderer's 0.6 px and the segmentation's 1 px
smoothing: 1.17 px). Lesions of the benchmark's 60 trees (steps 1-4, on the segmentation's
unclipped attenuation, :attr:`~angiohull.segmentation.SegmentationResult.lumen_attenuation`, since
2026-12-06): %DS -0.3 ± 3.8 points and MLD +0.014 ± 0.079 mm, where the tree's own diameters
(masks) give -1.5 ± 6.7 and +0.040 ± 0.129; on 60 other trees -0.7 ± 5.0 against -1.8 ± 7.2, and
on lattices 0.3 % coarser / finer and 0.6 % coarser 5.6 / 5.0 / 4.8 (on the clipped attenuation:
4.3 on the benchmark's, 5.8 on the 60 others, 5.9 / - / 5.3).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..errors import QcaError
from ..geometry import Projection
from ..tree import VesselTree

__all__ = ["AttenuationFitSettings", "ViewCalibration", "AttenuationMeasurement", "calibrate_views",
           "image_diameters", "blurred_lumen_profile"]

_FINE_PX = 0.05  # the grid the blurred lumen profiles are tabulated on, px
_CHUNK = 64  # profiles fitted at once (bounds the (profiles, radii, samples) array)


@dataclass(frozen=True)
class AttenuationFitSettings:
    """Every setting of the fit (module notes); the same defaults for every tree."""

    step_px: float = 0.25  # sampling step along the normal, px
    reach_px: float = 4.0  # the profile reaches this far beyond the (reference) radius, px
    overlap_margin_px: float = 3.0  # another vessel's disc widened by this spoils a profile
    min_foreshortening: float = 0.6  # a view measures a point it sees at least this side on
    calibration_foreshortening: float = 0.8
    calibration_radius_px: tuple[float, float] = (2.5, 6.0)
    calibration_clearance_mm: float = 6.0  # from a branch's ends and from every lesion
    calibration_points: int = 40  # per view, spread along the candidates
    min_calibration: int = 8
    blur_grid_px: tuple[float, float, float] = (0.3, 2.5, 0.1)  # sigma searched in calibration: start, stop, step
    centre_grid_px: tuple[float, float] = (1.5, 0.25)  # c searched within +- this, in these steps
    radius_step_px: float = 0.05
    flank_mm: float = 3.0  # a lesion's flanks: its branch this far beyond its span (step 4) ...
    flank_gap_mm: float = 0.5  # ... from this far beyond it
    flank_agreement: float = 0.2  # a view measures the lesion where its flanks read within this share of the tree's
    min_flank_points: int = 3

    def __post_init__(self) -> None:
        for name in ("step_px", "reach_px", "radius_step_px", "flank_mm", "flank_agreement"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise QcaError(f"AttenuationFitSettings.{name} must be a positive number, got {value!r}")
        if not 0 < self.min_foreshortening <= 1 or not 0 < self.calibration_foreshortening <= 1:
            raise QcaError("AttenuationFitSettings.min_foreshortening and calibration_foreshortening must lie in "
                           f"(0, 1], got {self.min_foreshortening!r} and {self.calibration_foreshortening!r}")
        lo, hi = self.calibration_radius_px
        if not 0 < lo < hi:
            raise QcaError(f"AttenuationFitSettings.calibration_radius_px must be (low, high) with 0 < low < high, "
                           f"got {self.calibration_radius_px!r}")
        if self.min_calibration < 1 or self.calibration_points < self.min_calibration:
            raise QcaError("AttenuationFitSettings.calibration_points must be at least min_calibration (>= 1), got "
                           f"{self.calibration_points!r} and {self.min_calibration!r}")


@dataclass(frozen=True)
class ViewCalibration:
    """One view's calibration (module notes, step 1); ``attenuation_per_px`` is NaN where the view
    had fewer than ``min_calibration`` points (it then measures nothing)."""

    attenuation_per_px: float  # mu: attenuation per pixel of chord, side on
    blur_px: float  # sigma of the Gaussian blur, px
    points: int  # calibration points used

    @property
    def usable(self) -> bool:
        return math.isfinite(self.attenuation_per_px) and self.attenuation_per_px > 0

    def to_dict(self) -> dict:
        return {"attenuation_per_px": self.attenuation_per_px, "blur_px": self.blur_px, "points": self.points}


@dataclass(frozen=True)
class AttenuationMeasurement:
    """Image diameters at some points of a tree: ``diameter_mm`` (nan where no view measured the
    point), ``views`` (how many did) and the per-view values ``(V, N)`` (nan where a view did not)."""

    diameter_mm: np.ndarray
    views: np.ndarray
    per_view_mm: np.ndarray


def blurred_lumen_profile(x_px: np.ndarray, radius_px: float, blur_px: float) -> np.ndarray:
    """``2 sqrt(R^2 - x^2)`` (0 beyond ``R``) convolved with a Gaussian of sigma ``blur_px``, at ``x_px``:
    the exact integral, evaluated by quadrature on a fine grid (the oracle of the tabulated fit)."""
    from scipy.stats import norm

    x = np.asarray(x_px, dtype=np.float64)
    t = np.linspace(-radius_px, radius_px, 4001)
    chord = 2.0 * np.sqrt(np.maximum(radius_px ** 2 - t ** 2, 0.0))
    kernel = norm.pdf((x[:, None] - t[None, :]) / blur_px) / blur_px
    return np.trapezoid(chord[None, :] * kernel, t, axis=1) if hasattr(np, "trapezoid") else np.trapz(
        chord[None, :] * kernel, t, axis=1)


class _Table:
    """Blurred lumen profiles ``G_R(x)`` for one sigma and a grid of radii, on a fine x grid."""

    def __init__(self, radii_px: np.ndarray, blur_px: float, half_px: float):
        self.radii = radii_px
        self.x = np.arange(-half_px, half_px + 1e-9, _FINE_PX)
        # each fine cell holds the chord's mean over the cell (its exact integral over the width): a
        # lumen a pixel or two wide keeps its area on the grid
        r = radii_px[:, None]
        edges = np.clip((np.append(self.x, self.x[-1] + _FINE_PX) - 0.5 * _FINE_PX)[None, :], -r, r)
        area = edges * np.sqrt(np.maximum(r * r - edges * edges, 0.0)) + r * r * np.arcsin(edges / r)
        chord = np.diff(area, axis=1) / _FINE_PX
        k = np.arange(-math.ceil(5.0 * blur_px / _FINE_PX), math.ceil(5.0 * blur_px / _FINE_PX) + 1) * _FINE_PX
        kernel = np.exp(-0.5 * (k / blur_px) ** 2)
        n = chord.shape[1] + len(k) - 1
        size = 1 << (n - 1).bit_length()
        full = np.fft.irfft(np.fft.rfft(chord, size, axis=1) * np.fft.rfft(kernel / kernel.sum(), size)[None, :],
                            size, axis=1)
        lag = (len(k) - 1) // 2
        self.values = full[:, lag:lag + chord.shape[1]]  # the "same" part of the full convolution

    def at(self, q: np.ndarray) -> np.ndarray:
        """``(R, *q.shape)``: every radius's profile at offsets ``q`` (px; linear interpolation)."""
        pos = np.clip((q - self.x[0]) / _FINE_PX, 0.0, len(self.x) - 1.000001)
        i = pos.astype(np.int64)
        w = pos - i
        return self.values[:, i] * (1.0 - w) + self.values[:, i + 1] * w


def _detrended(values: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``values`` (..., S) less their least-squares line in ``q`` (S,) along the last axis."""
    qc = q - q.mean()
    slope = (values * qc).sum(axis=-1, keepdims=True) / float((qc * qc).sum())
    return values - values.mean(axis=-1, keepdims=True) - slope * qc


@dataclass
class _Geometry:
    uv: np.ndarray  # (N, 2) px
    px_per_mm: np.ndarray  # (N,)
    foreshortening: np.ndarray  # (N,)
    normal: np.ndarray  # (N, 2) unit, (u, v)


def _geometry(projection: Projection, points: np.ndarray, tangents: np.ndarray) -> _Geometry:
    uv = projection.project(points)
    px_per_mm = max(projection.focal_lengths_px) / projection.depth_mm(points)
    d2 = np.einsum("nij,nj->ni", projection.jacobian(points), tangents)
    length = np.linalg.norm(d2, axis=1)
    direction = d2 / np.maximum(length, 1e-12)[:, None]
    return _Geometry(uv, px_per_mm, length / px_per_mm, np.column_stack([-direction[:, 1], direction[:, 0]]))


@dataclass
class _TreeArrays:
    points: np.ndarray
    radius: np.ndarray
    owner: np.ndarray
    arc: np.ndarray
    length: np.ndarray  # of the point's branch
    tangents: np.ndarray
    offsets: np.ndarray  # first point of each branch


def _arrays(tree: VesselTree) -> _TreeArrays:
    points, radius, owner = tree.points()
    arc = np.concatenate([b.arc_length_mm for b in tree.branches])
    length = np.array([b.length_mm for b in tree.branches])[owner]
    offsets = np.concatenate([[0], np.cumsum([b.n_points for b in tree.branches])])
    return _TreeArrays(points, radius, owner, arc, length, np.concatenate([b.tangents() for b in tree.branches]),
                       offsets)


def _clear(t: _TreeArrays, g: _Geometry, index: np.ndarray, half_px: np.ndarray, margin_px: float) -> np.ndarray:
    """(len(index),) bool: no other vessel's projected disc (widened by ``margin_px``) reaches the
    profile line of each point (module notes)."""
    from scipy.spatial import cKDTree

    radius_px = t.radius * g.px_per_mm
    kd = cKDTree(g.uv)
    out = np.ones(len(index), dtype=bool)
    reach = half_px + radius_px.max() + margin_px
    for k, (i, near) in enumerate(zip(index, kd.query_ball_point(g.uv[index], reach))):
        near = np.asarray(near, dtype=np.int64)
        same = (t.owner[near] == t.owner[i]) & (np.abs(t.arc[near] - t.arc[i]) <= t.radius[near] + t.radius[i] + 1.0)
        near = near[~same]
        if len(near) == 0:
            continue
        d = g.uv[near] - g.uv[i]
        along = np.clip(d @ g.normal[i], -half_px[k], half_px[k])
        off = np.linalg.norm(d - along[:, None] * g.normal[i][None, :], axis=1)
        out[k] = not np.any(off < radius_px[near] + margin_px)
    return out


def _profiles(image: np.ndarray, g: _Geometry, index: np.ndarray, q: np.ndarray) -> np.ndarray:
    from scipy import ndimage as ndi

    u = g.uv[index, 0, None] + q[None, :] * g.normal[index, 0, None]
    v = g.uv[index, 1, None] + q[None, :] * g.normal[index, 1, None]
    return ndi.map_coordinates(image, [v.ravel(), u.ravel()], order=1, mode="nearest").reshape(u.shape)


def _centres(settings: AttenuationFitSettings) -> np.ndarray:
    half, step = settings.centre_grid_px
    return np.arange(-half, half + 1e-9, step)


@dataclass(frozen=True)
class _CalibrationTemplates:
    """The free fit's model profiles, which depend on the settings alone: per blur of the grid and
    per centre offset, every radius's blurred lumen sampled on ``q`` and detrended, with its sum of
    squares."""

    half_px: int  # every calibration profile's half-length
    radii: np.ndarray  # (R,) px
    q: np.ndarray  # (S,) px
    blurs: tuple[float, ...]
    shapes: tuple[tuple[np.ndarray, ...], ...]  # [blur][centre]: (R, S)
    norms: tuple[tuple[np.ndarray, ...], ...]  # [blur][centre]: (R,)


@functools.lru_cache(maxsize=2)
def _calibration_templates(settings: AttenuationFitSettings) -> _CalibrationTemplates:
    """Built once per settings (about 30 MB with the defaults) instead of once per view."""
    lo, hi = settings.calibration_radius_px
    half_px = math.ceil(hi + settings.reach_px)
    radii = np.arange(0.5 * lo, 1.5 * hi + 1e-9, settings.radius_step_px)
    q = np.arange(-half_px, half_px + 1e-9, settings.step_px)
    centres = _centres(settings)
    start, stop, step = settings.blur_grid_px
    blurs, shapes, norms = [], [], []
    for sigma in np.arange(start, stop + 1e-9, step):
        table = _Table(radii, float(sigma), half_px + centres.max() + 1.0)
        gts = tuple(_detrended(table.at(q - c), q) for c in centres)
        for gt in gts:
            gt.flags.writeable = False
        blurs.append(float(sigma))
        shapes.append(gts)
        norms.append(tuple((gt * gt).sum(axis=1) for gt in gts))
    return _CalibrationTemplates(half_px, radii, q, tuple(blurs), tuple(shapes), tuple(norms))


def _fit_free(y: np.ndarray, radius0_px: np.ndarray, templates: _CalibrationTemplates
              ) -> tuple[np.ndarray, np.ndarray]:
    """Per profile, the amplitude (``mu / f``) and blur of the best free fit (calibration): over the
    blurs and centres of ``templates``, radii within half of ``radius0_px`` either way."""
    radii = templates.radii
    yt = _detrended(y, templates.q)  # (P, S)
    best = np.full(len(y), np.inf)
    amp = np.full(len(y), np.nan)
    blur = np.full(len(y), np.nan)
    window = (radii[None, :] >= 0.5 * radius0_px[:, None]) & (radii[None, :] <= 1.5 * radius0_px[:, None])  # (P, R)
    for sigma, shapes, norms in zip(templates.blurs, templates.shapes, templates.norms):
        for gt, gg in zip(shapes, norms):  # (R, S), (R,)
            yg = yt @ gt.T  # (P, R)
            a = yg / np.maximum(gg, 1e-12)[None, :]
            ss = (yt * yt).sum(axis=1)[:, None] - yg * a
            ss = np.where(window & (a > 0), ss, np.inf)
            r = np.argmin(ss, axis=1)
            value = ss[np.arange(len(y)), r]
            better = value < best
            best[better] = value[better]
            amp[better] = a[np.arange(len(y)), r][better]
            blur[better] = sigma
    return amp, blur


def _fit_radius(y: np.ndarray, q: np.ndarray, amplitude: np.ndarray, table: _Table,
                settings: AttenuationFitSettings) -> np.ndarray:
    """Per profile, ``R`` (px) with the amplitude held (module notes, step 2)."""
    if len(y) > _CHUNK:
        return np.concatenate([_fit_radius(y[k:k + _CHUNK], q, amplitude[k:k + _CHUNK], table, settings)
                               for k in range(0, len(y), _CHUNK)])
    yt = _detrended(y, q)  # (P, S)
    best = np.full(len(y), np.inf)
    out = np.full(len(y), np.nan)
    for c in _centres(settings):
        gt = _detrended(table.at(q - c), q)  # (R, S)
        model = amplitude[:, None, None] * gt[None, :, :]  # (P, R, S)
        ss = ((yt[:, None, :] - model) ** 2).sum(axis=2)  # (P, R)
        r = np.argmin(ss, axis=1)
        rows = np.arange(len(y))
        value = ss[rows, r]
        # a parabola through the neighbours refines R
        left, right = np.clip(r - 1, 0, len(table.radii) - 1), np.clip(r + 1, 0, len(table.radii) - 1)
        s0, s1, s2 = ss[rows, left], value, ss[rows, right]
        denom = s0 - 2.0 * s1 + s2
        shift = np.where((left < r) & (right > r) & (denom > 0), 0.5 * (s0 - s2) / np.maximum(denom, 1e-300), 0.0)
        radius = table.radii[r] + np.clip(shift, -0.5, 0.5) * settings.radius_step_px
        better = value < best
        best[better] = value[better]
        out[better] = radius[better]
    return out


def calibrate_views(tree: VesselTree, projections: Sequence[Projection], attenuation: Sequence[np.ndarray],
                    avoid_mm: np.ndarray | None = None,
                    settings: AttenuationFitSettings = AttenuationFitSettings()) -> list[ViewCalibration]:
    """Each view's ``mu`` and blur from the tree's healthy vessels (module notes, step 1).
    ``avoid_mm`` (K, 3): points (lesions) the calibration keeps ``calibration_clearance_mm`` from."""
    images = _check_views(projections, attenuation)
    t = _arrays(tree)
    clearance = settings.calibration_clearance_mm
    ok = (t.arc >= clearance) & (t.length - t.arc >= clearance)
    ends = np.concatenate([t.points[t.offsets[:-1]], t.points[t.offsets[1:] - 1]])
    avoid = ends if avoid_mm is None or len(avoid_mm) == 0 else np.vstack([ends, np.asarray(avoid_mm, float).reshape(-1, 3)])
    from scipy.spatial import cKDTree

    ok &= cKDTree(avoid).query(t.points)[0] >= clearance
    out = []
    lo, hi = settings.calibration_radius_px
    for projection, image in zip(projections, images):
        g = _geometry(projection, t.points, t.tangents)
        radius_px = t.radius * g.px_per_mm
        candidates = np.flatnonzero(ok & (radius_px >= lo) & (radius_px <= hi)
                                    & (g.foreshortening >= settings.calibration_foreshortening))
        templates = _calibration_templates(settings)  # one profile length for every calibration point
        candidates = candidates[_clear(t, g, candidates, np.full(len(candidates), float(templates.half_px)),
                                       settings.overlap_margin_px)]
        if len(candidates) > settings.calibration_points:
            candidates = candidates[np.linspace(0, len(candidates) - 1, settings.calibration_points).round().astype(int)]
        if len(candidates) < settings.min_calibration:
            out.append(ViewCalibration(float("nan"), float("nan"), int(len(candidates))))
            continue
        amp, blur = _fit_free(_profiles(image, g, candidates, templates.q), radius_px[candidates], templates)
        amp = amp * g.foreshortening[candidates]
        good = np.isfinite(amp) & (amp > 0)
        if good.sum() < settings.min_calibration:
            out.append(ViewCalibration(float("nan"), float("nan"), int(good.sum())))
            continue
        out.append(ViewCalibration(float(np.median(amp[good])), float(np.median(blur[good])), int(good.sum())))
    return out


def _groups(half_px: np.ndarray) -> list[np.ndarray]:
    """Indices grouped by the whole pixels of their profile's half-length (profiles of one length
    are fitted together)."""
    keys = np.ceil(half_px).astype(np.int64)
    return [np.flatnonzero(keys == k) for k in np.unique(keys)]


def image_diameters(tree: VesselTree, points: np.ndarray, projections: Sequence[Projection],
                    attenuation: Sequence[np.ndarray], calibrations: Sequence[ViewCalibration],
                    reference_radius_mm: np.ndarray | None = None,
                    settings: AttenuationFitSettings = AttenuationFitSettings()) -> AttenuationMeasurement:
    """The image diameter (module notes, step 2) at the tree's points ``points`` (indices into
    :meth:`VesselTree.points` order). ``reference_radius_mm`` (len(points),) sets each profile's
    reach (the tree's radius where not given)."""
    images = _check_views(projections, attenuation)
    if len(calibrations) != len(images):
        raise QcaError(f"one calibration per view is needed: {len(calibrations)} for {len(images)} views")
    t = _arrays(tree)
    index = np.asarray(points, dtype=np.int64).reshape(-1)
    if index.size and (index.min() < 0 or index.max() >= len(t.points)):
        raise QcaError(f"point indices must lie in 0..{len(t.points) - 1}, got {index.min()}..{index.max()}")
    reach_mm = t.radius[index] if reference_radius_mm is None else np.maximum(np.asarray(reference_radius_mm, float),
                                                                             t.radius[index])
    per_view = np.full((len(images), len(index)), np.nan)
    for v, (projection, image, cal) in enumerate(zip(projections, images, calibrations)):
        if not cal.usable or len(index) == 0:
            continue
        g = _geometry(projection, t.points, t.tangents)
        half = reach_mm * g.px_per_mm[index] + settings.reach_px
        use = g.foreshortening[index] >= settings.min_foreshortening
        use[use] = _clear(t, g, index[use], half[use], settings.overlap_margin_px)
        if not use.any():
            continue
        sel = np.flatnonzero(use)
        radii = np.arange(settings.radius_step_px, float(half[sel].max()) + 1e-9, settings.radius_step_px)
        table = _Table(radii, cal.blur_px, float(np.ceil(half[sel].max())) + _centres(settings).max() + 1.0)
        for group in _groups(half[sel]):
            k = sel[group]
            h = float(np.ceil(half[k].max()))
            q = np.arange(-h, h + 1e-9, settings.step_px)
            y = _profiles(image, g, index[k], q)
            amplitude = cal.attenuation_per_px / g.foreshortening[index[k]]
            radius_px = _fit_radius(y, q, amplitude, table, settings)
            per_view[v, k] = 2.0 * radius_px / g.px_per_mm[index[k]]
    views = np.isfinite(per_view).sum(axis=0)
    diameter = np.full(len(index), np.nan)
    seen = views > 0
    if seen.any():
        diameter[seen] = np.nanmedian(per_view[:, seen], axis=0)
    return AttenuationMeasurement(diameter, views, per_view)


def _check_views(projections: Sequence[Projection], attenuation: Sequence[np.ndarray]) -> list[np.ndarray]:
    if len(projections) != len(attenuation):
        raise QcaError(f"one attenuation image per view is needed: {len(attenuation)} images for "
                       f"{len(projections)} projections")
    images = []
    for k, (projection, image) in enumerate(zip(projections, attenuation)):
        a = np.asarray(image, dtype=np.float64)
        if a.ndim != 2:
            raise QcaError(f"attenuation image {k} must be 2D (rows, cols), got shape {a.shape}")
        if a.shape != tuple(projection.image_shape):
            raise QcaError(f"attenuation image {k} has shape {a.shape}; its projection's image is "
                           f"{tuple(projection.image_shape)} (rows, cols)")
        if not np.all(np.isfinite(a)):
            raise QcaError(f"attenuation image {k} has non-finite values")
        images.append(a)
    return images
