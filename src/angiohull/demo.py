"""The built-in default of ``angiohull demo``: a tubular phantom seen in three clinical views.

Renders :func:`~angiohull.synthetic.demo_phantom` into exact silhouette masks for the views of
:func:`~angiohull.synthetic.demo_views` and writes them as a study folder, with the phantom's
surface points as ground truth, so that the demo runs the same code path as a user's study.
"""

from __future__ import annotations

from pathlib import Path

from .study import View, save_study
from .synthetic import demo_phantom, demo_views

__all__ = ["write_demo_study", "DEMO_SURFACE_SPACING_MM"]

DEMO_SURFACE_SPACING_MM = 0.5
"""Spacing of the ground-truth surface samples of the demo phantom, mm."""


def write_demo_study(folder: str | Path) -> Path:
    """Write the demo study (masks, ``study.yaml``, ``gt.npy``) into ``folder``; return the YAML path."""
    phantom = demo_phantom()
    views = []
    for name, carm in demo_views():
        projection = carm.projection()
        views.append(View.from_carm(name.replace(" ", "_"), phantom.silhouette(projection), carm))
    return save_study(Path(folder), views, ground_truth_mm=phantom.surface_points_mm(DEMO_SURFACE_SPACING_MM))
