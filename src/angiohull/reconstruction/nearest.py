"""Nearest neighbours with a stated tie rule.

A k-d tree returns one of several equally near points by the way it was built, and near ties by
the last bits of the arithmetic. Lattice points and their projections are often equally near, so
the steps that pick "the nearest" (the centerline step, the refined preset's radius check) pick by
:func:`nearest_with_ties`: of the points within ``tie`` of the nearest distance, the one of lowest
rank.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..compiled import kernels

__all__ = ["nearest_with_ties"]


def nearest_with_ties(points: np.ndarray, query: np.ndarray, tie: float, rank: np.ndarray | None = None, *,
                      k: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """The nearest of ``points`` to each query point, ties going to the lowest rank.

    Parameters
    ----------
    points : (N, D) array, N >= 1
    query : (M, D) array
    tie : float
        Points whose distances are within this of the nearest one's are equally near.
    rank : (N,) array, optional
        The order among equally near points (default: their index).
    k : int, keyword-only
        Neighbours asked for at once; a query with more equally near points than that asks again.

    Returns
    -------
    distance : (M,) array
        Distance to the nearest point.
    index : (M,) int array
        Index into ``points`` of the chosen point.
    """
    points, query = np.asarray(points), np.asarray(query)
    rank = np.arange(len(points)) if rank is None else np.asarray(rank)
    compiled = kernels()
    if compiled is not None and points.ndim == 2 and points.shape[1] == 2 and len(points) and len(query) \
            and np.isfinite(points).all() and np.isfinite(query).all():
        points = np.ascontiguousarray(points, dtype=np.float64)
        query = np.ascontiguousarray(query, dtype=np.float64)
        return compiled.nearest_2d_with_ties(points, query, float(tie), np.ascontiguousarray(rank, dtype=np.int64),
                                             _cell_edge(points, query))
    tree = cKDTree(points)
    k = min(k, len(points))
    distance, index = tree.query(query, k=k)
    if k == 1:
        return distance, index
    tied = distance <= distance[:, :1] + tie
    ranked = np.where(tied, rank[index], np.iinfo(np.int64).max)
    nearest = index[np.arange(len(index)), np.argmin(ranked, axis=1)]
    for i in np.flatnonzero(tied[:, -1]):  # more equally near points than k: ask for all of them
        equally_near = np.asarray(tree.query_ball_point(query[i], distance[i, 0] + tie))
        nearest[i] = equally_near[np.argmin(rank[equally_near])]
    return distance[:, 0], nearest


def _cell_edge(points: np.ndarray, query: np.ndarray) -> float:
    """Cell edge of the compiled search's grid over the box of the points and the queries: about
    two points per cell, and at most 2N + 1 cells along either side (N points)."""
    both = np.concatenate([points, query])
    extent = both.max(axis=0) - both.min(axis=0)
    longest = float(extent.max())
    edge = max(float(np.sqrt(2.0 * float(extent[0]) * float(extent[1]) / len(points))), longest / (2 * len(points)))
    return edge if edge > 0 else 1.0
