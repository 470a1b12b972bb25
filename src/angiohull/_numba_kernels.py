"""Compiled kernels (numba) for the hot loops; loaded only through :mod:`angiohull.compiled`.

Each kernel computes exactly what the NumPy code it stands in for computes (same operations in
the same order, no fast-math: IEEE results bit for bit), so the kept points, skeletons and chosen
neighbours do not depend on whether numba is installed. The NumPy code stays the reference; the
tests compare the two on every path.
"""

from __future__ import annotations

import numba
import numpy as np

_JIT = dict(cache=True, nogil=True)


# --- Guo-Hall thinning (angiohull.thinning) -------------------------------------------------------

@numba.njit(**_JIT)
def guo_hall_thin_flat(flat, frozen, width, tables):  # pragma: no cover - compiled
    """Thin the flattened image ``flat`` (uint8, 0/1, a background margin of one pixel all round,
    rows ``width`` long) in place, as :func:`angiohull.thinning._thin_stacked_numpy` does: each
    subiteration decides the pixels whose neighbourhood changed in the last two subiterations on
    the image as it was when the subiteration began, then deletes them; ``frozen`` pixels stay."""
    size = flat.size
    offsets = np.array([-width, -width + 1, 1, width + 1, width, width - 1, -1, -width - 1])
    stamp = np.zeros(size, np.int32)  # the subiteration that last listed a pixel
    first = np.empty(size, np.int64)
    n = 0
    for p in range(width, size - width):  # foreground with a background 4-neighbour
        if flat[p] and not frozen[p] and (flat[p - width] == 0 or flat[p + width] == 0
                                          or flat[p - 1] == 0 or flat[p + 1] == 0):
            first[n] = p
            n += 1
    older = first[:n].copy()
    newer = first[:n].copy()
    look = np.empty(2 * n + 1, np.int64)
    deleted = np.empty(2 * n + 1, np.int64)
    subiteration = 0
    changed_in_pass = 0
    step = 0
    while True:
        step += 1
        need = len(older) + len(newer) + 1
        if look.size < need:
            look = np.empty(need, np.int64)
            deleted = np.empty(need, np.int64)
        m = 0
        for p in older:
            if stamp[p] != step and flat[p] and not frozen[p]:
                stamp[p] = step
                look[m] = p
                m += 1
        for p in newer:
            if stamp[p] != step and flat[p] and not frozen[p]:
                stamp[p] = step
                look[m] = p
                m += 1
        n_deleted = 0
        for i in range(m):
            p = look[i]
            code = (flat[p - width] | (flat[p - width + 1] << 1) | (flat[p + 1] << 2) | (flat[p + width + 1] << 3)
                    | (flat[p + width] << 4) | (flat[p + width - 1] << 5) | (flat[p - 1] << 6)
                    | (flat[p - width - 1] << 7))  # p2 .. p9 (the image holds 0 / 1)
            if tables[subiteration, code]:
                deleted[n_deleted] = p
                n_deleted += 1
        for i in range(n_deleted):
            flat[deleted[i]] = 0
        changed_in_pass += n_deleted
        touched = np.empty(8 * n_deleted, np.int64)
        n_touched = 0
        for i in range(n_deleted):
            for bit in range(8):
                q = deleted[i] + offsets[bit]
                if flat[q]:
                    touched[n_touched] = q
                    n_touched += 1
        older = newer
        newer = touched[:n_touched]
        if subiteration == 1:
            if changed_in_pass == 0:
                break
            changed_in_pass = 0
        subiteration = 1 - subiteration


# --- carving (angiohull.reconstruction.hierarchical) ---------------------------------------------

@numba.njit(**_JIT)
def _fill_summed_area_table(mask, table):  # pragma: no cover - compiled
    """``table[r, c] = mask[:r, :c].sum()`` for a uint8 0/1 mask, into an int32 (rows + 1, cols + 1)
    array (masks under 2**31 pixels)."""
    rows, cols = mask.shape
    table[0, :] = 0
    for r in range(rows):
        table[r + 1, 0] = 0
        run = 0
        for c in range(cols):
            run += mask[r, c]
            table[r + 1, c + 1] = table[r, c + 1] + run


@numba.njit(inline="always", **_JIT)
def _box_may_be_kept(m, table, rows, cols, reach, x0, x1, y0, y1, z0, z1):  # pragma: no cover - compiled
    """:meth:`FootprintTest.may_keep` for one box (its corners' projections computed as
    ``project_row`` does)."""
    u_lo = np.inf
    u_hi = -np.inf
    v_lo = np.inf
    v_hi = -np.inf
    for corner in range(8):
        x = x1 if corner & 4 else x0
        y = y1 if corner & 2 else y0
        z = z1 if corner & 1 else z0
        w = x * m[2, 0] + y * m[2, 1] + z * m[2, 2] + m[2, 3]
        if not w > 0:
            return True  # reaches behind the source
        u = (x * m[0, 0] + y * m[0, 1] + z * m[0, 2] + m[0, 3]) / w
        v = (x * m[1, 0] + y * m[1, 1] + z * m[1, 2] + m[1, 3]) / w
        u_lo = min(u_lo, u)
        u_hi = max(u_hi, u)
        v_lo = min(v_lo, v)
        v_hi = max(v_hi, v)
    c0 = int(min(max(np.ceil(u_lo - reach), 0.0), cols))
    c1 = int(min(max(np.floor(u_hi + reach) + 1.0, 0.0), cols))
    r0 = int(min(max(np.ceil(v_lo - reach), 0.0), rows))
    r1 = int(min(max(np.floor(v_hi + reach) + 1.0, 0.0), rows))
    if c1 <= c0 or r1 <= r0:
        return False
    return table[r1, c1] - table[r0, c1] - table[r1, c0] + table[r0, c0] > 0


@numba.njit(inline="always", **_JIT)
def _cell_may_be_kept(axis, k, i, j, l, size, matrices, tables, shapes, reach):  # pragma: no cover
    for view in range(matrices.shape[0]):
        rows, cols = shapes[view, 0], shapes[view, 1]
        table = tables[view, :rows + 1, :cols + 1]
        if not _box_may_be_kept(matrices[view], table, rows, cols, reach,
                                axis[i], axis[min(i + size, k) - 1], axis[j], axis[min(j + size, k) - 1],
                                axis[l], axis[min(l + size, k) - 1]):
            return False
    return True


@numba.njit(**_JIT)
def carve_lattice(axis, root, leaf, matrices, masks, shapes, threshold, reach_px, footprint_reach,  # pragma: no cover
                  distances, band_slack):
    """The points of the lattice ``axis**3`` that every view keeps, in lattice order, as
    :func:`~angiohull.reconstruction.hierarchical.carve_hierarchical` finds them (views in the
    order given): cells of ``root**3`` points culled by their footprints, then their halves down to
    ``leaf**3``, then each point of a surviving leaf by :class:`MaskLookup`'s window test.

    ``masks`` (views, R, C) uint8 0/1, each view's own extent given by ``shapes`` (rows, cols; the
    rest zeros). ``distances`` (views, R, C): each mask's distance transform, for the wide
    thresholds where :class:`MaskLookup` decides by it first (within ``band_slack`` of the
    threshold, by the window); an empty array otherwise. Returns the kept points (n, 3) and the
    points alive after each view.
    """
    n_masks, most_rows, most_cols = masks.shape
    tables = np.empty((n_masks, most_rows + 1, most_cols + 1), np.int32)
    for view in range(n_masks):
        _fill_summed_area_table(masks[view], tables[view])
    k = axis.size
    n_views = matrices.shape[0]
    n_leaf = (k + leaf - 1) // leaf
    alive = np.zeros((n_leaf, n_leaf, n_leaf), np.bool_)
    # depth first through the cells: a cell that every view may keep is split in eight (halved
    # edges) until it is a leaf; the same leaves survive as level by level
    depth = 1
    while (root >> (depth - 1)) > leaf:
        depth += 1
    stack = np.empty((7 * depth + 1, 4), np.int64)
    for i in range(0, k, root):
        for j in range(0, k, root):
            for l in range(0, k, root):
                stack[0, 0] = i
                stack[0, 1] = j
                stack[0, 2] = l
                stack[0, 3] = root
                top = 1
                while top:
                    top -= 1
                    a, b, c, size = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
                    if not _cell_may_be_kept(axis, k, a, b, c, size, matrices, tables, shapes, footprint_reach):
                        continue
                    if size <= leaf:
                        alive[a // leaf, b // leaf, c // leaf] = True
                        continue
                    half = size // 2
                    for da in (half, 0):  # pushed in reverse: children popped in lattice order
                        for db in (half, 0):
                            for dc in (half, 0):
                                if a + da < k and b + db < k and c + dc < k:
                                    stack[top, 0] = a + da
                                    stack[top, 1] = b + db
                                    stack[top, 2] = c + dc
                                    stack[top, 3] = half
                                    top += 1
    # the surviving leaves of each column of cells along z, in z order
    first = np.zeros(n_leaf * n_leaf + 1, np.int64)
    for a in range(n_leaf):
        for b in range(n_leaf):
            first[a * n_leaf + b + 1] = first[a * n_leaf + b] + np.count_nonzero(alive[a, b])
    column = np.empty(first[-1], np.int64)
    for a in range(n_leaf):
        for b in range(n_leaf):
            column[first[a * n_leaf + b]:first[a * n_leaf + b + 1]] = np.flatnonzero(alive[a, b])
    survivors = np.zeros(n_views, np.int64)
    capacity = 1024
    kept = np.empty((capacity, 3), np.float64)
    n_kept = 0
    for i in range(k):  # lattice order: x, then y, then z
        x = axis[i]
        for j in range(k):
            y = axis[j]
            cells = (i // leaf) * n_leaf + j // leaf
            for cell in column[first[cells]:first[cells + 1]]:
                for l in range(cell * leaf, min(cell * leaf + leaf, k)):
                    z = axis[l]
                    keep = True
                    for view in range(n_views):
                        if not _near_mask(matrices[view], masks[view], shapes[view, 0], shapes[view, 1], threshold,
                                          reach_px, x, y, z, distances, view, band_slack):
                            keep = False
                            break
                        survivors[view] += 1
                    if keep:
                        if n_kept == capacity:
                            capacity *= 2
                            grown = np.empty((capacity, 3), np.float64)
                            grown[:n_kept] = kept[:n_kept]
                            kept = grown
                        kept[n_kept, 0] = x
                        kept[n_kept, 1] = y
                        kept[n_kept, 2] = z
                        n_kept += 1
    return kept[:n_kept].copy(), survivors


@numba.njit(inline="always", **_JIT)
def _near_mask(m, mask, rows, cols, threshold, reach, x, y, z, distances, view, band_slack):  # pragma: no cover
    """The point is in front of the source and a mask pixel centre lies strictly closer than the
    threshold to its projection (:meth:`MaskLookup.near_uv`, the same arithmetic: by the distance
    transform where it is given and clear of the threshold, else by reading the window)."""
    w = x * m[2, 0] + y * m[2, 1] + z * m[2, 2] + m[2, 3]
    if not w > 0:
        return False
    u = (x * m[0, 0] + y * m[0, 1] + z * m[0, 2] + m[0, 3]) / w
    v = (x * m[1, 0] + y * m[1, 1] + z * m[1, 2] + m[1, 3]) / w
    if distances.shape[0] > 0:
        ru = np.floor(u + 0.5)
        rv = np.floor(v + 0.5)
        if ru >= 0 and ru < cols and rv >= 0 and rv < rows:  # False for nan
            to_centre = np.sqrt((u - ru) ** 2 + (v - rv) ** 2)
            nearest = distances[view, int(rv), int(ru)]
            if nearest + to_centre < threshold - band_slack:
                return True
            if nearest - to_centre >= threshold + band_slack:
                return False
    if np.isnan(u):
        u = -1e9
    if np.isnan(v):
        v = -1e9
    fu = np.floor(min(max(u, -reach - 1.0), cols + reach))
    fv = np.floor(min(max(v, -reach - 1.0), rows + reach))
    row = int(fv)
    col = int(fu)
    inside = row + 1 - reach >= 0 and row + reach < rows and col + 1 - reach >= 0 and col + reach < cols
    for b in range(1 - reach, reach + 1):
        r = row + b
        if not inside and (r < 0 or r >= rows):
            continue
        for a in range(1 - reach, reach + 1):
            c = col + a
            if (inside or 0 <= c < cols) and mask[r, c]:
                du = u - (fu + a)
                dv = v - (fv + b)
                if np.sqrt(du * du + dv * dv) < threshold:
                    return True
    return False


# --- nearest with ties (angiohull.reconstruction.nearest) ----------------------------------------

@numba.njit(**_JIT)
def nearest_2d_with_ties(points, query, tie, rank, cell):  # pragma: no cover - compiled
    """For each query point, the distance to the nearest of ``points`` (N >= 1, finite, 2D) and,
    of the points within ``tie`` of that distance, the one of lowest ``rank`` (its index).

    The points are binned into square cells of edge ``cell``; a query searches rings of cells
    outward until no unsearched cell can hold a point within ``tie`` of the nearest found.
    Distances are ``sqrt(d0**2 + d1**2)`` as :class:`scipy.spatial.cKDTree` gives them."""
    n = points.shape[0]
    lo0 = points[0, 0]
    lo1 = points[0, 1]
    hi0 = lo0
    hi1 = lo1
    for p in range(n):
        lo0 = min(lo0, points[p, 0])
        hi0 = max(hi0, points[p, 0])
        lo1 = min(lo1, points[p, 1])
        hi1 = max(hi1, points[p, 1])
    n0 = int((hi0 - lo0) / cell) + 1
    n1 = int((hi1 - lo1) / cell) + 1
    start = np.zeros(n0 * n1 + 1, np.int64)
    where = np.empty(n, np.int64)
    for p in range(n):
        c = min(int((points[p, 0] - lo0) / cell), n0 - 1) * n1 + min(int((points[p, 1] - lo1) / cell), n1 - 1)
        where[p] = c
        start[c + 1] += 1
    for c in range(n0 * n1):
        start[c + 1] += start[c]
    order = np.empty(n, np.int64)
    fill = start[:-1].copy()
    for p in range(n):
        order[fill[where[p]]] = p
        fill[where[p]] += 1
    m = query.shape[0]
    distance = np.empty(m, np.float64)
    index = np.empty(m, np.int64)
    for q in range(m):
        a = query[q, 0]
        b = query[q, 1]
        # the query's cell (it may lie outside the grid) and the first ring that meets the grid
        qa = int(np.floor((a - lo0) / cell))
        qb = int(np.floor((b - lo1) / cell))
        first = max(max(0, -qa, qa - (n0 - 1)), max(0, -qb, qb - (n1 - 1)))
        last = max(max(qa, n0 - 1 - qa), max(qb, n1 - 1 - qb))
        best = np.inf
        for ring in range(first, last + 1):
            if (ring - 1) * cell > best + tie:
                break
            best, _ = _ring_scan(points, order, start, n0, n1, qa, qb, ring, a, b, False, best, 0.0, rank, -1)
        bound = best + tie
        chosen = -1
        for ring in range(first, last + 1):
            if (ring - 1) * cell > bound:
                break
            _, chosen = _ring_scan(points, order, start, n0, n1, qa, qb, ring, a, b, True, best, bound, rank, chosen)
        distance[q] = best
        index[q] = chosen
    return distance, index


@numba.njit(inline="always", **_JIT)
def _ring_scan(points, order, start, n0, n1, qa, qb, ring, a, b,  # pragma: no cover - compiled
               choosing, best, bound, rank, chosen):
    """The points of the cells at Chebyshev distance ``ring`` from cell (qa, qb), seen from (a, b):
    the least distance, or ``best`` if that is less; with ``choosing``, of the points within
    ``bound``, the one of lowest rank (or ``chosen`` if that ranks lower). Returns (best, chosen)."""
    for i in range(max(qa - ring, 0), min(qa + ring, n0 - 1) + 1):
        step = 1 if i == qa - ring or i == qa + ring else 2 * ring  # a whole row, or its two ends
        for j in range(qb - ring, qb + ring + 1, step):
            if j < 0 or j >= n1:
                continue
            c = i * n1 + j
            for s in range(start[c], start[c + 1]):
                p = order[s]
                d0 = points[p, 0] - a
                d1 = points[p, 1] - b
                d = np.sqrt(d0 * d0 + d1 * d1)
                if choosing:
                    if d <= bound and (chosen < 0 or rank[p] < rank[chosen]):
                        chosen = p
                elif d < best:
                    best = d
    return best, chosen


# --- distances to a 2D centreline (angiohull.reconstruction.centreline_fit) ----------------------

@numba.njit(**_JIT)
def centreline_distances(u, v, cutoff, floor_limit, use_floor, floor, candidate_row, candidate_u,
                         candidate_v):  # pragma: no cover - compiled
    """:meth:`Centreline.distances` for the points it measures itself: ``cutoff`` where a point is
    not finite or its nearest pixel's floor exceeds ``floor_limit`` (the cutoff as NumPy compares it
    with the single-precision floor), else the least distance to that pixel's candidates (rows of
    ``candidate_u``, ``candidate_v`` padded with inf at the end), at most ``cutoff``. Returns the
    distances and which points the caller must ask its k-d tree (off the image, or every point
    when ``use_floor`` is False)."""
    n = u.size
    rows, cols = floor.shape
    distance = np.full(n, cutoff)
    ask = np.zeros(n, np.bool_)
    for i in range(n):
        a = u[i]
        b = v[i]
        if not (np.isfinite(a) and np.isfinite(b)):
            continue
        iu = np.floor(a + 0.5)
        iv = np.floor(b + 0.5)
        if not use_floor or not (iu >= 0 and iu < cols and iv >= 0 and iv < rows):
            ask[i] = True
            continue
        r = int(iv)
        c = int(iu)
        if not floor[r, c] <= floor_limit:
            continue
        row = candidate_row[r, c]
        least = np.inf
        for k in range(candidate_u.shape[1]):
            cu = candidate_u[row, k]
            if cu == np.inf:
                break
            du = a - cu
            dv = b - candidate_v[row, k]
            least = min(least, du * du + dv * dv)
        distance[i] = min(np.sqrt(least), cutoff)
    return distance, ask
