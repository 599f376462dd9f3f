"""The safe PRM's graph work compiled with numba: K-S neighbours on a uniform grid, the roadmaps' CSR rows and
their connected components.

* :func:`grid_build` sorts points (in the space's metric: coordinates times its weights) into the cells of a
  uniform grid; a roadmap numbers its milestones in that order (:class:`.roadmap.Grid`), so the points of a cell,
  and of a column of cells, are consecutive. :func:`k_s_neighbours` answers "at most k nearest within s" for any
  points from it, ring of cells by ring of cells until no unvisited cell can hold a nearer point. The answers are
  a KD-tree's (``scipy.spatial.cKDTree.query(..., k, distance_upper_bound=s)``, checked in
  ``tests/test_compiled.py``), without building one per roadmap.
* :func:`k_s_pairs`: the undirected K-S pairs of the milestones themselves, each once, sorted (lo, hi): the
  candidate edges of Algorithm 1 when every milestone is offered to all its K-S neighbours.
* :func:`csr_rows`: both directions of the selected edges as CSR rows, entries in the order a stable sort by
  row gives (what ``scipy.sparse`` would build, without the sort); :func:`component_labels`: the connected
  components by union-find.

Compiled when the module is imported (cached on disk by numba), so a roadmap's build never pays it.
"""

from __future__ import annotations

from itertools import pairwise
from threading import Lock

import numpy as np
from numba import njit
from surgiplan.threads import in_parallel

_FLAGS = {"cache": True, "nogil": True}
#: a milestone's first guess of its k-th nearest neighbour's distance: this times the previous milestone's (a guess
#: too short costs one more scan of the block; one too long, more candidates to sort)
_GUESS = 1.2
#: :func:`k_s_pairs`' slabs a thread: enough that the last slab handed out ends about when the others do
_SLABS_A_THREAD = 4


@njit(**_FLAGS)
def grid_build(points, cell):
    """Cells of side ``cell`` over the points' bounding box: (origin, cells per axis, first entry of each cell in
    the sorted order, the point indices sorted by cell (stable: within a cell by index))."""
    n, d = points.shape
    origin = np.empty(d)
    dims = np.empty(d, dtype=np.int64)
    for k in range(d):
        low = np.inf
        high = -np.inf
        for i in range(n):
            low = min(low, points[i, k])
            high = max(high, points[i, k])
        if n == 0:
            low = high = 0.0
        origin[k] = low
        dims[k] = max(1, int((high - low) / cell) + 1)
    total = 1
    for k in range(d):
        total *= dims[k]
    counts = np.zeros(total + 1, dtype=np.int64)
    which = np.empty(n, dtype=np.int64)
    for i in range(n):
        index = 0
        for k in range(d):
            c = min(max(int((points[i, k] - origin[k]) / cell), 0), dims[k] - 1)
            index = index * dims[k] + c
        which[i] = index
        counts[index + 1] += 1
    for c in range(total):
        counts[c + 1] += counts[c]
    start = counts.copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[start[which[i]]] = i
        start[which[i]] += 1
    return origin, dims, counts, order


@njit(cache=True, nogil=True, inline="always")
def _insert(total, p, count, k, out_index, out_distance):
    """Point p at squared distance ``total`` into the ``count`` nearest so far (sorted, at most ``k``: the farthest
    drops out when full); returns how many there are now."""
    slot = count if count < k else k - 1
    while slot > 0 and out_distance[slot - 1] > total:
        out_distance[slot] = out_distance[slot - 1]
        out_index[slot] = out_index[slot - 1]
        slot -= 1
    out_distance[slot] = total
    out_index[slot] = p
    return min(count + 1, k)


@njit(**_FLAGS)
def _roots(out_distance, count):
    """The ``count`` nearest's squared distances made distances; returns ``count``."""
    for slot in range(count):
        out_distance[slot] = np.sqrt(out_distance[slot])
    return count


@njit(**_FLAGS)
def _nearest_in_grid(x, points, origin, dims, cell, first, k, s, skip, out_index, out_distance):
    """The at most ``k`` nearest points to ``x`` strictly within ``s`` (point ``skip`` excluded), nearest first,
    into the outputs; returns how many. ``points`` sorted by cell."""
    d = points.shape[1]
    centre = np.empty(d, dtype=np.int64)
    for j in range(d):
        centre[j] = min(max(int(np.floor((x[j] - origin[j]) / cell)), 0), dims[j] - 1)
    worst = s * s  # a candidate must be nearer than this: s, then the k-th nearest once there are k
    count = 0
    low = np.empty(d, dtype=np.int64)
    high = np.empty(d, dtype=np.int64)
    at = np.empty(d, dtype=np.int64)
    ring = 0
    while True:
        covers_all = True
        for j in range(d):
            low[j] = centre[j] - ring
            high[j] = centre[j] + ring
            if low[j] > 0 or high[j] < dims[j] - 1:
                covers_all = False
        # the cells at Chebyshev distance ``ring`` from the centre cell, clipped to the grid
        for j in range(d):
            at[j] = max(low[j], 0)
        while True:
            on_ring = ring == 0
            index = 0
            for j in range(d):
                if at[j] == low[j] or at[j] == high[j]:
                    on_ring = True
                index = index * dims[j] + at[j]
            if on_ring:
                for e in range(first[index], first[index + 1]):
                    total = 0.0
                    for j in range(d):
                        diff = points[e, j] - x[j]
                        total += diff * diff
                    if total >= worst or e == skip:
                        continue
                    count = _insert(total, e, count, k, out_index, out_distance)
                    if count == k:
                        worst = out_distance[k - 1]
            # the next cell of the block (odometer over the clipped ranges)
            j = d - 1
            while j >= 0:
                at[j] += 1
                if at[j] <= min(high[j], dims[j] - 1):
                    break
                at[j] = max(low[j], 0)
                j -= 1
            if j < 0:
                break
        if covers_all:
            break
        # every point outside the block scanned so far is at least this far from x
        bound = np.inf
        for j in range(d):
            bound = min(bound, x[j] - (origin[j] + (centre[j] - ring) * cell))
            bound = min(bound, origin[j] + (centre[j] + ring + 1) * cell - x[j])
        if bound > 0 and bound * bound >= worst:
            break
        ring += 1
    return _roots(out_distance, count)


@njit(**_FLAGS)
def _nearest_in_grid3(x0, x1, x2, points, origin, dims, cell, first, k, s, skip, out_index, out_distance):
    """:func:`_nearest_in_grid` for three coordinates: the same cells in the same order, unrolled; a column of
    cells (along z) is one run of points."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    ox, oy, oz = origin[0], origin[1], origin[2]
    cx = min(max(int(np.floor((x0 - ox) / cell)), 0), nx - 1)
    cy = min(max(int(np.floor((x1 - oy) / cell)), 0), ny - 1)
    cz = min(max(int(np.floor((x2 - oz) / cell)), 0), nz - 1)
    worst = s * s
    count = 0
    ring = 0
    while True:
        for ix in range(max(cx - ring, 0), min(cx + ring, nx - 1) + 1):
            edge_x = ix == cx - ring or ix == cx + ring
            for iy in range(max(cy - ring, 0), min(cy + ring, ny - 1) + 1):
                shell = edge_x or iy == cy - ring or iy == cy + ring
                base = (ix * ny + iy) * nz
                # on the ring's shell every z of the block (one run); inside it only its two z faces
                step = 1 if shell or ring == 0 else 2 * ring
                iz = max(cz - ring, 0) if shell else cz - ring
                while iz <= min(cz + ring, nz - 1):
                    if iz >= 0:
                        last = min(cz + ring, nz - 1) if step == 1 else iz
                        for e in range(first[base + iz], first[base + last + 1]):
                            a0, a1, a2 = points[e, 0] - x0, points[e, 1] - x1, points[e, 2] - x2
                            total = a0 * a0 + a1 * a1 + a2 * a2
                            if total >= worst or e == skip:
                                continue
                            count = _insert(total, e, count, k, out_index, out_distance)
                            if count == k:
                                worst = out_distance[k - 1]
                        if step == 1:
                            break
                    iz += step
        if cx - ring <= 0 and cy - ring <= 0 and cz - ring <= 0:
            if cx + ring >= nx - 1 and cy + ring >= ny - 1 and cz + ring >= nz - 1:
                break
        bound = min(
            x0 - (ox + (cx - ring) * cell),
            ox + (cx + ring + 1) * cell - x0,
            x1 - (oy + (cy - ring) * cell),
            oy + (cy + ring + 1) * cell - x1,
            x2 - (oz + (cz - ring) * cell),
            oz + (cz + ring + 1) * cell - x2,
        )
        if bound > 0 and bound * bound >= worst:
            break
        ring += 1
    return _roots(out_distance, count)


@njit(**_FLAGS)
def k_s_nearest(x, points, origin, dims, cell, first, k, s, skip, out_index, out_distance):
    if points.shape[1] == 3:
        return _nearest_in_grid3(
            x[0], x[1], x[2], points, origin, dims, cell, first, k, s, skip, out_index, out_distance
        )
    return _nearest_in_grid(x, points, origin, dims, cell, first, k, s, skip, out_index, out_distance)


@njit(**_FLAGS)
def k_s_neighbours(queries, points, origin, dims, cell, first, k, s):
    """For each query point, its at most ``k`` nearest points within ``s`` (``points``: sorted by cell, as
    :class:`.roadmap.Grid` holds them): (indices, distances, counts); rows nearest first, padded with -1 and inf."""
    m = queries.shape[0]
    index = np.full((m, max(k, 1)), -1, dtype=np.int64)
    distance = np.full((m, max(k, 1)), np.inf)
    counts = np.zeros(m, dtype=np.int64)
    if k == 0 or points.shape[0] == 0:
        return index, distance, counts
    for i in range(m):
        counts[i] = k_s_nearest(queries[i], points, origin, dims, cell, first, k, s, -1, index[i], distance[i])
    return index, distance, counts


@njit(**_FLAGS)
def _block_neighbours3(points, origin, dims, cell, first, k, s, slab_lo, slab_hi, index, distance, counts):
    """The K-S neighbours of every point (three coordinates, sorted by cell), cell by cell. A cell's 3 x 3 x 3 block
    is nine runs of points (columns of three cells along z); each point of the cell keeps, of the block's points,
    those nearer than a guess of its k-th nearest's distance (:data:`_GUESS` times the previous point's; twice
    as far in squared distance, up to s, until it keeps k), without a branch (every point is written, the count
    moves on only for those kept: a branch taken at random for a quarter of them cost more than all the
    arithmetic), then the k nearest of those, sorted. A point whose k-th nearest might lie beyond the block (or
    within s beyond it) is answered by :func:`k_s_nearest` instead. The answers of :func:`k_s_nearest` for every
    point of the cells with x index in [``slab_lo``, ``slab_hi``)."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    s2 = s * s
    starts = np.empty(9, dtype=np.int64)
    ends = np.empty(9, dtype=np.int64)
    kept = np.empty(points.shape[0])
    kept_index = np.empty(points.shape[0], dtype=np.uint64)
    best = np.empty(k)
    guess = s2
    one, zero = np.uint64(1), np.uint64(0)  # unsigned indices: no test for wrapping around at each access
    for cx in range(slab_lo, slab_hi):
        for cy in range(ny):
            for cz in range(nz):
                c = (cx * ny + cy) * nz + cz
                if first[c] == first[c + 1]:
                    continue
                runs = 0
                for ix in range(max(cx - 1, 0), min(cx + 1, nx - 1) + 1):
                    for iy in range(max(cy - 1, 0), min(cy + 1, ny - 1) + 1):
                        base = (ix * ny + iy) * nz
                        starts[runs] = first[base + max(cz - 1, 0)]
                        ends[runs] = first[base + min(cz + 1, nz - 1) + 1]
                        runs += 1
                # the block's faces on the grid's edge bound nothing (no point lies beyond them)
                low_x = origin[0] + (cx - 1) * cell if cx > 1 else -np.inf
                high_x = origin[0] + (cx + 2) * cell if cx < nx - 2 else np.inf
                low_y = origin[1] + (cy - 1) * cell if cy > 1 else -np.inf
                high_y = origin[1] + (cy + 2) * cell if cy < ny - 2 else np.inf
                low_z = origin[2] + (cz - 1) * cell if cz > 1 else -np.inf
                high_z = origin[2] + (cz + 2) * cell if cz < nz - 2 else np.inf
                for i in range(first[c], first[c + 1]):
                    x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
                    me = np.uint64(i)
                    while True:
                        size = zero
                        for r in range(runs):
                            for e in range(np.uint64(starts[r]), np.uint64(ends[r])):
                                a0, a1, a2 = points[e, 0] - x0, points[e, 1] - x1, points[e, 2] - x2
                                total = a0 * a0 + a1 * a1 + a2 * a2
                                kept[size] = total
                                kept_index[size] = e
                                size += one if (total < guess) & (e != me) else zero
                        if size >= k or guess >= s2:
                            break
                        guess = min(2.0 * guess, s2)
                    count = 0
                    out = index[i]
                    for b in range(size):
                        if count < k or kept[b] < best[k - 1]:
                            count = _insert(kept[b], kept_index[b], count, k, out, best)
                    worst = best[k - 1] if count == k else s2
                    bound = min(x0 - low_x, high_x - x0, x1 - low_y, high_y - x1, x2 - low_z, high_z - x2)
                    if bound * bound >= worst:
                        counts[i] = count
                        for slot in range(count):
                            distance[i, slot] = np.sqrt(best[slot])
                        guess = min(_GUESS * _GUESS * worst, s2)
                    else:  # the block may miss a nearer point: the ring search from scratch
                        counts[i] = k_s_nearest(points[i], points, origin, dims, cell, first, k, s, i, out, distance[i])


@njit(**_FLAGS)
def neighbour_rows(points, origin, dims, cell, first, k, s, slab_lo, slab_hi, index, distance, counts):
    """The K-S neighbours of the points of the cells with x index in [``slab_lo``, ``slab_hi``) (``points``: sorted
    by cell, as :class:`.roadmap.Grid` holds them; a slab's points are consecutive) into their rows of ``index``,
    ``distance`` and ``counts``. Slabs are independent: threads may fill disjoint slabs at once."""
    if points.shape[1] == 3:
        _block_neighbours3(points, origin, dims, cell, first, k, s, slab_lo, slab_hi, index, distance, counts)
        return
    per_slab = 1
    for axis in range(1, dims.shape[0]):
        per_slab *= dims[axis]
    for i in range(first[slab_lo * per_slab], first[slab_hi * per_slab]):
        counts[i] = k_s_nearest(points[i], points, origin, dims, cell, first, k, s, i, index[i], distance[i])


@njit(**_FLAGS)
def unique_pairs(index, distance, counts):
    """The undirected pairs (lo, hi) of the neighbour rows (point i and each of its ``counts[i]`` neighbours
    ``index[i]``), each once, sorted by lo then hi, and their lengths (``distance``)."""
    n = counts.shape[0]
    # bucket every pair by its lower index, then sort and deduplicate each bucket (unsigned indices throughout:
    # no test for wrapping around at each access)
    m, one = np.uint64(n), np.uint64(1)
    size = np.zeros(n + 1, dtype=np.uint64)
    for i in range(m):
        for slot in range(np.uint64(counts[i])):
            size[min(i, np.uint64(index[i, slot])) + one] += one
    for i in range(m):
        size[i + one] += size[i]
    fill = size[:n].copy()
    partner = np.empty(size[n], dtype=np.uint64)
    length = np.empty(size[n])
    for i in range(m):
        for slot in range(np.uint64(counts[i])):
            j = np.uint64(index[i, slot])
            lo = min(i, j)
            at = fill[lo]
            partner[at] = max(i, j)
            length[at] = distance[i, slot]
            fill[lo] = at + one
    pairs = np.empty((size[n], 2), dtype=np.int64)
    lengths = np.empty(size[n])
    total = np.uint64(0)
    for lo in range(m):
        a, b = size[lo], size[lo + one]
        for e in range(a + one, b):  # insertion sort: a bucket holds about 2k entries
            v = partner[e]
            w = length[e]
            f = e
            while f > a and partner[f - one] > v:
                partner[f] = partner[f - one]
                length[f] = length[f - one]
                f -= one
            partner[f] = v
            length[f] = w
        for e in range(a, b):
            if e == a or partner[e] != partner[e - one]:
                pairs[total, 0] = lo
                pairs[total, 1] = partner[e]
                lengths[total] = length[e]
                total += one
    return pairs[:total], lengths[:total]  # views: a copy would cost more than the spare entries (page faults)


def k_s_pairs(points, origin, dims, cell, first, k, s, threads=1):
    """The undirected pairs (lo, hi) of points where one is among the other's K-S neighbours, each once, sorted by
    lo then hi (``points``: sorted by cell, as :class:`.roadmap.Grid` holds them), and their lengths (Euclidean,
    in the points' coordinates). With ``threads`` > 1 the neighbour rows are found in slabs of cells
    (:data:`_SLABS_A_THREAD` a thread, split where the points are, and handed out in turn to whichever thread is
    free: one slab's points can take longer than another's) on that many threads at once
    (:func:`surgiplan.threads.in_parallel`); the answer is the same."""
    n = points.shape[0]
    kk = max(int(k), 1)
    index = np.empty((n, kk), dtype=np.int64)
    distance = np.empty((n, kk))
    counts = np.zeros(n, dtype=np.int64)
    if k > 0 and n:
        threads = max(int(threads), 1)
        per_slab = int(np.prod(dims[1:]))
        slab_first = np.asarray(first[::per_slab])  # the first point of each slab (and, last, n)
        parts = 1 if threads == 1 else threads * _SLABS_A_THREAD
        cuts = np.searchsorted(slab_first, np.linspace(0, n, parts + 1)[1:-1])
        bounds = [0, *sorted(set(int(c) for c in cuts)), int(dims[0])]
        slabs = iter([(lo, hi) for lo, hi in pairwise(bounds) if hi > lo])
        taking = Lock()

        def work() -> None:
            while True:
                with taking:
                    slab = next(slabs, None)
                if slab is None:
                    return
                neighbour_rows(points, origin, dims, cell, first, k, s, *slab, index, distance, counts)

        in_parallel([(work, ())] * threads)
    return unique_pairs(index, distance, counts)


@njit(**_FLAGS)
def cover_pairs(pairs, reach, clearance, inside, safe, d_thresh):
    """The covering-ball decisions of :func:`.roadmap.certify_roadmap_edges` for every pair: for R and for
    R_safe, 1 certified by the end balls, 0 impossible (an end cannot keep the margin), 2 undecided; and how many
    R edges the balls certified."""
    count = pairs.shape[0]
    free_state = np.empty(count, dtype=np.int8)
    safe_state = np.zeros(count, dtype=np.int8)
    covered = 0
    for e in range(count):
        i, j = pairs[e, 0], pairs[e, 1]
        free_a, free_b = min(clearance[i], inside[i]), min(clearance[j], inside[j])
        if free_a > 0 and free_b > 0:
            if free_a + free_b > reach[e]:
                free_state[e] = 1
                covered += 1
            else:
                free_state[e] = 2
        else:
            free_state[e] = 0
        if d_thresh > 0 and safe[i] and safe[j]:
            safe_a, safe_b = min(clearance[i] - d_thresh, inside[i]), min(clearance[j] - d_thresh, inside[j])
            if safe_a >= 0 and safe_b >= 0:
                safe_state[e] = 1 if safe_a + safe_b > reach[e] else 2
    return free_state, safe_state, covered


@njit(**_FLAGS)
def cover_by_midpoint(need, pairs, state, ok, clear_m, inside_m, first, second, clearance, inside, margin, gate):
    """The midpoint step of :func:`.roadmap.certify_roadmap_edges` for one roadmap (R: ``margin`` 0, where a
    clearance must be positive; R_safe: ``margin`` d_thresh, where it may be zero, and only the pairs that
    ``gate`` (R's decisions) let through). Of the pairs ``need[x]`` still undecided (``state`` 2), the midpoint's
    clearance and slack (``clear_m[x]``, ``inside_m[x]``) less the margin, if it keeps it, and the ends' cover the
    two halves (speed bounds ``first[x]``, ``second[x]``): certified into ``ok``. Returns how many, and the x
    whose midpoint keeps the margin without covering them (they need the exact check)."""
    strict = margin == 0.0
    exact = np.empty(need.shape[0], dtype=np.int64)
    count = 0
    covered = 0
    for x in range(need.shape[0]):
        e = need[x]
        if state[e] != 2 or not gate[e]:
            continue
        m = min(clear_m[x] - margin, inside_m[x])
        if m > 0 or (m == 0 and not strict):
            i, j = pairs[e, 0], pairs[e, 1]
            a, b = min(clearance[i] - margin, inside[i]), min(clearance[j] - margin, inside[j])
            if a + m > first[x] and m + b > second[x]:
                ok[e] = True
                covered += 1
            else:
                exact[count] = x
                count += 1
    return covered, exact[:count]


@njit(**_FLAGS)
def csr_rows(n, edges, cost, mask, floor):
    """Both directions of ``edges[mask]`` as CSR (indptr, indices, data; the indices unsigned, as the searches
    take them): row i lists, in edge order, first the edges (i, j), then the edges (j, i); costs at least
    ``floor`` (scipy's graph routines drop explicit zeros)."""
    indptr = np.zeros(n + 1, dtype=np.int64)
    for e in range(edges.shape[0]):
        if mask[e]:
            indptr[edges[e, 0] + 1] += 1
            indptr[edges[e, 1] + 1] += 1
    for i in range(n):
        indptr[i + 1] += indptr[i]
    fill = indptr[:n].copy()
    indices = np.empty(indptr[n], dtype=np.uint32)
    data = np.empty(indptr[n])
    for side in range(2):
        for e in range(edges.shape[0]):
            if mask[e]:
                row, col = edges[e, side], edges[e, 1 - side]
                indices[fill[row]] = col
                data[fill[row]] = max(cost[e], floor)
                fill[row] += 1
    return indptr.astype(np.uint32), indices, data


@njit(**_FLAGS)
def _root(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(**_FLAGS)
def component_labels(n, edges, mask):
    """The connected component of every node over ``edges[mask]``: labels 0, 1, ... in order of first node."""
    parent = np.arange(n)
    for e in range(edges.shape[0]):
        if mask[e]:
            a, b = _root(parent, edges[e, 0]), _root(parent, edges[e, 1])
            if a != b:
                if a < b:
                    parent[b] = a
                else:
                    parent[a] = b
    labels = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        r = _root(parent, i)
        if r == i:
            labels[i] = count
            count += 1
        else:
            labels[i] = labels[r]
    return labels, count


@njit(**_FLAGS)
def _extent(points):
    """Each column's largest value less its smallest (``np.ptp(points, axis=0)``; numpy reduces the rows of a
    narrow array one element at a time)."""
    n, d = points.shape
    out = np.zeros(d)
    for k in range(d):
        low = points[0, k]
        high = low
        for i in range(1, n):
            low = min(low, points[i, k])
            high = max(high, points[i, k])
        out[k] = high - low
    return out


def grid_cell(points: np.ndarray, s: float) -> float:
    """The cell side for :func:`grid_build`: about eight points a cell (the 15 nearest of a point then lie in its
    block of 27 cells, mostly), and at least s / 8 (bounded work a ring)."""
    if len(points) == 0:
        return max(s, 1e-9)
    extent = _extent(np.ascontiguousarray(points, dtype=float))  # np.ptp(points, axis=0): 0.35 ms at 5,000 x 3
    extent = extent[extent > 0]
    if not extent.size:
        return max(s, 1e-9)
    spacing = float(np.prod(extent) / len(points)) ** (1.0 / len(extent))
    return max(2.0 * spacing, s / 8.0, 1e-12)


def _compile() -> None:
    """Load (or compile) every kernel for the types the roadmap passes."""
    points = np.zeros((2, 3))
    points[1] = 1.0
    grid_cell(points, 1.0)
    origin, dims, first, _ = grid_build(points, 1.0)
    k_s_neighbours(points, points, origin, dims, 1.0, first, 2, 2.0)
    pairs, lengths = k_s_pairs(points, origin, dims, 1.0, first, 2, 2.0)
    mask = np.ones(len(pairs), dtype=np.bool_)
    free_state, _, _ = cover_pairs(pairs, lengths, np.ones(2), np.ones(2), mask[:1].repeat(2), 0.5)
    need = np.arange(len(pairs), dtype=np.int64)
    some = np.ones(len(pairs))
    cover_by_midpoint(need, pairs, free_state, mask.copy(), some, some, some, some, np.ones(2), np.ones(2), 0.0, mask)
    csr_rows(2, pairs, np.ones(len(pairs)), mask, 1e-15)
    component_labels(2, pairs, mask)


_compile()
