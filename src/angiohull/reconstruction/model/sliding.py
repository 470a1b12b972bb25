"""Two views: tree points slid along one view's rays until the other view's mask is explained
(the ``tree`` method's last step, module notes of :mod:`angiohull.reconstruction.model`).

A point seen by view A stays on A's ray through it whatever its depth: moving it along that ray
leaves A's picture of the tree as it is and moves the point in view B along B's epipolar line.
Where B's mask holds a piece of pixels that the tree's tubes leave unexplained and a single
branch comes near it (where two do, the piece may be the rim of either), the run of that
branch's points near the piece (and a margin of arc either side) is moved so along A's rays, by
offsets interpolated linearly between knots along the run (zero at the run's start, and at its
end but at a branch's free end; a run holding a junction stays), chosen by a pattern search to
maximise, in B, the mask pixels the tubes cover less the tube pixels outside the mask, less a
weight on the run's 3D length (a millimetre more must explain ``length_px_per_mm`` more pixels:
a wiggle also covers a wide blob). The search moves every fourth knot first, the knots between
following linearly, then every second, then each (a run moves as a whole before it bends), and
the move is kept only where it gains at least ``min_gain`` of the piece's pixels.

The case: a vessel that one view shows folded on itself (a hairpin whose two arms merge into one
wide band). The skeleton of that view cuts across the fold inside its tip, the matching pairs the
other view's clean band with it, and the tree, right in that other view, runs at the wrong depth
along its rays and leaves the fold's tip unexplained. Nothing in it is specific to a fold: any run
a view sees cleanly and places at a depth that leaves the other view's pixels unexplained is
moved where that view's mask says, and only where the gain is large.

Arrays, projections and trees in; a tree out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from ...compiled import kernels
from ...geometry import Projection
from ...tree import Branch, VesselTree
from .agreement import _disc_pixels, tube_silhouette

__all__ = ["SlideSettings", "SLIDE_SETTINGS", "slid_along_rays"]


@dataclass(frozen=True)
class SlideSettings:
    """Parameters of :func:`slid_along_rays`; the same for every case."""

    min_pixels: int = 20  # a view's unexplained pieces (8-connected) of at least this many pixels are tried
    reach_px: float = 2.0  # the run: a branch's points whose projected disc comes within this of the piece ...
    margin_mm: float = 4.0  # ... and this much arc either side
    knot_mm: float = 2.0  # offsets along the rays interpolated linearly between knots this far apart along the run
    knot_strides: tuple[int, ...] = (4, 2, 1)  # coarse to fine: every 4th knot moves first (the rest follow), ...
    max_offset_mm: float = 12.0  # a knot moves at most this far along its ray
    steps_mm: tuple[float, ...] = (4.0, 2.0, 1.0, 0.5)  # the pattern search's steps, coarse to fine, ...
    fine_steps_mm: tuple[float, ...] = (1.0, 0.5)  # ... and on the finer knots
    length_px_per_mm: float = 10.0  # a mm the run grows in 3D must explain this many more pixels of the view
    min_gain: float = 0.5  # a move is kept where the score gains at least this share of the piece's pixels


SLIDE_SETTINGS = SlideSettings()


_DENSE_SHARE = 1 / 16  # _Picture.moved counts on the whole image where its discs hold more pixels than this share of it


class _Picture:
    """One view's picture of a tree: per pixel, how many of the tree's samples (every ``step_mm``
    of each branch, as :func:`.agreement.tube_silhouette` takes them) cover it; samples of a run
    can be moved, the counts following."""

    def __init__(self, branches: Sequence[Branch], view: Projection, mask: np.ndarray, step_mm: float):
        self.view, self.shape = view, mask.shape
        self.focal = max(view.focal_lengths_px)
        self.weight = np.where(mask.ravel(), 1, -1)  # a covered pixel: +1 in the mask, -1 outside
        self.step_mm = step_mm
        self.samples = [self._sampled(b) for b in branches]
        self._compiled = kernels()
        if self._compiled is not None:
            self.count = self._signed_counts(np.concatenate([b.points_mm for b in self.samples]),
                                             np.concatenate([b.radius_mm for b in self.samples]), 1).ravel()
        else:
            self.count = np.bincount(np.concatenate([self.pixels(b.points_mm, b.radius_mm)[0] for b in self.samples]),
                                     minlength=mask.size).astype(np.int32)

    def _sampled(self, branch: Branch) -> Branch:
        return branch.resampled(self.step_mm) if branch.length_mm > self.step_mm else branch

    def replace(self, k: int, branch: Branch, now: np.ndarray) -> None:
        """Branch ``k``'s samples, at ``now`` at present, taken again from ``branch``."""
        if self._compiled is not None:
            self.count -= self._signed_counts(now, self.samples[k].radius_mm, 1).ravel()
            self.samples[k] = self._sampled(branch)
            self.count += self._signed_counts(self.samples[k].points_mm, self.samples[k].radius_mm, 1).ravel()
            return
        np.subtract.at(self.count, self.pixels(now, self.samples[k].radius_mm)[0], 1)
        self.samples[k] = self._sampled(branch)
        np.add.at(self.count, self.pixels(self.samples[k].points_mm, self.samples[k].radius_mm)[0], 1)

    def pixels(self, points: np.ndarray, radii: np.ndarray) -> np.ndarray:
        return _disc_pixels(self.view.project(points), radii * self.focal / self.view.depth_mm(points), self.shape)

    def _signed_counts(self, points: np.ndarray, radii: np.ndarray, sign) -> np.ndarray:
        """Per pixel (the image's shape, int32), the sum of ``sign`` (per sample, or one for all)
        over the discs that cover it: the compiled kernel's count of :meth:`pixels`."""
        counts = np.zeros(self.shape, dtype=np.int32)
        self._compiled.add_disc_counts(np.ascontiguousarray(self.view.project(points), dtype=np.float64),
                                       np.ascontiguousarray(radii * self.focal / self.view.depth_mm(points),
                                                            dtype=np.float64),
                                       np.broadcast_to(np.asarray(sign, dtype=np.int32), (len(points),)).copy(),
                                       counts)
        return counts

    def moved(self, old: np.ndarray, new: np.ndarray, radii: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
        """Samples at ``old`` moved to ``new`` (their radii ``radii``), the counts left as they
        are: the change of the covered mask pixels less the covered pixels outside them, and the
        pixels touched with their counts' changes (for :meth:`keep`). Where the discs hold more
        pixels than :data:`_DENSE_SHARE` of the image's (wide vessels on a large image), the
        changes are counted on the whole image and the pixels whose count does not change left
        out (they change neither the score nor the counts), instead of sorting the discs' pixels
        (the same score and counts; the slide on the XCAT vessel's 960 x 960 views 23.8 -> 13.4 s).
        With the compiled kernels the discs are counted on the whole image always, in compiled code,
        without listing their pixels (the same score and counts again; 2026-12-08)."""
        if self._compiled is not None:  # counted on the whole image in compiled code (the same score and counts)
            dense = self._signed_counts(np.vstack([old, new]), np.concatenate([radii, radii]),
                                        np.repeat(np.array([-1, 1], dtype=np.int32), len(radii))).ravel()
            touched = np.flatnonzero(dense)
            change = dense[touched]
            was, now = self.count[touched] > 0, self.count[touched] + change > 0
            return int((self.weight[touched] * (now.astype(np.int64) - was)).sum()), touched, change
        pixels, owner = self.pixels(np.vstack([old, new]), np.concatenate([radii, radii]))
        sign = np.where(owner >= len(radii), 1, -1)
        if len(pixels) > _DENSE_SHARE * self.weight.size:
            dense = np.bincount(pixels, weights=sign, minlength=self.weight.size)
            touched = np.flatnonzero(dense)
            change = dense[touched].astype(np.int32)
        else:
            touched, which = np.unique(pixels, return_inverse=True)
            change = np.bincount(which, weights=sign, minlength=len(touched)).astype(np.int32)
        was, now = self.count[touched] > 0, self.count[touched] + change > 0
        return int((self.weight[touched] * (now.astype(np.int64) - was)).sum()), touched, change

    def keep(self, touched: np.ndarray, change: np.ndarray) -> None:
        """A move's counts' changes (:meth:`moved`) applied."""
        self.count[touched] += change


def _run(tree: VesselTree, projection: Projection, piece_uv: np.ndarray,
         settings: SlideSettings) -> tuple[int, np.ndarray] | None:
    """The one branch whose points' projected discs come within ``reach_px`` of the piece, and its
    run of points (indices) from the first to the last of those, ``margin_mm`` of arc either side;
    None where no branch or more than one comes near, or where the run holds a point another
    branch leaves from (the junction stays)."""
    near_tree = cKDTree(piece_uv)
    found = []
    for k, branch in enumerate(tree.branches):
        rho = branch.radius_mm * max(projection.focal_lengths_px) / projection.depth_mm(branch.points_mm)
        distance, _ = near_tree.query(projection.project(branch.points_mm))
        near = np.flatnonzero(distance <= rho + settings.reach_px)
        if len(near):
            found.append((k, near))
    if len(found) != 1:  # none, or another vessel passes by: the piece may be its rim
        return None
    k, near = found[0]
    branch = tree.branches[k]
    arc = branch.arc_length_mm
    lo = max(int(np.searchsorted(arc, arc[near.min()] - settings.margin_mm, side="left")), 0)
    hi = min(int(np.searchsorted(arc, arc[near.max()] + settings.margin_mm, side="right")) - 1, branch.n_points - 1)
    junctions = {tree.branches[c].parent_point for c in tree.children(k)}
    if hi - lo < 2 or any(lo < j < hi for j in junctions):
        return None
    return k, np.arange(lo, hi + 1)


def slid_along_rays(tree: VesselTree, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                    settings: SlideSettings = SLIDE_SETTINGS, step_mm: float = 0.25) -> tuple[VesselTree, int]:
    """Two views: runs of the tree's points moved along one view's rays where the other view's
    mask holds pieces the tree leaves unexplained (module notes).

    Parameters
    ----------
    tree : VesselTree
    projections, masks : sequences of two
        The views (masks boolean, shapes the projections' image shapes).
    settings : SlideSettings
    step_mm : float
        The tubes are drawn from samples this far apart (as :func:`.agreement.tube_silhouette`).

    Returns
    -------
    tree : VesselTree
        The same branches and topology, some of their points moved (the radii kept).
    moved : int
        The runs moved.
    """
    if len(projections) != 2:
        raise ValueError(f"slid_along_rays works on two views, got {len(projections)}")
    branches = list(tree.branches)
    moved = 0
    for b in (0, 1):
        seen_by, view = projections[1 - b], projections[b]
        mask = np.asarray(masks[b], dtype=bool)
        drawn = tube_silhouette(VesselTree(tuple(branches)), view, step_mm=step_mm)
        pieces, n = ndi.label(mask & ~drawn, structure=np.ones((3, 3), dtype=bool))
        picture = None  # the counts, drawn again once a piece is tried
        if n == 0:
            continue
        sizes = np.bincount(pieces.ravel(), minlength=n + 1)
        sizes[0] = 0
        for piece in np.flatnonzero(sizes >= settings.min_pixels):
            rows, cols = np.nonzero(pieces == piece)
            found = _run(VesselTree(tuple(branches)), view, np.column_stack([cols, rows]).astype(float), settings)
            if found is None:
                continue
            k, run = found
            if picture is None:
                picture = _Picture(branches, view, mask, step_mm)
            branch, samples = branches[k], picture.samples[k]
            # the branch's end moves only where it is free (no child leaves it: its first point is that end)
            free_end = run[-1] == branch.n_points - 1 and all(
                tree_branch.parent != k or tree_branch.parent_point != branch.n_points - 1 for tree_branch in branches)
            arc = branch.arc_length_mm
            lo_mm, hi_mm = arc[run[0]], arc[run[-1]]
            sample_arc = samples.arc_length_mm
            # the run's samples (its first point's stays: the offset is zero there)
            inner = np.flatnonzero((sample_arc > lo_mm) & (sample_arc <= hi_mm))
            if len(inner) < 2:
                continue
            knots = np.linspace(lo_mm, hi_mm, max(int(np.round((hi_mm - lo_mm) / settings.knot_mm)), 1) + 1)
            base = samples.points_mm[inner]
            rays = base - seen_by.camera_centre_mm
            rays /= np.linalg.norm(rays, axis=1, keepdims=True)
            radii = samples.radius_mm[inner]
            s = sample_arc[inner]
            ends = samples.points_mm[[inner[0] - 1]]  # the sample before the run, fixed
            after = samples.points_mm[[inner[-1] + 1]] if inner[-1] + 1 < samples.n_points else ends[:0]

            def placed(values: np.ndarray, at: np.ndarray | slice = slice(None)) -> np.ndarray:
                return base[at] + np.interp(s[at], knots, values)[:, None] * rays[at]

            def length(points: np.ndarray) -> float:
                return float(np.linalg.norm(np.diff(np.vstack([ends, points, after]), axis=0), axis=1).sum())

            values = np.zeros(len(knots))  # the offsets at the knots (mm along the rays)
            current = base.copy()
            gain, run_length = 0.0, length(current)
            for level, stride in enumerate(settings.knot_strides):  # every stride-th knot moves, the rest follow
                at = np.unique(np.append(np.arange(0, len(knots), stride), len(knots) - 1))
                for step in settings.steps_mm if level == 0 else settings.fine_steps_mm:
                    improved = True
                    while improved:
                        improved = False
                        for i in range(1, len(at) if free_end else len(at) - 1):  # the first knot stays
                            j = at[i]
                            lo = knots[at[i - 1]]
                            hi = knots[at[i + 1]] if i + 1 < len(at) else np.inf
                            near = np.flatnonzero((s > lo) & (s < hi))
                            for sign in (1.0, -1.0):
                                moved_to = values[j] + sign * step
                                if abs(moved_to) > settings.max_offset_mm:
                                    continue
                                trial = values[at]
                                trial[i] = moved_to
                                trial = np.interp(knots, knots[at], trial)
                                new = placed(trial, near)
                                delta, touched, change = picture.moved(current[near], new, radii[near])
                                points = current.copy()
                                points[near] = new
                                new_length = length(points)
                                score = delta - settings.length_px_per_mm * (new_length - run_length)
                                if score > 1e-9:
                                    picture.keep(touched, change)
                                    values, current, run_length = trial, points, new_length
                                    gain += score
                                    improved = True
                                    break
            if gain < settings.min_gain * sizes[piece]:
                picture.keep(*picture.moved(current, base, radii)[1:])  # back
                continue
            points = branch.points_mm.copy()
            points[run] += np.interp(arc[run], knots, values)[:, None] * _unit(points[run] - seen_by.camera_centre_mm)
            if not (np.linalg.norm(np.diff(points, axis=0), axis=1) > 0).all():
                picture.keep(*picture.moved(current, base, radii)[1:])  # back
                continue
            branches[k] = Branch(points, branch.radius_mm, branch.parent, branch.parent_point, branch.name)
            now = samples.points_mm.copy()
            now[inner] = current
            picture.replace(k, branches[k], now)
            moved += 1
    return (VesselTree(tuple(branches)) if moved else tree), moved


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
