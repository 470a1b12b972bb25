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
    tree = cKDTree(points)
    rank = np.arange(len(points)) if rank is None else np.asarray(rank)
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
