"""Synthetic data with exact ground truth: the analytic tubular phantom of ``angiohull demo``."""

from __future__ import annotations

from .phantom import Tube, TubePhantom, demo_phantom, demo_views

__all__ = ["Tube", "TubePhantom", "demo_phantom", "demo_views"]
