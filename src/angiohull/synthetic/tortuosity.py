"""Tortuosity indices of a centreline polyline.

Both indices are computed on the polyline resampled at a fixed arc-length step (default 1 mm), so
they do not depend on how densely the vessel happened to be sampled:

* :func:`distance_metric` — arc length / chord (1 for a straight vessel), the "DM" of Bullitt et
  al., IEEE TMI 22(9) 2003;
* :func:`sum_of_angles_metric` — the total turning angle per centimetre of arc ("SOAM", same
  paper): at each inner point the in-plane angle between consecutive steps and the torsional angle
  between consecutive osculating planes, combined as ``sqrt(ip**2 + tp**2)``, summed and divided
  by the arc over which the turning is measured (from the middle of the first step to the middle
  of the last, so that a circle gives exactly its curvature up to the step's discretisation);
* :func:`curvature_metric` — the in-plane part alone (total curvature per centimetre). Unlike the
  torsional part it is well conditioned where the curve is nearly straight (at the inflections of
  a wavy vessel the osculating plane is undefined and the torsional angle jumps by up to pi), so
  this is the index that defines angiohull's tortuosity levels; SOAM is reported beside it.
"""

from __future__ import annotations

import numpy as np

from .. import _validation as _v
from ..errors import AngiohullError
from ..tree.model import arc_length_mm

__all__ = ["resample_polyline", "distance_metric", "sum_of_angles_metric", "curvature_metric", "arc_length_mm"]


def resample_polyline(points_mm: np.ndarray, step_mm: float = 1.0) -> np.ndarray:
    """The polyline's points at arc lengths ``0, step, 2 step, ...`` (and its end), linear in between.

    Parameters
    ----------
    points_mm : array_like, shape (M, 3)
        Polyline vertices, mm, ``M >= 2`` with a positive length.
    step_mm : float
        Arc-length step, mm (> 0).

    Returns
    -------
    ndarray, shape (n, 3)
        ``n = floor(length / step) + 1`` points, plus the end point when the length is not a
        multiple of the step.
    """
    points = _v.points_array(points_mm, "points_mm")
    step = _v.positive_finite(step_mm, "step_mm")
    arc = arc_length_mm(points)
    if points.shape[0] < 2 or arc[-1] <= 0:
        raise AngiohullError(f"a tortuosity index needs a polyline of positive length, got {points.shape[0]} point(s) "
                             f"and length {arc[-1]:.3g} mm")
    stations = np.arange(0.0, arc[-1], step)
    if arc[-1] - stations[-1] > 1e-9 * max(1.0, arc[-1]):
        stations = np.append(stations, arc[-1])
    return np.stack([np.interp(stations, arc, points[:, k]) for k in range(3)], axis=1)


def distance_metric(points_mm: np.ndarray) -> float:
    """Arc length over chord (end-to-end distance); 1 for a straight polyline, inf for a closed one."""
    points = _v.points_array(points_mm, "points_mm")
    length = arc_length_mm(points)[-1]
    chord = float(np.linalg.norm(points[-1] - points[0]))
    if length <= 0:
        raise AngiohullError("distance_metric needs a polyline of positive length")
    return float(length / chord) if chord > 0 else float("inf")


def _turning_angles(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """In-plane angles (at inner vertices) and torsional angles (between consecutive planes), rad."""
    steps = np.diff(points, axis=0)
    unit = steps / np.linalg.norm(steps, axis=1, keepdims=True)
    cos_ip = np.clip(np.einsum("ij,ij->i", unit[:-1], unit[1:]), -1.0, 1.0)
    in_plane = np.arccos(cos_ip)
    normals = np.cross(unit[:-1], unit[1:])
    norm = np.linalg.norm(normals, axis=1)
    defined = norm > 1e-9
    safe = np.where(defined[:, None], normals / np.where(defined, norm, 1.0)[:, None], 0.0)
    cos_tp = np.clip(np.einsum("ij,ij->i", safe[:-1], safe[1:]), -1.0, 1.0)
    torsion = np.where(defined[:-1] & defined[1:], np.arccos(cos_tp), 0.0)
    return in_plane, torsion


def sum_of_angles_metric(points_mm: np.ndarray, step_mm: float = 1.0) -> float:
    """SOAM, radians per centimetre: ``sum(sqrt(ip_k**2 + tp_k**2)) / length``.

    ``ip_k`` is the angle between steps ``k`` and ``k + 1`` of the resampled polyline, ``tp_k``
    the angle between the osculating planes at vertices ``k`` and ``k + 1`` (0 where a plane is
    undefined, i.e. three collinear points); the last inner vertex has no torsional angle.
    """
    points = resample_polyline(points_mm, step_mm)
    if points.shape[0] < 3:
        return 0.0
    in_plane, torsion = _turning_angles(points)
    torsion = np.append(torsion, 0.0)
    total = float(np.sqrt(in_plane ** 2 + torsion ** 2).sum())
    return total / (_turning_arc_mm(points) / 10.0)


def curvature_metric(points_mm: np.ndarray, step_mm: float = 1.0) -> float:
    """Total in-plane turning angle per centimetre of arc (radians / cm) of the resampled polyline.

    For a circle of radius ``r`` mm this is ``10 / r`` (its curvature per cm) up to the
    discretisation of the step.
    """
    points = resample_polyline(points_mm, step_mm)
    if points.shape[0] < 3:
        return 0.0
    in_plane, _ = _turning_angles(points)
    return float(in_plane.sum()) / (_turning_arc_mm(points) / 10.0)


def _turning_arc_mm(points: np.ndarray) -> float:
    """Arc from the middle of the first step to the middle of the last (where the angles are measured)."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return float(steps.sum() - 0.5 * (steps[0] + steps[-1]))
