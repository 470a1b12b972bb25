"""The vessel tree of a visual hull: skeleton, then centres and radii fitted to the views.

:func:`hull_tree` turns the kept lattice points of any reconstruction (either preset, any number of
views) into a :class:`~angiohull.tree.VesselTree`:

1. **Skeleton.** The kept lattice cells form an occupancy volume (pooled to cells of at most
   ``max_cell_mm`` on very fine lattices). On a fine lattice a thin vessel is carved with gaps of
   a cell or two (a cell projects to more than the 1 px threshold; the refined preset keeps such
   parts together by the same rule), so the volume is first dilated by ``floor(bridge_mm / cell)``
   cells (one at K = 256, none at the paper's K = 100). Centerline paths through it
   (:func:`angiohull.tree.teasar.teasar_skeleton`; 3D thinning can lose whole limbs) make the
   skeleton, and :func:`angiohull.tree.skeleton.tree_from_skeleton` the graph: cycles cut, small
   gaps joined (larger ones along the shortest path through ``support_points_mm``, the carving
   before refinement, where the refined preset dropped a true piece; with three views or more,
   where it holds none, by a straight chord that every view but one shows: :class:`SupportBridge`),
   spurs no longer than two
   local radii removed, the root at the widest tip, branches continued through junctions. Its
   radii (the distance to the nearest empty cell of the undilated volume) only start the fit: the
   hull is wider than the vessel, and the lattice coarse.
2. **Branches** are resampled every ``point_step_mm`` and smoothed along their arc length
   (Gaussian, ``smoothing_mm``), children re-attached to their parent's smoothed point.
3. **Cross-sections in the views** (``iterations`` times). At each point, in each view, the mask
   is sampled (bilinearly, every ``profile_step_px``) along the normal of the projected
   centerline (the tangent: the chord of the branch from one radius, at least 0.5 mm, behind the
   point to one radius ahead; a vessel bends little within its radius); the run of vessel pixels
   through the projection gives two sub-pixel edges (the 0.5 crossings, half-way between a vessel
   pixel centre and a background one, as the pixel-centre rule of the masks puts them), hence a
   width ``w`` and the offset ``c`` of its middle from the projection. A view *sees* the point's
   cross-section when
   - the run exists (the projection lies on the mask or within 2 px of it, and the run ends
     inside the profile),
   - the vessel is not foreshortened there (the projected tangent is at least
     ``min_foreshortening`` of its length at that depth), and
   - nothing else of the tree spoils the run: no point of another branch, or of the same branch
     farther along it than the two radii plus ``overlap_margin_mm`` (a loop crossing itself), has
     a projected disc that, widened by ``overlap_margin_px``, crosses the run's line within the
     point's projected radius of it. A disc beside the line, ahead or behind along the projected
     centerline, leaves the run as it is. (Since 2026-12-03; before, every disc within the two
     projected radii plus the margin counted, on whatever side: on the authors' 48 studies two
     thirds of the tree method's points and views counted as overlapped and a third of its points
     was fitted to no view; and since a branch's own points farther than the arc rule's reach lie
     that near in the image wherever the view foreshortens it, a 1 mm vessel hid itself in every
     view that foreshortened it below about 0.77. With the line rule, below about 0.45.)
   Each seeing view gives the radius ``w / 2 * depth / f`` (``f`` the focal length in pixels);
   the point's radius is the median (the mean of two) over the seeing views that foreshorten the
   vessel least: those within ``radius_foreshortening_tolerance`` of the least foreshortening
   one. A cross-section seen at a slant projects as an ellipse that reaches along the vessel, so
   the silhouette of a narrowing there takes the width of the wider cross-sections beside it (on
   the QCA benchmark's 3-view segmented trees, every seeing view counted: minimal lumen diameters
   0.04 mm wider on average, up to 0.7 mm at short lesions). A point no view sees (at a
   bifurcation, where the other branch's first points overlap it in every view, or where vessels
   cross in every view) gets its radius interpolated along its branch from the points that are
   seen (on a branch with none, the smallest radius any view gives: an overlap only widens a run).
   The point moves by the least-squares step that puts its projection on the axis as each view
   shows it (along each view's normal; the step along the 3D tangent is held at zero), at most one
   radius per iteration, then the branches are smoothed again (``smoothing_mm / 2``). A view shows
   the axis at the middle of its run where it sees the point, or where another vessel crosses the
   run only within its silhouette (both edges still the vessel's own); and, where only one edge is
   the vessel's own (another vessel's disc reaches past the other edge, or the run does not end
   within the reach on that side: a vessel merged with another in that view, a point by a
   junction), at that edge plus the projected radius towards the other side (since 2026-12-03;
   before, such views gave nothing, and the points they were the only views of stayed where the
   skeleton put them: on the authors' 48 studies, after the line rule above, a fifth of the tree
   method's points were seen by no view and a quarter by one, 0.70 and 0.40 mm (median) from the
   true axis against 0.18 mm with two. Paired, the tree method: 3 exact clinical views, 100
   generated trees, Dice3D +0.60 ± 0.11, centerline -0.044 mm (98 of 100 nearer); 6 views
   +0.02 ± 0.04, centerline -0.008 mm; 2 clinical views, 200 trees, exact +0.72 ± 0.14,
   segmented +0.65 ± 0.21, branch recall +0.023 / +0.020; the authors' 48 studies 88.9 ->
   89.6 %, +0.75 ± 0.26). After the last iteration the positions are smoothed once more: every
   point now moves with its views' edges, whose sub-pixel noise makes a polyline longer than its
   vessel (on the QCA benchmark's 60 trees in 3 views, branch lengths within 1 % or 1 mm of the
   truth 0.657 without it, 0.709 with a Gaussian of 0.5 mm, from exact masks; 0.537 and 0.628 from
   segmented angiograms; the centerline distance on 100 trees 0.110 and 0.111 mm). Since
   2026-12-05 that smoothing is a quadratic least-squares fit over ``final_window_mm`` of arc
   length about each point (Savitzky–Golay; a branch shorter than the window: the Gaussian of
   ``final_smoothing_mm``, as before). A Gaussian draws a bend's points in towards its centre,
   shortening it (a circle of radius R by the factor exp(-sigma^2 / (2 R^2)): the middle stretches
   of tortuous trees read 0.9 % short), and a wider one to smooth more noise cuts more; a
   quadratic fit follows a bend and smooths the noise more. On the QCA benchmark (3 views, dev
   runs at 9a70016, its 60 trees and 60 others) branch lengths within 1 % or 1 mm of the truth
   went from 0.770 to 0.806 and 0.779 to 0.815 from exact masks, 0.673 to 0.683 and 0.688 to
   0.705 from segmented angiograms; bifurcation angles within 5 degrees 0.811 to 0.828 and 0.832
   to 0.840 (exact), 0.790 to 0.784 and 0.812 to 0.802 (segmented). Other windows on the first 60,
   exact masks: 2, 3, 4, 6, 7, 8 and 10 mm gave 0.783, 0.780, 0.783, 0.799, 0.812, 0.793 and 0.748
   (7 mm from segmented angiograms 0.660 and 0.731, angles 0.779 and 0.785: not taken); Gaussians
   of 0.75 and 1 mm 0.751 and 0.748. The tree method: 3 exact views Dice3D +0.11 ± 0.05,
   centerline -0.006 mm; two views within the noise (the tree-method benchmark's 60 trees, exact
   -0.11 ± 0.17, segmented -0.33 ± 0.37; 120 others, segmented +0.12 ± 0.22).
   Before the last iteration, with three views or more, the tails of branches past their last
   child (stubs) that no view sees over ``max_unseen_share`` of their points are cut off (for
   these removals a branch's own points hide each other only where, besides the arc rule above,
   the image path between them is longer than the two projected radii plus
   ``overlap_margin_px``: a loop, not a straight stretch that the view foreshortens; the arc rule
   alone hides every point of a branch of radius 1 mm whose foreshortening is below about 0.45):
   where the skeleton ran a branch on beside the vessel and made the vessel's continuation a
   child, the stub hides that child in every view (on the authors' 48 studies it took true side
   branches with it). The root's head, its points before its first junction, is cut off the same
   way: the skeleton's path starts at a tip, often a phantom piece or a stub no view sees, and as
   part of the root it is no leaf (on the authors' ``perpendicular_moderate_001`` a phantom of
   18 mm, 10 mm from the true vessel, started the root and kept a fat tube there: Dice3D 87.1 %,
   92.0 % without it, the root then everywhere within 2.2 mm of the true centerlines). Unless a
   child leaves that junction within ``head_fork_deg`` of the head (chords over 3 mm): the
   skeleton split a vessel's end into two prongs, which hide each other in every view (cut, the
   true ostium went on 3 of the 48 studies). Then leaf branches that no view sees over that share
   are removed, repeatedly (spurs, stubs at a junction, phantom pieces the hull kept where vessels
   cross in every view). With two
   views a phantom and the true branch it mirrors overlap each other in both views, nothing tells
   them apart, and nothing is removed.
   Before each iteration, and once after the last, a **hairpin** at a branch's end is cut out:
   where a branch's only child leaves its last point turning back by more than ``fold_bend_deg``
   (the chords over one radius, at least 1 mm, either side; a tube cannot turn so within its
   radius), the fit has pulled the junction's corner out into a spur, the branch running up it and
   the child back down beside it. The branch's last stretch and the child's first, each at most
   ``hairpin_reach_radii`` of the branch's radii, are replaced by the chord between the pair of
   their points that leaves the path turning least (the angles at the chord's two ends), points
   every ``point_step_mm`` (since 2026-12-07; on the QCA benchmark's 60 trees in three views, from
   exact masks, the refined hull: left tree 4's circumflex read 4.3 mm long and its first marginal
   6.3 mm, the spur 3 mm out beside the true junction). A fold is one vessel: not where the child
   is narrower than ``hairpin_width_ratio`` times the branch (median radii over the next
   ``hairpin_reach_radii`` radii beyond the stretches), a side branch leaving where the branch
   ends (since 2026-12-07: a root traced from inside the RCA back to its ostium, the conus leaving
   its last point turning back, lost 5 mm of the RCA's start to the cut).
4. **Root.** The skeleton's root is its widest tip by the voxels' depth, which the occupancy
   gives only coarsely, and the stub from the ostium to the first side branch can be short enough
   to go as a spur. Once the radii are fitted, the ostium is the tip (the root's start or a
   branch end with no child there) whose radius averaged over ``ostium_window_mm`` is the
   largest (the widest such mean within two windows of the tip, clear of junctions, else the
   mean one window in: the first window alone is the end cap's; a tip only as wide as the root's
   start leaves the root where it is; a branch end from which only children narrower by
   ``ostium_inner_ratio`` run on, and that a view sees, counts as a tip: the wide vessel ends
   there, as where the stub to the ostium went as a spur and the skeleton ran on into the conus
   branch). A tip no view sees over those two windows has only the radius interpolated from the
   nearest seen point inside (a phantom stub at the left main's split carries the left main's):
   of the tips within ``ostium_inner_ratio`` of the widest, a seen one goes first, and an unseen
   side branch no longer than ``ostium_junction_mm`` (a stub by a junction, its radii the
   junction's) is no candidate. Or, where a point inside a branch is wider than the chosen tip by
   ``ostium_inner_ratio`` (the root's start, when chosen, counted as wide as its widest mean
   within its two windows up to its first junction: the end cap's excess and a junction's reach
   can leave no stretch clear of both)
   or more (averaged over the same arc, and farther than ``ostium_junction_mm`` from where
   branches meet, as radii swell there), that point (the stub went as a spur); when it lies more than
   ``reroot_mm`` from the root's start, the tree is traced again from there
   (:func:`angiohull.tree.skeleton.rerooted`; at an interior point the wider side carries the
   root on and the other starts a child at the root's first point), and step 6 extends the new
   root's start to the end of the masks.
   Then the fit's folds are read again. Where a branch's centerline turns by more than
   ``fold_bend_deg`` between the chord from one radius behind a point to it and the chord from it
   to one radius ahead (a tube turns there by r / R radians, under 90 degrees unless its axis bends
   tighter than 0.64 of its radius, which a tube cannot), the skeleton has folded through the blob
   of two vessels, up one and back down the other beside it (at the RCA's ostium, where the conus
   branch climbs beside the RCA's first centimetre), and the cross-sections there are read along
   the vessels. Their radii, and those of the held points in the same run along the branch, are
   interpolated from the points beyond (generated right tree 15 in three views, the QCA worked
   example: the root's first 7 mm were 4.11 mm wide where the ostium is 2.44 mm; 2.38 mm since
   2026-12-04). The root step itself still reads the folds' radii: on 2 of 60 generated trees the
   fold's wide radius is what brings the root to the ostium (re-read before the root step, the
   root went 6 and 27 mm off).
   Then the tree is traced again from its root on the fitted points (as
   :func:`angiohull.tree.skeleton.rerooted` traces it: at a junction a branch goes on into the
   neighbour that best continues it over ``SkeletonSettings.direction_window_mm``, the others start
   children), where it went on before changed only for a neighbour at least as wide, and a root that
   starts at a junction keeping its way (with no way in, the rule would take the widest: on right
   tree 26 of the QCA benchmark, whose root's head had been cut to the conus's junction, the
   conus's swollen start). The skeleton chose the continuations on the hull's voxels, where the blob of a
   junction bends the paths; fitted, the vessel running straight through a junction is plain, and
   where the skeleton's branch had turned into the side branch (the root of left tree 0 of the QCA
   benchmark into the first obtuse marginal, at 90 degrees, the circumflex going on as its child)
   the side branch's junction then sat at the corner the turn cut, 3 mm before the true one, where
   step 5 cannot move it (a child running along its parent is left as it is). With three views or
   more: with two, the fitted points hold the depth errors of the pairing, and traced again they
   moved the two-view trees of the tree method's benchmark farther from the truth as often as
   nearer (with the slide along the rays of :mod:`.model.sliding`, 15 of the 16 exact-mask trees
   it changed farther, by up to 0.2 mm). Since 2026-12-07; on
   the QCA benchmark's 60 trees in three views from exact masks (the refined hull), with the
   hairpins of step 3: branch lengths within 1 % or 1 mm 80.9 -> 84.8 %, bifurcation angles MAE
   2.45 -> 2.32 degrees (405 -> 416 measured); 60 other trees 81.2 -> 84.4 %, 2.47 -> 2.21 degrees.
5. **Junctions.** Where two vessels leave each other they are one blob in the hull and in every
   view, and the skeleton's junction lies where the blob's medial axis splits: displaced along the
   parent towards where the child leans, by a few millimetres for a child at 20-50 degrees (on 24
   generated trees from 3 views, half the junctions lay more than 1.9 mm from the truth). So each
   child (parents first) is read from its first point clear of the parent's tube (the axes
   farther apart than the two radii plus ``junction_margin_mm``): the line through the next
   ``junction_fit_mm`` of it (least squares), extended back, meets the parent at the parent's
   point nearest to it behind that start. When the line passes that point within
   ``junction_max_miss_radii`` parent radii, crosses the parent at ``junction_min_angle_deg`` or
   more (a child nearly along its parent meets it nowhere in particular) and the point lies within
   ``junction_max_move_mm`` of the skeleton's junction, the child starts there, straight to its
   clear start (the radius there held over the straight part; no view sees a cross-section where
   the vessels merge). Same 24 trees: median junction error 0.86 mm instead of 1.90 mm.
   The clear start lies where the axes are the two radii minus a quarter millimetre apart
   (``junction_margin_mm`` = -0.25; 2026-12-04, +0.5 before): a side branch curves as it leaves,
   and the farther out the line is read, the more that curve tilts it (notes in docs/vessel-tree.md).
   That tilt, and a child leaving at an acute angle (clear only 5-15 mm out), still put the line's
   junction millimetres off, so the masks decide last (since 2026-12-05): every parent point within
   ``junction_silhouette_reach_mm`` of it (or of the skeleton's junction, when the line is refused;
   a child whose axis runs along the parent keeps its start) and behind the clear start is a
   candidate, joined to the clear start by a cubic Hermite curve (leaving along the chord, arriving
   along the child) drawn as the child's tube, with the rest of the tree drawn as discs of its radii
   (the parent at its median radius within the reach plus ``junction_silhouette_parent_mm``: where
   the two merge, its cross-sections read both); the candidate whose drawing disagrees with the
   fewest mask pixels, over all views, wins when it beats the first junction by more than
   ``junction_silhouette_gain_px`` (of those within ``junction_silhouette_tie_px`` of the fewest,
   the one nearest the first), and the child starts along its curve (a wide tube or window is read
   on every k-th pixel: ``_JUNCTION_STRIDE_RADIUS_PX``, ``_JUNCTION_MAX_PIXELS``). On the QCA benchmark's 60 trees
   (3 views, exact masks) children's junctions more than 1 mm from the truth fell from 28 to 23 %
   (more than 2 mm: 18 to 13 %) and bifurcation angles within 5 degrees rose from 82 to 87 % (83
   to 90 % on 60 other trees; docs/vessel-tree.md).
6. **Ends.** Near a tip the cross-sections are the end cap's, not a tube's, and the skeleton's
   path ends where the hull's excess beyond the cap is farthest: bent off the axis (the root's
   start, at the left main's ostium, 2-3 mm to the side on 4 of 8 generated left trees). So each
   tip's last ``tip_straight_radii`` radii (the largest radius within ``junction_fit_mm`` of the
   tip: an end cap's cross-sections narrow towards it) are first laid on the least-squares line of the
   ``junction_fit_mm`` of its branch before them, when the tip lies farther than
   ``tip_hook_radii`` radii from that line (only the ends of branches without children, and the
   root's start unless a child leaves from the stretch; a short
   trunk's line, near its junction, may tilt a start that has no hook). Then the
   skeleton may stop short of a vessel's end or overshoot it where the hull ends in
   a point. Each tip of the tree (the root's start and every branch end with no child there) moves
   along its tangent to the farthest place, within ``end_reach_radii`` radii, where the end cap
   (the point plus one radius along the tangent) still projects onto the mask in every view; a tip
   whose cap is off a mask is cut back to where no view shows it off its mask: a branch's end
   exactly there (a point interpolated, not the resampled point before it), the root's start to
   the point after it and no farther than its first child's parent point (its children's parent
   points follow the cut; cut exactly too, the second pass rooted generated right tree 15, three
   views, elsewhere: its first 10 mm 1.19 mm wide, the ostium 2.44 mm); a
   cap that projects past an image's edge is off no mask there (the vessel may run on), so a tip
   whose cap lies past an edge and on the other masks stays where it is.
7. Radii may be smoothed along the branch (Gaussian, ``radius_smoothing_mm``) before the ends
   move; by default they are not: a smoothing of 0.5 mm filled stenoses in (on 16 generated trees
   with 36 stenoses, the minimal lumen diameter came out 0.070 mm too wide on average, against
   -0.004 mm unsmoothed) for a radius MAE of 0.043 instead of 0.048 mm.
8. **Second pass** (``fit_passes`` = 2, since 2026-12-05; :func:`refit_tree`). With three views
   or more, steps 2-6 run once more on the tree the first pass gave, as if it were the skeleton:
   resampled, smoothed, its cross-sections fitted ``iterations`` times, the root, junctions and
   ends placed again. The first pass starts from the skeleton's coarse positions and radii and
   moves the root, the junctions and the ends only after its cross-section fits; the second starts
   from fitted ones. (Why a second pass gains where more iterations within one did not, 5 instead
   of 3 losing 0.20 +- 0.19 Dice3D points on two views, is not pinned down: it runs the smoothing
   and the root, junction and end steps again too.) Paired against one pass, 30 RCA + 30 left
   generated trees, the tree method from 3 exact clinical views: Dice3D +0.25 +- 0.09 points,
   centerline -0.015 mm, radius MAE -0.002 mm; the authors' 48 studies 90.05 -> 90.30 % (+0.25 +-
   0.20); the refined hull's tree on the QCA benchmark (3 views, exact masks): branch lengths
   within 1 % or 1 mm 72.5 -> 75.4 %, bifurcation angles within 5 degrees 79.2 -> 82.7 %. With two
   views the hull's tree keeps one pass: its phantom branches overlap the true ones in both views,
   and with a second pass the QCA benchmark's two-view hull column found 70 of the 147 stenoses
   instead of 81. The tree method fits its final two-view tree a second time itself
   (docs/tree-method.md, step 5).
   From the second pass on (``bound_unmeasured``, since 2026-12-05), a view that cannot measure a
   point's axis (its run spoiled on both sides by other vessels, or the vessel foreshortened
   there) but found the run still bounds it: where the point's projected disc reaches past an edge
   of that run, the axis is drawn back to one radius inside the edge (to the run's middle where
   the run is narrower than the disc), as a target like a measured one; a disc inside the run
   says nothing. On the tree method's final two-view trees (generated, exact masks) 45 % of such
   point-views had the disc past an edge, and drawing them back cut their error along the normal
   from 1.0 to 0.6 px (towards the truth in 85 %). The first pass starts from the skeleton's
   positions and radii; in every build of the tree method's stretch rounds the bound moved the
   rounds' choices (exact masks +0.26 +- 0.11 Dice3D on 120 other trees, random pairs -0.12 +-
   0.37), in the final refit alone it gained on every two-view setting (docs/tree-method.md).

Arrays and projections in, a tree out; nothing here reads files.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from ..compiled import kernels
from ..errors import ReconstructionError, TreeError
from ..geometry import Projection
from ..tree import Branch, VesselTree
from ..tree.model import arc_length_mm, point_at_arc
from ..tree.skeleton import SkeletonInfo, SkeletonSettings, rerooted, tree_from_skeleton
from ..tree.teasar import teasar_skeleton
from ..tree.voxels import coordinates, dilated, distance_to, neighbour_edges
from .cube import Lattice
from .refine import cell_reach_px, projected_with_scale

__all__ = ["TreeSettings", "TREE_SETTINGS", "TreeBuild", "SupportBridge", "checked_occupancy", "hull_tree", "refit_tree"]


@dataclass(frozen=True)
class TreeSettings:
    """Parameters of :func:`hull_tree` (module notes); the same for every preset and case."""

    max_cell_mm: float = 0.4  # finer lattices are pooled to cells of at most this (whole factors; K = 1024: 0.35 mm)
    max_voxels: int = 1_000_000  # a hull filling more cells than this is not a vessel tree (no tree is built)
    bridge_mm: float = 0.6  # the occupancy is dilated by floor(bridge_mm / cell) cells before the paths
    point_step_mm: float = 0.5  # branch points every this much arc length
    smoothing_mm: float = 1.0  # Gaussian sigma of the positions along a branch, mm
    iterations: int = 3  # cross-section fits
    final_window_mm: float = 5.0  # after the fits, a quadratic fit over this much arc length about each point (0: Gaussian)
    final_smoothing_mm: float = 0.5  # ... and a Gaussian of this sigma on a branch shorter than that window, mm
    profile_step_px: float = 0.5  # sampling step along a cross-section, px (edges interpolated between samples)
    min_foreshortening: float = 0.4  # a view sees a cross-section when the vessel is at most ~66 deg out of its plane
    radius_foreshortening_tolerance: float = 0.2  # radii from the seeing views foreshortened at most this more than the least
    overlap_margin_px: float = 1.5  # projected discs closer than this (beyond touching) overlap
    overlap_margin_mm: float = 1.0  # points of one branch farther apart along it than the two radii plus this can overlap
    radius_smoothing_mm: float = 0.0  # Gaussian sigma of the radii along a branch, mm (0: none; see the notes)
    fit_passes: int = 2  # steps 2-6 run this many times with 3+ views, each on the tree the last gave (notes, step 8)
    bound_unmeasured: bool = True  # from the second pass on, a view that cannot measure a point keeps its disc in the run
    max_unseen_share: float = 0.75  # a leaf branch no view sees over this share of its points is removed
    head_fork_deg: float = 45.0  # ... and the root's head, unless a child leaves its junction within this of it
    fold_bend_deg: float = 90.0  # a centerline turning more than this between the chords a radius either side folds
    # (a tube cannot): its cross-sections there are read along the vessels; see the notes, step 4
    hairpin_reach_radii: float = 3.0  # a branch's only child turning back by more than fold_bend_deg at its end: the
    # hairpin cut out over at most this many parent radii of either (notes, step 3), ...
    hairpin_width_ratio: float = 0.6  # ... where the child is at least this share of the branch's width (a fold of
    # one vessel; a narrower child is a side branch leaving where the branch ends, e.g. the conus by the ostium)
    end_reach_radii: float = 3.0  # how far a tip may move (either way), in radii
    ostium_window_mm: float = 3.0  # the ostium is the tip whose radius, averaged over this much arc, is largest,
    ostium_inner_ratio: float = 1.3  # ... or a point inside a branch this many times wider still
    ostium_junction_mm: float = 5.0  # ... and farther than this from where branches meet
    reroot_mm: float = 5.0  # ... and the tree is rooted there when that lies farther than this from its root
    max_bridge_mm: float = 80.0  # longest path through the support hull that joins a part to the tree
    junction_margin_mm: float = -0.25  # a child is clear of its parent where their axes lie the two radii plus this apart
    # (negative: the child's cross-section still reaches this far into the parent's; see the notes, step 5)
    junction_fit_mm: float = 3.0  # the child's axis: the line through this much of it from where it is clear
    junction_max_miss_radii: float = 1.0  # ... which must pass the parent's axis within this many parent radii,
    junction_min_angle_deg: float = 15.0  # ... cross it at this angle or more,
    junction_max_move_mm: float = 8.0  # ... and this close to the skeleton's junction (else the junction stays)
    junction_silhouette_reach_mm: float = 3.0  # then the junction may move this far along the parent from there (or
    # from the skeleton's) to where the child's tube joining it best matches the masks (notes, step 5; 0: off) ...
    junction_silhouette_gain_px: float = 5.0  # ... when the pixels the tree and the masks disagree on fall by more
    junction_silhouette_tie_px: float = 2.0  # ... the junctions within this many of the fewest: the nearest one wins
    junction_silhouette_parent_mm: float = 5.0  # ... the parent drawn at its median radius over the reach and this
    tip_straight_radii: float = 1.5  # a tip's last this many radii are laid on the line of its branch before them,
    tip_hook_radii: float = 0.25  # ... when the tip lies farther than this many radii from that line
    skeleton: SkeletonSettings = field(default_factory=SkeletonSettings)


TREE_SETTINGS = TreeSettings()
"""The settings every reconstruction uses (measured in docs/vessel-tree.md)."""

_MIN_RADIUS_MM = 0.05
_JUNCTION_STRIDE_RADIUS_PX = 12.0  # the junction step reads every k-th pixel of a tube this wide and k/2 times it (radius),
_JUNCTION_MAX_PIXELS = 40_000  # ... or of a window larger than this, down to this many (XCAT, 2 views: 64 s without)
_SEEK_PX = 2.0  # a projection off the mask looks this far along the normal for the vessel


@dataclass(frozen=True)
class TreeBuild:
    """What :func:`hull_tree` did, for reports."""

    skeleton: SkeletonInfo
    points_fitted: int  # tree points after resampling
    unseen_leaves_removed: int  # leaf branches removed because no view saw them
    seen_share: tuple[float, ...]  # per view: share of the points whose cross-section it sees
    unseen_points: int  # points no view sees (radius interpolated along the branch)
    tips_moved_mm: tuple[float, ...]  # per tip: how far it moved (+ out, - back)
    rerooted_mm: float  # how far the root moved to the ostium after the fit (0: it stayed)
    junctions_moved_mm: tuple[float, ...]  # per child re-joined to its parent (axis and silhouette rules): how far (mm)
    timings_s: dict[str, float]
    unseen_stub_points_removed: int = 0  # points of branch tails past the last child that no view saw, cut off
    fold_points_reread: int = 0  # points at or beside a fold whose radii were interpolated from the points beyond
    unseen_head_points_removed: int = 0  # points of the root's head (before its first junction) no view saw, cut
    fit_passes: int = 1  # times steps 2-6 ran (:func:`refit_tree`)


# -- branch arrays -----------------------------------------------------------------------------
def quadratic_smoothed(points: np.ndarray, window: int) -> np.ndarray:
    """Each of ``points`` ((M, ...) along a line, evenly spaced) replaced by the value at it of the
    least-squares parabola through the ``window`` (odd, at most M) points centred on it; within
    ``window // 2`` of either end, by the parabola through the first or last ``window`` points
    (Savitzky–Golay of order 2). A parabola, a line or a constant comes back unchanged.

    Each value is a fixed weighting of ``window`` points (a row of :func:`_parabola_hat`): the
    middle row slides along the inside, the first and last rows give the ends. (scipy.signal's
    savgol_filter fits the same parabolas, the same values to about 1e-14 of their size, but
    importing scipy.signal costs about 0.8 s a process.)"""
    points = np.asarray(points, dtype=np.float64)
    n, half = len(points), window // 2
    if window % 2 == 0 or window < 3 or window > n:
        raise ValueError(f"the window must be odd, at least 3 and at most the {n} points, got {window}")
    hat = _parabola_hat(window)
    flat = points.reshape(n, -1)
    out = np.empty_like(flat)
    out[half:n - half] = ndi.correlate1d(flat, hat[half], axis=0)[half:n - half]  # inside: the middle row slides
    out[:half] = hat[:half] @ flat[:window]
    out[n - half:] = hat[half + 1:] @ flat[n - window:]
    return out.reshape(points.shape)


@functools.lru_cache(maxsize=64)
def _parabola_hat(window: int) -> np.ndarray:
    """(window, window): row i gives, from ``window`` evenly spaced values, the value at the i-th
    of them of their least-squares parabola (the fit's hat matrix; positions centred on the middle
    one, so that the normal equations stay well conditioned)."""
    x = np.arange(window, dtype=np.float64) - window // 2
    design = np.column_stack([np.ones(window), x, x * x])
    hat = design @ np.linalg.solve(design.T @ design, design.T)
    hat.setflags(write=False)
    return hat


_COLLAPSED_CHORD_MM = 1e-9  # _Arrays.tangents: a chord shorter than this gives no direction (a fold's apex)


@dataclass
class _Arrays:
    """The tree as flat arrays while it is fitted: points, radii and where each branch sits."""

    points: np.ndarray  # (N, 3)
    radius: np.ndarray  # (N,)
    starts: np.ndarray  # (B,) first index of each branch
    counts: np.ndarray  # (B,)
    parents: list[int | None]
    parent_points: list[int | None]
    names: list[str]

    @classmethod
    def of(cls, tree: VesselTree) -> "_Arrays":
        counts = np.array([b.n_points for b in tree.branches])
        return cls(np.concatenate([b.points_mm for b in tree.branches]),
                   np.concatenate([b.radius_mm for b in tree.branches]),
                   np.cumsum(counts) - counts, counts,
                   [b.parent for b in tree.branches], [b.parent_point for b in tree.branches],
                   [b.name for b in tree.branches])

    def span(self, b: int) -> slice:
        return slice(int(self.starts[b]), int(self.starts[b] + self.counts[b]))

    def child_points(self) -> list[list[int]]:
        """Per branch, the indices of its points that its children leave from (children in order)."""
        out: list[list[int]] = [[] for _ in range(len(self.counts))]
        for c in range(1, len(self.counts)):
            out[self.parents[c]].append(int(self.parent_points[c]))
        return out

    def anchor(self, b: int) -> int | None:
        """Flat index of the parent point of branch b."""
        parent = self.parents[b]
        return None if parent is None else int(self.starts[parent] + self.parent_points[b])

    def tangents(self, min_half_chord_mm: float = 0.5) -> np.ndarray:
        """(N, 3) unit tangents: at each point, the chord of its branch from one radius (at least
        ``min_half_chord_mm``) behind it to one radius ahead (clipped at the branch's ends). A tube
        bends little within its radius, and the cross-section is read across it: a tangent from the
        neighbours 0.5 mm away followed the skeleton's wiggles, and at the end of a thick vessel its
        bend towards a corner of the hull's cap put the normal along the vessel (the XCAT vessel,
        r ~ 10 mm: docs/vessel-tree.md, step 3)."""
        out = np.empty_like(self.points)
        for b in range(len(self.counts)):
            s = self.span(b)
            behind, ahead = self._chord_ends(b, min_half_chord_mm)
            g = ahead - behind
            length = np.linalg.norm(g, axis=1)
            folded = length < _COLLAPSED_CHORD_MM
            if folded.any():
                # at the apex of a fold whose arms coincide within the reach the chord collapses to
                # the arithmetic's noise (1e-14 mm), and its direction with it: one machine's last
                # bits drew another cross-section than another's (docs/tree-method.md,
                # "Reproducibility"); the step from the point before (at a branch's first point, to
                # the next) stands in
                p = self.points[s]
                step = np.vstack([p[1:2] - p[:1], np.diff(p, axis=0)]) if len(p) > 1 else np.zeros_like(p)
                g[folded], length[folded] = step[folded], np.linalg.norm(step[folded], axis=1)
            out[s] = g / np.maximum(length, 1e-12)[:, None]
        return out

    def _chord_ends(self, b: int, min_half_chord_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Branch b's points one radius (at least ``min_half_chord_mm``) of arc behind and ahead of
        each of its points (clipped at the branch's ends): two (n, 3) arrays."""
        p = self.points[self.span(b)]
        step = np.linalg.norm(np.diff(p, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(np.maximum(step, 1e-12))])
        half = np.maximum(self.radius[self.span(b)], min_half_chord_mm)
        ahead, behind = np.minimum(arc + half, arc[-1]), np.maximum(arc - half, 0.0)
        return (np.column_stack([np.interp(behind, arc, p[:, i]) for i in range(3)]),
                np.column_stack([np.interp(ahead, arc, p[:, i]) for i in range(3)]))

    def bends_deg(self, min_half_chord_mm: float = 0.5) -> np.ndarray:
        """(N,) the angle (degrees) between the chord from one radius behind each point to it and
        the chord from it to one radius ahead (0 at a branch's ends). A tube bends far less within
        its radius; a fold of the skeleton (two vessels merged, the path running up one and back
        down the other) turns by 90 degrees or more there."""
        out = np.zeros(len(self.points))
        for b in range(len(self.counts)):
            s = self.span(b)
            behind, ahead = self._chord_ends(b, min_half_chord_mm)
            back, on = self.points[s] - behind, ahead - self.points[s]
            lengths = np.linalg.norm(back, axis=1) * np.linalg.norm(on, axis=1)
            cos = np.einsum("ij,ij->i", back, on) / np.maximum(lengths, 1e-18)
            out[s] = np.where(lengths > 1e-18, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), 0.0)
        return out

    def smooth(self, sigma_mm: float, step_mm: float) -> None:
        """Gaussian smoothing of the positions along each branch (ends held), children re-attached."""
        if sigma_mm <= 0:
            return
        for b in range(len(self.counts)):
            p = self.points[self.span(b)]
            if len(p) >= 3:
                self._smoothed(b, ndi.gaussian_filter1d(p, sigma_mm / step_mm, axis=0, mode="nearest"))

    def smooth_quadratic(self, window_mm: float, sigma_mm: float, step_mm: float) -> None:
        """The positions of each branch fitted by :func:`quadratic_smoothed` over ``window_mm`` of arc
        length (ends held); a branch with no more points than the window has, or a window of 0, is
        smoothed by the Gaussian of ``sigma_mm`` instead; children re-attached."""
        window = 2 * int(round(window_mm / (2.0 * step_mm))) + 1
        if window < 5:
            self.smooth(sigma_mm, step_mm)
            return
        for b in range(len(self.counts)):
            p = self.points[self.span(b)]
            if len(p) > window:
                self._smoothed(b, quadratic_smoothed(p, window))
            elif len(p) >= 3 and sigma_mm > 0:
                self._smoothed(b, ndi.gaussian_filter1d(p, sigma_mm / step_mm, axis=0, mode="nearest"))

    def _smoothed(self, b: int, smooth: np.ndarray) -> None:
        """Branch ``b``'s positions set to ``smooth`` but for its two ends; its children re-attached."""
        s = self.span(b)
        smooth[0], smooth[-1] = self.points[s][0], self.points[s][-1]
        self.points[s] = smooth
        self.reattach(b)

    def reattach(self, parent: int) -> None:
        for child, p in enumerate(self.parents):
            if p == parent:
                self.points[self.starts[child]] = self.points[self.anchor(child)]

    def without_unseen_stubs(self, seen: np.ndarray, share: float) -> tuple["_Arrays", int]:
        """The arrays with each branch's tail past its last child's junction (a stub) cut off where
        no view sees over ``share`` of the tail's points. Returns the arrays and the points cut."""
        unseen = seen.sum(axis=0) == 0
        last = [max(c) if c else None for c in self.child_points()]
        keep = np.ones(len(self.points), dtype=bool)
        counts = self.counts.copy()
        for b, j in enumerate(last):
            if j is None or j == 0 or j >= self.counts[b] - 1:
                continue  # (a child at the first point: the branch would be that point alone)
            tail = slice(int(self.starts[b] + j + 1), int(self.starts[b] + self.counts[b]))
            if unseen[tail].mean() >= share:
                keep[tail] = False
                counts[b] = j + 1
        if keep.all():
            return self, 0
        return (_Arrays(self.points[keep], self.radius[keep], np.cumsum(counts) - counts, counts, list(self.parents),
                        list(self.parent_points), list(self.names)), int((~keep).sum()))

    def without_unseen_head(self, seen: np.ndarray, share: float, *, fork_deg: float | None = None,
                            reach_mm: float = 3.0) -> tuple["_Arrays", int]:
        """The arrays with the root's head (its points before its first child's junction) cut off
        where no view sees over ``share`` of them: the root starts at that junction then and its
        children's junction indices shift down. With ``fork_deg``, a head stays when a child at
        that junction leaves beside it (the chords from the junction to the points ``reach_mm``
        of arc along each within that angle). Returns the arrays and the points cut."""
        unseen = seen.sum(axis=0) == 0
        children = [c for c in range(1, len(self.counts)) if self.parents[c] == 0]
        first = min(self.parent_points[c] for c in children) if children else 0
        if first == 0 or first >= self.counts[0] - 1 or unseen[:first].mean() < share:
            return self, 0  # (first child at the root's last point: the root would be that point alone)
        if fork_deg is not None:
            def outward(p: np.ndarray) -> np.ndarray:
                arc = arc_length_mm(p)
                v = p[min(int(np.searchsorted(arc, reach_mm)), len(p) - 1)] - p[0]
                return v / max(float(np.linalg.norm(v)), 1e-12)
            head = outward(self.points[first::-1])
            for c in children:
                if self.parent_points[c] == first and self.counts[c] > 1:
                    if np.degrees(np.arccos(np.clip(head @ outward(self.points[self.span(c)]), -1, 1))) < fork_deg:
                        return self, 0
        counts = self.counts.copy()
        counts[0] -= first
        parent_points = [p - first if self.parents[c] == 0 else p for c, p in enumerate(self.parent_points)]
        return (_Arrays(self.points[first:], self.radius[first:], np.cumsum(counts) - counts, counts,
                        list(self.parents), parent_points, list(self.names)), first)

    def without_hairpins(self, min_turn_deg: float, reach_radii: float, step_mm: float,
                         width_ratio: float = 0.0) -> tuple["_Arrays", int, np.ndarray]:
        """The arrays with each hairpin at a branch's end cut out (module notes, step 3): where a
        branch's only child leaves its last point turning back by more than ``min_turn_deg`` (the
        chords over one radius, at least 1 mm, either side), the branch's last stretch and the
        child's first, each at most ``reach_radii`` parent radii of arc, are replaced by the chord
        between the pair of their points that leaves the path turning least (the angles at both of
        its ends, the chords over one radius behind and ahead), points every ``step_mm``; not where
        the child is narrower than ``width_ratio`` times the branch (their median radii over the
        next ``reach_radii`` radii of arc beyond the stretches, or over the whole branch where it
        is shorter): a side branch leaving where the branch ends is no fold. Returns
        the arrays, the number of hairpins cut and, per point of the new arrays, the index of the
        point it was (-1: a point of a chord)."""
        points = [self.points[self.span(b)] for b in range(len(self.counts))]
        origin = [np.arange(self.starts[b], self.starts[b] + self.counts[b]) for b in range(len(self.counts))]
        radius = [self.radius[self.span(b)] for b in range(len(self.counts))]
        parent_points = list(self.parent_points)
        cut = 0
        for b in range(1, len(self.counts)):
            p, k = self.parents[b], int(parent_points[b])
            parent, child = points[p], points[b]
            if k != len(parent) - 1 or len(parent) < 2 or len(child) < 3 or any(
                    self.parents[c] == p and parent_points[c] == k for c in range(1, len(self.counts)) if c != b):
                continue
            r = float(radius[p][k])
            chord = max(r, 1.0)
            parent_arc, child_arc = arc_length_mm(parent), arc_length_mm(child)
            into = parent[k] - point_at_arc(parent, parent_arc, parent_arc[k] - chord)
            out = point_at_arc(child, child_arc, chord) - child[0]
            if _angle_deg(into, out) <= min_turn_deg:
                continue
            reach = reach_radii * r
            if width_ratio > 0:
                before = radius[p][(parent_arc >= parent_arc[k] - 2 * reach) & (parent_arc < parent_arc[k] - reach)]
                beyond = radius[b][(child_arc > reach) & (child_arc <= 2 * reach)]
                width = float(np.median(before if len(before) else radius[p]))
                if float(np.median(beyond if len(beyond) else radius[b])) < width_ratio * width:
                    continue
            tail = np.flatnonzero(parent_arc >= parent_arc[k] - reach)
            tail = tail[tail >= 1]  # the branch keeps two points or more
            head = np.flatnonzero(child_arc <= reach)
            best, pair = np.inf, None
            for i in tail:
                before = parent[i] - point_at_arc(parent, parent_arc, parent_arc[i] - chord)
                for j in head:
                    if i == k and j == 0:
                        continue
                    join = child[j] - parent[i]
                    after = point_at_arc(child, child_arc, child_arc[j] + chord) - child[j]
                    turning = _angle_deg(before, join) + _angle_deg(join, after)
                    if turning < best:
                        best, pair = turning, (int(i), int(j))
            if pair is None:
                continue
            i, j = pair
            gap = float(np.linalg.norm(child[j] - parent[i]))
            fill = np.linspace(parent[i], child[j], max(int(np.ceil(gap / step_mm)), 1) + 1)[:-1]
            points[p], radius[p], origin[p] = parent[:i + 1], radius[p][:i + 1], origin[p][:i + 1]
            origin[b] = np.concatenate([np.full(len(fill), -1), origin[b][j:]])
            points[b] = np.concatenate([fill, child[j:]])
            radius[b] = np.concatenate([np.full(len(fill), radius[b][j]), radius[b][j:]])
            parent_points[b] = i
            for c in range(1, len(self.counts)):
                if self.parents[c] == p and c != b and parent_points[c] > i:  # siblings on the cut tail: at its cut
                    parent_points[c] = i
            for c in range(b + 1, len(self.counts)):  # the child's own children: the same points, or its new start
                if self.parents[c] == b:
                    parent_points[c] = max(int(parent_points[c]) - j, 0) + (len(fill) if parent_points[c] >= j else 0)
            cut += 1
        if cut == 0:
            return self, 0, np.arange(len(self.points))
        counts = np.array([len(x) for x in points])
        out = _Arrays(np.concatenate(points), np.concatenate(radius), np.cumsum(counts) - counts, counts,
                      list(self.parents), parent_points, list(self.names))
        for b in range(1, len(counts)):
            out.points[out.starts[b]] = out.points[out.anchor(b)]
        return out, cut, np.concatenate(origin)

    def without_unseen_leaves(self, seen: np.ndarray, share: float) -> tuple["_Arrays", int]:
        """The arrays without the leaf branches (no child) that no view sees over at least
        ``share`` of their points, repeatedly (a branch whose children all go may go next); the
        root stays. Returns the new arrays and the number of branches removed."""
        unseen = seen.sum(axis=0) == 0
        alive = np.ones(len(self.counts), dtype=bool)
        while True:
            parents = {p for b, p in enumerate(self.parents) if alive[b] and p is not None}
            drop = [b for b in range(1, len(self.counts)) if alive[b] and b not in parents
                    and unseen[self.span(b)].mean() >= share]
            if not drop:
                break
            alive[drop] = False
        if alive.all():
            return self, 0
        index = np.cumsum(alive) - 1
        keep = np.repeat(alive, self.counts)
        counts = self.counts[alive]
        parents = [None if self.parents[b] is None else int(index[self.parents[b]]) for b in np.flatnonzero(alive)]
        arrays = _Arrays(self.points[keep], self.radius[keep], np.cumsum(counts) - counts, counts, parents,
                         [self.parent_points[b] for b in np.flatnonzero(alive)], [self.names[b] for b in np.flatnonzero(alive)])
        return arrays, int((~alive).sum())

    def tree(self) -> VesselTree:
        """The tree, without a branch's repeated consecutive points (a child that leaves a dropped
        repeat leaves the kept point at the same place: the junction indices follow)."""
        kept_index = []
        for b in range(len(self.counts)):
            points = self.points[self.span(b)]
            keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9])
            kept_index.append((keep, np.cumsum(keep) - 1))
        branches = []
        for b in range(len(self.counts)):
            s = self.span(b)
            keep = kept_index[b][0]
            parent, at = self.parents[b], self.parent_points[b]
            if parent is not None:
                at = int(kept_index[parent][1][at])
            branches.append(Branch(self.points[s][keep], self.radius[s][keep], parent, at, self.names[b]))
        return VesselTree(tuple(branches))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two vectors, degrees (0 where either is zero)."""
    norms = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(float(a @ b) / norms, -1.0, 1.0)))) if norms > 0 else 0.0


# -- cross-sections ----------------------------------------------------------------------------
@dataclass(frozen=True)
class _Sections:
    """Per view and point: the run of the mask across the projected centerline."""

    found: np.ndarray  # (V, N) bool: a run through (or within 2 px of) the projection
    width_px: np.ndarray  # (V, N)
    offset_px: np.ndarray  # (V, N) middle of the run minus the projection, along the normal
    normal_px: np.ndarray  # (V, N, 2) unit normal in the image
    gradient: np.ndarray  # (V, N, 3) d(normal . uv)/dX, px per mm
    px_per_mm: np.ndarray  # (V, N) focal length / depth
    foreshortening: np.ndarray  # (V, N) |projected tangent| / px_per_mm
    uv: np.ndarray  # (V, N, 2)
    edges_px: np.ndarray | None = None  # (V, N, 2) the run's two edges along the normal (nan where not found)


# profiles of similar length are sampled together, each as long as its bin's reach (bins in steps of
# sqrt 2 sample about a tenth fewer values than steps of 2; the samples a profile uses are the same)
_REACH_BINS_PX = (12.0, 17.0, 24.0, 34.0, 48.0, 68.0, 96.0, 136.0, 192.0, 272.0, 384.0)


def _runs(image: np.ndarray, uv: np.ndarray, normal: np.ndarray, reach: np.ndarray,
          step_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The run of the mask through (or within ``_SEEK_PX`` of) each point along its normal, within
    ``reach`` px: ``(found, left edge, right edge)`` in px along the normal (edges at the 0.5
    crossings of the bilinear mask; an edge is nan where the run does not end within the reach on
    that side, and ``found`` is both edges found)."""
    n = len(uv)
    half = int(np.ceil(reach.max() / step_px))
    s = step_px * np.arange(-half, half + 1)
    u = uv[:, 0, None] + s[None, :] * normal[:, 0, None]
    v = uv[:, 1, None] + s[None, :] * normal[:, 1, None]
    profile = ndi.map_coordinates(image, [v.ravel(), u.ravel()], order=1, mode="constant", cval=0.0).reshape(u.shape)
    inside = profile >= 0.5
    index = np.arange(len(s))
    gap = np.where(inside, np.abs(index - half)[None, :], 10 ** 6)
    seed = np.argmin(gap, axis=1)
    found = gap[np.arange(n), seed] <= int(round(_SEEK_PX / step_px))
    outside = ~inside
    left = np.where(outside & (index[None, :] < seed[:, None]), index[None, :], -1).max(axis=1)
    right = np.where(outside & (index[None, :] > seed[:, None]), index[None, :], len(s)).min(axis=1)
    found_left = found & (left >= 0) & (s[np.clip(left, 0, None)] >= -reach)
    found_right = found & (right < len(s)) & (s[np.clip(right, None, len(s) - 1)] <= reach)
    left_c, right_c = np.clip(left, 0, len(s) - 2), np.clip(right, 1, len(s) - 1)
    rows = np.arange(n)
    p_out, p_in = profile[rows, left_c], profile[rows, left_c + 1]
    left_edge = s[left_c] + (0.5 - p_out) / np.maximum(p_in - p_out, 1e-9) * step_px
    p_in, p_out = profile[rows, right_c - 1], profile[rows, right_c]
    right_edge = s[right_c - 1] + (p_in - 0.5) / np.maximum(p_in - p_out, 1e-9) * step_px
    return found_left & found_right, np.where(found_left, left_edge, np.nan), np.where(found_right, right_edge, np.nan)


def _all_runs(image: np.ndarray, uv: np.ndarray, normal: np.ndarray, reach: np.ndarray,
              step_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_runs` of every point: the points in bins of similar reach, each bin's profiles as
    long as its longest reach. A run depends on the samples within its own reach alone, so the
    compiled kernel reads each point's samples outward from it, only as far as the run goes (the
    same samples, the same values)."""
    compiled = kernels()
    if compiled is not None:
        return compiled.mask_runs(image, np.ascontiguousarray(uv, dtype=np.float64),
                                  np.ascontiguousarray(normal, dtype=np.float64),
                                  np.ascontiguousarray(reach, dtype=np.float64), float(step_px),
                                  int(round(_SEEK_PX / step_px)))
    n = len(uv)
    found, left, right = np.zeros(n, dtype=bool), np.full(n, np.nan), np.full(n, np.nan)
    bins = np.searchsorted(_REACH_BINS_PX, reach)
    for b in np.unique(bins):
        sel = np.flatnonzero(bins == b)
        found[sel], left[sel], right[sel] = _runs(image, uv[sel], normal[sel], reach[sel], step_px)
    return found, left, right


def _sections(points: np.ndarray, tangents: np.ndarray, radius: np.ndarray, projections: Sequence[Projection],
              images: Sequence[np.ndarray], step_px: float) -> _Sections:
    n = len(points)
    out = {k: [] for k in ("found", "width_px", "offset_px", "normal_px", "gradient", "px_per_mm", "foreshortening", "uv",
                           "edges_px")}
    for projection, image in zip(projections, images):
        uv = projection.project(points)
        jac = projection.jacobian(points)
        f = max(projection.focal_lengths_px)
        px_per_mm = f / projection.depth_mm(points)
        d2 = np.einsum("nij,nj->ni", jac, tangents)
        length = np.linalg.norm(d2, axis=1)
        direction = d2 / np.maximum(length, 1e-12)[:, None]
        normal = np.column_stack([-direction[:, 1], direction[:, 0]])
        # a run up to 2.5 radii + 4 px either side (the radius may still be the hull's, too wide)
        reach = np.clip(2.5 * radius * px_per_mm + 4.0, 6.0, _REACH_BINS_PX[-1])
        found, left, right = _all_runs(image, uv, normal, reach, step_px)
        out["found"].append(found)
        out["width_px"].append(np.where(found, right - left, np.nan))
        out["offset_px"].append(np.where(found, 0.5 * (left + right), np.nan))
        out["normal_px"].append(normal)
        out["gradient"].append(np.einsum("ni,nij->nj", normal, jac))
        out["px_per_mm"].append(px_per_mm)
        out["foreshortening"].append(length / px_per_mm)
        out["uv"].append(uv)
        out["edges_px"].append(np.column_stack([left, right]))
    return _Sections(**{k: np.stack(v) for k, v in out.items()})


def _overlaps(sections: _Sections, arrays: "_Arrays", settings: TreeSettings, *, image_path: bool = False,
              sides: bool = False):
    """(V, N) bool: in the view, the point's cross-section is spoiled by another point's disc: a
    point of another branch, or of the same branch farther along it than the two radii (a loop
    crossing itself), whose projected disc, widened by ``overlap_margin_px``, crosses the line the
    point's run is read along (the normal through the point) within the point's projected radius
    of it. A disc beside that line, ahead or behind along the projected centreline, leaves the run
    as it is; a vessel crossing the line at a slant covers it for its width over the sine of the
    angle, which its discs along it (0.5 mm apart, the margin covering the gaps) give. With
    ``image_path``, a point of the same branch counts only where the path between the two in the
    image is also longer than the two discs reach (a foreshortened straight stretch's points lie
    near each other in the image, and so does the path between them). The fit keeps the arc rule
    alone (before the line rule, the image path put the junction of a side branch leaving at 35
    degrees, tests/test_tree_build.py, 2.1 mm off instead of 0.2).
    (The line rule since 2026-12-03. Before it every disc within the two radii plus the margin
    counted, whichever side it lay on: on the authors' 48 studies two thirds of the tree method's
    points and views counted as overlapped, and a third of the points was fitted to no view.)"""
    views, n = sections.found.shape
    owner = np.repeat(np.arange(len(arrays.counts)), arrays.counts)
    arc = np.empty(n)
    for b in range(len(arrays.counts)):
        p = arrays.points[arrays.span(b)]
        arc[arrays.span(b)] = arc_length_mm(p)
    radius = arrays.radius
    margin = settings.overlap_margin_px
    out = np.zeros((views, n), dtype=bool)
    left, right = np.zeros((views, n), dtype=bool), np.zeros((views, n), dtype=bool)
    compiled = kernels()
    for k in range(views):
        rho = radius * sections.px_per_mm[k]
        image_arc = np.zeros(n)
        if image_path:  # the path between two points of a branch in the image (the loop rule below)
            step = np.linalg.norm(np.diff(sections.uv[k], axis=0), axis=1)
            step[arrays.starts[1:] - 1] = 0.0  # no step from one branch's last point to the next one's first
            image_arc = np.concatenate([[0.0], np.cumsum(step)])
        if compiled is not None:  # the same pairs, rules and arithmetic, pair by pair (see spoiled_runs)
            compiled.spoiled_runs(np.ascontiguousarray(sections.uv[k]), np.ascontiguousarray(rho),
                                  np.ascontiguousarray(sections.normal_px[k]), arc, np.ascontiguousarray(radius),
                                  owner.astype(np.int64), image_arc, float(margin), float(settings.overlap_margin_mm),
                                  bool(image_path), bool(sides), out[k], left[k], right[k])
            continue
        pairs = cKDTree(sections.uv[k]).query_pairs(2.0 * float(rho.max()) + margin, output_type="ndarray")
        if len(pairs) == 0:
            continue
        i, j = pairs[:, 0], pairs[:, 1]
        # a disc that reaches a run's line within the point's radius lies within the two radii plus
        # the margin of it: the pairs farther apart are none of the rules' business
        du, dv = np.take(sections.uv[k, :, 0], j) - np.take(sections.uv[k, :, 0], i), \
            np.take(sections.uv[k, :, 1], j) - np.take(sections.uv[k, :, 1], i)
        near = np.flatnonzero(du * du + dv * dv < (np.take(rho, i) + np.take(rho, j) + margin) ** 2)
        i, j, du, dv = i[near], j[near], du[near], dv[near]
        loop = np.abs(arc[i] - arc[j]) > radius[i] + radius[j] + settings.overlap_margin_mm
        if image_path:
            # along one branch: a loop crossing itself, where the image path between the two points
            # is longer than their discs reach (a straight, foreshortened stretch's points are near
            # in the image but so is the path between them)
            loop &= np.abs(image_arc[i] - image_arc[j]) > rho[i] + rho[j] + margin
        hit = (owner[i] != owner[j]) | loop
        i, j, du, dv = i[hit], j[hit], du[hit], dv[hit]
        for a, b, sign in ((i, j, 1.0), (j, i, -1.0)):  # a's run, b's disc
            nu, nv = np.take(sections.normal_px[k, :, 0], a), np.take(sections.normal_px[k, :, 1], a)
            across, along = sign * (nu * du + nv * dv), np.abs(nu * dv - nv * du)
            reach = np.take(rho, b) + margin
            chord = np.sqrt(np.maximum(reach * reach - along * along, 0.0))
            rho_a = np.take(rho, a)
            hit = (along < reach) & (np.abs(across) - chord < rho_a)
            out[k, a[hit]] = True
            if sides:  # the disc reaches past the run's edge on that side
                left[k, a[hit & (across - chord < -rho_a)]] = True
                right[k, a[hit & (across + chord > rho_a)]] = True
    return (out, left, right) if sides else out


def _seen(sections: _Sections, arrays: "_Arrays", settings: TreeSettings, *, image_path: bool = False,
          sides: bool = False):
    """(V, N) bool: the view measures the point's cross-section (a run found, no overlap, not too
    foreshortened; module notes, step 3); with ``sides`` also :func:`_overlaps`' two (V, N) bool of
    the runs spoiled past their left and right edges."""
    spoiled = _overlaps(sections, arrays, settings, image_path=image_path, sides=sides)
    seen = sections.found & ~(spoiled[0] if sides else spoiled) & (sections.foreshortening >= settings.min_foreshortening)
    return (seen, *spoiled[1:]) if sides else seen


def _combine_radius(sections: _Sections, seen: np.ndarray, previous: np.ndarray,
                    foreshortening_tolerance: float = np.inf) -> np.ndarray:
    radius_views = 0.5 * sections.width_px / sections.px_per_mm  # (V, N), nan where not found
    # the views that foreshorten the vessel least: a cross-section seen at a slant projects as an
    # ellipse that reaches along the vessel, and the silhouette of a narrowing takes the width of
    # the wider cross-sections beside it
    least = np.where(seen, sections.foreshortening, -np.inf).max(axis=0)
    seen = seen & (sections.foreshortening >= least[None, :] - foreshortening_tolerance)
    seen_radius = np.where(seen, radius_views, np.nan)
    count = seen.sum(axis=0)
    with np.errstate(all="ignore"):
        median = np.nanmedian(np.where(count[None, :] > 0, seen_radius, 0.0), axis=0)
        smallest = np.nanmin(np.where(sections.found, radius_views, np.inf), axis=0)
    out = np.where(count > 0, median, np.where(np.isfinite(smallest), smallest, previous))
    return np.maximum(out, _MIN_RADIUS_MM)


def _centre_targets(sections: _Sections, radius: np.ndarray, seen: np.ndarray, spoiled_left: np.ndarray,
                    spoiled_right: np.ndarray, settings: TreeSettings,
                    bound_unmeasured: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Where the axis projects, along each view's normal, and in which views that is known: (V, N)
    offsets and bool. The middle of the run where the view sees the point, or where both of the
    run's edges are the vessel's own (another vessel crosses it within its silhouette); one edge
    plus the projected radius towards the other where only that edge is the vessel's own (the
    other side merges with another vessel or runs past the reach). With ``bound_unmeasured``, a
    view that knows neither (both edges another vessel's, or the vessel foreshortened) but found
    the run still bounds the point: where its projected disc reaches past an edge of the run, the
    axis is moved back to one radius inside that edge (to the run's middle where the run is
    narrower than the disc); where the disc lies inside, the view says nothing (module notes, step 8)."""
    left, right = sections.edges_px[..., 0], sections.edges_px[..., 1]
    clear = sections.foreshortening >= settings.min_foreshortening
    clean_left = clear & np.isfinite(left) & ~spoiled_left
    clean_right = clear & np.isfinite(right) & ~spoiled_right
    middle = seen | (clean_left & clean_right)
    rho = radius[None, :] * sections.px_per_mm
    offset = np.where(middle, sections.offset_px,
                      np.where(clean_left, left + rho, np.where(clean_right, right - rho, 0.0)))
    known = middle | clean_left | clean_right
    if bound_unmeasured:
        bounded = sections.found & ~known & np.isfinite(left) & np.isfinite(right)
        inner_left, inner_right = left + rho, right - rho
        with np.errstate(invalid="ignore"):
            inside = np.where(inner_left > inner_right, 0.5 * (left + right), np.clip(0.0, inner_left, inner_right))
        bounded &= inside != 0.0  # the disc reaches past an edge
        offset = np.where(bounded, inside, offset)
        known = known | bounded
    return offset, known


def _centre_step(sections: _Sections, offset: np.ndarray, known: np.ndarray, tangents: np.ndarray,
                 radius: np.ndarray) -> np.ndarray:
    """Least-squares move of every point onto its axis offsets in the views that know them (tangent
    held), at most one radius."""
    g = sections.gradient  # (V, N, 3)
    weight = known.astype(np.float64)
    c = np.where(known, offset, 0.0)
    normal = np.einsum("vn,vni,vnj->nij", weight, g, g)
    rhs = np.einsum("vn,vni,vn->ni", weight, g, c)
    scale = np.einsum("vn,vni,vni->n", np.ones_like(weight), g, g) / max(1, g.shape[0])
    normal += (scale[:, None, None] * tangents[:, :, None] * tangents[:, None, :]
               + 1e-3 * scale[:, None, None] * np.eye(3)[None])
    unknown = known.sum(axis=0) == 0
    normal[unknown] = np.eye(3)  # (no view knows them: they stay, and a point without a tangent solves too)
    step = np.linalg.solve(normal, rhs[..., None])[..., 0]
    step[unknown] = 0.0
    length = np.linalg.norm(step, axis=1)
    too_far = length > radius
    step[too_far] *= (radius[too_far] / length[too_far])[:, None]
    return step


def _fold_stretches(arrays: _Arrays, held: np.ndarray, max_bend_deg: float) -> np.ndarray:
    """(N,) bool: the points where their branch folds (:meth:`_Arrays.bends_deg` above
    ``max_bend_deg``) and the held points next to them (each run of folded or held points along a
    branch that holds a folded one)."""
    fold = arrays.bends_deg() > max_bend_deg
    out = np.zeros(len(fold), dtype=bool)
    if not fold.any():
        return out
    for b in range(len(arrays.counts)):
        s = arrays.span(b)
        runs, count = ndi.label(held[s] | fold[s])
        if count:
            out[s] = np.isin(runs, runs[fold[s]])
    return out


def _interpolate_held(arrays: _Arrays, held: np.ndarray) -> None:
    """Radii of held points (no view sees them) interpolated along their branch from the others."""
    for b in range(len(arrays.counts)):
        s = arrays.span(b)
        hold = held[s]
        if not hold.any() or hold.all():
            continue
        p = arrays.points[s]
        arc = arc_length_mm(p)
        r = arrays.radius[s]
        r[hold] = np.interp(arc[hold], arc[~hold], r[~hold])
        arrays.radius[s] = r


def _smooth_radii(arrays: _Arrays, sigma_mm: float, step_mm: float) -> None:
    if sigma_mm <= 0:
        return
    for b in range(len(arrays.counts)):
        s = arrays.span(b)
        if arrays.counts[b] >= 3:
            arrays.radius[s] = ndi.gaussian_filter1d(arrays.radius[s], sigma_mm / step_mm, mode="nearest")


# -- ends -----------------------------------------------------------------------------------------
def _inside_all(points: np.ndarray, projections: Sequence[Projection], images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(inside, outside)``, (N,) bool each: every view shows the point on its mask; some view
    whose image holds the point's projection shows it off its mask (a view the point projects out
    of shows neither: the vessel may run on past the image's edge)."""
    inside, outside = np.ones(len(points), dtype=bool), np.zeros(len(points), dtype=bool)
    for projection, image in zip(projections, images):
        uv = projection.project(points)
        on_mask = ndi.map_coordinates(image, [uv[:, 1], uv[:, 0]], order=1, mode="constant", cval=0.0) >= 0.5
        rows, columns = image.shape
        in_image = (uv[:, 0] >= -0.5) & (uv[:, 0] <= columns - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= rows - 0.5)
        inside &= on_mask
        outside |= in_image & ~on_mask
    return inside, outside


def _tip_move(end: np.ndarray, outward: np.ndarray, radius: float, projections, images, reach_mm: float,
              step_mm: float) -> float:
    """How far (mm, + outward) the tip at ``end`` moves: out while its cap lies on every mask, or
    back to the nearest cap no view shows off its mask (a cap past an image's edge stays)."""
    offsets = np.arange(-reach_mm, reach_mm + 1e-9, step_mm)
    caps = end[None, :] + (offsets[:, None] + radius) * outward[None, :]
    inside, outside = _inside_all(caps, projections, images)
    zero = int(np.argmin(np.abs(offsets)))
    if inside[zero]:
        # outward while every cap on the way is inside
        run = zero
        while run + 1 < len(offsets) and inside[run + 1]:
            run += 1
        return float(offsets[run])
    if not outside[zero]:
        return 0.0  # past an image's edge and on the other masks: nothing says where the vessel ends
    # cut back to the nearest cap no view shows off its mask
    back = np.flatnonzero(~outside[:zero])
    return float(offsets[back[-1]]) if len(back) else 0.0


def _rooted_at_ostium(arrays: "_Arrays", settings: TreeSettings,
                      held: np.ndarray | None = None) -> tuple["_Arrays", float]:
    """The tree rooted at its ostium (module notes, step 4), and how far the root moved (mm).
    ``held``: (points,) bool, the points no view sees (their radii interpolated along the
    branch); None: every point is seen."""
    window = max(2, int(round(settings.ostium_window_mm / settings.point_step_mm)))
    child_points = arrays.child_points()
    onward_from_end: list[list[int]] = [[] for _ in range(len(arrays.counts))]  # children leaving a branch's last point
    for c in range(1, len(arrays.counts)):
        if arrays.parent_points[c] == arrays.counts[arrays.parents[c]] - 1:
            onward_from_end[arrays.parents[c]].append(c)
    tips: list[tuple[float, int]] = []  # (mean radius over the window from the tip, flat index)
    unseen: list[bool] = []  # per tip: no view sees any point of its reach (two windows from it)
    inner, inner_radius = 0, -np.inf
    for b in range(len(arrays.counts)):
        r = arrays.radius[arrays.span(b)]
        start = int(arrays.starts[b])
        mean = ndi.uniform_filter1d(r, size=min(window, len(r)), mode="nearest")
        if b == 0:
            root_mean = mean
        # not where branches meet: their cross-sections merge there and the radii swell
        arc = arc_length_mm(arrays.points[arrays.span(b)])
        junctions = [arc[p] for p in child_points[b]]
        if b > 0:
            junctions.append(0.0)
        clear = np.ones(len(r), dtype=bool)
        for at in junctions:
            clear &= np.abs(arc - at) > settings.ostium_junction_mm
        # a tip's radius: the widest mean over the window within two windows of it, where no
        # branches meet, else the mean one window from it (its first window alone is the end
        # cap's, narrower than the vessel: a root that started at the ostium was moved to a wider
        # point inside, 10-20 mm away). A branch end where only narrower children run on (by
        # ostium_inner_ratio) and that a view sees is a tip too: the wide vessel ends there (the
        # stub to the ostium went as a spur, and the skeleton ran on into the conus branch)
        last = len(r) - 1
        onward = onward_from_end[b]
        ends = [(0, slice(0, 2 * window))] if b == 0 else []
        if b > 0 or last > 0:  # (a root of one point is its start: always a tip)
            ends.append((last, slice(max(len(r) - 2 * window, 0), len(r))))
        for at, near in ends:
            centres = np.arange(len(r))[near]
            inside = centres[(np.abs(centres - at) >= window // 2) & clear[near]]
            past_cap = min(window, len(r) - 1) if at == 0 else max(len(r) - 1 - window, 0)
            radius = float(mean[inside].max()) if len(inside) else float(mean[past_cap])
            tip_unseen = held is not None and bool(held[arrays.span(b)][near].all())
            if at == last and onward:
                widest_onward = max(float(arrays.radius[arrays.span(c)][:window].mean()) for c in onward)
                if tip_unseen or radius < settings.ostium_inner_ratio * widest_onward:
                    continue
            if tip_unseen and b != 0 and arc[-1] <= settings.ostium_junction_mm:
                radius = -np.inf  # a stub by a junction that no view sees: its radii are the junction's
            tips.append((radius, start + at))
            unseen.append(tip_unseen)
        if clear.any():
            k = int(np.flatnonzero(clear)[np.argmax(mean[clear])])
            if mean[k] > inner_radius:
                inner, inner_radius = start + k, float(mean[k])
    start_radius = tips[0][0]  # the root's start (its entry comes first)
    if any(unseen) and not all(unseen):
        # an unseen tip's radius is the one interpolated from the nearest seen point inside: of the
        # tips within ostium_inner_ratio of the widest, a seen one goes first (a phantom stub at the
        # left main's split carried the left main's radius and held the root 10-14 mm from the ostium)
        widest = max(radius for radius, _ in tips)
        seen_best, tip_radius, best = max((not u, radius, at) for u, (radius, at) in zip(unseen, tips)
                                          if radius * settings.ostium_inner_ratio >= widest)
        start_seen = not unseen[0]
    else:
        tip_radius, best = max(tips)
        start_seen = seen_best = True
    if best != 0 and tip_radius <= start_radius and (start_seen or not seen_best):
        tip_radius, best = start_radius, 0  # as wide as where the root starts (a stub held at one radius): it stays
    reach = min([2 * window, len(root_mean)] + child_points[0])
    if best == 0 and reach > window // 2:
        # against a point inside, the root's start counts as wide as it gets within its two
        # windows, up to its first junction: where the end cap's excess and the reach of a junction
        # overlap, the stretch clear of both is too short to leave the cap (a root that started at
        # the ostium went 13-47 mm inside)
        tip_radius = max(tip_radius, float(root_mean[window // 2:reach].max()))
    if inner_radius > settings.ostium_inner_ratio * tip_radius:
        best = inner  # the stub to the ostium went as a spur: the ostium is inside a branch
    distance = float(np.linalg.norm(arrays.points[best] - arrays.points[0]))
    if distance <= settings.reroot_mm:
        return arrays, 0.0
    branch = int(np.searchsorted(arrays.starts, best, side="right") - 1)
    tree = arrays.tree()
    point = int(np.argmin(np.linalg.norm(tree.branches[branch].points_mm - arrays.points[best], axis=1)))
    tree = rerooted(tree, branch, point, window_mm=settings.skeleton.direction_window_mm)
    return _Arrays.of(tree), distance


def _fitted_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares line through ``points``: ``(centroid, unit direction from the first point
    towards the last)``."""
    centre = points.mean(axis=0)
    axis = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    return centre, (-axis if axis @ (points[-1] - points[0]) < 0 else axis)


def _clear_direction(child: np.ndarray, first: int) -> np.ndarray:
    """The child's unit direction at its first clear point: the chord to the point 3 points on."""
    direction = child[min(first + 3, len(child) - 1)] - child[first]
    return direction / max(float(np.linalg.norm(direction)), 1e-12)


def _joining_curve(junction: np.ndarray, child: np.ndarray, first: int, step_mm: float) -> np.ndarray:
    """The child's start from ``junction`` on its parent to its first clear point ``child[first]``:
    the cubic Hermite curve leaving along the chord and arriving along the child's direction there
    (over the next 3 points), points at most ``step_mm`` apart, both ends included."""
    end = child[first]
    direction = _clear_direction(child, first)
    chord = end - junction
    length = float(np.linalg.norm(chord))
    s = np.linspace(0.0, 1.0, max(2, int(np.ceil(length / step_mm)) + 1))[:, None]
    return ((2 * s ** 3 - 3 * s ** 2 + 1) * junction + (s ** 3 - 2 * s ** 2 + s) * chord
            + (-2 * s ** 3 + 3 * s ** 2) * end + (s ** 3 - s ** 2) * (length * direction))


def _joining_curves(junctions: np.ndarray, child: np.ndarray, first: int, step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_joining_curve` from each of ``junctions`` (J, 3) at once: the curves' points one
    after the other ((M, 3)) and the index of the junction each belongs to ((M,)). The same
    arithmetic on the same values, element by element (the parameters are those of
    :func:`numpy.linspace`: ``k * (1 / (n - 1))``, the last 1), so the points are those of the
    curves built one by one, bit for bit."""
    end = child[first]
    direction = _clear_direction(child, first)
    chords = end - junctions
    lengths = np.array([float(np.linalg.norm(chord)) for chord in chords])  # as _joining_curve's (one dot each)
    counts = np.array([max(2, int(np.ceil(length / step_mm)) + 1) for length in lengths])
    owner = np.repeat(np.arange(len(junctions)), counts)
    first_of = np.cumsum(counts) - counts
    k = (np.arange(len(owner)) - first_of[owner]).astype(np.float64)
    s = k * (1.0 / (counts - 1))[owner]
    s[first_of + counts - 1] = 1.0
    s = s[:, None]
    curves = ((2 * s ** 3 - 3 * s ** 2 + 1) * junctions[owner] + (s ** 3 - 2 * s ** 2 + s) * chords[owner]
              + (-2 * s ** 3 + 3 * s ** 2) * end + (s ** 3 - s ** 2) * (lengths[:, None] * direction)[owner])
    return curves, owner


def _disc_hits(pixels: np.ndarray, centres_px: np.ndarray, radii_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (pixel, disc) index pairs where a pixel of ``pixels`` (N, 2) lies in a disc."""
    if len(centres_px) == 0 or len(pixels) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    pairs = cKDTree(pixels).sparse_distance_matrix(cKDTree(centres_px), float(radii_px.max()), output_type="ndarray")
    inside = pairs["v"] <= radii_px[pairs["j"]]
    return pairs["i"][inside].astype(np.intp), pairs["j"][inside].astype(np.intp)


def _wrong_pixels(image: np.ndarray, lo: np.ndarray, hi: np.ndarray, stride: int, uv: np.ndarray,
                  radius_px: np.ndarray, owner: np.ndarray, n_candidates: int, others_uv: np.ndarray,
                  others_px: np.ndarray) -> np.ndarray:
    """Per candidate, the pixels of the grid ``lo + stride * k`` below ``hi`` ((u, v) each) that
    some candidate's tube covers and where the candidate's tube with the rest of the tree disagrees
    with ``image`` (>= 0.5 inside): (n_candidates,) int. The tubes are discs (centres ``uv``,
    radii ``radius_px``, candidate ``owner``), the rest of the tree the discs ``others_uv``,
    ``others_px``; a pixel lies in a disc where :func:`_disc_hits` says so. The compiled kernel
    visits each disc's box of grid pixels with the same distance test; the NumPy code pairs the
    pixels with the discs by k-d trees."""
    compiled = kernels()
    if compiled is not None:
        return compiled.tube_wrong_pixels(image, int(lo[0]), int(lo[1]), len(range(lo[0], hi[0], stride)),
                                          len(range(lo[1], hi[1], stride)), int(stride), uv, radius_px,
                                          owner.astype(np.int64), int(n_candidates), others_uv, others_px)
    v, u = np.mgrid[lo[1]:hi[1]:stride, lo[0]:hi[0]:stride]
    pixels = np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)
    # only the pixels some candidate's tube covers can tell the candidates apart
    hit_pixel, hit_disc = _disc_hits(pixels, uv, radius_px)
    covers = np.zeros((len(pixels), n_candidates), dtype=bool)
    covers[hit_pixel, owner[hit_disc]] = True
    reach = covers.any(axis=1)
    pixels, covers = pixels[reach], covers[reach]
    inside = image[pixels[:, 1].astype(int), pixels[:, 0].astype(int)] >= 0.5
    rest = np.zeros(len(pixels), dtype=bool)
    rest[_disc_hits(pixels, others_uv, others_px)[0]] = True
    # a pixel the rest of the tree covers is covered whichever candidate joins
    return np.count_nonzero((covers | rest[:, None]) != inside[:, None], axis=0)


def _junction_on_silhouettes(parent: np.ndarray, parent_arc: np.ndarray, child: np.ndarray, child_radius_mm: float,
                             first: int, reference: int, others: tuple[np.ndarray, np.ndarray], silhouettes,
                             settings: TreeSettings) -> int:
    """The parent point (index; ``parent_arc``: the parent's arc lengths) to join the child to
    (module notes, step 5): of those within ``junction_silhouette_reach_mm`` of ``reference`` (the
    axis rule's junction, or the skeleton's) and behind the clear start, the one whose joining
    curve's tube (with the rest of the tree, the points ``others``: positions and radii) disagrees
    with the fewest mask pixels, summed over the views, unless no junction lowers that count by
    more than ``junction_silhouette_gain_px``; among those within ``junction_silhouette_tie_px`` of
    the fewest, the nearest to ``reference``."""
    projections, images = silhouettes
    candidates = np.flatnonzero((np.abs(parent_arc - parent_arc[reference]) <= settings.junction_silhouette_reach_mm)
                                & ((child[first] - parent) @ _clear_direction(child, first) > 0))
    candidates = np.union1d(candidates, [reference])
    if len(candidates) == 1:
        return reference
    # discs half a step apart, at most an eighth of a radius on a wide tube (the union's edge within
    # a hundredth of a radius of the tube's)
    spacing_mm = max(0.5 * settings.point_step_mm, 0.125 * child_radius_mm)
    flat, owner = _joining_curves(parent[candidates], child, first, spacing_mm)
    others_mm, others_radius_mm = others
    wrong = np.zeros(len(candidates))
    for projection, image in zip(projections, images):
        focal = max(projection.focal_lengths_px)
        uv = projection.project(flat)
        radius_px = child_radius_mm * focal / projection.depth_mm(flat)
        lo = np.maximum(np.floor(uv.min(axis=0) - radius_px.max() - 1.0).astype(int), 0)
        hi = np.minimum(np.ceil(uv.max(axis=0) + radius_px.max() + 1.0).astype(int) + 1, image.shape[::-1])
        if np.any(hi <= lo):
            continue
        # a wide tube (every second pixel from 12 px of radius, every third from 18, ...) or window is
        # read on every stride-th pixel (counts scaled back up)
        widest_px = float(radius_px.max())
        tube_stride = (int(widest_px // (0.5 * _JUNCTION_STRIDE_RADIUS_PX))
                       if widest_px >= _JUNCTION_STRIDE_RADIUS_PX else 1)
        stride = max(tube_stride, int(np.ceil(np.sqrt(np.prod(hi - lo) / _JUNCTION_MAX_PIXELS))))
        others_uv = projection.project(others_mm)
        others_px = others_radius_mm * focal / projection.depth_mm(others_mm)
        near = np.all((others_uv + others_px[:, None] >= lo - 1) & (others_uv - others_px[:, None] <= hi + 1), axis=1)
        wrong += stride * stride * _wrong_pixels(image, lo, hi, stride, uv, radius_px, owner, len(candidates),
                                                 others_uv[near], others_px[near])
    if wrong.min() >= wrong[np.flatnonzero(candidates == reference)[0]] - settings.junction_silhouette_gain_px:
        return reference
    ties = np.flatnonzero(wrong <= wrong.min() + settings.junction_silhouette_tie_px)
    return int(candidates[ties[np.argmin(np.abs(candidates[ties] - reference))]])


def _junction_on_axes(arrays: _Arrays, settings: TreeSettings,
                      silhouettes: tuple[Sequence[Projection], Sequence[np.ndarray]] | None = None
                      ) -> tuple[_Arrays, list[float]]:
    """Each child's start moved to where its own axis, extended back, meets its parent's, then
    along the parent to where the child's joining tube best matches the masks ``silhouettes``
    (projections, images; module notes, step 5). Returns the new arrays and, per child moved, how
    far its junction moved (mm)."""
    step = settings.point_step_mm
    n_branches = len(arrays.counts)
    points = [arrays.points[arrays.span(b)].copy() for b in range(n_branches)]
    radius = [arrays.radius[arrays.span(b)].copy() for b in range(n_branches)]
    parent_points = list(arrays.parent_points)
    fit = max(2, int(round(settings.junction_fit_mm / step)))
    min_sine = np.sin(np.radians(settings.junction_min_angle_deg))
    moved: list[float] = []
    for b in range(1, n_branches):  # parents come first: a parent is final before its children move
        p = arrays.parents[b]
        parent, parent_radius, child, child_radius = points[p], radius[p], points[b], radius[b]
        # the child's first point clear of the parent's tube: the axis distance exceeds both radii
        # and the margin (before it the two vessels merge in every view and the hull)
        # np.linalg.norm(child[:, None] - parent[None], axis=2), coordinate by coordinate: the same
        # squares added in the same order (x, y, then z), without the three-long strided reduction
        dx, dy, dz = (child[:, k, None] - parent[None, :, k] for k in range(3))
        gaps = np.sqrt((dx * dx + dy * dy) + dz * dz)
        nearest = np.argmin(gaps, axis=1)
        clear = gaps[np.arange(len(child)), nearest] > parent_radius[nearest] + child_radius + settings.junction_margin_mm
        if not clear.any():
            continue
        first = int(np.argmax(clear))
        piece = child[first:first + fit + 1]
        if len(piece) < 3:
            continue
        _, axis = _fitted_line(piece)
        # the parent's points behind the clear start, by their distance from the extended axis
        relative = parent - child[first]
        along = relative @ axis
        miss = np.linalg.norm(relative - along[:, None] * axis, axis=1)
        behind = np.flatnonzero(along <= 0)
        if len(behind) == 0:
            continue
        k = parent_points[b]
        j = int(behind[np.argmin(miss[behind])])
        tangent = parent[min(j + 1, len(parent) - 1)] - parent[max(j - 1, 0)]
        tangent_norm = float(np.linalg.norm(tangent))
        sine = float(np.linalg.norm(np.cross(axis, tangent / tangent_norm))) if tangent_norm > 0 else 0.0
        if sine < min_sine:
            continue  # the child runs along its parent and meets it nowhere in particular: kept as it is
        if (miss[j] > settings.junction_max_miss_radii * parent_radius[j]
                or float(np.linalg.norm(parent[j] - parent[k])) > settings.junction_max_move_mm):
            j = k  # the axis passes the parent by or meets it far away: the skeleton's junction
        if silhouettes is not None and settings.junction_silhouette_reach_mm > 0:
            # the candidates draw the child up to its clear start; the rest of the tree is drawn as it is,
            # but the parent near the junction at its median radius (where the two merge, its
            # cross-sections read both vessels)
            parent_arc = arc_length_mm(parent)
            near = np.abs(parent_arc - parent_arc[j]) <= (settings.junction_silhouette_reach_mm
                                                          + settings.junction_silhouette_parent_mm)
            parent_radius_seen = parent_radius.copy()
            parent_radius_seen[near] = np.median(parent_radius[near])
            rest_points = np.concatenate([points[c] for c in range(n_branches) if c not in (b, p)] + [parent, child[first:]])
            rest_radius = np.concatenate([radius[c] for c in range(n_branches) if c not in (b, p)]
                                         + [parent_radius_seen, child_radius[first:]])
            j = _junction_on_silhouettes(parent, parent_arc, child, float(child_radius[first]), first, j,
                                         (rest_points, rest_radius), silhouettes, settings)
        elif j == k:
            continue  # kept as the skeleton has it
        shift_mm = float(np.linalg.norm(parent[j] - parent[k]))
        start = _joining_curve(parent[j], child, first, step)[:-1]
        count = len(start)
        old = child
        points[b] = np.concatenate([start, child[first:]])
        radius[b] = np.concatenate([np.full(count, child_radius[first]), child_radius[first:]])
        parent_points[b] = j
        for c in range(b + 1, n_branches):  # grandchildren: the same place on the new polyline
            if arrays.parents[c] == b:
                parent_points[c] = int(np.argmin(np.linalg.norm(points[b] - old[parent_points[c]], axis=1)))
        moved.append(shift_mm)
    if not moved:
        return arrays, moved
    counts = np.array([len(x) for x in points])
    out = _Arrays(np.concatenate(points), np.concatenate(radius), np.cumsum(counts) - counts, counts,
                  list(arrays.parents), parent_points, list(arrays.names))
    for b in range(1, n_branches):
        out.points[out.starts[b]] = out.points[out.anchor(b)]
    return out, moved


def _straight_tips(arrays: _Arrays, settings: TreeSettings) -> int:
    """Each tip's last ``tip_straight_radii`` radii laid on the line of the ``junction_fit_mm`` of
    its branch before them (module notes, step 6), in place; returns how many tips were straightened."""
    children_at = arrays.child_points()
    fit = settings.junction_fit_mm
    count = 0
    for b in range(len(arrays.counts)):
        span = arrays.span(b)
        # the end of a branch no child leaves from, and the root's start: the end of a branch that
        # has children stays (where the branch goes on past its last child for a few mm, the line
        # of the 3 mm before its tip runs through the junction's swelling; straightening such ends
        # too tilted the daughters: on 60 QCA trees the distal angles' MAE went from 4.7 to 5.1
        # degrees)
        ends = [] if children_at[b] else [False]
        for at_start in ends + ([True] if b == 0 else []):
            points = arrays.points[span][::-1] if not at_start else arrays.points[span]
            radius = arrays.radius[span][::-1] if not at_start else arrays.radius[span]
            arc = arc_length_mm(points)
            # the vessel's radius: the largest within the stretch (an end cap's cross-sections narrow
            # to nothing towards the tip, and their median straightened a thick vessel's hook over a
            # third of it)
            tip_radius = float(np.max(radius[arc <= fit]))
            cap = settings.tip_straight_radii * tip_radius
            line = np.flatnonzero((arc >= cap) & (arc <= cap + fit))
            near = np.flatnonzero(arc < cap)
            if len(line) < 3 or len(near) == 0:
                continue
            if at_start and any(c <= near[-1] for c in children_at[b]):
                continue  # a child leaves from the stretch that would move: it stays as it is
            centre, away = _fitted_line(points[line])
            axis = -away  # towards the tip
            off = points[0] - centre
            if np.linalg.norm(off - (off @ axis) * axis) <= settings.tip_hook_radii * tip_radius:
                continue  # the tip lies on the line already (within the tolerance): no hook
            anchor = centre + ((points[line[0]] - centre) @ axis) * axis
            straight = anchor + (arc[line[0]] - arc[near])[:, None] * axis
            if at_start:
                arrays.points[int(arrays.starts[b]) + near] = straight
            else:
                arrays.points[int(arrays.starts[b] + arrays.counts[b]) - 1 - near] = straight
            count += 1
    return count


def _move_ends(arrays: _Arrays, projections, images, settings: TreeSettings) -> tuple[VesselTree, list[float]]:
    tree = arrays.tree()
    has_child_at = {(b.parent, b.parent_point) for b in tree.branches[1:]}
    branches = list(tree.branches)
    moved = []
    step = settings.point_step_mm
    for index, b in enumerate(branches):
        points, radius = b.points_mm, b.radius_mm
        ends = [("end", points[-1], points[-1] - points[max(0, len(points) - 1 - 4)], float(np.median(radius[-5:])))]
        if index == 0:
            ends.append(("start", points[0], points[0] - points[min(len(points) - 1, 4)], float(np.median(radius[:5]))))
        shift = 0
        for which, end, direction, r in ends:
            if which == "end" and (index, len(points) - 1) in has_child_at:
                continue
            norm = np.linalg.norm(direction)
            if norm == 0:
                continue
            outward = direction / norm
            move = _tip_move(end, outward, r, projections, images, settings.end_reach_radii * r, 0.1)
            moved.append(move)
            if which == "end":
                if move > 0:
                    extra = end + np.outer(np.arange(1, int(np.ceil(move / step)) + 1) * min(step, move), outward)
                    extra[-1] = end + move * outward
                    points = np.vstack([points, extra])
                    radius = np.concatenate([radius, np.full(len(extra), radius[-1])])
                elif move < 0:
                    arc = arc_length_mm(points)
                    target = arc[-1] + move
                    keep = arc <= target
                    children_points = [c.parent_point for c in branches if c.parent == index]
                    last_needed = max(children_points) if children_points else 0
                    keep[:last_needed + 1] = True
                    if keep.sum() >= 2:
                        last = int(np.flatnonzero(keep)[-1])
                        end_point, end_radius = point_at_arc(points, arc, target), float(np.interp(target, arc, radius))
                        points, radius = points[keep], radius[keep]
                        if target - arc[last] > 1e-3:  # the new end where the cap left the masks, not the point before it
                            points, radius = np.vstack([points, end_point]), np.append(radius, end_radius)
            else:  # the root's start: prepend, or cut back to before its first child
                if move > 0:
                    count = int(np.ceil(move / step))
                    extra = end + np.outer(np.arange(count, 0, -1) * (move / count), outward)
                    points = np.vstack([extra, points])
                    radius = np.concatenate([np.full(count, radius[0]), radius])
                    shift = count
                elif move < 0:
                    arc = arc_length_mm(points)
                    children_points = [c.parent_point for c in branches if c.parent == index]
                    cut = min(int(np.searchsorted(arc, -move, side="left")), min(children_points, default=len(points)),
                              len(points) - 2)
                    if cut > 0:
                        points, radius = points[cut:], radius[cut:]
                        shift = -cut
        branches[index] = Branch(points, radius, b.parent, b.parent_point, b.name)
        if shift:
            for j, c in enumerate(branches):
                if c.parent == index:
                    branches[j] = Branch(c.points_mm, c.radius_mm, c.parent, c.parent_point + shift, c.name)
    return VesselTree(tuple(branches)), moved


# -- the whole build -------------------------------------------------------------------------------
def _occupancy(points_mm: np.ndarray, lattice: Lattice, cell_mm: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The kept lattice cells as a bool volume (cropped, 2 empty cells around), pooled by the largest
    whole factor f that keeps cells at most ``cell_mm`` (a cell is kept when any of its f**3 lattice
    cells is): ``(volume, centre of voxel 0 in mm, voxel edge in mm)``."""
    h = lattice.spacing_mm
    factor = max(1, int(np.floor(cell_mm / h)))
    ijk = np.round((points_mm + lattice.half_edge_mm) / h).astype(np.int64) // factor
    low = ijk.min(axis=0) - 2
    local = ijk - low
    volume = np.zeros(tuple(local.max(axis=0) + 3), dtype=bool)
    volume[tuple(local.T)] = True
    spacing = factor * h
    return volume, low * spacing + 0.5 * (factor - 1) * h - lattice.half_edge_mm, spacing


def checked_occupancy(points_mm: np.ndarray, lattice: Lattice, settings: TreeSettings = TREE_SETTINGS
                      ) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`_occupancy` of ``points_mm`` in cells of at most ``settings.max_cell_mm``; raises
    ReconstructionError where they fill more than ``settings.max_voxels`` cells (no vessel tree does:
    a mask that is not a vessel mask, or views that do not agree at all)."""
    volume, origin, spacing = _occupancy(np.asarray(points_mm, dtype=np.float64), lattice, settings.max_cell_mm)
    occupied = int(np.count_nonzero(volume))
    if occupied > settings.max_voxels:
        raise ReconstructionError(f"the hull fills {occupied:,} cells of {spacing:.2f} mm, more than a vessel tree's "
                                  f"{settings.max_voxels:,}; are the masks vessel masks?")
    return volume, origin, spacing


class SupportBridge:
    """Shortest paths through a support hull, for :func:`~angiohull.tree.skeleton.tree_from_skeleton`:
    through its cells, or, where they hold no path (the carving, too, has gaps of a cell or two in
    thin vessels), through its cells grown by one; where neither does and ``views`` (projections,
    masks) holds three views or more, the straight chord of :meth:`_chord`. The graph of the whole
    hull is built once (and that of the grown hull when first needed) and serves every part; each
    search stops at its reach. Most gaps are short: a search first reaches a little past the straight gap between the
    part and the tree, then twice as far while no target lies that close, up to the whole reach."""

    def __init__(self, support_mm: np.ndarray, lattice: Lattice, limit_mm: float,
                 views: tuple[Sequence[Projection], Sequence[np.ndarray]] | None = None):
        self._limit = limit_mm
        self._support, self._lattice = support_mm, lattice
        self._occupied: np.ndarray | None = None
        self._graphs: dict[bool, tuple] = {}
        # the chord rule (three views or more): the views and, per view, where a point lies near enough its mask
        self._views = views if views is not None and len(views[0]) >= 3 else None
        self._near: list[np.ndarray] | None = None

    def _graph(self, grown: bool) -> tuple:
        """(index volume, cell centres in mm, sparse graph) of the hull's cells, grown by one or
        not; the index volume holds 1 + the cell's index (0: no cell), in C order."""
        import scipy.sparse as sparse

        if grown not in self._graphs:
            box = self._occupied
            voxels = coordinates(dilated(box, 1) if grown else box)
            index = np.zeros(box.shape, dtype=np.int32)  # untouched pages are never allocated
            index[tuple(voxels.T)] = np.arange(1, len(voxels) + 1, dtype=np.int32)
            heads, tails, lengths = neighbour_edges(voxels, box.shape)
            # both directions stored: a directed search needs no transpose per call; lengths in
            # cells, not mm: a lattice holds many shortest paths of one length, and in mm the last
            # bit of the cell edge (which can differ between machines) chose among them
            graph = sparse.coo_matrix((np.concatenate([lengths] * 2),
                                       (np.concatenate([heads, tails]), np.concatenate([tails, heads]))),
                                      shape=(len(voxels), len(voxels))).tocsr()
            self._graphs[grown] = (index, self._origin + self._h * voxels, graph)
        return self._graphs[grown]

    def _lookup(self, index: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
        local = np.round((points_mm - self._origin) / self._h).astype(np.int64)
        ok = np.all((local >= 0) & (local < np.array(index.shape)), axis=1)
        found = np.full(len(points_mm), -1, dtype=np.int64)
        found[ok] = index[tuple(local[ok].T)].astype(np.int64) - 1
        found = np.unique(found)
        return found[found >= 0]

    def __call__(self, part_mm: np.ndarray, tree_mm: np.ndarray) -> np.ndarray | None:
        from scipy.sparse.csgraph import dijkstra

        if self._occupied is None:  # the first use: most trees need no bridge
            self._occupied, self._origin, self._h = _occupancy(self._support, self._lattice, self._lattice.spacing_mm)
        for grown in (False, True):
            index, points, graph = self._graph(grown)
            sources, targets = self._lookup(index, part_mm), self._lookup(index, tree_mm)
            if len(sources) == 0 or len(targets) == 0:
                continue
            # most gaps are short: the search reaches a little past the straight gap first (no path
            # is shorter than it; the nearest target within reach is the nearest of all), and twice
            # as far each time no target lies that close, up to the whole reach
            gap = float(cKDTree(points[targets]).query(points[sources])[0].min())
            for limit in _widening_limits(1.5 * gap + 2.0 * self._h, self._limit):
                distance, predecessors, _ = dijkstra(graph, directed=True, indices=sources, min_only=True,
                                                     limit=limit / self._h, return_predecessors=True)
                best = targets[np.argmin(distance[targets])]
                if np.isfinite(distance[best]):
                    path = [int(best)]
                    while predecessors[path[-1]] >= 0:
                        path.append(int(predecessors[path[-1]]))
                    return points[path[::-1]]
        return self._chord(part_mm, tree_mm) if self._views is not None else None

    def _chord(self, part_mm: np.ndarray, tree_mm: np.ndarray) -> np.ndarray | None:
        """A straight join across a gap the support hull does not cross: the shortest of the chords
        from a part's point to its nearest tree point (of the part's :data:`_CHORD_CANDIDATES`
        points nearest the tree), at most the reach long, every point of which (every
        :data:`_CHORD_STEP_MM`) projects near the mask of every view but one: within a lattice
        cell's projection (its half-diagonal plus half a pixel, the refined preset's axis reach)
        of a vessel pixel. A vessel that one view's mask breaks (a severe stenosis, a faint
        stretch) leaves no hull across the break, while the others still show it; a chord to
        another vessel crosses background in two views or more."""
        projections, masks = self._views
        if self._near is None:
            self._near = [ndi.distance_transform_edt(~(np.asarray(m) > 0.5)) for m in masks]
        distance, nearest = cKDTree(tree_mm).query(part_mm, distance_upper_bound=self._limit)
        order = np.argsort(distance, kind="stable")[:_CHORD_CANDIDATES]
        for i in order[np.isfinite(distance[order])]:
            start, end = part_mm[i], tree_mm[nearest[i]]
            steps = max(int(np.ceil(float(distance[i]) / _CHORD_STEP_MM)), 2)
            chord = start + np.linspace(0.0, 1.0, steps + 1)[:, None] * (end - start)
            views_near = np.zeros(len(chord), dtype=np.int64)
            for projection, near in zip(projections, self._near):
                uv, px_per_mm = projected_with_scale(projection, chord)
                reach_px = cell_reach_px(self._lattice.spacing_mm, px_per_mm)
                cols, rows = np.floor(uv[:, 0] + 0.5).astype(np.int64), np.floor(uv[:, 1] + 0.5).astype(np.int64)
                inside = (rows >= 0) & (rows < near.shape[0]) & (cols >= 0) & (cols < near.shape[1])
                gap_px = np.full(len(chord), np.inf)
                gap_px[inside] = near[rows[inside], cols[inside]]
                views_near += gap_px <= reach_px
            if np.all(views_near >= len(projections) - 1):
                return chord
        return None


_CHORD_CANDIDATES = 40  # SupportBridge._chord tries the chords of this many of a part's points, the shortest first
_CHORD_STEP_MM = 0.1  # ... each checked every this much


def _widening_limits(first: float, last: float) -> list[float]:
    """Search limits from ``first``, doubling, to ``last`` (which ends the list)."""
    limits = []
    while first < last:
        limits.append(first)
        first *= 2.0
    return limits + [last]


def _skeleton_input(volume: np.ndarray, bridge: int
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """The volume the centerline paths run through (``volume`` dilated by ``bridge`` cells), its
    voxels' distance from the boundary in voxels when it is cheap to give (None otherwise), the
    distance of every voxel of it to the nearest cell outside the undilated ``volume`` (0 for the
    cells the dilation added), all in ``np.argwhere`` order of the returned volume, and its voxels
    (``np.argwhere``)."""
    grown = dilated(volume, 1)
    shell = grown & ~volume  # the empty cells next to the volume
    paths = grown if bridge == 1 else dilated(volume, bridge) if bridge else volume
    voxels = coordinates(paths)
    # the nearest empty cell of a cell of the volume is one of the shell's (the volume has empty
    # cells around it); searched ring by ring around each cell, a fraction of a k-d tree's time
    # or a full 3D distance transform's of the box
    depth = distance_to(shell, voxels)
    dbf = depth + 1.0 if bridge == 1 else depth if bridge == 0 else None  # one dilation adds one cell
    return paths, dbf, depth, voxels


def hull_tree(points_mm: np.ndarray, lattice: Lattice, projections: Sequence[Projection], masks: Sequence[np.ndarray],
              *, support_points_mm: np.ndarray | None = None, support_bridge: SupportBridge | None = None,
              settings: TreeSettings = TREE_SETTINGS) -> tuple[VesselTree, TreeBuild]:
    """The vessel tree of carved lattice points (module notes).

    Parameters
    ----------
    points_mm : (N, 3) array
        Kept lattice points of ``lattice`` (any preset).
    lattice : Lattice
    projections, masks : sequences
        The views the points were carved with (masks as carved).
    support_points_mm : (S, 3) array, optional, keyword-only
        Lattice points of a wider hull that holds ``points_mm`` (the carving before the refined
        preset's steps): parts of the tree the narrower hull left apart are joined along the
        shortest path through it (at most ``max_bridge_mm``).
    support_bridge : SupportBridge, optional, keyword-only
        The same for several trees of one support hull: built once, it keeps the hull's graphs
        (instead of ``support_points_mm``; its reach is its own).
    settings : TreeSettings

    Returns
    -------
    tree : VesselTree
    build : TreeBuild

    Raises
    ------
    ReconstructionError
        If the points are too few for a skeleton with a branch.
    """
    timings: dict[str, float] = {}
    start = time.perf_counter()
    if len(points_mm) < 2:
        raise ReconstructionError(f"the hull has {len(points_mm)} point(s); a vessel tree needs a skeleton of two or more")
    volume, origin, spacing = checked_occupancy(points_mm, lattice, settings)
    paths, dbf, depth, voxels = _skeleton_input(volume, int(np.floor(settings.bridge_mm / spacing)))
    skeleton, _ = teasar_skeleton(paths, dbf=dbf, voxels=voxels)
    # the skeleton's voxels among the path volume's (both in C order): their distance to an empty cell
    radius_volume = depth[skeleton[paths]] * spacing
    images = [np.asarray(m, dtype=np.float32) for m in masks]
    bridge = support_bridge
    if bridge is None and support_points_mm is not None and len(support_points_mm):
        bridge = SupportBridge(np.asarray(support_points_mm, dtype=np.float64), lattice, settings.max_bridge_mm,
                               views=(projections, masks))

    try:
        raw, skeleton_info = tree_from_skeleton(skeleton, radius_volume, origin_mm=origin,
                                                spacing_mm=spacing, settings=settings.skeleton,
                                                bridge=bridge)
    except TreeError as exc:
        raise ReconstructionError(f"no vessel tree in the hull: {exc}") from None
    timings["skeleton"] = time.perf_counter() - start
    tree, build = _fitted(raw, projections, images, skeleton_info, timings, settings)
    if settings.fit_passes > 1 and len(projections) >= 3:  # with two views, one (module notes, step 8)
        tree, build = refit_tree(tree, projections, masks, build=build, passes=settings.fit_passes - 1,
                                 settings=settings)
    return tree, build


def refit_tree(tree: VesselTree, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
               build: TreeBuild | None = None, passes: int = 1,
               settings: TreeSettings = TREE_SETTINGS) -> tuple[VesselTree, TreeBuild]:
    """Fit a vessel tree to the views ``passes`` times more: steps 2-6 of the module notes with the
    tree as the skeleton (module notes, step 8).

    ``build``, the :class:`TreeBuild` that made ``tree`` (:func:`hull_tree`), is carried on: the
    one returned sums the removals and the times (the passes here under ``timings_s["refit"]``),
    keeps its skeleton, tip and junction moves, and describes the last pass's points
    (``seen_share``, ``unseen_points``, ``points_fitted``). Without it, the build is the passes'
    own.
    """
    images = [np.asarray(m, dtype=np.float32) for m in masks]
    for _ in range(passes):
        start = time.perf_counter()
        tree, last = _fitted(tree, projections, images, build.skeleton if build else SkeletonInfo(), {}, settings,
                             refit=True)
        if build is None:
            build = replace(last, timings_s={"refit": time.perf_counter() - start})
            continue
        timings = dict(build.timings_s)
        timings["refit"] = timings.get("refit", 0.0) + time.perf_counter() - start
        build = replace(build, points_fitted=last.points_fitted,
                        unseen_leaves_removed=build.unseen_leaves_removed + last.unseen_leaves_removed,
                        seen_share=last.seen_share, unseen_points=last.unseen_points,
                        rerooted_mm=build.rerooted_mm + last.rerooted_mm, timings_s=timings,
                        unseen_stub_points_removed=build.unseen_stub_points_removed + last.unseen_stub_points_removed,
                        fold_points_reread=last.fold_points_reread,
                        unseen_head_points_removed=build.unseen_head_points_removed + last.unseen_head_points_removed,
                        fit_passes=build.fit_passes + 1)
    return tree, build


def _fitted(raw: VesselTree, projections: Sequence[Projection], images: Sequence[np.ndarray],
            skeleton_info: SkeletonInfo, timings: dict[str, float], settings: TreeSettings,
            refit: bool = False) -> tuple[VesselTree, TreeBuild]:
    """Steps 2-6 of the module notes on a tree (the skeleton's, or with ``refit`` a fitted one:
    then the views that cannot measure a point bound it, ``settings.bound_unmeasured``)."""

    start = time.perf_counter()
    step = settings.point_step_mm
    arrays = _Arrays.of(raw.resampled(step))
    arrays.smooth(settings.smoothing_mm, step)
    held = np.zeros(len(arrays.points), dtype=bool)
    seen = np.zeros((len(projections), len(arrays.points)), dtype=bool)
    removed = stub_points = head_points = 0

    def measure(current: _Arrays) -> tuple[np.ndarray, _Sections]:
        tangents = current.tangents()
        return tangents, _sections(current.points, tangents, current.radius, projections, images,
                                   settings.profile_step_px)

    measured: tuple = (None,)
    for iteration in range(settings.iterations):
        arrays, _, _ = arrays.without_hairpins(settings.fold_bend_deg, settings.hairpin_reach_radii, step,
                                                  settings.hairpin_width_ratio)
        if iteration == settings.iterations - 1 and len(projections) >= 3:
            # the last fit without the branches no view sees; with two views a phantom and the true
            # branch it mirrors overlap each other in both, and nothing tells them apart
            # (a branch's own points hide each other only where the image path between them is longer
            # than their discs reach: a loop; see _overlaps). First the stubs, a branch's tail past
            # its last child, where the skeleton ran the branch on beside the vessel and made the
            # vessel's continuation the child: the child they hide is seen again once they go
            measured = arrays, *measure(arrays)
            visible = _seen(measured[2], arrays, settings, image_path=True)
            # and the root's head (no view sees the start of the skeleton's path: a phantom, or a
            # stub like the tails above), unless a child leaves beside it (the two prongs of a
            # fork at a vessel's end hide each other)
            arrays, head_points = arrays.without_unseen_head(visible, settings.max_unseen_share,
                                                              fork_deg=settings.head_fork_deg)
            visible = visible[:, head_points:]  # the head is the flat arrays' first points
            arrays, stub_points = arrays.without_unseen_stubs(visible, settings.max_unseen_share)
            if stub_points or head_points:
                measured = arrays, *measure(arrays)
                visible = _seen(measured[2], arrays, settings, image_path=True)
            arrays, removed = arrays.without_unseen_leaves(visible, settings.max_unseen_share)
        # the cross-sections of the removals serve the fit when nothing was removed
        tangents, sections = measured[1:] if measured[0] is arrays else measure(arrays)
        seen, spoiled_left, spoiled_right = _seen(sections, arrays, settings, sides=True)
        held = seen.sum(axis=0) == 0
        arrays.radius = _combine_radius(sections, seen, arrays.radius, settings.radius_foreshortening_tolerance)
        _interpolate_held(arrays, held)
        offset, known = _centre_targets(sections, arrays.radius, seen, spoiled_left, spoiled_right, settings,
                                        bound_unmeasured=refit and settings.bound_unmeasured)
        arrays.points = arrays.points + _centre_step(sections, offset, known, tangents, arrays.radius)
        for b in range(len(arrays.counts)):
            arrays.reattach(b)
        arrays.smooth(0.5 * settings.smoothing_mm, step)
    arrays, _, origin = arrays.without_hairpins(settings.fold_bend_deg, settings.hairpin_reach_radii, step,
                                                  settings.hairpin_width_ratio)
    held = np.where(origin >= 0, held[np.maximum(origin, 0)], False)  # a chord's points: as if seen
    arrays.smooth_quadratic(settings.final_window_mm, settings.final_smoothing_mm, step)
    _smooth_radii(arrays, settings.radius_smoothing_mm, step)
    # a fold's radii are read along the vessels: after the root step (whose choice of the ostium
    # still reads them; see the notes, step 4) they and the held points beside them are interpolated
    # from the points beyond, on the tree as rooted (points keep their places when it is rooted again)
    folded_mm = arrays.points[_fold_stretches(arrays, held, settings.fold_bend_deg)]
    arrays, rerooted_mm = _rooted_at_ostium(arrays, settings, held)
    if len(projections) >= 3:  # traced again on the fitted points (notes, step 4; with two views the skeleton's stand)
        arrays = _Arrays.of(rerooted(arrays.tree(), 0, 0, window_mm=settings.skeleton.direction_window_mm,
                                     narrower=False))
    reread = np.zeros(len(arrays.points), dtype=bool)
    if len(folded_mm):
        reread = cKDTree(folded_mm).query(arrays.points)[0] < 1e-6
        _interpolate_held(arrays, reread)
    arrays, junctions_moved = _junction_on_axes(arrays, settings, (projections, images))
    _straight_tips(arrays, settings)
    timings["fit"] = time.perf_counter() - start

    start = time.perf_counter()
    tree, moved = _move_ends(arrays, projections, images, settings)
    timings["ends"] = time.perf_counter() - start
    build = TreeBuild(skeleton=skeleton_info, points_fitted=len(arrays.points), unseen_leaves_removed=removed,
                      seen_share=tuple(float(x) for x in seen.mean(axis=1)), unseen_points=int(held.sum()),
                      tips_moved_mm=tuple(moved), rerooted_mm=rerooted_mm,
                      junctions_moved_mm=tuple(junctions_moved), timings_s=timings,
                      unseen_stub_points_removed=stub_points, fold_points_reread=int(reread.sum()),
                      unseen_head_points_removed=head_points)
    return tree, build
