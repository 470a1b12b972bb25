"""Names and defaults shared by the command line and the library.

Plain Python, no NumPy: the command line reads its choices and defaults from here, so that
``angiohull --help`` starts without importing the numerical stack. The modules that implement each
choice import their names from here too (one definition); tests check the two agree.
"""

from __future__ import annotations

__all__ = ["DEFAULT_RESOLUTION", "DEFAULT_THRESHOLD_PX", "ENGINE_NAMES", "AUTO_ENGINE", "ENGINE_CHOICES", "PRESETS",
           "REFINED_RESOLUTION", "METHODS", "DEFAULT_METHOD", "chosen_method", "RASTERISERS", "TREE_KINDS",
           "TORTUOSITY_LEVELS"]

DEFAULT_RESOLUTION = 100
"""K of the paper's experiments."""

DEFAULT_THRESHOLD_PX = 1.0
"""The paper's distance threshold, pixels (strict)."""

ENGINE_NAMES: tuple[str, ...] = ("kdtree", "lookup", "octree")
"""The carving engines (``reconstruction.ENGINES``): the paper's reference and two faster exact ones."""

AUTO_ENGINE = "octree"
"""What ``engine="auto"`` runs: the fastest engine that keeps exactly the reference's points."""

ENGINE_CHOICES: tuple[str, ...] = ("auto", *ENGINE_NAMES)
"""Names accepted by ``reconstruct(engine=...)`` and the CLI's ``--engine``."""

PRESETS: tuple[str, ...] = ("paper", "refined")
"""``reconstruct(preset=...)``: the method as published, or with the improvements of ``reconstruction.refine``."""

REFINED_RESOLUTION = 256
"""K of the refined preset (finer than the paper's 100: less thickening)."""

METHODS: tuple[str, ...] = ("hull", "tree")
"""``reconstruct(method=...)``: ``hull``, the paper's visual hull (either preset); ``tree`` (beyond
the paper), the vessel tree from centerline correspondences across the views, with tubes fitted to
the masks (``reconstruction.model``, docs/tree-method.md)."""

DEFAULT_METHOD = "tree"
"""The method when none is named and no hull option is given (:func:`chosen_method`): ``tree``, the
better on every accuracy score of the benchmark (docs/results/tree-method.md: generated trees in 2,
3 and 6 views, the authors' 48 studies, the XCAT vessel but for its nearly opposite pairs of views,
160-180 degrees apart); the paper's ``hull`` was the default until 2026-12-07. The paper's
experiments (``angiohull experiment``) keep ``hull``."""


def chosen_method(method: str | None, preset: str | None = None, min_views: int | None = None,
                  tree: bool = True) -> str:
    """The method a reconstruction runs: ``method`` when named; else ``hull`` when a hull option is
    given (a ``preset``, which picks how the hull is carved; ``min_views``, its robust carving; or no
    vessel tree, ``tree=False``, which the tree method cannot skip), else :data:`DEFAULT_METHOD`.

    >>> chosen_method(None), chosen_method(None, "refined"), chosen_method(None, tree=False), chosen_method("hull")
    ('tree', 'hull', 'hull', 'hull')
    """
    if method is not None:
        return method
    return "hull" if preset is not None or min_views is not None or not tree else DEFAULT_METHOD

RASTERISERS: tuple[str, ...] = ("exact", "paper")
"""``exact``: pixel set iff the ray through its centre meets the solid. ``paper``: surface points
splatted by truncation, closed with a disk of radius 2, Gaussian sigma 0.5 thresholded at 0.25."""

TREE_KINDS: tuple[str, ...] = ("rca", "left")
"""The trees the generator makes: the right coronary artery, or the left (left main, LAD, LCx)."""

TORTUOSITY_LEVELS: tuple[str, ...] = ("simple", "moderate", "tortuous")
"""The generator's tortuosity levels (bands of a measured index, see ``synthetic.tree``)."""
