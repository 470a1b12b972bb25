"""angiohull: visual-hull reconstruction of coronary arteries from a few X-ray angiography views.

Implements Lau & Dziubich, "Visual Hull-Based Approach for Coronary Vessel Three-Dimensional
Reconstruction", Applied Sciences 2025, 15(19), 10450, with its geometry, metrics and study format
(see docs/conventions.md).

The names below are imported on first use, so that ``import angiohull`` (and the command line's
``--help``) does not load the numerical stack.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_LAZY = {
    "AngiohullError": "errors", "EmptyHullError": "errors", "GeometryError": "errors",
    "ReconstructionError": "errors", "StudyError": "errors",
    "CArmGeometry": "geometry", "Projection": "geometry", "cube_half_edge_mm": "geometry",
    "format_clinical_angles": "geometry", "parse_clinical_angles": "geometry",
    "ReconstructionResult": "reconstruction", "reconstruct": "reconstruction",
}

__all__ = ["__version__", *_LAZY]

if TYPE_CHECKING:  # pragma: no cover
    from .errors import AngiohullError, EmptyHullError, GeometryError, ReconstructionError, StudyError
    from .geometry import CArmGeometry, Projection, cube_half_edge_mm, format_clinical_angles, parse_clinical_angles
    from .reconstruction import ReconstructionResult, reconstruct


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'angiohull' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
