"""How well a vessel tree explains the views' masks: its tubes' silhouette drawn into each view and
compared with the mask (Dice coefficient).

With two views every matching of their centerlines is consistent with both silhouettes in
principle, but a wrong one (a vessel of one view paired with the wrong vessel of the other) leaves
parts of the masks to phantoms or to nothing once its tree has been fitted and pruned; the ``tree``
method builds a tree from each of its alternative matchings and keeps the one that agrees best
(module notes of :mod:`angiohull.reconstruction.model`).

The silhouette is the union of the discs of the tree's centerline samples (every ``step_mm`` of
arc length), each of its radius scaled by the projection's focal length over its depth, drawn on
the pixel centres (integer ``(u, v)``).
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple, Sequence

import numpy as np
from scipy import ndimage as ndi

from ...compiled import kernels
from ...geometry import Projection
from ...tree import Branch, VesselTree

__all__ = ["tube_silhouette", "mask_agreement", "Suspect", "suspect_pieces"]


def _samples(tree: VesselTree, step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    points, radii = [], []
    for branch in tree.branches:
        b = branch.resampled(step_mm) if branch.length_mm > step_mm else branch
        points.append(b.points_mm)
        radii.append(b.radius_mm)
    if not points:
        return np.zeros((0, 3)), np.zeros(0)
    return np.concatenate(points), np.concatenate(radii)


@lru_cache(maxsize=64)
def _offsets(reach: int) -> tuple[np.ndarray, np.ndarray]:
    """The pixel offsets (du, dv) of the square of half-edge ``reach``."""
    du, dv = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1))
    return du.ravel(), dv.ravel()


def _disc_groups(uv: np.ndarray, rho: np.ndarray, shape: tuple[int, int]):
    """The pixels within ``rho`` of each ``uv`` (the discs of :func:`tube_silhouette`, on the pixel
    centres, inside an image of ``shape``), one group of samples of one reach at a time:
    ``(samples (S,), flat pixel indices, (S, offsets) bool of the offsets inside)``."""
    reach = np.ceil(rho).astype(np.int64)
    for k in np.unique(reach):
        at = np.flatnonzero(reach == k)
        du, dv = _offsets(int(k))
        cu = np.rint(uv[at, 0]).astype(np.int64)[:, None] + du[None, :]
        cv = np.rint(uv[at, 1]).astype(np.int64)[:, None] + dv[None, :]
        inside = (cu - uv[at, 0][:, None]) ** 2 + (cv - uv[at, 1][:, None]) ** 2 <= rho[at][:, None] ** 2
        inside &= (cu >= 0) & (cv >= 0) & (cu < shape[1]) & (cv < shape[0])
        yield at, cv[inside] * shape[1] + cu[inside], inside


def _disc_pixels(uv: np.ndarray, rho: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices into an image of ``shape`` of the pixels of :func:`_disc_groups`, and the
    sample each belongs to (one entry per sample and pixel: a pixel two discs cover comes twice)."""
    pixels, owners = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for at, flat, inside in _disc_groups(uv, rho, shape):
        pixels.append(flat)
        owners.append(np.broadcast_to(at[:, None], inside.shape)[inside])
    return np.concatenate(pixels), np.concatenate(owners)


def tube_silhouette(tree: VesselTree, projection: Projection, *, step_mm: float = 0.25) -> np.ndarray:
    """The pixels of ``projection``'s image (its ``image_shape``) that the tree's tubes cover:
    within the projected radius of a centerline sample taken every ``step_mm`` (> 0) of arc
    length; boolean, shape ``projection.image_shape``."""
    if not step_mm > 0:
        raise ValueError(f"step_mm must be > 0, got {step_mm}")
    shape = tuple(int(n) for n in projection.image_shape)
    image = np.zeros(shape, dtype=bool)
    points, radii = _samples(tree, step_mm)
    if len(points) == 0:
        return image
    front = projection.in_front(points)
    points, radii = points[front], radii[front]
    uv = projection.project(points)
    rho = radii * max(projection.focal_lengths_px) / projection.depth_mm(points)
    compiled = kernels()
    if compiled is not None:  # the same pixels, sample by sample (no offset grids: a thick tube's are large)
        covers = np.zeros(shape, dtype=np.int32)
        compiled.add_disc_counts(np.ascontiguousarray(uv, dtype=np.float64), np.ascontiguousarray(rho, dtype=np.float64),
                                 np.ones(len(uv), dtype=np.int32), covers)
        return covers > 0
    pixels = image.reshape(-1)  # a view of the image
    for _, flat, _ in _disc_groups(uv, rho, shape):  # one offset grid per reach: (samples, offsets) at once
        pixels[flat] = True
    return image


def mask_agreement(tree: VesselTree, projections: Sequence[Projection], masks: Sequence[np.ndarray], *,
                   step_mm: float = 0.25) -> np.ndarray:
    """Per view, the Dice coefficient between its mask and the tree's :func:`tube_silhouette`
    (1 where both are empty)."""
    out = np.ones(len(projections))
    for k, (projection, mask) in enumerate(zip(projections, masks)):
        mask = np.asarray(mask, dtype=bool)
        drawn = tube_silhouette(tree, projection, step_mm=step_mm)
        total = int(mask.sum()) + int(drawn.sum())
        if total:
            out[k] = 2.0 * int((mask & drawn).sum()) / total
    return out


class Suspect(NamedTuple):
    """A piece of a tree whose pairing a hypothesis takes for wrong: the points ``first`` to
    ``end`` (exclusive) of branch ``branch``: a side branch whole, or a window of the root."""

    branch: int
    first: int
    end: int


def _root_windows(root: Branch, window_mm: float) -> list[tuple[int, int]]:
    """The root's windows ``window_mm`` long, each starting half a window after the last, the
    last ending at or past the root's end (a root shorter than a window: one window, all of it);
    (first, end) point indices."""
    arc = root.arc_length_mm
    starts = np.arange(0.0, max(float(arc[-1]) - window_mm, 0.0) + 1e-9, 0.5 * window_mm)
    return [(int(np.searchsorted(arc, s)), min(int(np.searchsorted(arc, s + window_mm)) + 1, len(arc)))
            for s in starts]


def suspect_pieces(tree: VesselTree, projections: Sequence[Projection], masks: Sequence[np.ndarray], count: int,
                   min_pixels: int = 5, *, root_window_mm: float = 0.0, step_mm: float = 0.25) -> list[Suspect]:
    """The pieces of the tree most likely paired wrongly across two views: the side branches and,
    with ``root_window_mm`` > 0, windows of the root that long (:func:`_root_windows`), ranked
    together by the unexplained mask pixels they touch; at most ``count`` of them, most first
    (ties: side branches first, in their order, then windows along the root). A window that
    touches none, or that overlaps one ranked before it by more than half its points, is no
    suspect. A view's unexplained pixels are those of its mask outside the tree's
    :func:`tube_silhouette`, in 8-connected pieces; a piece of the tree touches such a piece of at
    least ``min_pixels`` pixels where it reaches within two pixels (4-connected steps) of the
    tree piece's own silhouette; it scores the pixels of the pieces it touches, summed over the
    views. A vessel of one view paired with the wrong vessel of the other leaves the rest of that
    vessel, beyond the shorter of the two, unexplained beside it; where the root itself is paired
    wrongly over a stretch (the distal RCA of one view with the acute marginal of the other), a
    window of the root is the piece beside it."""
    if count <= 0:
        return []
    suspects = [Suspect(k, 0, tree.branches[k].n_points) for k in range(1, tree.n_branches)]
    if root_window_mm > 0:
        suspects += [Suspect(0, first, end) for first, end in _root_windows(tree.branches[0], root_window_mm)]
    if not suspects:
        return []
    alone = [VesselTree((Branch(b.points_mm, b.radius_mm, None, None, b.name),)) for b in tree.branches]
    root = tree.branches[0]
    windows = {k: VesselTree((Branch(root.points_mm[s.first:s.end], root.radius_mm[s.first:s.end],
                                     name="root window"),))
               for k, s in enumerate(suspects) if s.branch == 0}
    touched = np.zeros(len(suspects))
    for projection, mask in zip(projections, masks):
        # each branch's own silhouette; the tree's is their union (the same discs)
        own_silhouettes = [tube_silhouette(branch, projection, step_mm=step_mm) for branch in alone]
        drawn = own_silhouettes[0].copy()
        for own in own_silhouettes[1:]:
            drawn |= own
        unexplained = np.asarray(mask, dtype=bool) & ~drawn
        pieces, n = ndi.label(unexplained, structure=np.ones((3, 3), dtype=bool))
        if n == 0:
            continue
        size = np.bincount(pieces.ravel(), minlength=n + 1)
        size[0] = 0
        size[size < min_pixels] = 0
        for k, suspect in enumerate(suspects):
            own = (own_silhouettes[suspect.branch] if suspect.branch
                   else tube_silhouette(windows[k], projection, step_mm=step_mm))
            rows, cols = np.nonzero(own)
            if len(rows) == 0:
                continue
            # two dilation steps reach two pixels past the silhouette's box at most
            lo_r, lo_c = max(rows.min() - 2, 0), max(cols.min() - 2, 0)
            hi_r, hi_c = min(rows.max() + 3, own.shape[0]), min(cols.max() + 3, own.shape[1])
            near = ndi.binary_dilation(own[lo_r:hi_r, lo_c:hi_c], iterations=2)
            ids = np.unique(pieces[lo_r:hi_r, lo_c:hi_c][near])
            touched[k] += size[ids].sum()
    out: list[Suspect] = []
    for k in np.argsort(-touched, kind="stable"):
        if len(out) == count:
            break
        suspect = suspects[k]
        if suspect.branch == 0:
            if touched[k] <= 0:
                continue
            half = 0.5 * (suspect.end - suspect.first)
            if any(o.branch == 0 and min(suspect.end, o.end) - max(suspect.first, o.first) > half for o in out):
                continue
        out.append(suspect)
    return out
