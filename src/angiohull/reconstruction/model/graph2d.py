"""The 2D centerline graph of one view's mask: skeleton pixels, their chains and half-widths.

Notation: P skeleton pixels, E chains. A chain is an ordered run of skeleton pixels between two
*nodes* (pixels with one neighbour, the ends, or three or more, the junctions and the crossings of
vessels that overlap in the view); both end pixels belong to the chain.

1. The mask is thinned (Guo–Hall, :func:`angiohull.thinning.guo_hall_thin`).
2. Pixels are neighbours when 8-adjacent, except that a diagonal pair that also meets through a
   pixel 4-adjacent to both is not (so a staircase is a line, not a chain of junctions).
3. Chains are traced from every node; closed loops without a node are opened at one pixel.
4. End chains (one end a tip) shorter than ``spur_widths`` half-widths of the vessel where they
   leave it, plus ``spur_px``, are spurs of the thinning: they are removed and the graph traced
   again (``spur_rounds`` times).
5. Each pixel's half-width is the distance transform of the mask less half a pixel (the distance
   from a pixel centre to the nearest background pixel centre overshoots the edge by half a
   pixel), and its tangent the direction of the chain over ``tangent_px`` pixels either side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from ...thinning import guo_hall_thin

__all__ = ["CenterlineGraph2D", "centerline_graph"]

_OFFSETS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


@dataclass(frozen=True)
class CenterlineGraph2D:
    """A view's centerline graph (module notes). Pixel coordinates are ``(u, v)`` = (column, row)."""

    uv_px: np.ndarray  # (P, 2) skeleton pixel centres
    half_width_px: np.ndarray  # (P,) vessel half-width at each pixel
    tangent: np.ndarray  # (P, 2) unit direction of the chain through the pixel (sign arbitrary)
    chain_of: np.ndarray  # (P,) the chain a pixel belongs to (a node pixel: one of its chains)
    chains: tuple[np.ndarray, ...]  # E arrays of pixel indices, ordered along the chain
    degree: np.ndarray  # (P,) neighbours of each pixel in the graph
    neighbour_start: np.ndarray  # (P + 1,) the neighbours of pixel i are
    neighbour_index: np.ndarray  # neighbour_index[neighbour_start[i]:neighbour_start[i + 1]]

    @property
    def n_pixels(self) -> int:
        return len(self.uv_px)

    def neighbours(self, i: int) -> np.ndarray:
        return self.neighbour_index[self.neighbour_start[i]:self.neighbour_start[i + 1]]

    def spanning_forest(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """A breadth-first spanning forest of the pixel graph (cycles, where vessels cross or touch,
        are cut): ``(parent (P,), -1 at each root; levels: pixel indices by depth, roots first)``."""
        parent = np.full(self.n_pixels, -2, dtype=np.int64)
        levels: list[np.ndarray] = []
        for root in np.argsort(-self.half_width_px, kind="stable"):
            if parent[root] != -2:
                continue
            parent[root] = -1
            frontier = np.array([root], dtype=np.int64)
            depth = 0
            while len(frontier):
                if depth >= len(levels):
                    levels.append(frontier)
                else:
                    levels[depth] = np.concatenate([levels[depth], frontier])
                nxt = []
                for i in frontier:
                    for j in self.neighbours(int(i)):
                        if parent[j] == -2:
                            parent[j] = i
                            nxt.append(j)
                frontier = np.array(nxt, dtype=np.int64)
                depth += 1
        return parent, levels

    def chain_length_px(self, e: int) -> float:
        uv = self.uv_px[self.chains[e]]
        return float(np.linalg.norm(np.diff(uv, axis=0), axis=1).sum())


def _neighbours(skeleton: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Pixel coordinates (row, col) of the skeleton and each pixel's neighbour list (module notes, 2)."""
    rows, cols = np.nonzero(skeleton)
    index = np.full(skeleton.shape, -1, dtype=np.int64)
    index[rows, cols] = np.arange(len(rows))
    padded = np.pad(index, 1, constant_values=-1)
    heads, tails = [], []
    for dr, dc in _OFFSETS:
        other = padded[rows + 1 + dr, cols + 1 + dc]
        keep = other >= 0
        if dr != 0 and dc != 0:
            # a diagonal step that a 4-path of two steps also makes is left to that path
            keep &= (padded[rows + 1 + dr, cols + 1] < 0) & (padded[rows + 1, cols + 1 + dc] < 0)
        heads.append(np.flatnonzero(keep))
        tails.append(other[keep])
    heads, tails = np.concatenate(heads), np.concatenate(tails)
    order = np.argsort(heads, kind="stable")
    heads, tails = heads[order], tails[order]
    bounds = np.searchsorted(heads, np.arange(len(rows) + 1))
    return np.column_stack([rows, cols]), [tails[bounds[i]:bounds[i + 1]] for i in range(len(rows))]


def _trace(neighbours: list[np.ndarray]) -> list[list[int]]:
    degree = np.array([len(n) for n in neighbours])
    chains: list[list[int]] = []
    used: set[tuple[int, int]] = set()
    visited = np.zeros(len(neighbours), dtype=bool)
    for start in np.flatnonzero(degree != 2):
        visited[start] = True
        for first in neighbours[start]:
            if (start, int(first)) in used:
                continue
            chain = [int(start), int(first)]
            used.add((int(start), int(first)))
            previous, current = int(start), int(first)
            while degree[current] == 2:
                visited[current] = True
                a, b = neighbours[current]
                nxt = int(b) if a == previous else int(a)
                previous, current = current, nxt
                chain.append(current)
                if current == start:
                    break
            visited[current] = True
            used.add((current, previous))
            chains.append(chain)
    # closed loops with no node: open each at its first pixel
    for start in np.flatnonzero(~visited & (degree == 2)):
        if visited[start]:
            continue
        chain = [int(start)]
        visited[start] = True
        previous, current = int(start), int(neighbours[start][0])
        while not visited[current]:
            visited[current] = True
            chain.append(current)
            a, b = neighbours[current]
            nxt = int(b) if a == previous else int(a)
            previous, current = current, nxt
        chain.append(int(start))
        chains.append(chain)
    return chains


def _spurs(chains: list[list[int]], degree: np.ndarray, rc: np.ndarray, half_width: np.ndarray,
           widths: float, extra_px: float) -> np.ndarray:
    """Pixels of the spur chains (module notes, 4), their junction pixel excluded."""
    drop: list[int] = []
    for chain in chains:
        a, b = chain[0], chain[-1]
        ends = int(degree[a] == 1) + int(degree[b] == 1)
        if ends != 1:
            continue
        junction = a if degree[a] != 1 else b
        length = np.linalg.norm(np.diff(rc[chain], axis=0), axis=1).sum()
        if length < widths * half_width[junction] + extra_px:
            drop.extend(c for c in chain if c != junction)
    return np.array(drop, dtype=np.int64)


def centerline_graph(mask: np.ndarray, *, spur_widths: float = 1.5, spur_px: float = 2.0, spur_rounds: int = 2,
                     tangent_px: int = 3) -> CenterlineGraph2D:
    """The centerline graph of a binary mask (module notes).

    Parameters
    ----------
    mask : (rows, cols) array
        Nonzero = vessel.
    spur_widths, spur_px : float
        An end chain shorter than ``spur_widths`` half-widths plus ``spur_px`` is a spur.
    spur_rounds : int
        Rounds of spur removal.
    tangent_px : int
        Half-window of the tangents along a chain, pixels.
    """
    mask = np.asarray(mask, dtype=bool)
    skeleton = guo_hall_thin(mask).astype(bool)
    distance = ndi.distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    for _ in range(spur_rounds + 1):
        rc, neighbours = _neighbours(skeleton)
        degree = np.array([len(n) for n in neighbours], dtype=np.int64)
        half_width = np.maximum(distance[rc[:, 0], rc[:, 1]] - 0.5, 0.5)
        chains = _trace(neighbours)
        drop = _spurs(chains, degree, rc, half_width, spur_widths, spur_px)
        if len(drop) == 0:
            break
        skeleton = skeleton.copy()
        skeleton[rc[drop, 0], rc[drop, 1]] = False
    isolated = degree == 0
    uv = rc[:, ::-1].astype(np.float64)
    chain_of = np.full(len(rc), -1, dtype=np.int64)
    tangent = np.zeros((len(rc), 2))
    arrays = []
    for e, chain in enumerate(chains):
        c = np.asarray(chain, dtype=np.int64)
        arrays.append(c)
        free = chain_of[c] < 0
        chain_of[c[free]] = e
        points = uv[c]
        k = np.arange(len(c))
        ahead = points[np.minimum(k + tangent_px, len(c) - 1)] - points[np.maximum(k - tangent_px, 0)]
        norm = np.linalg.norm(ahead, axis=1, keepdims=True)
        t = np.where(norm > 0, ahead / np.maximum(norm, 1e-12), 0.0)
        tangent[c[free]] = t[free]
    if isolated.any():  # single pixels: a chain each
        for p in np.flatnonzero(isolated):
            chain_of[p] = len(arrays)
            arrays.append(np.array([p], dtype=np.int64))
    start = np.concatenate([[0], np.cumsum(degree)]).astype(np.int64)
    flat = np.concatenate(neighbours).astype(np.int64) if len(neighbours) else np.zeros(0, dtype=np.int64)
    return CenterlineGraph2D(uv_px=uv, half_width_px=half_width, tangent=tangent, chain_of=chain_of,
                             chains=tuple(arrays), degree=degree,
                             neighbour_start=start, neighbour_index=flat)
