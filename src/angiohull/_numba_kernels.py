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
def _cell_buckets(xy, lo0, lo1, cell, n0, n1):  # pragma: no cover - compiled
    """The 2D points ``xy`` binned into the ``n0`` x ``n1`` square cells of edge ``cell`` from
    (``lo0``, ``lo1``): each point's cell (``where``), and the points of cell ``c`` as
    ``order[start[c]:start[c + 1]]``, in their index order (a counting sort)."""
    n = xy.shape[0]
    where = np.empty(n, np.int64)
    start = np.zeros(n0 * n1 + 1, np.int64)
    for p in range(n):
        c = min(int((xy[p, 0] - lo0) / cell), n0 - 1) * n1 + min(int((xy[p, 1] - lo1) / cell), n1 - 1)
        where[p] = c
        start[c + 1] += 1
    for c in range(n0 * n1):
        start[c + 1] += start[c]
    order = np.empty(n, np.int64)
    fill = start[:-1].copy()
    for p in range(n):
        order[fill[where[p]]] = p
        fill[where[p]] += 1
    return where, start, order


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
    where, start, order = _cell_buckets(points, lo0, lo1, cell, n0, n1)
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


# --- the refined preset (angiohull.reconstruction.refine) -----------------------------------------

@numba.njit(**_JIT)
def nearest_lattice_axis(axis_ijk, axis_mm, query_ijk, query_mm, spacing_cells, largest_length,
                         reach_squared):  # pragma: no cover - compiled
    """:func:`angiohull.reconstruction.refine._nearest_axis` where the nearest axis point lies
    within ``largest_length`` (a squared lattice distance, the NumPy code's shell table): the
    axis points at the least squared lattice distance (whole numbers, compared exactly) are the
    equally near ones; the index is the lowest of them, the distance the least of
    ``sqrt(d0 * d0 + d1 * d1 + d2 * d2)`` (mm, summed in that order, as
    :class:`scipy.spatial.cKDTree` computes it) over them. The axis points are binned on cubes of
    ``spacing_cells`` lattice spacings; a query reads the cubes around its own, ring by ring, until
    no unread cube can hold a point as near as the nearest found. Returns (distance, index,
    settled): ``settled`` is False where this cannot tell (the nearest beyond ``largest_length``,
    or a squared distance within a part in 1e9 of ``reach_squared``, the k-d tree's strict
    bound): the caller asks the NumPy code there. Queries settled with no axis point within reach
    get distance inf and index 0."""
    c = spacing_cells
    n_axis = axis_ijk.shape[0]
    n_query = query_ijk.shape[0]
    distance = np.full(n_query, np.inf)
    index = np.zeros(n_query, np.int64)
    settled = np.zeros(n_query, np.bool_)
    if n_axis == 0:
        return distance, index, settled
    low0 = min(axis_ijk[:, 0].min(), query_ijk[:, 0].min())
    low1 = min(axis_ijk[:, 1].min(), query_ijk[:, 1].min())
    low2 = min(axis_ijk[:, 2].min(), query_ijk[:, 2].min())
    n0 = (max(axis_ijk[:, 0].max(), query_ijk[:, 0].max()) - low0) // c + 1
    n1 = (max(axis_ijk[:, 1].max(), query_ijk[:, 1].max()) - low1) // c + 1
    n2 = (max(axis_ijk[:, 2].max(), query_ijk[:, 2].max()) - low2) // c + 1
    start = np.zeros(n0 * n1 * n2 + 1, np.int64)
    cell_of = np.empty(n_axis, np.int64)
    for a in range(n_axis):
        k = ((axis_ijk[a, 0] - low0) // c * n1 + (axis_ijk[a, 1] - low1) // c) * n2 + (axis_ijk[a, 2] - low2) // c
        cell_of[a] = k
        start[k + 1] += 1
    for k in range(n0 * n1 * n2):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    member = np.empty(n_axis, np.int64)  # axis indices by cube, increasing within each
    for a in range(n_axis):
        member[fill[cell_of[a]]] = a
        fill[cell_of[a]] += 1
    for q in range(n_query):
        x = query_ijk[q, 0]
        y = query_ijk[q, 1]
        z = query_ijk[q, 2]
        i = (x - low0) // c
        j = (y - low1) // c
        k = (z - low2) // c
        best = np.int64(-1)
        lowest = np.int64(-1)
        least = np.inf
        ring = 0
        while True:
            for ii in range(max(i - ring, 0), min(i + ring, n0 - 1) + 1):
                for jj in range(max(j - ring, 0), min(j + ring, n1 - 1) + 1):
                    edge = ii == i - ring or ii == i + ring or jj == j - ring or jj == j + ring
                    kk = max(k - ring, 0)
                    while kk <= min(k + ring, n2 - 1):
                        cube = (ii * n1 + jj) * n2 + kk
                        for s in range(start[cube], start[cube + 1]):
                            a = member[s]
                            dx = x - axis_ijk[a, 0]
                            dy = y - axis_ijk[a, 1]
                            dz = z - axis_ijk[a, 2]
                            n = dx * dx + dy * dy + dz * dz
                            if best < 0 or n <= best:
                                d0 = query_mm[q, 0] - axis_mm[a, 0]
                                d1 = query_mm[q, 1] - axis_mm[a, 1]
                                d2 = query_mm[q, 2] - axis_mm[a, 2]
                                squared = 0.0
                                squared += d0 * d0
                                squared += d1 * d1
                                squared += d2 * d2
                                if best < 0 or n < best:
                                    best = n
                                    least = squared
                                    lowest = a
                                else:
                                    least = min(least, squared)
                                    lowest = min(lowest, a)
                        if edge or kk == k + ring:
                            kk += 1
                        else:  # inside the ring's cube of cubes: only its two ends along the last axis
                            kk = k + ring
            # every unread point is at least `margin` lattice spacings away along some axis
            margin = min(min(x - (low0 + (i - ring) * c) + 1, low0 + (i + ring + 1) * c - x),
                         min(min(y - (low1 + (j - ring) * c) + 1, low1 + (j + ring + 1) * c - y),
                             min(z - (low2 + (k - ring) * c) + 1, low2 + (k + ring + 1) * c - z)))
            if best >= 0 and best < margin * margin:
                break
            if best > largest_length and margin * margin > largest_length:
                best = -2  # the nearest is beyond the table
                break
            if best < 0 and margin * margin > largest_length:
                best = -2
                break
            ring += 1
        if best < 0:
            continue
        if abs(least - reach_squared) > 1e-9 * reach_squared:
            settled[q] = True
            if least < reach_squared:
                distance[q] = np.sqrt(least)
                index[q] = lowest
    return distance, index, settled


_STEP_REACH = 24  # steps of at most this many lattice spacings on every axis have their samples listed once


@numba.njit(**_JIT)
def _step_samples(dx, dy, dz, s0, s1):  # pragma: no cover - compiled
    """The lattice points the segment from a lattice point by the step (dx, dy, dz) passes, as
    :func:`angiohull.reconstruction.refine._gaps` samples it (every half spacing, each sample
    rounded to its nearest lattice point, halves to even): flat offsets (strides s0, s1, 1) from the
    start, without repeats of the previous sample and without the two ends."""
    fx = np.float64(dx)
    fy = np.float64(dy)
    fz = np.float64(dz)
    steps = max(np.int64(np.ceil(2.0 * np.sqrt(fx * fx + fy * fy + fz * fz))), 1)
    end = dx * s0 + dy * s1 + dz
    out = np.empty(max(steps - 1, 0), np.int64)
    n = 0
    previous = np.int64(0)
    for k in range(1, steps):
        fraction = k / steps
        f = np.int64(np.rint(fx * fraction)) * s0 + np.int64(np.rint(fy * fraction)) * s1 \
            + np.int64(np.rint(fz * fraction))
        if f != previous and f != 0 and f != end:
            out[n] = f
            n += 1
        previous = f
    return out[:n]


@numba.njit(inline="always", **_JIT)
def _first_at_least(values, low, high, x):  # pragma: no cover - compiled
    """The first index in low..high of the sorted ``values`` whose value is at least ``x`` (high if
    none)."""
    while low < high:
        middle = (low + high) >> 1
        if values[middle] < x:
            low = middle + 1
        else:
            high = middle
    return low


@numba.njit(**_JIT)
def rival_pairs(axis_uv, reach_px, axis_piece, tube_uv, tube_piece, axis_local, tube_local, hull,
                shape):  # pragma: no cover - compiled
    """:func:`angiohull.reconstruction.refine._rivals`: the pairs (axis point, piece) such that a tube
    point of that other piece projects within the axis point's reach (``du * du + dv * dv`` within
    the largest reach squared and its square root within the point's reach, as the NumPy code
    compares) and the segment between their lattice points (``*_local``, indices into the flat
    C-order volume ``hull`` of ``shape``) leaves the hull. Ordered by axis point, then piece; per
    pair the tube points are tried farthest first, up to the first that is across a gap."""
    n_tube = tube_uv.shape[0]
    if n_tube == 0 or axis_uv.shape[0] == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    largest = reach_px.max()
    limit = largest * largest
    # the tube points in rows of height half the largest reach, sorted by u within each row: an axis
    # point reads, in each row within reach, the stretch of u within reach (a hair wider, so that
    # rounding cannot leave out a point that the exact test below keeps)
    wide = largest * (1.0 + 1e-6)
    height = 0.5 * wide
    low_v = min(axis_uv[:, 1].min(), tube_uv[:, 1].min())
    high_v = max(axis_uv[:, 1].max(), tube_uv[:, 1].max())
    n_rows = np.int64(np.floor((high_v - low_v) / height)) + 1
    row_of = np.empty(n_tube, np.int64)
    row_start = np.zeros(n_rows + 1, np.int64)
    for t in range(n_tube):
        r = min(np.int64(np.floor((tube_uv[t, 1] - low_v) / height)), n_rows - 1)
        row_of[t] = r
        row_start[r + 1] += 1
    for r in range(n_rows):
        row_start[r + 1] += row_start[r]
    fill = row_start[:-1].copy()
    by_row = np.empty(n_tube, np.int64)
    for t in range(n_tube):
        by_row[fill[row_of[t]]] = t
        fill[row_of[t]] += 1
    for r in range(n_rows):  # by u within the row
        stretch = by_row[row_start[r]:row_start[r + 1]]
        by_row[row_start[r]:row_start[r + 1]] = stretch[np.argsort(tube_uv[stretch, 0])]
    sorted_u = tube_uv[by_row, 0].copy()
    sorted_v = tube_uv[by_row, 1].copy()
    sorted_piece = tube_piece[by_row].copy()
    s0 = shape[1] * shape[2]
    s1 = shape[2]
    n_distance = 3 * (shape[0] * shape[0] + shape[1] * shape[1] + shape[2] * shape[2]) + 1
    out_axis = np.empty(1024, np.int64)
    out_piece = np.empty(1024, np.int64)
    n_out = 0
    candidate = np.empty(64, np.int64)
    order_key = np.empty(64, np.int64)
    span = 2 * _STEP_REACH + 1
    slot = np.full(span * span * span, -1, np.int32)  # a step's row of slot_start, or -1
    slot_start = np.empty(1025, np.int64)
    slot_start[0] = 0
    n_slots = 0
    table = np.empty(4096, np.int64)
    n_table = 0
    for a in range(axis_uv.shape[0]):
        u = axis_uv[a, 0]
        v = axis_uv[a, 1]
        own = axis_piece[a]
        ax = axis_local[a, 0]
        ay = axis_local[a, 1]
        az = axis_local[a, 2]
        m = 0
        first_row = max(np.int64(np.floor((v - wide - low_v) / height)), 0)
        last_row = min(np.int64(np.floor((v + wide - low_v) / height)), n_rows - 1)
        for r in range(first_row, last_row + 1):
            gap = max(low_v + r * height - v, v - (low_v + (r + 1) * height), 0.0)
            half = np.sqrt(max(wide * wide - gap * gap, 0.0)) * (1.0 + 1e-6) + 1e-9 * wide
            first = _first_at_least(sorted_u, row_start[r], row_start[r + 1], u - half)
            last = _first_at_least(sorted_u, first, row_start[r + 1], u + half)
            for s in range(first, last):
                if sorted_piece[s] == own:
                    continue
                du = u - sorted_u[s]
                dv = v - sorted_v[s]
                squared = du * du
                squared += dv * dv
                if not (squared <= limit and np.sqrt(squared) <= reach_px[a]):
                    continue
                if m == candidate.size:
                    candidate = np.concatenate((candidate, np.empty(m, np.int64)))
                    order_key = np.concatenate((order_key, np.empty(m, np.int64)))
                t = by_row[s]
                dx = tube_local[t, 0] - ax
                dy = tube_local[t, 1] - ay
                dz = tube_local[t, 2] - az
                candidate[m] = t
                order_key[m] = sorted_piece[s] * n_distance + (n_distance - 1 - (dx * dx + dy * dy + dz * dz))
                m += 1
        if m == 0:
            continue
        if m <= 48:  # few: sorted in place (no allocation)
            for i in range(1, m):
                key = order_key[i]
                t = candidate[i]
                j = i - 1
                while j >= 0 and order_key[j] > key:
                    order_key[j + 1] = order_key[j]
                    candidate[j + 1] = candidate[j]
                    j -= 1
                order_key[j + 1] = key
                candidate[j + 1] = t
        else:
            order = np.argsort(order_key[:m])
            candidate[:m] = candidate[:m][order]
        start = ax * s0 + ay * s1 + az
        done_piece = -1
        for i in range(m):
            t = candidate[i]
            piece = tube_piece[t]
            if piece == done_piece:
                continue
            dx = tube_local[t, 0] - ax
            dy = tube_local[t, 1] - ay
            dz = tube_local[t, 2] - az
            # the step's samples, listed once per step (the segments between rivals run along
            # viewing rays: few distinct steps) where the step is short enough for the index
            if abs(dx) <= _STEP_REACH and abs(dy) <= _STEP_REACH and abs(dz) <= _STEP_REACH:
                code = ((dx + _STEP_REACH) * span + dy + _STEP_REACH) * span + dz + _STEP_REACH
                if slot[code] < 0:
                    samples = _step_samples(dx, dy, dz, s0, s1)
                    if n_table + samples.size > table.size:
                        table = np.concatenate((table, np.empty(max(table.size, samples.size), np.int64)))
                    table[n_table:n_table + samples.size] = samples
                    slot[code] = n_slots
                    slot_start[n_slots] = n_table
                    n_table += samples.size
                    slot_start[n_slots + 1] = n_table
                    n_slots += 1
                    if n_slots + 1 == slot_start.size:
                        slot_start = np.concatenate((slot_start, np.empty(slot_start.size, np.int64)))
                first = slot_start[slot[code]]
                last = slot_start[slot[code] + 1]
                samples = table[first:last]
            else:
                samples = _step_samples(dx, dy, dz, s0, s1)
            leaves = False
            for k in range(samples.size):
                if not hull[start + samples[k]]:
                    leaves = True
                    break
            if leaves:
                done_piece = piece
                if n_out == out_axis.size:
                    out_axis = np.concatenate((out_axis, np.empty(n_out, np.int64)))
                    out_piece = np.concatenate((out_piece, np.empty(n_out, np.int64)))
                out_axis[n_out] = a
                out_piece[n_out] = piece
                n_out += 1
    return out_axis[:n_out].copy(), out_piece[:n_out].copy()


# --- calibration (angiohull.reconstruction.calibration) -------------------------------------------

@numba.njit(**_JIT)
def dilate_by_offsets(image, offsets):  # pragma: no cover - compiled
    """``image`` (bool, 2D) dilated by the footprint whose (dy, dx) offsets from its centre are the
    rows of ``offsets``, nothing beyond the border: each set pixel sets the pixels at its offsets,
    as :func:`angiohull.reconstruction.calibration._dilated`'s shifted ORs do."""
    rows, cols = image.shape
    out = image.copy()
    for r in range(rows):
        for c in range(cols):
            if image[r, c]:
                for k in range(offsets.shape[0]):
                    rr = r + offsets[k, 0]
                    cc = c + offsets[k, 1]
                    if rr >= 0 and rr < rows and cc >= 0 and cc < cols:
                        out[rr, cc] = True
    return out


# --- the tree method (angiohull.reconstruction.model.tubes) ---------------------------------------

@numba.njit(**_JIT)
def balls_on_lattice(centres, radii, margin, axis, half, h, lo, shape):  # pragma: no cover - compiled
    """The lattice points (of coordinates ``axis`` on every axis, spacing ``h``, half edge ``half``)
    within ``radii + margin`` of any ball centre, as a bool volume of ``shape`` from lattice index
    ``lo``: per ball and lattice column (i, j) near it, the run of z indices that
    :func:`angiohull.reconstruction.model.tubes.lattice_points_in_tubes` finds (the same estimate
    from the square root, moved twice by the same exact tests)."""
    k = axis.size
    # each (ball, column) run marked at its two ends, the runs' union summed along z after: one
    # write per run instead of one per point (a thick tube's balls overlap nearly whole)
    marks = np.zeros((shape[0], shape[1], shape[2] + 1), np.int32)
    for b in range(centres.shape[0]):
        cx = centres[b, 0]
        cy = centres[b, 1]
        z = centres[b, 2]
        grow = radii[b] + margin
        cells = np.int64(np.ceil(grow / h)) + 1
        base_i = np.int64(np.floor((cx + half) / h))
        base_j = np.int64(np.floor((cy + half) / h))
        square = grow ** 2
        # (the box ``lo``, ``shape`` holds every ball's reach; the ranges stay within it regardless)
        for i in range(max(base_i - cells, 0, lo[0]), min(base_i + cells + 1, k - 1, lo[0] + shape[0] - 1) + 1):
            dx = axis[i] - cx
            for j in range(max(base_j - cells, 0, lo[1]), min(base_j + cells + 1, k - 1, lo[1] + shape[1] - 1) + 1):
                dy = axis[j] - cy
                rem = square - dx * dx - dy * dy
                if not rem >= 0:
                    continue
                span = np.sqrt(rem)
                k_lo = min(max(np.int64(np.ceil((z - span + half) / h - 1e-9)), 0), k - 1)
                k_hi = min(max(np.int64(np.floor((z + span + half) / h + 1e-9)), 0), k - 1)
                for _ in range(2):
                    if k_lo > 0 and (axis[k_lo - 1] - z) ** 2 <= rem:
                        k_lo -= 1
                    if (axis[min(k_lo, k - 1)] - z) ** 2 > rem:
                        k_lo += 1
                    if k_hi < k - 1 and (axis[k_hi + 1] - z) ** 2 <= rem:
                        k_hi += 1
                    if (axis[max(k_hi, 0)] - z) ** 2 > rem:
                        k_hi -= 1
                first = max(k_lo, lo[2])
                last = min(k_hi, lo[2] + shape[2] - 1)
                if first <= last:
                    marks[i - lo[0], j - lo[1], first - lo[2]] += 1
                    marks[i - lo[0], j - lo[1], last + 1 - lo[2]] -= 1
    volume = np.zeros((shape[0], shape[1], shape[2]), np.bool_)
    for i in range(shape[0]):
        for j in range(shape[1]):
            count = 0
            for kk in range(shape[2]):
                count += marks[i, j, kk]
                volume[i, j, kk] = count > 0
    return volume


# --- the tree method's silhouettes (angiohull.reconstruction.model.agreement) ----------------------

@numba.njit(**_JIT)
def add_disc_counts(uv, rho, sign, counts):  # pragma: no cover - compiled
    """Add ``sign[s]`` to ``counts`` (a 2D int array, the image's shape) at each pixel of the disc
    of every sample ``s`` as :func:`angiohull.reconstruction.model.agreement._disc_groups` finds
    them: the pixel centres (integer u, v) of the square of half-edge ``ceil(rho[s])`` around the
    rounded centre ``uv[s]``, inside the image, whose squared distance to the centre is at most
    ``rho[s]`` squared (the same test); a pixel two discs cover counted twice (as
    :func:`angiohull.reconstruction.model.agreement._disc_pixels` lists it twice)."""
    rows = counts.shape[0]
    cols = counts.shape[1]
    for s in range(uv.shape[0]):
        u = uv[s, 0]
        v = uv[s, 1]
        r = rho[s]
        reach = np.int64(np.ceil(r))
        ru = np.int64(np.rint(u))
        rv = np.int64(np.rint(v))
        bound = r ** 2
        for cv in range(max(rv - reach, 0), min(rv + reach, rows - 1) + 1):
            dv2 = (cv - v) ** 2
            for cu in range(max(ru - reach, 0), min(ru + reach, cols - 1) + 1):
                if (cu - u) ** 2 + dv2 <= bound:
                    counts[cv, cu] += sign[s]


# --- the tree method's junctions (angiohull.reconstruction.vessel_tree) ---------------------------

@numba.njit(**_JIT)
def _grid_span(c, reach, lo, stride, n):  # pragma: no cover - compiled
    """The first and last index ``k`` (0 <= k < n) of the grid ``lo + stride * k`` that may lie
    within ``reach`` of ``c``: one index more on either side than the division says (the distance
    test decides); ``(0, -1)`` where none."""
    x0 = np.floor((c - reach - lo) / stride) - 1.0
    x1 = np.floor((c + reach - lo) / stride) + 1.0
    if not (x0 <= n - 1 and x1 >= 0):  # (also a nan centre)
        return 0, -1
    return max(np.int64(x0), 0), min(np.int64(x1), n - 1)


@numba.njit(**_JIT)
def _mark_grid_discs(centres, radii, column, lo_u, lo_v, stride, n_u, n_v, gate, out):  # pragma: no cover - compiled
    """Set ``out[p, column[k]]`` for each pixel ``p`` (``b * n_u + a``) of the grid ``(lo_u + stride
    * a, lo_v + stride * b)`` with ``gate[p]`` that lies in disc ``k`` (centres (K, 2) u, v; radii
    (K,)) as scipy's k-d tree pairs them (``sparse_distance_matrix`` up to the largest radius, then
    the disc's own): the squared distance ``du * du + dv * dv`` (pixel minus centre) at most the
    largest radius squared, and its square root at most the disc's radius."""
    if centres.shape[0] == 0:
        return
    reach = radii.max()
    bound = reach * reach
    for k in range(centres.shape[0]):
        cu = centres[k, 0]
        cv = centres[k, 1]
        a0, a1 = _grid_span(cu, reach, lo_u, stride, n_u)
        b0, b1 = _grid_span(cv, reach, lo_v, stride, n_v)
        for b in range(b0, b1 + 1):
            dv = np.float64(lo_v + stride * b) - cv
            for a in range(a0, a1 + 1):
                p = b * n_u + a
                if gate[p]:
                    du = np.float64(lo_u + stride * a) - cu
                    d = du * du + dv * dv
                    if d <= bound and np.sqrt(d) <= radii[k]:
                        out[p, column[k]] = True


@numba.njit(**_JIT)
def tube_wrong_pixels(image, lo_u, lo_v, n_u, n_v, stride, uv, radius_px, owner, n_candidates, others_uv,
                      others_px):  # pragma: no cover - compiled
    """Per candidate, the pixels of the grid ``(lo_u + stride * a, lo_v + stride * b)`` (``a <
    n_u``, ``b < n_v``) that some candidate's disc covers and where the candidate's discs with the
    discs ``others_uv`` disagree with ``image`` (>= 0.5 inside), as
    :func:`angiohull.reconstruction.vessel_tree._wrong_pixels` counts them; a pixel lies in a disc
    where :func:`_mark_grid_discs` says so."""
    size = n_u * n_v
    covers = np.zeros((size, n_candidates), np.bool_)
    _mark_grid_discs(uv, radius_px, owner, lo_u, lo_v, stride, n_u, n_v, np.ones(size, np.bool_), covers)
    reached = np.zeros(size, np.bool_)
    for p in range(size):
        for c in range(n_candidates):
            if covers[p, c]:
                reached[p] = True
                break
    rest = np.zeros((size, 1), np.bool_)  # only where a candidate reaches: the others tell no candidate apart
    _mark_grid_discs(others_uv, others_px, np.zeros(others_uv.shape[0], np.int64), lo_u, lo_v, stride, n_u, n_v,
                     reached, rest)
    counts = np.zeros(n_candidates, np.int64)
    for p in range(size):
        if not reached[p]:
            continue
        b = p // n_u
        inside = image[lo_v + stride * b, lo_u + stride * (p - b * n_u)] >= 0.5
        if rest[p, 0]:  # covered whichever candidate joins
            if not inside:
                for c in range(n_candidates):
                    counts[c] += 1
        else:
            for c in range(n_candidates):
                if covers[p, c] != inside:
                    counts[c] += 1
    return counts


# --- the tree method's cross-sections (angiohull.reconstruction.vessel_tree) ----------------------

@numba.njit(**_JIT)
def _bilinear(image, v, u):  # pragma: no cover - compiled
    """``scipy.ndimage.map_coordinates(image, [[v], [u]], order=1, mode="constant", cval=0)`` as
    float32, with its arithmetic: outside ``[0, size - 1]`` on an axis 0; else the weights ``1 - x``
    and ``1 - (1 - x)`` of the fraction ``x``, the four corners summed row by row (the one past the
    last row or column is the one before it, with weight 0)."""
    rows, cols = image.shape
    if not (v >= 0.0 and v <= rows - 1 and u >= 0.0 and u <= cols - 1):
        return np.float32(0.0)
    fv = np.floor(v)
    fu = np.floor(u)
    r = np.int64(fv)
    c = np.int64(fu)
    wv0 = 1.0 - (v - fv)
    wv1 = 1.0 - wv0
    wu0 = 1.0 - (u - fu)
    wu1 = 1.0 - wu0
    r1 = r + 1 if r + 1 < rows else max(rows - 2, 0)
    c1 = c + 1 if c + 1 < cols else max(cols - 2, 0)
    t = 0.0
    t += np.float64(image[r, c]) * wv0 * wu0
    t += np.float64(image[r, c1]) * wv0 * wu1
    t += np.float64(image[r1, c]) * wv1 * wu0
    t += np.float64(image[r1, c1]) * wv1 * wu1
    return np.float32(t)


@numba.njit(**_JIT)
def mask_runs(image, uv, normal, reach, step_px, seek_steps):  # pragma: no cover - compiled
    """Per point, the run of ``image`` through it along its normal, as
    :func:`angiohull.reconstruction.vessel_tree._runs` reads it from profiles sampled every
    ``step_px`` (``step_px * k`` from the point, bilinearly): ``(found, left edge, right edge)``.
    Only the samples the run needs are read: outward from the point to the first sample inside
    (at most ``seek_steps`` away, nearest first, the lower side first on a tie), then on to the
    first sample outside on either side, not beyond ``reach``; the edges are interpolated between
    the samples on either side of the 0.5 crossing in float32, as NumPy does with the profile."""
    n = uv.shape[0]
    found = np.zeros(n, np.bool_)
    left = np.full(n, np.nan)
    right = np.full(n, np.nan)
    half_value = np.float32(0.5)
    tiny = np.float32(1e-9)
    step32 = np.float32(step_px)
    for i in range(n):
        u0 = uv[i, 0]
        v0 = uv[i, 1]
        nu = normal[i, 0]
        nv = normal[i, 1]
        seed = 0
        seeded = False
        for d in range(seek_steps + 1):
            for k in (-d, d):
                s = step_px * np.float64(k)
                if _bilinear(image, v0 + s * nv, u0 + s * nu) >= half_value:
                    seed = k
                    seeded = True
                    break
            if seeded:
                break
        if not seeded:
            continue
        # the last sample outside before the seed, within the reach
        k = seed - 1
        p_in = _bilinear(image, v0 + (step_px * np.float64(seed)) * nv, u0 + (step_px * np.float64(seed)) * nu)
        found_left = False
        while step_px * np.float64(k) >= -reach[i]:
            s = step_px * np.float64(k)
            p_out = _bilinear(image, v0 + s * nv, u0 + s * nu)
            if not (p_out >= half_value):
                found_left = True
                left[i] = s + np.float64((half_value - p_out) / max(p_in - p_out, tiny) * step32)
                break
            p_in = p_out
            k -= 1
        k = seed + 1
        p_in = _bilinear(image, v0 + (step_px * np.float64(seed)) * nv, u0 + (step_px * np.float64(seed)) * nu)
        found_right = False
        while step_px * np.float64(k) <= reach[i]:
            s = step_px * np.float64(k)
            p_out = _bilinear(image, v0 + s * nv, u0 + s * nu)
            if not (p_out >= half_value):
                found_right = True
                right[i] = step_px * np.float64(k - 1) + np.float64((p_in - half_value) / max(p_in - p_out, tiny)
                                                                     * step32)
                break
            p_in = p_out
            k += 1
        found[i] = found_left and found_right
    return found, left, right


# --- the tree method's pixel matching (angiohull.reconstruction.model.matching) ------------------

@numba.njit(**_JIT)
def _first_least(values):  # pragma: no cover - compiled
    """``np.argmin(values)``: the first least value's index, or the first nan's."""
    choice = 0
    best = values[0]
    for c in range(1, values.size):
        v = values[c]
        if not np.isnan(best) and (v < best or np.isnan(v)):
            best = v
            choice = c
    return choice


@numba.njit(**_JIT)
def forest_states(unary, every, offset, order, start, parent):  # pragma: no cover - compiled
    """:func:`angiohull.reconstruction.model.matching._forest_states` with the levels flat
    (``order[start[d]:start[d + 1]]``: level d's pixels): per pixel of a level, from the deepest
    up, and parent state, the child state of least ``total + transition`` (the first of equal
    ones, as argmin), that sum added to the parent's total in the level's order (as ``np.add.at``);
    then the roots' least totals and each level's choices below its parents' states."""
    n, states = unary.shape
    total = unary.copy()
    best_child = np.zeros((n, states), np.int64)
    joint = np.empty(states)
    for depth in range(start.size - 2, 0, -1):
        base = offset[depth - 1] - start[depth]
        for k in range(start[depth], start[depth + 1]):
            p = order[k]
            up = parent[p]
            for b in range(states):
                for c in range(states):
                    joint[c] = total[p, c] + every[base + k, c, b]
                choice = _first_least(joint)
                best_child[p, b] = choice
                total[up, b] += joint[choice]
    state = np.zeros(n, np.int64)
    if start.size > 1:
        for k in range(start[0], start[1]):
            state[order[k]] = _first_least(total[order[k]])
    for depth in range(1, start.size - 1):
        for k in range(start[depth], start[depth + 1]):
            p = order[k]
            state[p] = best_child[p, state[parent[p]]]
    return state


# --- the tree method's spoiled cross-sections (angiohull.reconstruction.vessel_tree) -------------

@numba.njit(**_JIT)
def spoiled_runs(uv, rho, normal, arc, radius, owner, image_arc, margin_px, margin_mm, image_path, sides, out,
                 left, right):  # pragma: no cover - compiled
    """One view of :func:`angiohull.reconstruction.vessel_tree._overlaps`, in place on its rows
    ``out``, ``left`` and ``right``: the pairs ``i < j`` whose squared distance (``j`` minus
    ``i``) is less than ``(rho_i + rho_j + margin_px)**2`` (all of them within the k-d tree's
    search radius ``2 max(rho) + margin_px``, so the same pairs), of two branches or a loop (arc,
    and with ``image_path`` image arc, apart by more than the two radii and the margin), and each
    point's run crossed by the other's disc, with the same arithmetic pair by pair. The pairs are
    found in square cells a little wider than the search radius."""
    n = uv.shape[0]
    if n < 2:
        return
    widest = rho[0]
    lo0 = uv[0, 0]
    lo1 = uv[0, 1]
    hi0 = lo0
    hi1 = lo1
    for p in range(n):
        widest = max(widest, rho[p])
        lo0 = min(lo0, uv[p, 0])
        hi0 = max(hi0, uv[p, 0])
        lo1 = min(lo1, uv[p, 1])
        hi1 = max(hi1, uv[p, 1])
    cell = max((2.0 * widest + margin_px) * (1.0 + 1e-6), 1e-300)
    while ((hi0 - lo0) / cell + 1.0) * ((hi1 - lo1) / cell + 1.0) > 4.0 * n + 64.0:
        cell *= 2.0
    n0 = int((hi0 - lo0) / cell) + 1
    n1 = int((hi1 - lo1) / cell) + 1
    where, start, order = _cell_buckets(uv, lo0, lo1, cell, n0, n1)
    for i in range(n):
        a0 = where[i] // n1
        b0 = where[i] - a0 * n1
        for ca in range(max(a0 - 1, 0), min(a0 + 1, n0 - 1) + 1):
            for cb in range(max(b0 - 1, 0), min(b0 + 1, n1 - 1) + 1):
                c = ca * n1 + cb
                for m in range(start[c], start[c + 1]):
                    j = order[m]
                    if j <= i:
                        continue
                    du = uv[j, 0] - uv[i, 0]
                    dv = uv[j, 1] - uv[i, 1]
                    s = rho[i] + rho[j] + margin_px
                    if not (du * du + dv * dv < s * s):
                        continue
                    loop = abs(arc[i] - arc[j]) > radius[i] + radius[j] + margin_mm
                    if image_path:
                        loop = loop and abs(image_arc[i] - image_arc[j]) > rho[i] + rho[j] + margin_px
                    if not (owner[i] != owner[j] or loop):
                        continue
                    for side in range(2):
                        a = i if side == 0 else j
                        b = j if side == 0 else i
                        sign = 1.0 if side == 0 else -1.0
                        nu = normal[a, 0]
                        nv = normal[a, 1]
                        across = sign * (nu * du + nv * dv)
                        along = abs(nu * dv - nv * du)
                        reach = rho[b] + margin_px
                        chord = np.sqrt(max(reach * reach - along * along, 0.0))
                        rho_a = rho[a]
                        if along < reach and abs(across) - chord < rho_a:
                            out[a] = True
                            if sides:
                                if across - chord < -rho_a:
                                    left[a] = True
                                if across + chord > rho_a:
                                    right[a] = True


# --- the TEASAR paths' graph (angiohull.tree.voxels.path_cost_graph) ----------------------------------

@numba.njit(**_JIT)
def forward_cost_rows(flat, index, deltas, lengths, depth):  # pragma: no cover - compiled
    """The CSR rows (``indptr``, ``tails`` (int32), ``cost``) of the edges of
    :func:`angiohull.tree.voxels.neighbour_edges`: voxel ``h`` (flat index ``flat[h]`` into the
    padded grid whose flat ``index`` holds 1 + each voxel's position, 0 for none) and each voxel at
    ``flat[h] + deltas[o]``, offset after offset, cost ``lengths[o] / (0.5 * (depth[h] +
    depth[t]))**2`` (the square a product, as NumPy's ``** 2``)."""
    n = flat.size
    indptr = np.zeros(n + 1, np.int32)
    tails = np.empty(deltas.size * n, np.int32)
    cost = np.empty(deltas.size * n, np.float64)
    e = 0
    for h in range(n):
        f = flat[h]
        for o in range(deltas.size):
            t = index[f + deltas[o]] - 1
            if t >= 0:
                mean = 0.5 * (depth[h] + depth[t])
                tails[e] = t
                cost[e] = lengths[o] / (mean * mean)
                e += 1
        indptr[h + 1] = e
    return indptr, tails[:e].copy(), cost[:e].copy()


# --- the TEASAR paths' cover (angiohull.tree.teasar.teasar_skeleton) --------------------------------

@numba.njit(**_JIT)
def teasar_cover_hits(path, reach, todo, largest):  # pragma: no cover - compiled
    """Per voxel of ``todo`` ((T, 3) int64), whether it lies within the reach of its nearest voxel
    of ``path`` ((P, 3) int64; ``reach`` (P,)), as the k-d tree's nearest within ``largest`` (the
    largest reach) decides: 1 where it does whichever of the voxels at the least distance the tree
    gives, 0 where it does not, 2 where that choice, or a distance within a ten-millionth of a
    reach, could decide (the k-d tree answers those). Squared distances are whole numbers, exact."""
    out = np.empty(todo.shape[0], np.int8)
    bound = largest * largest * (1.0 - 1e-9)
    for t in range(todo.shape[0]):
        x, y, z = todo[t, 0], todo[t, 1], todo[t, 2]
        best = -1
        low = np.inf
        high = -np.inf
        for p in range(path.shape[0]):
            dx, dy, dz = path[p, 0] - x, path[p, 1] - y, path[p, 2] - z
            d2 = dx * dx + dy * dy + dz * dz
            if best < 0 or d2 < best:
                best = d2
                low = reach[p]
                high = reach[p]
            elif d2 == best:
                low = min(low, reach[p])
                high = max(high, reach[p])
        squared = float(best)
        if squared > high * high * (1.0 + 1e-9):
            out[t] = 0
        elif squared < low * low * (1.0 - 1e-9) and squared < bound:
            out[t] = 1
        else:
            out[t] = 2
    return out
