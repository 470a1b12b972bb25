"""The ``refined`` preset: sharper hulls from what is known about vessels (beyond the paper).

The visual hull of three views is thicker than the vessel (a tube seen from three directions
carves to a polygon around its circular section, widened by the pixel threshold) and carries
phantom volume where the cones of different branches meet. :func:`refine_hull` removes both with
steps that stay interpretable:

1. **Masks** (:func:`clean_mask`): vessel pixels with fewer than 2 vessel neighbours (of 8) are
   dropped and background pixels with at least 5 are filled, before carving: isolated false
   positives go, pinholes close, and a vessel that lost pixels at random keeps the rest.
2. **Connectivity**: the tree is one structure; connected parts of the hull (26-neighbourhood on
   the lattice, after growing each part by ``bridge_cells`` lattice spacings, so that gaps of up
   to two missing lattice points are bridged) holding less than ``component_fraction`` of its
   points are dropped. A lattice cell projects to about 2 px at K = 256, more than the 1 px
   threshold, so a thin vessel, or one whose mask lost pixels, is sampled with gaps; without the
   bridge such a stretch counts as a separate part. A small part stays when, in some view, at
   least ``unique_fraction`` of its points project beyond a lattice cell's reach of every other
   part's point, onto the connected piece of the mask that the large parts project onto
   (:func:`_unexplained_parts`): a vessel that one view's mask breaks for a few millimetres (a
   severe stenosis, a faint stretch) leaves its part beyond the break apart in the hull, while the
   other views show it on the tree's own mask piece, where nothing else explains it (the
   explanation step's rule for pieces); a phantom projects onto other vessels' pixels in every
   view, and a speck carved from false-positive pixels onto blobs apart from the tree.
3. **Radius consistency**: *axis points* are the hull points whose projection lies on the 2D
   centreline (Guo–Hall thinning of the mask), within the projection of a lattice cell, in at
   least ``axis_views`` views (3; every view when there are fewer): they stand for the vessels' 3D
   centrelines. Two views fix a point and a third confirms it; with more views, a vessel is
   overlapped by another or seen end-on in some of them, where its 2D centreline runs elsewhere.
   Each gets a radius: in every view, the half-width of the mask at the 2D centreline pixel
   nearest to its projection, converted to mm at its depth; the smallest over the views (a vessel
   overlapping another in one view only looks wider there). A hull point is kept when its
   distance to the nearest axis point is at most that point's radius plus ``slack_cells`` lattice
   spacings. This trims the polygonal excess of the hull and the threshold's widening back to a
   tube. (A 3D skeleton of the hull would be the obvious axis, but scikit-image's 3D thinning can
   delete structures of even thickness entirely, scikit-image issue #3757.)
4. **Explanation** (before the radius check; :func:`drop_explained_pieces`): where the cones of
   branches that cross in projection meet, the hull keeps *phantom* pieces that project onto vessel
   pixels, even onto the 2D centreline, in every view, so they carry axis points of their own. What
   gives them away is that every one of their pixels is already explained by a real vessel: a
   phantom piece lies, in every view, on viewing rays that also cross a true vessel elsewhere,
   while a true vessel has at least one view in which it alone explains its pixels.

   - *Pieces*: the axis points are split into connected pieces (26-neighbourhood on the lattice)
     that project onto one and the same 2D centreline branch (the Guo–Hall centreline cut at its
     junction pixels) in every view. A phantom piece attached to a true vessel follows other 2D
     branches than the vessel does, so the split falls where it leaves the vessel, with no length
     or size parameter.
   - *Rivals*: in a view, an axis point has a rival when a hull point of another piece (within the
     radius check's tube around that piece's axis points) projects within the axis point's reach
     (the same tolerance that made it an axis point) and the straight segment between the two
     leaves the hull: they sit on one viewing ray, in different objects. Two points of the same
     vessel on one ray are joined through the vessel; this needs no distance threshold, so a vessel
     whose radius is underestimated (e.g. under false-negative pixels) does not rival itself.
   - *Greedy removal*: a piece's score is the largest, over the views, fraction of its axis points
     without a rival among the pieces still kept. The piece with the lowest score is dropped while
     that score is below ``unique_fraction`` (a half: most of the piece is explained by something
     else in every view), and the scores of the pieces it rivalled are updated. Dropping the most
     redundant piece first resolves a phantom and a true vessel that rival each other in one view:
     the true vessel has another view of its own.

   The radius check then uses the axis points of the kept pieces only, so the phantom's hull points,
   farther than a radius from any true axis point, go too.

**Image storage.** The same view can be stored flipped or transposed (with the equivalent matrix).
Thinning and the ties of a distance transform depend on the orientation of the pixel grid, so each
image is first brought into the orientation its geometry sets
(:func:`angiohull.geometry.canonical_storage`), and ties between equally near lattice points go to
the lowest lattice index: the refined points are the same whatever the storage (a property test).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import ndimage as ndi
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .. import options
from ..compiled import kernels
from ..geometry import Projection, canonical_storage
from ..thinning import guo_hall_thin as thin, pixel_box
from ..tree.voxels import dilated
from .cube import Lattice
from .nearest import nearest_with_ties

__all__ = ["RefineSettings", "REFINED", "clean_mask", "refine_hull", "tube_axis", "centreline_branches",
           "drop_explained_pieces"]


@dataclass(frozen=True)
class RefineSettings:
    """Parameters of the ``refined`` preset."""

    resolution: int = options.REFINED_RESOLUTION  # lattice points per axis (finer than the paper's 100: less thickening)
    # a salted mask (is_salted: many specks beside the vessels, few pinholes) loses its 8-connected pieces under
    # speck_px pixels before clean_mask; a clean mask's few small pieces and heavy pepper's fragments stay
    speck_px: int = 20
    salt_pieces_per_px: float = 0.005
    salt_min_pieces: int = 10
    pinhole_px: int = 9
    min_neighbours: int = 2  # clean_mask: a vessel pixel needs this many vessel neighbours (of 8)
    fill_neighbours: int = 5  # clean_mask: a background pixel with this many vessel neighbours is filled
    component_fraction: float = 0.05  # drop connected parts of the hull smaller than this fraction
    # connectivity: parts of the hull count as connected when, grown by this many lattice spacings,
    # they touch (1: gaps of up to two missing lattice points; 0: touching parts only)
    bridge_cells: int = 1
    slack_cells: float = 0.5  # tolerance of the radius check, in lattice spacings
    # an axis point lies on the 2D centreline in at least this many views (in every view when there
    # are fewer): every view, as first built, lost 4-11 Dice points with 4 and 6 views
    axis_views: int = 3
    # explanation step: an axis piece is dropped when, in every view, less than this fraction of its
    # axis points is free of rivals (hull points of other pieces on the same viewing ray, across a gap
    # in the hull): a half = "mostly explained by something else in every view". 0 turns it off.
    unique_fraction: float = 0.5


_EIGHT = np.ones((3, 3), dtype=bool)  # 8-neighbourhood in 2D

REFINED = RefineSettings()
"""The settings of ``preset="refined"`` (the same for every case; measured in docs/beyond-the-paper.md)."""


def _column_min(a: np.ndarray) -> np.ndarray:
    """``a.min(axis=0)`` of an (n, d) array, column by column (NumPy reduces a narrow array along
    its long axis several times slower)."""
    return np.array([a[:, k].min() for k in range(a.shape[1])])


def _column_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=0)``, column by column (see :func:`_column_min`)."""
    return np.array([a[:, k].max() for k in range(a.shape[1])])


def _flat_index(ijk: np.ndarray, strides: np.ndarray) -> np.ndarray:
    """``ijk @ strides`` for (n, 3) integer indices, column by column (exact integers)."""
    return ijk[:, 0] * strides[0] + ijk[:, 1] * strides[1] + ijk[:, 2] * strides[2]


def clean_mask(mask: np.ndarray, min_neighbours: int = 2, fill_neighbours: int = 5) -> np.ndarray:
    """Remove isolated specks and fill pinholes of a bool mask.

    A vessel pixel stays when at least ``min_neighbours`` of its 8 neighbours are vessel; a
    background pixel becomes vessel when at least ``fill_neighbours`` of them are. Unlike a median
    filter, a vessel that has lost half of its pixels at random is kept (its pixels still have about
    half of their neighbours), while a lone false positive goes.
    """
    mask = np.asarray(mask, dtype=bool)
    out = np.zeros(mask.shape, dtype=bool)
    box = pixel_box(mask, 1) if mask.ndim == 2 else None
    if fill_neighbours <= 0 or box is None:
        kernel = np.ones((3, 3), dtype=np.int32)
        kernel[1, 1] = 0
        neighbours = ndi.convolve(mask.astype(np.int32), kernel, mode="constant")
        return (mask & (neighbours >= min_neighbours)) | (~mask & (neighbours >= fill_neighbours))
    # only the box around the vessel pixels, grown by one, can change: farther pixels have no
    # vessel neighbour (and stay background); within it, the neighbours are counted on a copy
    # padded with a ring of background (the pixels around the box, or outside the image)
    r0, r1, c0, c1 = box
    crop = mask[r0:r1, c0:c1]
    padded = np.zeros((r1 - r0 + 2, c1 - c0 + 2), dtype=np.uint8)
    padded[1:-1, 1:-1] = crop
    neighbours = np.zeros(crop.shape, dtype=np.uint8)
    for dr in range(3):
        for dc in range(3):
            if dr != 1 or dc != 1:
                neighbours += padded[dr:dr + crop.shape[0], dc:dc + crop.shape[1]]
    out[r0:r1, c0:c1] = (crop & (neighbours >= min_neighbours)) | (~crop & (neighbours >= fill_neighbours))
    return out


def _pieces(image: np.ndarray, eight: bool) -> tuple[np.ndarray, np.ndarray]:
    """The connected pieces of a bool image (8-connected, or 4-connected): their labels (0 off the
    pieces) and, per label, its size in pixels (the pixels off the pieces at 0)."""
    labels, count = ndi.label(image, structure=np.ones((3, 3), dtype=bool) if eight else None)
    return labels, np.bincount(labels.ravel(), minlength=count + 1)


def without_small_components(mask: np.ndarray, min_pixels: int) -> np.ndarray:
    """A bool mask without its 8-connected pieces of fewer than ``min_pixels`` pixels: specks of a
    noisy segmentation, which no other view can match, go; a mask with none comes back unchanged.

    >>> m = np.zeros((6, 8), bool); m[1, 1] = m[2, 2] = True; m[4, 1:7] = True
    >>> without_small_components(m, 3).astype(int)[[1, 2, 4]].sum(axis=1)
    array([0, 0, 6])
    """
    mask = np.asarray(mask, dtype=bool)
    labels, sizes = _pieces(mask, eight=True)
    if len(sizes) == 1:
        return mask.copy()
    keep = sizes >= min_pixels
    keep[0] = False
    return keep[labels]


def is_salted(mask: np.ndarray, speck_px: int, specks_per_pixel: float, min_specks: int, pinhole_px: int) -> bool:
    """Whether a bool mask is salted: its specks (8-connected pieces under ``speck_px`` pixels)
    number more than ``specks_per_pixel`` per mask pixel and at least ``min_specks``, beside a piece
    that is no speck, and at least :data:`_SPECKS_PER_PINHOLE` times its pinholes (4-connected
    background pieces of at most ``pinhole_px`` pixels). A clean mask's few small pieces (a thin
    vessel's broken ends) stay under the first bound; a vessel broken into fragments by pepper
    leaves pinholes with its fragments (measured per mask pixel: 60 % pepper 0.067 fragments and
    0.039 pinholes, 75 % 0.30 and 0.011; salt of 1-10 %: 0.2-0.5 specks and 0.001 pinholes).

    >>> m = np.zeros((40, 40), bool); m[20, :] = True; m[::4, ::4] = True
    >>> is_salted(m, 3, 0.005, 10, 9), is_salted(m, 3, 0.005, 200, 9)
    (True, False)
    """
    mask = np.asarray(mask, dtype=bool)
    return _salted(mask, _pieces(mask, eight=True)[1], speck_px, specks_per_pixel, min_specks, pinhole_px)


def _salted(mask: np.ndarray, sizes: np.ndarray, speck_px: int, specks_per_pixel: float, min_specks: int,
            pinhole_px: int) -> bool:
    """:func:`is_salted` of ``mask`` whose 8-connected pieces have ``sizes`` (:func:`_pieces`)."""
    specks = int(np.count_nonzero(sizes[1:] < speck_px))
    if specks == len(sizes) - 1 or specks < min_specks or specks <= specks_per_pixel * np.count_nonzero(mask):
        return False
    pinholes = int(np.count_nonzero(_pieces(~mask, eight=False)[1][1:] <= pinhole_px))
    return specks >= _SPECKS_PER_PINHOLE * pinholes


def without_salt(mask: np.ndarray, speck_px: int, specks_per_pixel: float, min_specks: int,
                 pinhole_px: int) -> np.ndarray:
    """A salted mask (:func:`is_salted`) without its specks (:func:`without_small_components`); any
    other mask unchanged. Its pieces are labelled once for both."""
    mask = np.asarray(mask, dtype=bool)
    labels, sizes = _pieces(mask, eight=True)
    if not _salted(mask, sizes, speck_px, specks_per_pixel, min_specks, pinhole_px):
        return mask.copy()
    keep = sizes >= speck_px
    keep[0] = False
    return keep[labels]


_SPECKS_PER_PINHOLE = 30  # is_salted: salt leaves 200-500 specks per pinhole, heavy pepper's fragments 2-30


def with_small_holes_filled(mask: np.ndarray, max_pixels: int, min_holes_per_pixel: float = 0.0,
                            min_holes: int = 0) -> np.ndarray:
    """A bool mask with its holes of at most ``max_pixels`` pixels filled: the 4-connected pieces of
    background that small (a piece at the image's edge counts too), where they number more than
    ``min_holes_per_pixel`` per mask pixel and at least ``min_holes`` (pepper, a noisy
    segmentation's pinholes, which break a skeleton into loops; a clean mask's few small holes,
    where vessels cross, stay); otherwise, or with none, the mask comes back unchanged.

    >>> m = np.ones((5, 7), bool); m[2, 1] = False; m[1:4, 3:5] = False; m[:, 6] = False
    >>> int((~with_small_holes_filled(m, 4)).sum()), int((~with_small_holes_filled(m, 5)).sum())
    (11, 6)
    >>> int((~with_small_holes_filled(m, 5, min_holes_per_pixel=0.1)).sum())  # 2 small holes in 23 pixels: kept
    12
    """
    mask = np.asarray(mask, dtype=bool)
    labels, sizes = _pieces(~mask, eight=False)
    if len(sizes) == 1:
        return mask.copy()
    fill = sizes <= max_pixels
    fill[0] = False
    holes = np.count_nonzero(fill)
    if holes <= min_holes_per_pixel * np.count_nonzero(mask) or holes < min_holes:
        return mask.copy()
    return mask | fill[labels]


def centreline_branches(centreline: np.ndarray) -> np.ndarray:
    """Label the branches of a 2D centreline (bool image): pixels between junctions.

    A junction pixel has at least 3 centreline pixels among its 8 neighbours. The other centreline
    pixels are labelled by 8-connected runs (1..n); each connected cluster of junction pixels gets a
    label of its own (n+1...). Background is 0.
    """
    centreline = np.asarray(centreline, dtype=bool)
    neighbours = ndi.convolve(centreline.astype(np.int32), _EIGHT.astype(np.int32), mode="constant") - 1
    junction = centreline & (neighbours >= 3)
    runs, n_runs = ndi.label(centreline & ~junction, structure=_EIGHT)
    clusters, _ = ndi.label(junction, structure=_EIGHT)
    return np.where(junction, clusters + n_runs, runs)


def _axis_pieces(axis_local: np.ndarray, branch_per_view: Sequence[np.ndarray]) -> np.ndarray:
    """Piece index (0..m-1) of every axis point: connected on the lattice (26-neighbourhood) and on
    the same 2D centreline branch in every view. ``axis_local``: (A, 3) lattice indices, in lattice
    order; ``branch_per_view``: (A,) branch labels per view."""
    keys = [_neighbour_components(axis_local) + 1, *(np.asarray(b, dtype=np.int64) for b in branch_per_view)]
    # pieces numbered in the lexicographic order of their keys: packed into one integer where it fits
    sizes = [int(k.max()) + 1 for k in keys]
    if np.prod(sizes, dtype=object) < 2 ** 63 and all(k.min() >= 0 for k in keys):
        packed = keys[0]
        for key, size in zip(keys[1:], sizes[1:]):
            packed = packed * size + key
        _, piece = np.unique(packed, return_inverse=True)
    else:
        _, piece = np.unique(np.stack(keys, axis=1), axis=0, return_inverse=True)
    return piece.ravel()


def _point_components(volume: np.ndarray, local: np.ndarray) -> np.ndarray:
    """The 26-connected component of ``volume`` (3D bool) holding each of the points ``local``
    ((N, 3) indices of True voxels, in lattice order): (N,) int, components numbered 0, 1, ... in the
    order of their first voxel in C order (as :func:`scipy.ndimage.label` numbers them, less one).

    Found on the runs of True voxels along the last axis instead of voxel by voxel: two runs in
    neighbouring rows (the last axis fixed, the other two indices differing by at most one) are
    connected when they overlap or touch diagonally (their ends at most one apart)."""
    nx, ny, nz = volume.shape
    padded = np.zeros((nx * ny, nz + 2), dtype=bool)
    padded[:, 1:-1] = volume.reshape(nx * ny, nz)
    change = np.flatnonzero(padded[:, 1:] != padded[:, :-1])  # in each row: a start, an end, ...
    row, start, stop = change[0::2] // (nz + 1), change[0::2] % (nz + 1), change[1::2] % (nz + 1)
    width = nz + 2  # keys row * width + z keep the rows apart even for z - 1 and z + 1
    start_key, end_key = row * width + start, row * width + stop - 1
    x, y = row // ny, row % ny
    first, second = [], []
    for dx, dy in ((0, 1), (1, -1), (1, 0), (1, 1)):
        valid = np.flatnonzero((x + dx < nx) & (y + dy >= 0) & (y + dy < ny))
        other = (row[valid] + dx * ny + dy) * width
        low = np.searchsorted(end_key, other + start[valid] - 1, side="left")
        high = np.searchsorted(start_key, other + stop[valid], side="right")
        count = np.maximum(high - low, 0)
        first.append(np.repeat(valid, count))
        second.append(np.repeat(low - np.cumsum(count) + count, count) + np.arange(int(count.sum())))
    first, second = np.concatenate(first), np.concatenate(second)
    graph = coo_matrix((np.ones(len(first), dtype=np.int8), (first, second)), shape=(len(row), len(row)))
    _, run_component = connected_components(graph, directed=False)
    point_key = (local[:, 0] * ny + local[:, 1]) * width + local[:, 2]
    component = run_component[np.searchsorted(start_key, point_key, side="right") - 1]
    # renumber by first appearance (the points are in C order, so is each component's first voxel)
    _, first_point, inverse = np.unique(component, return_index=True, return_inverse=True)
    rank = np.empty(len(first_point), dtype=np.int64)
    rank[np.argsort(first_point)] = np.arange(len(first_point))
    return rank[inverse.ravel()]


def _neighbour_components(local: np.ndarray) -> np.ndarray:
    """:func:`_point_components` of the volume that holds just the points ``local`` ((N, 3)
    distinct lattice indices in lattice order): the points joined by an edge to each of their
    26-neighbours among them (few points: no volume)."""
    shape = _column_max(local) + 3  # a margin of one beyond the points on both sides: no wrapping
    strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
    flat = _flat_index(local + 1, strides)  # increasing
    first, second = [], []
    for offset in ((0, 0, 1), (0, 1, -1), (0, 1, 0), (0, 1, 1), *((1, a, b) for a in (-1, 0, 1) for b in (-1, 0, 1))):
        target = flat + np.array(offset, dtype=np.int64) @ strides
        position = np.minimum(np.searchsorted(flat, target), len(flat) - 1)
        hit = np.flatnonzero(flat[position] == target)
        first.append(hit)
        second.append(position[hit])
    first, second = np.concatenate(first), np.concatenate(second)
    graph = coo_matrix((np.ones(len(first), dtype=np.int8), (first, second)), shape=(len(flat), len(flat)))
    _, component = connected_components(graph, directed=False)
    _, first_point, inverse = np.unique(component, return_index=True, return_inverse=True)
    rank = np.empty(len(first_point), dtype=np.int64)
    rank[np.argsort(first_point)] = np.arange(len(first_point))
    return rank[inverse.ravel()]


def _gaps(start: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """(K,) bool: the straight segment from the lattice point of flat index start[k] (into the
    C-contiguous bool volume ``hull``) by the integer step (dx[k], dy[k], dz[k]), both ends in the
    hull, passes a lattice point outside ``hull``: sampled every half lattice spacing, each sample
    rounded to its nearest lattice point (an offset from the start half-way between two lattice
    steps goes to the even one).

    Every sample lies in the box of its segment's ends, so inside the volume. The samples' offsets
    from the start depend on the step alone, and the segments between rivals share few steps (they
    run along viewing rays): the lattice points a step's samples visit are listed once per step, as
    flat offsets into ``hull`` without repeats (consecutive samples often round to the same lattice
    point) and without the ends (in the hull), and every segment reads its points through that
    list."""
    gap = np.zeros(len(start), dtype=bool)
    if len(start) == 0:
        return gap
    strides = np.array(hull.strides, dtype=np.int64) // hull.itemsize
    span = 2 * np.array(hull.shape, dtype=np.int64) - 1  # a step's coordinates lie within +-(shape - 1)
    code = ((dx + (hull.shape[0] - 1)) * span[1] + (dy + (hull.shape[1] - 1))) * span[2] + (dz + (hull.shape[2] - 1))
    unique_code, which = np.unique(code, return_inverse=True)
    which = which.ravel()
    unique = np.stack([unique_code // (span[1] * span[2]), (unique_code // span[2]) % span[1], unique_code % span[2]],
                      axis=1) - (np.array(hull.shape, dtype=np.int64) - 1)
    step = unique.astype(np.float64)
    steps = np.maximum(np.ceil(2.0 * np.sqrt((step * step).sum(axis=1))).astype(np.int64), 1)
    # samples 1 .. steps - 1 of each step, as flat offsets
    count = steps - 1
    first = np.cumsum(count) - count
    owner = np.repeat(np.arange(len(unique)), count)
    k = np.arange(len(owner)) - first[owner] + 1
    fraction = k / steps[owner]
    table = (np.rint(step[:, 0][owner] * fraction) * float(strides[0]) + np.rint(step[:, 1][owner] * fraction) * float(strides[1])
             + np.rint(step[:, 2][owner] * fraction) * float(strides[2])).astype(np.int64)  # exact: integers below 2**53
    # the samples along a segment move monotonically on each axis, so a lattice point's samples
    # are consecutive: keep the first of each run, and drop the ends
    previous = np.empty_like(table)
    previous[1:] = table[:-1]
    previous[first[count > 0]] = 0
    new = (table != previous) & (table != 0) & (table != (unique @ strides)[owner])
    table = table[new]
    count = np.bincount(owner[new], minlength=len(unique))
    first = np.cumsum(count) - count
    # every segment's lattice points: its start plus its step's offsets
    count = count[which]
    tested = np.flatnonzero(count)
    if len(tested) == 0:
        return gap
    segment_start = np.cumsum(count) - count
    position = np.repeat(first[which] - segment_start, count) + np.arange(int(segment_start[-1] + count[-1]))
    inside = hull.ravel()[np.repeat(start, count) + table[position]]
    gap[tested] = ~np.logical_and.reduceat(inside, segment_start[tested])
    return gap


def _rivals(axis_uv: np.ndarray, reach_px: np.ndarray, axis_points: np.ndarray, axis_piece: np.ndarray,
            tube_uv: np.ndarray, tube_points: np.ndarray, tube_piece: np.ndarray,
            hull: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One view's rivals: the pairs (axis point index, piece) such that a hull point of that other
    piece projects within the axis point's reach (closed) and is separated from it by a gap in the
    hull. Each pair once, in the order of (axis point index, piece). (Per pair, the farthest such
    hull point is tried first, the lowest index of equally far ones: it is the one most likely
    across a gap; the others only when it is not.) ``axis_points`` and ``tube_points`` are (n, 3)
    integer lattice indices into the volume ``hull``. The compiled kernel, where numba is
    installed, gives the same pairs."""
    compiled = kernels()
    if compiled is not None:
        return compiled.rival_pairs(np.ascontiguousarray(axis_uv, dtype=np.float64),
                                    np.ascontiguousarray(reach_px, dtype=np.float64),
                                    np.ascontiguousarray(axis_piece, dtype=np.int64),
                                    np.ascontiguousarray(tube_uv, dtype=np.float64),
                                    np.ascontiguousarray(tube_piece, dtype=np.int64),
                                    np.ascontiguousarray(axis_points, dtype=np.int64),
                                    np.ascontiguousarray(tube_points, dtype=np.int64),
                                    np.ascontiguousarray(hull).ravel(), np.array(hull.shape, dtype=np.int64))
    axis_index, tube_index = _pairs_within(axis_uv, reach_px, axis_piece, tube_uv, tube_piece)
    rival_piece = tube_piece[tube_index]
    if len(axis_index) == 0:
        return axis_index, rival_piece
    axis_xyz, tube_xyz = np.ascontiguousarray(axis_points.T), np.ascontiguousarray(tube_points.T)
    offset = [t[tube_index] - a[axis_index] for a, t in zip(axis_xyz, tube_xyz)]
    distance = offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2]  # squared, in lattice spacings
    axis_index, rival_piece, tube_index = _sorted_pairs(axis_index, rival_piece, distance, tube_index,
                                                        len(axis_points), int(tube_piece.max()) + 1, len(tube_points))
    group_start = np.r_[True, (np.diff(axis_index) != 0) | (np.diff(rival_piece) != 0)]
    group = np.cumsum(group_start) - 1
    first = np.flatnonzero(group_start)
    axis_flat = axis_points @ (np.array(hull.strides, dtype=np.int64) // hull.itemsize)

    def gaps(pairs: np.ndarray) -> np.ndarray:
        a, t = axis_index[pairs], tube_index[pairs]
        return _gaps(axis_flat[a], *(tc[t] - ac[a] for ac, tc in zip(axis_xyz, tube_xyz)), hull)

    apart = gaps(first)
    rest = np.flatnonzero(~group_start & ~apart[group])
    if len(rest):
        apart[group[rest[gaps(rest)]]] = True
    return axis_index[first[apart]], rival_piece[first[apart]]


def _pairs_within(axis_uv: np.ndarray, reach_px: np.ndarray, axis_piece: np.ndarray, tube_uv: np.ndarray,
                  tube_piece: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(axis index, tube index) of the pairs of an axis point and a tube point of another piece whose
    projections lie within the axis point's reach (closed), ordered by axis index: the pairs that
    ``cKDTree(axis_uv).sparse_distance_matrix(cKDTree(tube_uv), reach_px.max())`` returns, kept where
    the pieces differ and the distance it computes is within ``reach_px``.

    The tube points are binned on a grid of cells of half the largest reach (a hair more, so that
    rounding cannot move a point within reach beyond the cells searched); each axis point reads the
    cells of the rows within reach, and the distances are computed as the tree does (the squared
    differences summed, compared with the largest reach squared, then the square root)."""
    largest = float(reach_px.max())
    split = 2
    cell = largest / split * (1.0 + 1e-6)
    low = np.array([min(axis_uv[:, 0].min(), tube_uv[:, 0].min()), min(axis_uv[:, 1].min(), tube_uv[:, 1].min())])
    tube_cell = np.floor((tube_uv - low) / cell).astype(np.int64) + split
    axis_cell = np.floor((axis_uv - low) / cell).astype(np.int64) + split
    width = int(max(tube_cell[:, 1].max(), axis_cell[:, 1].max())) + split + 1
    tube_key = tube_cell[:, 0] * width + tube_cell[:, 1]
    by_key = np.argsort(tube_key)
    sorted_key = tube_key[by_key]
    # rows of cells -split..split; the columns of a row that a point within reach can lie in
    rows = np.arange(-split, split + 1)
    columns = np.minimum(split, 1 + np.floor(np.sqrt(split * split - np.maximum(np.abs(rows) - 1, 0) ** 2)).astype(np.int64))
    centre = (axis_cell[:, 0] * width + axis_cell[:, 1])[:, None] + rows[None, :] * width
    first = np.searchsorted(sorted_key, (centre - columns[None, :]).ravel(), side="left")
    count = np.searchsorted(sorted_key, (centre + columns[None, :] + 1).ravel(), side="left") - first
    start = np.cumsum(count) - count
    position = np.repeat(first - start, count) + np.arange(int(count.sum()))  # in the sorted tube points
    per_axis = count.reshape(len(axis_uv), -1).sum(axis=1)
    other = np.flatnonzero(tube_piece[by_key][position] != np.repeat(axis_piece, per_axis))
    axis_index, position = np.repeat(np.arange(len(axis_uv)), per_axis)[other], position[other]
    du = axis_uv[:, 0][axis_index] - tube_uv[by_key, 0][position]
    dv = axis_uv[:, 1][axis_index] - tube_uv[by_key, 1][position]
    squared = du * du
    squared += dv * dv
    near = np.flatnonzero(squared <= largest * largest)
    axis_index, position = axis_index[near], position[near]
    near = np.sqrt(squared[near]) <= reach_px[axis_index]
    return axis_index[near], by_key[position[near]]


def _sorted_pairs(axis_index: np.ndarray, rival_piece: np.ndarray, distance: np.ndarray, tube_index: np.ndarray,
                  n_axis: int, n_pieces: int, n_tube: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(axis_index, rival_piece, tube_index) ordered by axis index, piece, decreasing distance
    (non-negative integers) and tube index. The four keys are packed into one integer where they
    fit (one sort of plain integers instead of a four-key lexsort; the pairs are distinct, so is the
    packed key)."""
    n_distance = int(distance.max()) + 1
    if n_axis * n_pieces * n_distance * n_tube < 2 ** 63:
        key = ((axis_index.astype(np.int64) * n_pieces + rival_piece) * n_distance + (n_distance - 1 - distance)) * n_tube
        key = np.sort(key + tube_index)
        tube_index = key % n_tube
        key //= n_tube * n_distance
        return key // n_pieces, key % n_pieces, tube_index
    order = np.lexsort((tube_index, -distance, rival_piece, axis_index))
    return axis_index[order].astype(np.int64), rival_piece[order], tube_index[order]


def drop_explained_pieces(axis_piece: np.ndarray, rivals: Sequence[tuple[np.ndarray, np.ndarray]],
                          unique_fraction: float) -> np.ndarray:
    """Greedy explanation test on axis pieces (see the module notes, step 4).

    Parameters
    ----------
    axis_piece : (A,) int array
        Piece index (0..m-1) of every axis point.
    rivals : sequence of pairs of (R,) int arrays, one per view
        (axis point index, piece index of its rival), each pair once: in that view, the axis point
        shares its viewing ray with a hull point of that piece, across a gap in the hull.
    unique_fraction : float
        A piece is dropped when its score (the largest, over the views, fraction of its axis points
        with no rival among the kept pieces) is below this; 0 keeps every piece.

    Returns
    -------
    kept : (m,) bool array
        The pieces kept. Pieces are dropped one at a time, the lowest score first.
    """
    n_pieces = int(axis_piece.max()) + 1 if len(axis_piece) else 0
    size = np.bincount(axis_piece, minlength=n_pieces).astype(np.float64)
    kept = np.ones(n_pieces, dtype=bool)
    if n_pieces == 0 or not rivals:
        return kept
    rival_count, by_rival = [], []
    for axis_index, rival_piece in rivals:
        rival_count.append(np.bincount(axis_index, minlength=len(axis_piece)))
        order = np.argsort(rival_piece, kind="stable")
        bounds = np.searchsorted(rival_piece[order], np.arange(n_pieces + 1))
        by_rival.append((axis_index[order], bounds))

    def score(pieces_mask: np.ndarray) -> np.ndarray:
        free = [np.bincount(axis_piece[pieces_mask], weights=(c == 0)[pieces_mask], minlength=n_pieces)
                for c in rival_count]
        return np.max(free, axis=0) / np.maximum(size, 1.0)

    scores = score(np.ones(len(axis_piece), dtype=bool))
    while True:
        worst = int(np.argmin(np.where(kept, scores, np.inf)))
        if not kept[worst] or scores[worst] >= unique_fraction:
            return kept
        kept[worst] = False
        freed = []
        for count, (axis_index, bounds) in zip(rival_count, by_rival):
            hit = axis_index[bounds[worst]:bounds[worst + 1]]
            np.subtract.at(count, hit, 1)
            freed.append(hit)
        touched = np.zeros(n_pieces, dtype=bool)
        touched[axis_piece[np.concatenate(freed)]] = True
        touched &= kept
        if touched.any():
            scores[touched] = score(touched[axis_piece])[touched]


def refine_hull(points_mm: np.ndarray, lattice: Lattice, projections: Sequence[Projection],
                masks: Sequence[np.ndarray], settings: RefineSettings = REFINED) -> tuple[np.ndarray, dict]:
    """Connectivity, explanation and radius consistency applied to carved lattice points (see the
    module notes).

    Parameters
    ----------
    points_mm : (N, 3) array
        Kept lattice points of ``lattice``.
    lattice : Lattice
    projections, masks : sequences
        The views the points were carved with (masks as carved, i.e. already cleaned).
    settings : RefineSettings

    Returns
    -------
    points : (M, 3) array
        The refined points, a subset of ``points_mm`` in the same order.
    info : dict
        Counts removed by each step (``pieces_removed``: axis pieces dropped by the explanation step).
    """
    info = {"components_removed": 0, "components_kept_unexplained": 0, "pieces_removed": 0, "radius_removed": 0}
    if len(points_mm) == 0:
        return points_mm, info
    # in lattice order, so that ties between equally near points do not depend on the input's order
    order = _lattice_order(points_mm, lattice)
    ordered = points_mm[order]
    big, radius, axis, nearest = _axis_points(ordered, lattice, projections, masks, settings, info)
    keep = np.zeros(len(points_mm), dtype=bool)
    if axis is None:
        keep[order[big]] = True
        return points_mm[keep], info
    if len(axis) == 0:
        info["radius_removed"] = int(big.sum())
        return points_mm[:0], info
    # radius consistency: keep hull points within the radius of their nearest (kept) axis point
    candidates = ordered[big]
    _, in_tube = _radius_tube(candidates, _lattice_indices(candidates, lattice), radius, axis,
                              settings.slack_cells * lattice.spacing_mm, nearest)
    keep[order[np.flatnonzero(big)[in_tube]]] = True
    info["radius_removed"] = int((~in_tube).sum())
    return points_mm[keep], info


def projected_with_scale(projection: Projection, points_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(uv, px_per_mm)``: the points' projections (px) and the view's magnification at each (px
    per mm at its depth), from one product (:meth:`Projection.project` and ``.depth_mm`` in one)."""
    homogeneous = projection.homogeneous(points_mm)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = homogeneous[:, :2] / homogeneous[:, 2:3]
    px_per_mm = max(projection.focal_lengths_px) / (homogeneous[:, 2] / np.linalg.norm(projection.matrix[2, :3]))
    return uv, px_per_mm


def cell_reach_px(spacing_mm: float, px_per_mm: np.ndarray) -> np.ndarray:
    """How far (px) a lattice cell's projection reaches from its point: its half-diagonal at the
    point's magnification plus half a pixel (the reach within which a point counts as on a 2D
    centreline, explained by another point, or near a mask)."""
    return 0.5 * np.sqrt(3.0) * spacing_mm * px_per_mm + 0.5


def _unexplained_parts(points_mm: np.ndarray, labels: np.ndarray, big: np.ndarray, projections: Sequence[Projection],
                       masks: Sequence[np.ndarray], lattice: Lattice, unique_fraction: float) -> np.ndarray:
    """(N,) bool: the points of the small parts (``~big``) that carry on a vessel of the large ones
    in some view: the parts that, in some view, have at least ``unique_fraction`` of their points
    projecting farther from every other part's point (large, or small and another) than a lattice
    cell's projection reaches (its half-diagonal plus half a pixel, the axis points' reach) onto
    the connected piece of the mask that the large parts' points project onto. Hull points project
    inside every mask, so such a part is all that explains those pixels, where the view shows them
    joined to the tree (the view that breaks the vessel is another one); a phantom where the cones
    of other vessels meet projects onto their pixels in every view, and a speck carved from
    false-positive pixels onto blobs apart from the tree. Another small part counts as explaining
    too: the part beyond a break is small itself, and the phantoms where its cone meets other
    vessels' (4-12 mm from any vessel on a QCA benchmark tree, left 14) project onto its pixels in
    one view and onto the large parts' in the others."""
    small = np.flatnonzero(~big)
    parts = int(labels.max()) + 1
    count = np.bincount(labels[small], minlength=parts)
    best = np.zeros(parts)
    for projection, mask in zip(projections, masks):
        mask = np.asarray(mask, dtype=bool)
        uv, px_per_mm = projected_with_scale(projection, points_mm)
        reach_px = cell_reach_px(lattice.spacing_mm, px_per_mm[small])
        bound = float(reach_px.max()) + 1.0
        # only the large parts' points near the small ones can explain their pixels
        low, high = _column_min(uv[small]) - bound, _column_max(uv[small]) + bound
        near = uv[big]
        near = near[np.all((near >= low) & (near <= high), axis=1)]
        free = np.ones(len(small), dtype=bool)
        if len(near):
            distance, _ = cKDTree(near).query(uv[small], distance_upper_bound=bound)
            free = distance > reach_px
        # nor by another small part's point (a phantom where this part's cone meets others')
        pairs = cKDTree(uv[small]).query_pairs(bound, output_type="ndarray")
        if len(pairs):
            i, j = pairs[:, 0], pairs[:, 1]
            apart = labels[small[i]] != labels[small[j]]
            gap = np.linalg.norm(uv[small[i]] - uv[small[j]], axis=1)
            free[i[apart & (gap <= reach_px[i])]] = False
            free[j[apart & (gap <= reach_px[j])]] = False
        pieces, _ = ndi.label(mask, structure=_EIGHT)
        cols = np.clip(np.floor(uv[:, 0] + 0.5).astype(np.int64), 0, mask.shape[1] - 1)
        rows = np.clip(np.floor(uv[:, 1] + 0.5).astype(np.int64), 0, mask.shape[0] - 1)
        on_tree = np.zeros(int(pieces.max()) + 1, dtype=bool)
        on_tree[pieces[rows[big], cols[big]]] = True
        on_tree[0] = False
        free &= on_tree[pieces[rows[small], cols[small]]]
        share = np.bincount(labels[small], weights=free.astype(np.float64), minlength=parts) / np.maximum(count, 1)
        best = np.maximum(best, share)
    out = np.zeros(len(points_mm), dtype=bool)
    out[small] = best[labels[small]] >= unique_fraction
    return out


def _lattice_indices(points_mm: np.ndarray, lattice: Lattice) -> np.ndarray:
    """(N, 3) int: the (i, j, k) lattice indices of lattice points."""
    return np.round((points_mm + lattice.half_edge_mm) / lattice.spacing_mm).astype(np.int64)


def _lattice_order(points_mm: np.ndarray, lattice: Lattice) -> np.ndarray:
    """The permutation that sorts lattice points by their (i, j, k) lattice indices."""
    ijk = _lattice_indices(points_mm, lattice)
    k = lattice.resolution
    if len(ijk) and ijk.min() >= 0 and ijk.max() < k:  # one key, sorted stably: the order of the lexsort below
        return np.argsort((ijk[:, 0] * k + ijk[:, 1]) * k + ijk[:, 2], kind="stable")
    return np.lexsort((ijk[:, 2], ijk[:, 1], ijk[:, 0]))


def tube_axis(points_mm: np.ndarray, lattice: Lattice, projections: Sequence[Projection],
              masks: Sequence[np.ndarray], settings: RefineSettings = REFINED) -> tuple[np.ndarray, np.ndarray]:
    """The axis points the radius check of :func:`refine_hull` keeps (after connectivity and
    explanation) and their radii: a model of the vessels as a union of balls.

    Returns
    -------
    axis_points : (A, 3) array, mm
    radius : (A,) array, mm (the smallest half-width the views show at the point)
    """
    if len(points_mm) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    ordered = points_mm[_lattice_order(points_mm, lattice)]
    big, radius, axis, _ = _axis_points(ordered, lattice, projections, masks, settings, {})
    if axis is None:
        return np.zeros((0, 3)), np.zeros(0)
    return ordered[big][axis], radius[axis]


def _box(mask: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[tuple[int, int], tuple[int, int]]:
    """(row, col) start and stop of the box that holds the mask's pixels and (rows, cols), grown by
    one pixel (within the image)."""
    low = [rows.min(initial=mask.shape[0]), cols.min(initial=mask.shape[1])]
    high = [rows.max(initial=-1), cols.max(initial=-1)]
    box = pixel_box(mask)
    if box is not None:
        low = [min(low[0], box[0]), min(low[1], box[2])]
        high = [max(high[0], box[1] - 1), max(high[1], box[3] - 1)]
    start = (max(int(low[0]) - 1, 0), max(int(low[1]) - 1, 0))
    stop = (min(int(high[0]) + 2, mask.shape[0]), min(int(high[1]) + 2, mask.shape[1]))
    return start, stop


def _inside_distance(mask: np.ndarray, where: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.distance_transform_edt(mask)`` at the pixels ``where`` (a subset of the
    vessel pixels of the bool image ``mask``; 0 elsewhere): the distance from each to the nearest
    background pixel centre of the image.

    The nearest background pixel b of a vessel pixel f has a vessel 8-neighbour (the step from b
    toward f is nearer to f, so it is not background): a k-d tree of the background pixels next to
    the vessel finds it, and gives the same distance (the square root of the summed squares of
    integers). An image without background goes to the distance transform."""
    out = np.zeros(mask.shape)
    padded = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), dtype=bool)
    padded[1:-1, 1:-1] = mask
    near_vessel = np.zeros(mask.shape, dtype=bool)
    for dr in range(3):
        for dc in range(3):
            if dr != 1 or dc != 1:
                near_vessel |= padded[dr:dr + mask.shape[0], dc:dc + mask.shape[1]]
    edge = np.argwhere(near_vessel & ~mask)
    if len(edge) == 0:
        return np.where(where, ndi.distance_transform_edt(mask), 0.0)
    query = np.argwhere(where)
    if len(query):
        out[where] = cKDTree(edge.astype(np.float64)).query(query.astype(np.float64), k=1)[0]
    return out


_TIE_MM = 1e-9
"""Points whose distances differ by less than this are equally near (lattice points often are)."""


def _lattice_shells(cells: int) -> dict[int, np.ndarray]:
    """The lattice offsets (n, 3) of each squared length up to ``cells ** 2`` that has any."""
    r = np.arange(-cells, cells + 1)
    offsets = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    length = (offsets * offsets).sum(axis=1)
    return {n: offsets[length == n] for n in range(cells * cells + 1) if (length == n).any()}


_SHELLS = _lattice_shells(8)


def _nearest_axis(axis_ijk: np.ndarray, axis_mm: np.ndarray, query_ijk: np.ndarray, query_mm: np.ndarray,
                  reach_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """``nearest_with_ties(axis_mm, query_mm, _TIE_MM)`` for lattice points (``*_ijk``: their
    (n, 3) lattice indices, ``axis_ijk`` in lattice order) with an axis point nearer than
    ``reach_mm``: the distance (mm) to the nearest axis point and the index of the nearest, the
    lowest of equally near ones. The other queries get distance inf and index 0.

    The squared distance between two lattice points is an integer number of squared spacings;
    distances of different integers differ by far more than the tie tolerance (at least
    spacing / (2 sqrt(n)), about a micrometre at K = 1024), those of the same integer by rounding
    only. So a k-d tree gives the distance and one nearest axis point (the distance is the smallest
    the tree computes, whichever of the equally near points it found), and the equally near ones
    are the axis points on the shell of lattice offsets of the same squared length around the
    query, read from a volume (up to 8 spacings away; :func:`nearest_with_ties` beyond)."""
    compiled = kernels()
    if compiled is not None and len(axis_ijk) and len(query_ijk):
        return _nearest_axis_compiled(compiled, axis_ijk, axis_mm, query_ijk, query_mm, reach_mm)
    return _nearest_axis_numpy(axis_ijk, axis_mm, query_ijk, query_mm, reach_mm)


def _nearest_axis_numpy(axis_ijk: np.ndarray, axis_mm: np.ndarray, query_ijk: np.ndarray, query_mm: np.ndarray,
                        reach_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_nearest_axis` in NumPy (the reference): a k-d tree, then the shells of the ties."""
    distance, index = cKDTree(axis_mm).query(query_mm, k=1, distance_upper_bound=reach_mm)
    found = np.flatnonzero(index < len(axis_mm))
    index[index >= len(axis_mm)] = 0
    if len(found) == 0:
        return distance, index
    cells = max(int(np.sqrt(n)) for n in _SHELLS)
    query_ijk = query_ijk[found]
    low = np.minimum(_column_min(axis_ijk), _column_min(query_ijk)) - cells
    shape = np.maximum(_column_max(axis_ijk), _column_max(query_ijk)) - low + cells + 1
    strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
    axis_flat = _flat_index(axis_ijk - low, strides)  # increasing: the axis points are in lattice order
    occupied = np.zeros(int(np.prod(shape)), dtype=bool)
    occupied[axis_flat] = True
    offset = query_ijk - axis_ijk[index[found]]
    length = offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1] + offset[:, 2] * offset[:, 2]  # squared lattice distance
    query_flat = _flat_index(query_ijk - low, strides)
    by_length = np.argsort(length, kind="stable")
    bounds = np.searchsorted(length[by_length], np.arange(cells * cells + 2))
    for n, shell in _SHELLS.items():
        which = by_length[bounds[n]:bounds[n + 1]]
        if len(which) == 0 or len(shell) == 1:
            continue
        flat = query_flat[which][:, None] + (shell @ strides)[None, :]
        hit = occupied[flat]
        tied = np.flatnonzero(hit.sum(axis=1) > 1)
        if len(tied):  # the lowest index of the equally near axis points
            flat = np.where(hit[tied], flat[tied], np.iinfo(np.int64).max)
            index[found[which[tied]]] = np.searchsorted(axis_flat, flat.min(axis=1))
    far = found[length > cells * cells]
    if len(far):
        distance[far], index[far] = nearest_with_ties(axis_mm, query_mm[far], _TIE_MM)
    return distance, index


_AXIS_CUBE_CELLS = 4  # the compiled search bins the axis points on cubes of this many lattice spacings


def _nearest_axis_compiled(compiled, axis_ijk: np.ndarray, axis_mm: np.ndarray, query_ijk: np.ndarray,
                           query_mm: np.ndarray, reach_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_nearest_axis` by the compiled kernel (axis points binned on cubes, the equally near
    ones by their whole-number squared lattice distance): the same distances and indices; the
    queries it cannot settle (the nearest beyond the shell table, or at the reach to rounding) go
    the NumPy way."""
    distance, index, settled = compiled.nearest_lattice_axis(
        np.ascontiguousarray(axis_ijk, dtype=np.int64), np.ascontiguousarray(axis_mm, dtype=np.float64),
        np.ascontiguousarray(query_ijk, dtype=np.int64), np.ascontiguousarray(query_mm, dtype=np.float64),
        _AXIS_CUBE_CELLS, max(_SHELLS), float(reach_mm) * float(reach_mm))
    rest = np.flatnonzero(~settled)
    if len(rest):
        distance[rest], index[rest] = _nearest_axis_numpy(axis_ijk, axis_mm, query_ijk[rest], query_mm[rest], reach_mm)
    return distance, index


def _radius_tube(candidates: np.ndarray, candidates_ijk: np.ndarray, radius: np.ndarray, axis: np.ndarray,
                 slack_mm: float, nearest: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(nearest axis point, within its radius + slack) of every candidate (``candidates_ijk``: their
    lattice indices). ``nearest``: (distance, position in ``axis``) of the candidates' nearest axis
    points where already known (position -1 where not), e.g. from a query of more axis points whose
    nearest is among these. The nearest axis point is looked for within the largest radius + slack
    only (farther candidates are outside the tube whichever it is): beyond, distance inf and
    position 0."""
    if nearest is None:
        distance, owner = _nearest_axis(candidates_ijk[axis], candidates[axis], candidates_ijk, candidates,
                                        _tube_reach(radius[axis], slack_mm))
    else:
        distance, owner = nearest[0].copy(), nearest[1].copy()
        unknown = np.flatnonzero(owner < 0)
        if len(unknown):
            distance[unknown], owner[unknown] = _nearest_axis(candidates_ijk[axis], candidates[axis],
                                                              candidates_ijk[unknown], candidates[unknown],
                                                              _tube_reach(radius[axis], slack_mm))
    return owner, distance <= radius[axis][owner] + slack_mm


def _tube_reach(radius: np.ndarray, slack_mm: float) -> float:
    """A distance (mm) beyond every tube: the largest radius plus the slack, plus a millimetre
    against rounding (the k-d tree's bound is strict)."""
    return float(radius.max()) + slack_mm + 1.0


def _axis_points(points_mm: np.ndarray, lattice: Lattice, projections: Sequence[Projection],
                 masks: Sequence[np.ndarray], settings: RefineSettings,
                 info: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, tuple | None]:
    """Steps 2-4 of the module notes: ``(big, radius, axis, nearest)``. ``big`` marks the points in
    large enough parts (the candidates), ``radius`` is each candidate's radius (mm) and ``axis``
    the indices of the kept axis points among the candidates (None when no candidate is an axis
    point); ``nearest`` is what is known of each candidate's nearest kept axis point (see
    :func:`_radius_tube`), or None. Fills the counts of ``info``."""
    h = lattice.spacing_mm
    ijk = _lattice_indices(points_mm, lattice)
    low = _column_min(ijk) - 2
    local = ijk - low
    volume = np.zeros(tuple(_column_max(local) + 3), dtype=bool)
    volume[tuple(local.T)] = True

    # 2. connectivity
    bridged = dilated(volume, settings.bridge_cells) if settings.bridge_cells else volume
    point_labels = _point_components(bridged, local)
    sizes = np.bincount(point_labels)
    big = sizes[point_labels] >= settings.component_fraction * len(points_mm)
    if settings.unique_fraction > 0 and big.any() and not big.all():
        # a small part that shows, in some view, pixels of the tree's own mask piece that the large
        # parts do not explain is a piece of a true vessel cut off by a gap in another view's mask
        # (the distal vessel past a severe stenosis): it stays, like a piece of its own in the
        # explanation step
        kept = _unexplained_parts(points_mm, point_labels, big, projections, masks, lattice, settings.unique_fraction)
        info["components_kept_unexplained"] = int(kept.sum())
        big |= kept
    info["components_removed"] = int((~big).sum())
    # 3. axis points: hull points whose projection lies on (within a lattice cell of) the 2D
    # centreline in at least axis_views views; each gets the smallest radius the views show there.
    candidates = points_mm[big]
    on_axis_views = np.zeros(len(candidates), dtype=np.int64)
    radius = np.full(len(candidates), np.inf)
    views = []
    for projection, mask in zip(projections, masks):
        # each image in the orientation its geometry sets, so that thinning and the ties of the
        # distance transforms do not depend on how the image was stored (flipped, transposed)
        storage = canonical_storage(projection)
        projection, mask = storage.apply(projection), storage.apply_image(np.asarray(mask, dtype=bool))
        uv, px_per_mm = projected_with_scale(projection, candidates)
        cols = np.clip(np.floor(uv[:, 0] + 0.5).astype(np.int64), 0, mask.shape[1] - 1)
        rows = np.clip(np.floor(uv[:, 1] + 0.5).astype(np.int64), 0, mask.shape[0] - 1)
        # the image maps below are computed on the box around the mask and the candidates' pixels,
        # grown by a background pixel: the same values as on the whole image (thinning sees only
        # 3x3 neighbourhoods; the nearest background pixel of a vessel pixel is never beyond the
        # ring of background around the box; every centreline pixel is inside it)
        (r0, c0), (r1, c1) = _box(mask, rows, cols)
        crop = mask[r0:r1, c0:c1]
        local_rows, local_cols = rows - r0, cols - c0
        centreline = thin(crop)
        inside = _inside_distance(crop, centreline)
        off_centre, nearest = ndi.distance_transform_edt(~centreline, return_indices=True)
        reach_px = cell_reach_px(h, px_per_mm)
        on_axis_views += off_centre[local_rows, local_cols] <= reach_px
        # half-width at the nearest centreline pixel; the distance to the nearest background pixel
        # centre overshoots the edge (half-way between pixel centres) by 0.5 px
        centre_rows, centre_cols = nearest[0, local_rows, local_cols], nearest[1, local_rows, local_cols]
        half_width = inside[centre_rows, centre_cols] - 0.5
        radius = np.minimum(radius, half_width / px_per_mm)
        views.append((uv, reach_px, centreline, centre_rows, centre_cols))
    near_axis = on_axis_views >= min(settings.axis_views, len(projections))
    if not near_axis.any():
        return big, radius, None, None
    axis = np.flatnonzero(near_axis)
    nearest = None
    # 4. explanation: drop axis pieces whose pixels other pieces explain in every view
    if settings.unique_fraction > 0:
        candidate_ijk = ijk[big]
        distance, owner = _nearest_axis(candidate_ijk[axis], candidates[axis], candidate_ijk, candidates,
                                        _tube_reach(radius[axis], settings.slack_cells * h))
        owner, in_tube = _radius_tube(candidates, candidate_ijk, radius, axis, settings.slack_cells * h,
                                      (distance, owner))
        piece = _axis_pieces(local[big][axis], [centreline_branches(c)[r[axis], k[axis]] for _, _, c, r, k in views])
        tube = np.flatnonzero(in_tube)
        tube_piece = piece[owner[tube]]
        hull = np.zeros_like(volume)
        hull[tuple(local[big].T)] = True
        candidate_local = local[big]
        rivals = [_rivals(uv[axis], reach[axis], candidate_local[axis], piece, uv[tube], candidate_local[tube],
                          tube_piece, hull) for uv, reach, *_ in views]
        kept = drop_explained_pieces(piece, rivals, settings.unique_fraction)
        info["pieces_removed"] = int((~kept).sum())
        kept_axis = kept[piece]
        # a candidate whose nearest axis point is kept has it as its nearest kept one too
        position = np.cumsum(kept_axis) - 1
        nearest = (np.where(kept_axis[owner], distance, np.inf), np.where(kept_axis[owner], position[owner], -1))
        axis = axis[kept_axis]
    return big, radius, axis, nearest
