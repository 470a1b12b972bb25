"""The built-in default of ``angiohull demo``: a synthetic right coronary tree in three clinical views,
or in two (``angiohull demo --views 2``, the clinical standard).

A moderate RCA tree drawn from a fixed seed (:data:`DEMO_SEED`) is rendered into exact silhouette
masks for RAO 30 CRA 30, LAO 60 CRA 30 and RAO 30 CAU 30 (SID 1200 mm, SOD 800 mm, 0.35 mm pixels,
512 x 512), or for the two clinical views of the tree method's benchmark, RAO 30 CAU 25 and LAO 45
CRA 20 (:data:`DEMO_TWO_VIEWS`), and written as a synthetic study folder, so that the demo runs the
same code path as a user's study (``angiohull synth --seed 2025`` writes the very same three-view
study, ``angiohull synth --seed 2025 --views "RAO 30 CAU 25; LAO 45 CRA 20"`` the two-view one).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from .synthetic.case import SynthOptions, make_case, write_case

__all__ = ["write_demo_study", "demo_options", "DEMO_SEED", "DEMO_OPTIONS", "DEMO_TWO_VIEWS"]

DEMO_SEED = 2025
"""Seed of the demo's tree."""

DEMO_OPTIONS = SynthOptions(kind="rca", tortuosity="moderate", views="clinical", rasteriser="exact", seed=DEMO_SEED)
"""The options of the demo study (the paper's clinical views and geometry)."""


DEMO_TWO_VIEWS = ("RAO 30 CAU 25", "LAO 45 CRA 20")
"""The two-view demo's views: the clinical pair of the tree method's benchmark (docs/results/tree-method.md)."""


def demo_options(views: int = 3) -> SynthOptions:
    """The demo study's options with three views (:data:`DEMO_OPTIONS`) or two (:data:`DEMO_TWO_VIEWS`)."""
    if views == 3:
        return DEMO_OPTIONS
    if views == 2:
        return replace(DEMO_OPTIONS, views=DEMO_TWO_VIEWS)
    raise ValueError(f"the demo has two views or three, not {views!r}")


def write_demo_study(folder: str | Path, views: int = 3) -> Path:
    """Write the demo study (masks, ``study.yaml``, ground truth, tree record) with ``views`` views (3 or
    2) into ``folder``; return the YAML path."""
    return write_case(Path(folder), make_case(demo_options(views)))
