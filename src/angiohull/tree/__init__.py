"""The vessel tree, the project's central result (docs/conventions.md, "The vessel tree").

* :mod:`.model`: :class:`VesselTree` and :class:`Branch` (ordered centerlines with radii, the
  topology, resampling, arc length, tangents, JSON);
* :mod:`.solid`: the lumen as a union of capsules: signed distance, inside test, a watertight
  surface mesh and a lumen label volume;
* :mod:`.skeleton`: a tree from the skeleton of a binary volume (graph, spur pruning, root).

Arrays in, arrays out: nothing here reads or writes files (see :mod:`angiohull.exports`).
"""

from __future__ import annotations

from .model import TREE_JSON_FORMAT, Bifurcation, Branch, VesselTree

__all__ = ["VesselTree", "Branch", "Bifurcation", "TREE_JSON_FORMAT"]
