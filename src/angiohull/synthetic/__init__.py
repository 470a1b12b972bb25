"""Synthetic data with exact ground truth.

* :mod:`.phantom` — tubes as unions of capsules with exact silhouettes (the analytic oracle);
* :mod:`.tree` — seeded coronary trees (RCA or left) described by a replayable parameter record;
* :mod:`.tortuosity` — tortuosity indices of a centreline;
* :mod:`.views`, :mod:`.render` — named view sets and binary masks (exact or the paper's rasteriser);
* :mod:`.corruptions` — recorded, replayable corruptions of masks;
* :mod:`.case` — a whole synthetic study (``angiohull synth``).
"""

from __future__ import annotations

from .case import SynthOptions, SyntheticCase, make_case, replay_case, write_case
from .corruptions import CorruptionSpec, draw_corruptions, parse_corruption
from .phantom import Tube, TubePhantom, demo_phantom, demo_views
from .render import RASTERISERS, render_mask
from .tree import (TORTUOSITY_LEVELS, TREE_KINDS, CoronaryTree, TreeParams, build_tree, draw_tree_params,
                   generate_tree)
from .views import VIEW_SETS, carm_views, parse_views

__all__ = [
    "Tube", "TubePhantom", "demo_phantom", "demo_views",
    "TREE_KINDS", "TORTUOSITY_LEVELS", "TreeParams", "CoronaryTree", "draw_tree_params", "build_tree", "generate_tree",
    "VIEW_SETS", "parse_views", "carm_views", "RASTERISERS", "render_mask",
    "CorruptionSpec", "parse_corruption", "draw_corruptions",
    "SynthOptions", "SyntheticCase", "make_case", "write_case", "replay_case",
]
