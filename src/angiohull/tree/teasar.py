"""Centerline paths through a binary volume (the TEASAR idea of Sato et al., 2000).

scikit-image's 3D thinning (Lee et al.) can delete whole pieces of a tubular object (measured here:
the thinned hull of a Y-shaped tube kept 98 voxels of the ~230 its axes need; scikit-image issue
#3757), and a skeleton with a hole where a vessel was cannot be repaired afterwards. Paths of a
shortest-path tree, in contrast, always reach every part of the volume they are asked to:

1. ``dbf`` (distance from boundary): the distance of every voxel of the volume to the nearest voxel
   outside it.
2. One shortest-path tree (Dijkstra) per connected part of the volume (26-neighbourhood), from the
   part's deepest voxel, with edge costs ``length / (mean dbf of the two voxels)**2``: deep
   voxels are cheap, so paths run along the middle of the vessels.
3. Repeatedly, the voxel farthest (in that cost) from the root among those not yet *covered* is a
   new target: its path back to the root, up to the first voxel already on the skeleton, joins the
   skeleton, and every voxel within ``ball_scale * dbf + ball_voxels`` of its nearest voxel of the
   new path becomes covered. The loop ends when every voxel is covered.

The result is a set of paths that reaches the end of every vessel (thinning stops short of them),
with no hole; small side paths where the surface bulges are possible and are the spur pruning's
business (:func:`angiohull.tree.skeleton.tree_from_skeleton`).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ..compiled import kernels
from ..errors import TreeError
from .voxels import coordinates, dilated, distance_to, path_cost_graph

__all__ = ["teasar_skeleton"]

def teasar_skeleton(volume: np.ndarray, *, ball_scale: float = 1.5, ball_voxels: float = 2.0,
                    dbf: np.ndarray | None = None, voxels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centerline paths of a 3D bool volume (module notes).

    Parameters
    ----------
    volume : (X, Y, Z) bool array
    ball_scale, ball_voxels : float, keyword-only
        A path covers the voxels within ``ball_scale * dbf + ball_voxels`` (voxels) of its voxels.
    dbf : (N,) float array, optional, keyword-only
        The distance from the boundary (voxels) of every voxel of the volume, in ``np.argwhere``
        order, when the caller has it (else computed: to the nearest outside voxel).
    voxels : (N, 3) int array, optional, keyword-only
        ``np.argwhere(volume)``, when the caller has it.

    Returns
    -------
    skeleton : (X, Y, Z) bool array
        The voxels of the paths.
    dbf : (N,) float array
        Distance (voxels) from each skeleton voxel, in ``np.argwhere(skeleton)`` order, to the
        nearest voxel outside the volume.
    """
    volume = np.asarray(volume, dtype=bool)
    if volume.ndim != 3:
        raise TreeError(f"volume must be a 3D bool array, got shape {volume.shape}")
    skeleton = np.zeros(volume.shape, dtype=bool)
    voxels = coordinates(volume) if voxels is None else np.asarray(voxels, dtype=np.int64)
    n = len(voxels)
    if n == 0:
        return skeleton, np.zeros(0)
    # 1. distance from the boundary: to the nearest outside voxel next to the volume (searched ring
    # by ring around each voxel: a fraction of a full distance transform of the box)
    if dbf is None:
        padded = np.pad(volume, 1)
        dbf = distance_to(dilated(padded) & ~padded, voxels + 1)
    else:
        dbf = np.asarray(dbf, dtype=np.float64)
        if dbf.shape != (n,) or not np.all(dbf > 0):
            raise TreeError(f"dbf must hold a distance > 0 for each of the volume's {n} voxels, got shape {dbf.shape}")

    # 2. the voxel graph and its shortest-path forest from each part's deepest voxel
    graph = path_cost_graph(voxels, volume.shape, dbf)
    parts, label = connected_components(graph, directed=False)
    by_part = np.lexsort((-dbf, label))  # each part's voxels, deepest first
    roots = by_part[np.flatnonzero(np.r_[True, np.diff(label[by_part]) != 0])]
    distance, predecessor, _ = dijkstra(graph, directed=False, indices=roots, min_only=True,
                                        return_predecessors=True)

    # 3. paths to the farthest uncovered voxel until every voxel is covered
    on_path = np.zeros(n, dtype=bool)
    on_path[roots] = True
    covered = np.zeros(n, dtype=bool)
    reach = ball_scale * dbf + ball_voxels

    cells: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def near(path: np.ndarray, todo: np.ndarray, largest: float) -> np.ndarray:
        """The voxels of ``todo`` that may lie within ``largest`` of a voxel of ``path``: those in
        the cells (of edge >= ``largest``) next to a cell that holds a voxel of the path."""
        edge = max(1, int(np.ceil(largest)))
        if edge not in cells:
            shape = np.asarray(volume.shape, dtype=np.int64) // edge + 3  # a cell of margin each side
            strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
            around = (np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)]) @ strides)
            cells[edge] = ((voxels // edge + 1) @ strides, around, shape)
        key, around, shape = cells[edge]
        marked = np.zeros(int(np.prod(shape)), dtype=bool)
        marked[(np.unique(key[path])[:, None] + around[None, :]).ravel()] = True
        return todo[marked[key[todo]]]

    compiled = kernels()

    def cover(path: np.ndarray, uncovered: np.ndarray) -> None:
        """Mark the voxels of ``uncovered`` within reach of a voxel of ``path`` (nearest path voxel
        decides, as the k-d tree gives it), and the path's own. The compiled kernel decides every
        voxel whose nearest path voxels all decide alike, clear of the reaches' bounds, by brute
        force; the k-d tree the rest."""
        largest = float(reach[path].max())
        todo = near(path, uncovered, largest)  # the others are out of reach
        if compiled is not None:
            status = compiled.teasar_cover_hits(voxels[path], reach[path], voxels[todo], largest)
            hit = status == 1
            ask = np.flatnonzero(status == 2)
        else:
            hit, ask = np.zeros(len(todo), dtype=bool), np.arange(len(todo))
        if len(ask):
            gap, nearest = cKDTree(voxels[path]).query(voxels[todo[ask]], distance_upper_bound=largest)
            found = np.isfinite(gap)
            found[found] = gap[found] <= reach[path][nearest[found]]
            hit[ask] = found
        covered[todo[hit]] = True
        covered[path] = True

    cover(roots, np.arange(n))
    uncovered = np.flatnonzero(~covered)
    while True:
        uncovered = uncovered[~covered[uncovered]]  # ascending, as np.flatnonzero(~covered)
        if len(uncovered) == 0:
            break
        target = int(uncovered[np.argmax(distance[uncovered])])
        path = [target]
        while not on_path[path[-1]]:
            step = predecessor[path[-1]]
            if step < 0:  # a root (always on the path)
                break
            path.append(step)
        path = np.array(path)
        on_path[path] = True
        cover(path, uncovered)
    chosen = np.flatnonzero(on_path)
    skeleton[tuple(voxels[chosen].T)] = True
    # np.argwhere order is the voxels' C order, as chosen (voxels came from np.argwhere too)
    return skeleton, dbf[chosen]
