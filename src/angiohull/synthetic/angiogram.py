"""Angiogram-like X-ray images of a tubular phantom, with the exact vessel mask as ground truth.

:func:`render_angiogram` turns any :class:`~angiohull.synthetic.phantom.TubePhantom` seen through a
:class:`~angiohull.geometry.Projection` into the kind of image a C-arm records during a contrast
injection, so that the vessel segmentation can be judged against the true mask:

1. **Vessel line integral.** For each pixel, the length (mm) of the ray from the X-ray source
   through the pixel centre inside the phantom's solid (the union of its capsules, overlaps
   counted once): ``chord``. A pixel has ``chord > 0`` exactly where the phantom's silhouette
   (:meth:`TubePhantom.silhouette`) is set, up to rays that only graze a surface.
2. **Background.** The patient's body seen through the same ray: a smooth random line integral
   ``T`` (Gaussian-filtered white noise at a few correlation lengths, plus a linear ramp), in units
   of attenuation (dimensionless, ``mu * length``).
3. **Beer–Lambert.** Relative intensity ``I = exp(-(T + mu_vessel * chord))`` (1 = unattenuated
   beam): vessels are dark on a bright background.
4. **Detector.** A Gaussian blur (focal spot and detector spread), then quantum noise (Poisson with
   ``photons_per_pixel`` quanta for an unattenuated pixel) and electronic noise (Gaussian).
5. **Collimator** (optional). Outside a rectangle with rounded corners, ``collimator_px`` from the
   image border, the beam is attenuated by the shutters to ``collimator_transmission``.

Randomness (texture and noise) comes only from the generator passed in; the same seed gives the
same image. The vessel mask returned is the phantom's exact silhouette, independent of noise.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import ndimage as ndi

from .. import _validation as _v
from ..errors import AngiohullError
from ..geometry import CArmGeometry, Projection
from .phantom import TubePhantom

__all__ = ["AngiogramParameters", "Angiogram", "render_angiogram", "vessel_chord_length_mm", "to_counts"]

# (pixel, piece) pairs evaluated at once, to bound memory.
_PAIR_CHUNK = 1_048_576


@dataclass(frozen=True)
class AngiogramParameters:
    """How an angiogram is rendered. Attenuations are dimensionless line integrals (``mu * length``).

    The defaults give images like a cardiac cine frame after contrast injection: a vessel of
    4 mm chord transmits ``exp(-1.0)`` = 37 % of the background intensity, a 2 mm one 61 %; about
    2.5 % quantum noise on the background; a body texture that varies the background intensity by
    about +/- 15 % over a few centimetres.
    """

    vessel_attenuation_per_mm: float = 0.25  # mu of contrast-filled lumen, 1/mm
    background_attenuation: float = 1.0  # mean line integral of the body, dimensionless
    background_texture: float = 0.15  # standard deviation of the smooth body texture, dimensionless
    texture_scales_px: tuple[float, ...] = (48.0, 12.0)  # correlation lengths of the texture, px
    background_ramp: float = 0.3  # total change of the body line integral across the image (linear ramp)
    blur_px: float = 0.6  # sigma of the Gaussian detector blur, px (0: none)
    photons_per_pixel: float = 4000.0  # quanta recorded by an unattenuated pixel (Poisson noise); inf: none
    electronic_noise: float = 0.002  # standard deviation of additive Gaussian noise, relative to the unattenuated beam
    collimator_px: int = 0  # width of the shuttered border, px (0: no collimator)
    collimator_corner_px: float = 24.0  # radius of the rounded corners of the collimated field, px
    collimator_transmission: float = 0.15  # relative intensity behind the shutters

    def __post_init__(self) -> None:
        err = AngiohullError
        for name in ("vessel_attenuation_per_mm", "photons_per_pixel", "collimator_transmission"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0 and (math.isfinite(value) or name == "photons_per_pixel")):
                raise err(f"AngiogramParameters.{name} must be a positive number, got {value!r}")
        for name in ("background_attenuation", "background_texture", "background_ramp", "blur_px",
                     "electronic_noise", "collimator_corner_px"):
            value = _v.finite(getattr(self, name), f"AngiogramParameters.{name}", error=err)
            if value < 0:
                raise err(f"AngiogramParameters.{name} must be >= 0, got {value!r}")
        scales = tuple(_v.positive_finite(s, "AngiogramParameters.texture_scales_px", error=err) for s in self.texture_scales_px)
        object.__setattr__(self, "texture_scales_px", scales)
        if isinstance(self.collimator_px, bool) or not isinstance(self.collimator_px, (int, np.integer)) or self.collimator_px < 0:
            raise err(f"AngiogramParameters.collimator_px must be an integer >= 0, got {self.collimator_px!r}")


@dataclass(frozen=True, eq=False)
class Angiogram:
    """A rendered angiogram and its ground truth.

    Attributes
    ----------
    image : ndarray of float64, shape (rows, cols)
        Relative intensity (1 = unattenuated beam), noisy; vessels dark.
    mask : ndarray of bool, shape (rows, cols)
        The phantom's exact silhouette in this view (the true vessel mask).
    chord_mm : ndarray of float64, shape (rows, cols)
        Length of each pixel's ray inside the phantom, mm (noise-free).
    field : ndarray of bool, shape (rows, cols)
        The irradiated field (False behind the collimator; all True without one).
    parameters : AngiogramParameters
        The parameters used.
    """

    image: np.ndarray
    mask: np.ndarray
    chord_mm: np.ndarray
    field: np.ndarray
    parameters: AngiogramParameters

    def parameters_dict(self) -> dict[str, Any]:
        """The parameters as plain Python values (for reports)."""
        return asdict(self.parameters)


def _as_projection(projection: Projection | CArmGeometry) -> Projection:
    if isinstance(projection, CArmGeometry):
        return projection.projection()
    if not isinstance(projection, Projection):
        raise AngiohullError(f"projection must be a Projection or CArmGeometry, got {type(projection).__name__}")
    return projection


def _pieces(phantom: TubePhantom) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phantom's capsules cut into pieces no longer than twice their radius (same union)."""
    a, b, r = phantom.segments_mm()
    length = np.linalg.norm(b - a, axis=1)
    n = np.maximum(1, np.ceil(length / (2.0 * r))).astype(np.int64)
    seg = np.repeat(np.arange(r.size), n)
    k = np.arange(seg.size) - np.repeat(np.cumsum(n) - n, n)
    t0 = (k / n[seg])[:, None]
    t1 = ((k + 1) / n[seg])[:, None]
    edge = (b - a)[seg]
    return a[seg] + t0 * edge, a[seg] + t1 * edge, r[seg]


def _pixel_boxes(proj: Projection, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """Pixel rectangles ``(r0, r1, c0, c1)`` (inclusive) covering the projections of boxes [lo, hi]."""
    rows, cols = proj.image_shape
    sel = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=bool)
    corners = np.where(sel[None], hi[:, None, :], lo[:, None, :])
    h = corners @ proj.matrix[:, :3].T + proj.matrix[:, 3]
    w = h[..., 2]
    behind = np.any(w <= 0, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(behind[:, None], 0.0, h[..., 0] / w)
        v = np.where(behind[:, None], 0.0, h[..., 1] / w)
    c0 = np.clip(np.where(behind, 0, np.floor(u.min(axis=1)) - 1), 0, cols).astype(np.int64)
    c1 = np.clip(np.where(behind, cols - 1, np.ceil(u.max(axis=1)) + 1), -1, cols - 1).astype(np.int64)
    r0 = np.clip(np.where(behind, 0, np.floor(v.min(axis=1)) - 1), 0, rows).astype(np.int64)
    r1 = np.clip(np.where(behind, rows - 1, np.ceil(v.max(axis=1)) + 1), -1, rows - 1).astype(np.int64)
    return r0, r1, c0, c1


def _quadratic_interval(qa: np.ndarray, qb: np.ndarray, qc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where ``qa s^2 + 2 qb s + qc <= 0`` (qa > 0): ``[s0, s1]``, or NaNs when empty."""
    disc = qb * qb - qa * qc
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.where(disc >= 0, disc, np.nan))
        return (-qb - root) / qa, (-qb + root) / qa


def _capsule_intervals(source: np.ndarray, dirs: np.ndarray, a: np.ndarray, b: np.ndarray, r: np.ndarray):
    """Entry and exit distances ``(s_in, s_out)`` of rays ``source + s dirs`` through capsules.

    A capsule (the points within ``r`` of segment ab) is convex, so a ray meets it in one interval:
    the hull of its meetings with the two end balls and with the finite cylinder between them.
    Returns NaN where the ray misses. ``dirs`` are unit vectors; rows of ``a``, ``b``, ``r`` pair
    with rows of ``dirs``.
    """
    r_sq = r * r
    starts, ends = [], []
    for centre in (a, b):  # the end balls
        rel = source - centre
        s0, s1 = _quadratic_interval(np.ones_like(r), np.einsum("ij,ij->i", dirs, rel), np.einsum("ij,ij->i", rel, rel) - r_sq)
        starts.append(s0)
        ends.append(s1)
    edge = b - a
    length = np.linalg.norm(edge, axis=1)
    ok = length > 0
    axis = np.divide(edge, length[:, None], out=np.zeros_like(edge), where=ok[:, None])
    rel = source - a
    t_rel = np.einsum("ij,ij->i", rel, axis)
    t_dir = np.einsum("ij,ij->i", dirs, axis)
    w = rel - t_rel[:, None] * axis
    d_perp = dirs - t_dir[:, None] * axis
    qa = np.einsum("ij,ij->i", d_perp, d_perp)
    parallel = qa < 1e-15
    s0, s1 = _quadratic_interval(np.where(parallel, 1.0, qa), np.einsum("ij,ij->i", w, d_perp), np.einsum("ij,ij->i", w, w) - r_sq)
    s0 = np.where(parallel | ~ok, np.nan, s0)
    s1 = np.where(parallel | ~ok, np.nan, s1)
    # Clip to the slab 0 <= t_rel + s t_dir <= length (a ray parallel to the axis meets the caps instead).
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = -t_rel / t_dir
        tb = (length - t_rel) / t_dir
    lo_slab = np.where(t_dir != 0, np.minimum(ta, tb), np.where((t_rel >= 0) & (t_rel <= length), -np.inf, np.inf))
    hi_slab = np.where(t_dir != 0, np.maximum(ta, tb), np.where((t_rel >= 0) & (t_rel <= length), np.inf, -np.inf))
    s0c, s1c = np.maximum(s0, lo_slab), np.minimum(s1, hi_slab)
    empty = ~(s0c <= s1c)
    starts.append(np.where(empty, np.nan, s0c))
    ends.append(np.where(empty, np.nan, s1c))
    s_in = np.fmin(np.fmin(starts[0], starts[1]), starts[2])
    s_out = np.fmax(np.fmax(ends[0], ends[1]), ends[2])
    return np.maximum(s_in, 0.0), s_out  # the ray starts at the source


def vessel_chord_length_mm(phantom: TubePhantom, projection: Projection | CArmGeometry) -> np.ndarray:
    """Length (mm) of each pixel's ray inside the phantom's solid, overlapping capsules counted once.

    Parameters
    ----------
    phantom : TubePhantom
        The vessels.
    projection : Projection or CArmGeometry
        The view; its ``image_shape`` is the output's shape.

    Returns
    -------
    chord_mm : ndarray of float64, shape (rows, cols)
        For pixel ``(r, c)``, the measure of ``{s >= 0 : source + s D inside the solid}`` with ``D``
        the unit direction through the pixel centre ``(u, v) = (c, r)``. Zero off the vessels.

    Notes
    -----
    Each ray's intervals through the capsules it meets are merged (sorted by entry, a running
    maximum of the exits), so a point inside several capsules is counted once: bifurcations and
    the joints between consecutive segments are not darker than the vessel around them.
    """
    if not isinstance(phantom, TubePhantom):
        raise AngiohullError(f"phantom must be a TubePhantom, got {type(phantom).__name__}")
    proj = _as_projection(projection)
    rows, cols = proj.image_shape
    a, b, r = _pieces(phantom)
    r0, r1, c0, c1 = _pixel_boxes(proj, np.minimum(a, b) - r[:, None], np.maximum(a, b) + r[:, None])
    widths = np.maximum(c1 - c0 + 1, 0)
    counts = widths * np.maximum(r1 - r0 + 1, 0)
    left_inv = np.linalg.inv(proj.matrix[:, :3])
    source = proj.camera_centre_mm
    pix_parts, in_parts, out_parts = [], [], []
    cum = np.cumsum(counts)
    total = int(cum[-1]) if cum.size else 0
    for first in range(0, total, _PAIR_CHUNK):
        ids = np.arange(first, min(first + _PAIR_CHUNK, total), dtype=np.int64)
        piece = np.searchsorted(cum, ids, side="right")
        local = ids - (cum[piece] - counts[piece])
        rr = r0[piece] + local // widths[piece]
        cc = c0[piece] + local % widths[piece]
        dirs = cc[:, None] * left_inv[:, 0] + rr[:, None] * left_inv[:, 1] + left_inv[:, 2]
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        s_in, s_out = _capsule_intervals(source, dirs, a[piece], b[piece], r[piece])
        hit = s_out > s_in
        pix_parts.append(rr[hit] * cols + cc[hit])
        in_parts.append(s_in[hit])
        out_parts.append(s_out[hit])
    chord = np.zeros(rows * cols)
    if pix_parts and sum(p.size for p in pix_parts):
        pix = np.concatenate(pix_parts)
        s_in = np.concatenate(in_parts)
        s_out = np.concatenate(out_parts)
        order = np.lexsort((s_in, pix))
        pix, s_in, s_out = pix[order], s_in[order], s_out[order]
        # Running maximum of the exits within each pixel's run of intervals.
        group_start = np.r_[True, pix[1:] != pix[:-1]]
        prev_max = np.empty_like(s_out)
        reach = -np.inf
        # Vectorised per-group running max: offset each group so that groups cannot interact.
        span = float(max(np.max(s_out) - min(np.min(s_in), 0.0), 1.0)) * 2.0
        group_id = np.cumsum(group_start) - 1
        shifted = s_out + group_id * span
        running = np.maximum.accumulate(shifted) - group_id * span
        prev_max[1:] = running[:-1]
        prev_max[group_start] = reach
        contribution = np.maximum(s_out - np.maximum(s_in, prev_max), 0.0)
        np.add.at(chord, pix, contribution)
    return chord.reshape(rows, cols)


def _texture(shape: tuple[int, int], params: AngiogramParameters, rng: np.random.Generator) -> np.ndarray:
    """Smooth zero-mean random field with standard deviation ``background_texture``, plus the ramp."""
    rows, cols = shape
    field = np.zeros(shape)
    for scale in params.texture_scales_px:
        layer = ndi.gaussian_filter(rng.standard_normal(shape), scale, mode="reflect")
        std = layer.std()
        if std > 0:
            field += layer / std
    if params.texture_scales_px:
        field *= params.background_texture / math.sqrt(len(params.texture_scales_px))
    angle = rng.uniform(0.0, 2.0 * math.pi)
    v, u = np.mgrid[0:rows, 0:cols]
    ramp = (math.cos(angle) * (u / max(cols - 1, 1) - 0.5) + math.sin(angle) * (v / max(rows - 1, 1) - 0.5))
    return params.background_attenuation + field + params.background_ramp * ramp


def collimator_field(shape: tuple[int, int], border_px: int, corner_px: float) -> np.ndarray:
    """The irradiated field: a rectangle ``border_px`` inside the image with corners of radius ``corner_px``."""
    rows, cols = shape
    field = np.zeros(shape, dtype=bool)
    if border_px == 0:
        field[:] = True
        return field
    top, bottom, left, right = border_px, rows - 1 - border_px, border_px, cols - 1 - border_px
    if bottom < top or right < left:
        return field
    v, u = np.mgrid[0:rows, 0:cols]
    field = (v >= top) & (v <= bottom) & (u >= left) & (u <= right)
    radius = min(corner_px, (bottom - top) / 2.0, (right - left) / 2.0)
    if radius > 0:
        cu = np.clip(u, left + radius, right - radius)
        cv = np.clip(v, top + radius, bottom - radius)
        field &= (u - cu) ** 2 + (v - cv) ** 2 <= radius * radius
    return field


def render_angiogram(
    phantom: TubePhantom,
    projection: Projection | CArmGeometry,
    rng: np.random.Generator | int | None = None,
    parameters: AngiogramParameters | None = None,
) -> Angiogram:
    """Render an X-ray angiogram of ``phantom`` in one view (see the module notes for the model).

    Parameters
    ----------
    phantom : TubePhantom
        The contrast-filled vessels (any tube phantom, e.g. :func:`~angiohull.synthetic.demo_phantom`).
    projection : Projection or CArmGeometry
        The view; its ``image_shape`` gives the image's (rows, cols).
    rng : numpy.random.Generator or int, optional
        Source of the background texture and the noise (a seed or a Generator). None draws fresh
        entropy; pass a seed for a reproducible image.
    parameters : AngiogramParameters, optional
        Attenuation, texture, noise and collimator settings; defaults to ``AngiogramParameters()``.

    Returns
    -------
    Angiogram
        ``image`` (float64 relative intensity, vessels dark), ``mask`` (the exact silhouette),
        ``chord_mm``, ``field`` and the parameters.
    """
    params = AngiogramParameters() if parameters is None else parameters
    if not isinstance(params, AngiogramParameters):
        raise AngiohullError(f"parameters must be AngiogramParameters, got {type(params).__name__}")
    generator = np.random.default_rng(rng)
    proj = _as_projection(projection)
    shape = proj.image_shape
    chord = vessel_chord_length_mm(phantom, proj)
    mask = phantom.silhouette(proj)
    line_integral = _texture(shape, params, generator) + params.vessel_attenuation_per_mm * chord
    field = collimator_field(shape, int(params.collimator_px), params.collimator_corner_px)
    intensity = np.exp(-line_integral) * np.where(field, 1.0, params.collimator_transmission)
    if params.blur_px > 0:
        intensity = ndi.gaussian_filter(intensity, params.blur_px, mode="nearest")
    if math.isfinite(params.photons_per_pixel):
        intensity = generator.poisson(intensity * params.photons_per_pixel) / params.photons_per_pixel
    if params.electronic_noise > 0:
        intensity = intensity + generator.normal(0.0, params.electronic_noise, shape)
    image = np.clip(intensity, 0.0, None)
    return Angiogram(image=image, mask=mask, chord_mm=chord, field=field, parameters=params)


def to_counts(image: np.ndarray, *, bits: int = 12, white: float | None = None) -> np.ndarray:
    """Quantise a relative-intensity image to unsigned integers, as a detector stores it.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Relative intensity, >= 0.
    bits : int
        Bits stored (8 gives uint8, up to 16 gives uint16).
    white : float, optional
        Intensity mapped to the largest value ``2**bits - 1``; default: the image's maximum.

    Returns
    -------
    ndarray of uint8 or uint16
    """
    if not 1 <= bits <= 16:
        raise AngiohullError(f"bits must be within 1..16, got {bits!r}")
    array = np.asarray(image, dtype=np.float64)
    top = float(array.max()) if white is None else _v.positive_finite(white, "white")
    top = top if top > 0 else 1.0
    levels = (1 << bits) - 1
    counts = np.rint(np.clip(array / top, 0.0, 1.0) * levels)
    return counts.astype(np.uint8 if bits <= 8 else np.uint16)
