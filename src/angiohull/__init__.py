"""angiohull: visual-hull reconstruction of coronary arteries from a few X-ray angiography views.

Implements Lau & Dziubich, "Visual Hull-Based Approach for Coronary Vessel Three-Dimensional
Reconstruction", Applied Sciences 2025, 15(19), 10450, with its geometry, metrics and study format
(see docs/conventions.md).
"""

from __future__ import annotations

__version__ = "0.1.0"

from .errors import AngiohullError, EmptyHullError, GeometryError, ReconstructionError, StudyError  # noqa: E402
from .geometry import CArmGeometry, Projection, cube_half_edge_mm, format_clinical_angles, parse_clinical_angles  # noqa: E402
from .reconstruction import ReconstructionResult, reconstruct  # noqa: E402

__all__ = [
    "__version__",
    "AngiohullError",
    "EmptyHullError",
    "GeometryError",
    "ReconstructionError",
    "StudyError",
    "CArmGeometry",
    "Projection",
    "cube_half_edge_mm",
    "format_clinical_angles",
    "parse_clinical_angles",
    "ReconstructionResult",
    "reconstruct",
]
