"""Diameter profiles along a branch: the healthy taper, lesions, minimal lumen diameter, % stenosis.

Notation: a branch of M points has arc length ``a`` (mm, 0 at its first point) and lumen diameter
``d(a) = 2 r(a)`` (mm). The analysis, with the defaults of :class:`ProfileSettings`:

1. **Junction.** A side branch's first ``junction_mm(a)`` of arc lie inside its parent's lumen
   (its first point is on the parent's centerline), where a diameter says nothing about the side
   branch: the points with ``a <`` the parent's radius at the bifurcation are left out of steps 2
   and 3.
2. **Reference (healthy taper).** A straight line ``ref(a) = d0 + slope * a`` fitted robustly to
   the profile: a Theil–Sen start, then least squares on the points whose residual lies within
   ``[-k_low s, +k_high s]``, repeated until the set no longer changes, where ``s`` is 1.4826 times
   the median absolute residual of the kept points (the noise), at least ``noise_floor`` times
   the median diameter. Narrowings (negative residuals) and flares at bifurcations (positive ones)
   thus drop out of the fit. A profile shorter than ``min_reference_length_mm`` or with fewer
   than ``min_reference_points`` points has no reference (:class:`~angiohull.errors.QcaError`
   when it is asked for).
3. **Lesions.** The narrowing is ``n(a) = 1 - d(a) / ref(a)``. Lesions are *found* on the
   narrowing of the profile smoothed along the arc, ``n_s(a) = 1 - d_s(a) / ref(a)`` with ``d_s``
   a Gaussian average of ``d`` of ``detection_smoothing_mm`` (sigma, mm; truncated at 4 sigma,
   normalised where it reaches an end): a dip of one or two samples, which the diameter's own
   noise makes, does not start a lesion, while a stenosis, millimetres long, barely changes.
   Every local maximum of ``n_s`` of at least ``min_stenosis_pct`` percent, taken from the
   deepest down, starts a lesion that spans on each side the samples where ``n_s`` stays above
   ``edge_fraction`` of that maximum; a maximum inside an earlier lesion, or whose span runs into
   one before falling below its own edge level, adds nothing (it is a shoulder of that deeper
   lesion). A narrowing that still exceeds its edge level at an end of the analysed profile is not
   a focal lesion (a tapering tip, a vessel cut at the image border) and is not reported.
4. **Per lesion**, *measured* on the profile itself, not the smoothed one: the minimal lumen
   diameter ``MLD = min d`` over the lesion's span, its point (the patient-frame ``x, y, z`` of
   that centerline point), the reference diameter ``ref`` there, the percent diameter stenosis
   ``100 (1 - MLD / ref)`` and area stenosis ``100 (1 - (MLD / ref)^2)``; the start and end arc
   lengths where ``n`` falls below ``edge_fraction`` of its largest value over the span, walking
   out from that sample (the crossing interpolated linearly between points; where ``n`` stays
   above that level up to an end of the profile or into another lesion's span, the smoothed
   narrowing's crossing), and the lesion length ``end - start``. ``detection_smoothing_mm = 0``
   finds lesions on the profile itself.

For the synthetic generator's windows (:mod:`angiohull.synthetic.tree`) of severity ``s`` and
extent ``L`` on a straight taper, these definitions give %DS = 100 s and, with the default edge
fraction 1/4, a lesion length of ``(L / pi) arccos(2 * 0.25 - 1) = 2 L / 3`` for the raised cosine
and ``2 sigma sqrt(2 ln 4) = (L / 3) sqrt(2 ln 4) = 0.555 L`` for the Gaussian (``sigma = L / 6``):
:func:`window_lesion_length_mm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import _validation as _v
from ..errors import QcaError

__all__ = ["ProfileSettings", "ReferenceFit", "Lesion", "DiameterProfile", "reference_fit", "smoothed_along",
           "find_lesions", "window_lesion_length_mm"]


@dataclass(frozen=True)
class ProfileSettings:
    """Settings of the diameter-profile analysis (module notes); the same for every tree."""

    min_stenosis_pct: float = 20.0  # a narrowing of less than this is not reported as a lesion
    detection_smoothing_mm: float = 0.5  # sigma of the Gaussian along the arc that lesions are found on (0: none)
    edge_fraction: float = 0.25  # a lesion ends where the narrowing falls below this share of its maximum
    k_low: float = 2.5  # residuals below -k_low * noise are left out of the reference fit (lesions)
    k_high: float = 3.5  # residuals above +k_high * noise are left out too (flares at bifurcations)
    noise_floor: float = 0.01  # the noise scale is at least this share of the median diameter
    min_reference_length_mm: float = 10.0  # a shorter profile has no reference diameter
    min_reference_points: int = 8
    max_iterations: int = 50

    def __post_init__(self) -> None:
        for name in ("k_low", "k_high", "noise_floor", "min_reference_length_mm"):
            _v.positive_finite(getattr(self, name), f"ProfileSettings.{name}", error=QcaError)
        if not 0.0 < _v.finite(self.min_stenosis_pct, "ProfileSettings.min_stenosis_pct", error=QcaError) < 100.0:
            raise QcaError(f"ProfileSettings.min_stenosis_pct must lie in (0, 100), got {self.min_stenosis_pct!r}")
        if not _v.finite(self.detection_smoothing_mm, "ProfileSettings.detection_smoothing_mm", error=QcaError) >= 0.0:
            raise QcaError(f"ProfileSettings.detection_smoothing_mm must be >= 0 (0: no smoothing), got "
                           f"{self.detection_smoothing_mm!r}")
        if not 0.0 < _v.finite(self.edge_fraction, "ProfileSettings.edge_fraction", error=QcaError) < 1.0:
            raise QcaError(f"ProfileSettings.edge_fraction must lie in (0, 1), got {self.edge_fraction!r}")
        _v.positive_int(self.min_reference_points, "ProfileSettings.min_reference_points", error=QcaError)
        _v.positive_int(self.max_iterations, "ProfileSettings.max_iterations", error=QcaError)


@dataclass(frozen=True)
class ReferenceFit:
    """The healthy taper ``ref(a) = diameter_at_start_mm + slope_mm_per_mm * a``."""

    diameter_at_start_mm: float  # ref(0), mm
    slope_mm_per_mm: float  # d ref / d a (negative: tapering), mm per mm of arc
    noise_mm: float  # robust scale of the residuals of the points kept, mm
    kept: np.ndarray  # (M,) bool: the points the fit used

    def __call__(self, arc_mm: np.ndarray) -> np.ndarray:
        return self.diameter_at_start_mm + self.slope_mm_per_mm * np.asarray(arc_mm, dtype=np.float64)


@dataclass(frozen=True)
class Lesion:
    """A focal narrowing of one branch (module notes, step 4); arc lengths along that branch."""

    branch: int
    start_mm: float
    end_mm: float
    mld_arc_mm: float  # arc length of the point of minimal lumen diameter
    mld_point_mm: tuple[float, float, float]  # that point, patient frame, mm
    mld_mm: float  # minimal lumen diameter
    reference_diameter_mm: float  # ref at the MLD point
    diameter_stenosis_pct: float
    area_stenosis_pct: float
    mld_source: str = "tree"  # "tree": the profile's own MLD; "images": measured again on the angiograms (:mod:`.attenuation`)

    @property
    def length_mm(self) -> float:
        return self.end_mm - self.start_mm

    def to_dict(self) -> dict:
        return {"branch": self.branch, "start_mm": self.start_mm, "end_mm": self.end_mm,
                "lesion_length_mm": self.length_mm, "mld_arc_mm": self.mld_arc_mm,
                "mld_point_mm": list(self.mld_point_mm), "mld_mm": self.mld_mm,
                "reference_diameter_mm": self.reference_diameter_mm,
                "diameter_stenosis_pct": self.diameter_stenosis_pct, "area_stenosis_pct": self.area_stenosis_pct,
                "mld_source": self.mld_source}


@dataclass(frozen=True)
class DiameterProfile:
    """One branch's profile: the samples, which of them were analysed, the reference and lesions."""

    branch: int
    arc_mm: np.ndarray  # (M,) arc length, mm
    diameter_mm: np.ndarray  # (M,) lumen diameter, mm
    analysed: np.ndarray  # (M,) bool: outside the junction with the parent (step 1)
    reference: ReferenceFit | None  # None: too short for a reference (``reason`` says why)
    lesions: tuple[Lesion, ...]
    reason: str = ""
    vessel: tuple[int, ...] = ()  # the branches read as one vessel with this one, proximal first (:mod:`.vessels`)
    # (M,) the diameter smoothed along the vessel that lesions are found on (step 3), mm; nan where
    # not analysed or without a reference; None when not computed
    smoothed_diameter_mm: np.ndarray | None = None

    def reference_mm(self) -> np.ndarray:
        """(M,) reference diameter at every sample (nan without a reference)."""
        if self.reference is None:
            return np.full(self.arc_mm.shape, np.nan)
        return self.reference(self.arc_mm)


def _theil_sen(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Median of pairwise slopes and the median intercept (pairs subsampled to at most ~20k)."""
    n = len(x)
    stride = max(1, int(math.ceil(n / 200)))
    xs, ys = x[::stride], y[::stride]
    i, j = np.triu_indices(len(xs), k=1)
    dx = xs[j] - xs[i]
    good = dx > 0
    slope = float(np.median((ys[j] - ys[i])[good] / dx[good])) if good.any() else 0.0
    return float(np.median(y - slope * x)), slope


def reference_fit(arc_mm: np.ndarray, diameter_mm: np.ndarray, settings: ProfileSettings = ProfileSettings(),
                  *, what: str = "profile") -> ReferenceFit:
    """The robust straight-line reference of a diameter profile (module notes, step 2).

    Parameters
    ----------
    arc_mm, diameter_mm : (M,) arrays
        Arc length (increasing) and diameter, mm.
    settings : ProfileSettings
    what : str
        Names the profile in errors (e.g. ``"branch 3 ('b3')"``).

    Raises
    ------
    QcaError
        If the profile is shorter than ``settings.min_reference_length_mm`` or has fewer than
        ``settings.min_reference_points`` points.
    """
    arc = np.asarray(arc_mm, dtype=np.float64)
    diameter = np.asarray(diameter_mm, dtype=np.float64)
    length = float(arc[-1] - arc[0]) if arc.size else 0.0
    if arc.size < settings.min_reference_points or length < settings.min_reference_length_mm:
        raise QcaError(f"{what}: {length:.1f} mm and {arc.size} point(s) are too short for a reference diameter "
                       f"fit, which needs at least {settings.min_reference_length_mm:g} mm and "
                       f"{settings.min_reference_points} points (ProfileSettings.min_reference_length_mm, "
                       f"min_reference_points)")
    floor = settings.noise_floor * float(np.median(diameter))
    intercept, slope = _theil_sen(arc, diameter)
    kept = np.ones(arc.shape, dtype=bool)
    noise = floor
    for _ in range(settings.max_iterations):
        residual = diameter - (intercept + slope * arc)
        noise = max(1.4826 * float(np.median(np.abs(residual[kept] - np.median(residual[kept])))), floor)
        new = (residual >= -settings.k_low * noise) & (residual <= settings.k_high * noise)
        if np.count_nonzero(new) < max(2, settings.min_reference_points // 2):
            break  # nothing left to fit: keep the last line
        slope, intercept = np.polyfit(arc[new], diameter[new], 1)
        slope, intercept = float(slope), float(intercept)
        if np.array_equal(new, kept):
            break
        kept = new
    return ReferenceFit(intercept, slope, noise, kept)


def _crossing(arc: np.ndarray, values: np.ndarray, i_in: int, i_out: int, level: float) -> float:
    """Arc length where ``values`` crosses ``level`` between the neighbours ``i_in`` (above) and
    ``i_out`` (below), linearly interpolated."""
    a, b = values[i_in], values[i_out]
    t = (a - level) / (a - b) if a != b else 0.5
    return float(arc[i_in] + t * (arc[i_out] - arc[i_in]))


def smoothed_along(arc_mm: np.ndarray, values: np.ndarray, sigma_mm: float) -> np.ndarray:
    """A Gaussian average of ``values`` along the arc: at each sample, the mean of the samples
    within ``4 sigma_mm`` of arc, weighted ``exp(-(delta a)^2 / (2 sigma_mm^2))`` and normalised
    (so that it stays an average where the window reaches an end). ``sigma_mm = 0``: a copy."""
    arc = np.asarray(arc_mm, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if sigma_mm <= 0.0 or arc.size < 2:
        return values.copy()
    reach = 4.0 * sigma_mm
    first = np.searchsorted(arc, arc - reach, side="left")
    stop = np.searchsorted(arc, arc + reach, side="right")
    span = int((stop - first).max())
    index = first[:, None] + np.arange(span)[None, :]
    inside = index < stop[:, None]
    index = np.minimum(index, arc.size - 1)
    weight = np.where(inside, np.exp(-0.5 * ((arc[index] - arc[:, None]) / sigma_mm) ** 2), 0.0)
    return (weight * values[index]).sum(axis=1) / weight.sum(axis=1)


def _narrowing(diameter: np.ndarray, reference: np.ndarray) -> np.ndarray:
    narrowing = 1.0 - diameter / np.where(reference > 0, reference, np.nan)
    return np.where(np.isfinite(narrowing), narrowing, 0.0)


def _spans(narrowing: np.ndarray, settings: ProfileSettings) -> list[tuple[int, int]]:
    """The closed lesions' sample spans ``(left, right)`` on a narrowing (module notes, step 3)."""
    m = len(narrowing)
    threshold = settings.min_stenosis_pct / 100.0
    padded = np.concatenate([[-np.inf], narrowing, [-np.inf]])
    peaks = np.flatnonzero((narrowing >= threshold) & (narrowing >= padded[:-2]) & (narrowing >= padded[2:]))
    claimed = np.zeros(m, dtype=bool)
    spans = []
    for peak in peaks[np.argsort(-narrowing[peaks], kind="stable")]:
        if claimed[peak]:
            continue
        level = settings.edge_fraction * narrowing[peak]
        left = peak
        while left > 0 and narrowing[left - 1] >= level and not claimed[left - 1]:
            left -= 1
        right = peak
        while right < m - 1 and narrowing[right + 1] >= level and not claimed[right + 1]:
            right += 1
        joins = (left > 0 and claimed[left - 1]) or (right < m - 1 and claimed[right + 1])
        claimed[left:right + 1] = True
        if joins:
            continue  # runs into a deeper lesion above its own edge level: part of that one
        if left == 0 or right == m - 1:
            continue  # open-ended: reaches an end of the analysed profile
        spans.append((int(left), int(right)))
    return spans


def _edge(arc: np.ndarray, narrowing: np.ndarray, k: int, step: int, level: float, owner: np.ndarray,
          own: int) -> float | None:
    """Arc length where ``narrowing`` first falls below ``level`` walking from sample ``k`` by
    ``step`` (-1 or +1); None where it does not before an end or another lesion's span."""
    i = k
    while 0 <= i + step < len(arc) and owner[i + step] in (-1, own):
        if narrowing[i + step] < level:
            return _crossing(arc, narrowing, i, i + step, level)
        i += step
    return None


def find_lesions(branch: int, arc_mm: np.ndarray, diameter_mm: np.ndarray, reference_mm: np.ndarray,
                 points_mm: np.ndarray, settings: ProfileSettings = ProfileSettings(), *,
                 smoothed_mm: np.ndarray | None = None) -> tuple[Lesion, ...]:
    """The lesions of an analysed profile (module notes, steps 3 and 4), ordered along the branch:
    found on the profile smoothed by ``settings.detection_smoothing_mm``, measured on the profile.

    ``arc_mm``, ``diameter_mm``, ``reference_mm`` are (M,), ``points_mm`` (M, 3): the analysed
    samples only, contiguous. ``smoothed_mm`` (M,): that smoothed diameter, when the caller has it
    (:func:`smoothed_along`).
    """
    arc = np.asarray(arc_mm, dtype=np.float64)
    diameter = np.asarray(diameter_mm, dtype=np.float64)
    reference = np.asarray(reference_mm, dtype=np.float64)
    if smoothed_mm is None:
        smoothed_mm = smoothed_along(arc, diameter, settings.detection_smoothing_mm)
    narrowing = _narrowing(diameter, reference)
    found_on = _narrowing(np.asarray(smoothed_mm, dtype=np.float64), reference)
    spans = _spans(found_on, settings)
    owner = np.full(len(arc), -1)
    for n, (left, right) in enumerate(spans):
        owner[left:right + 1] = n
    lesions: list[Lesion] = []
    for n, (left, right) in enumerate(spans):
        inside = np.arange(left, right + 1)
        k = int(inside[np.argmin(diameter[inside])])
        mld, ref = float(diameter[k]), float(reference[k])
        ratio = mld / ref
        deepest = int(inside[np.argmax(narrowing[inside])])  # the MLD point, but for the taper's slope
        level = settings.edge_fraction * float(narrowing[deepest])
        start = _edge(arc, narrowing, deepest, -1, level, owner, n)
        end = _edge(arc, narrowing, deepest, +1, level, owner, n)
        smoothed_level = settings.edge_fraction * float(found_on[inside].max())
        if start is None:
            start = _crossing(arc, found_on, left, left - 1, smoothed_level)
        if end is None:
            end = _crossing(arc, found_on, right, right + 1, smoothed_level)
        lesions.append(Lesion(branch, start, end, float(arc[k]), tuple(float(x) for x in points_mm[k]), mld, ref,
                              100.0 * (1.0 - ratio), 100.0 * (1.0 - ratio * ratio)))
    return tuple(sorted(lesions, key=lambda lesion: lesion.start_mm))


def window_lesion_length_mm(profile: str, extent_mm: float, edge_fraction: float = 0.25) -> float:
    """The lesion length the definitions of this module give for one of the synthetic generator's
    windows of extent ``extent_mm`` (cosine: support; Gaussian: 6 sigma) on a straight taper."""
    if profile == "cosine":
        return extent_mm / math.pi * math.acos(2.0 * edge_fraction - 1.0)
    if profile == "gaussian":
        return 2.0 * (extent_mm / 6.0) * math.sqrt(2.0 * math.log(1.0 / edge_fraction))
    raise QcaError(f"window profile must be 'cosine' or 'gaussian', got {profile!r}")
