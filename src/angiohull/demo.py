"""The built-in default of ``angiohull demo``: a synthetic right coronary tree in three clinical views.

A moderate RCA tree drawn from a fixed seed (:data:`DEMO_SEED`) is rendered into exact silhouette
masks for RAO 30 CRA 30, LAO 60 CRA 30 and RAO 30 CAU 30 (SID 1200 mm, SOD 800 mm, 0.35 mm pixels,
512 x 512) and written as a synthetic study folder, so that the demo runs the same code path as a
user's study (and ``angiohull synth --seed 2025`` writes the very same study).
"""

from __future__ import annotations

from pathlib import Path

from .synthetic.case import SynthOptions, make_case, write_case

__all__ = ["write_demo_study", "DEMO_SEED", "DEMO_OPTIONS"]

DEMO_SEED = 2025
"""Seed of the demo's tree."""

DEMO_OPTIONS = SynthOptions(kind="rca", tortuosity="moderate", views="clinical", rasteriser="exact", seed=DEMO_SEED)
"""The options of the demo study (the paper's clinical views and geometry)."""


def write_demo_study(folder: str | Path) -> Path:
    """Write the demo study (masks, ``study.yaml``, ground truth, tree record) into ``folder``; return the YAML path."""
    return write_case(Path(folder), make_case(DEMO_OPTIONS))
