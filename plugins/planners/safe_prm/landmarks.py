"""Landmarks for the safe PRM's A* (ALT: A*, landmarks, triangle inequality; Goldberg & Harrelson 2005).

At build, a few milestones of a roadmap are chosen as landmarks (the *farthest* strategy: each next one the
milestone farthest, in the roadmap, from those chosen, within the largest component) and their roadmap
distances to every milestone are stored, node-major (``far[v, j]``: milestone v to landmark j, ``inf`` in
another component). By the triangle inequality, for every landmark L the cost of any roadmap path from v to t
is at least ``|d(L, t) - d(L, v)|``: a lower bound that follows the roadmap around the obstacles, where the
straight-line distance cuts through them. :func:`.astar.search` takes the larger of the two bounds, so it
settles only the nodes that could still lie on a shortest path, far fewer than with the distance alone.

The distances come from :func:`dijkstra`, run to exhaustion from each landmark (``tests/test_safe_prm_query.py``
checks them against scipy's Dijkstra). Compiled when the module is imported.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: how many landmarks a roadmap gets. A query searches R once and R_safe once for each stretch it repairs, and a
#: repair's search is the longer (it goes around what R's path went through). The build computes R's and R_safe's
#: landmarks at once (:func:`surgiplan.threads.in_parallel`): on the block world at 5,000 milestones a Dijkstra
#: takes about 500 us on R (every milestone) and 300 us on R_safe (its largest component, three fifths of them),
#: so R's 16 take about 8 ms and R_safe's 32 about 10. Over 24 queries (8 seeds, three levels) 16 and 32 settle
#: 7,218 nodes; 16 and 28, which end together, settle 7,651 (6 % more), and the query with repair, timed back to
#: back and interleaved, took 83 against 77 us at 4 mm: the query's 100 us is the closer target, so R_safe keeps
#: its 32. 20 for R would settle fewer but double R's marks a node (:func:`.astar.search_graph`: a row of 16 is
#: half a cache line, of up to 32 a whole one). When R_safe is R (d_thresh 0) its 16 serve both.
FREE_LANDMARKS = 16
SAFE_LANDMARKS = 32
ONLY_LANDMARKS = 16
#: :func:`dijkstra`'s bucket width, as a fraction of the mean edge cost: an edge shorter than a bucket can
#: improve a node of the bucket being emptied, which is then expanded again (:func:`.astar.bucket_width`)
BUCKET_FRACTION = 1.0 / 8.0
#: :func:`dijkstra`'s units: a bucket's width over 2**shift, each shift in turn until every edge's weight fits its
#: field of the packed edge (16 or 32 bits, :func:`landmark_distances`) and the distances fit in 32 bits. 2**16: an
#: edge loses under a 500,000th of a mean edge to the rounding (the roadmap's distances may reach 8,192 mean edges
#: before the next); 2**11, the finest whose weights fit 16 bits at 5,000 milestones (the longest K-S edge there is
#: about 2.4 mean edges, 19 buckets): under a 16,000th of a mean edge, where a landmark's 16-bit mark
#: (:func:`.astar.search_graph`) rounds to about a 650th
_SHIFTS = (16, 11, 8, 4, 1)
#: a roadmap of at most this many milestones gets each edge packed in 32 bits: the far node in the low 16, the
#: weight in the high 16 (half the bytes of two 32-bit arrays, so R's rows at 5,000 milestones, 350 kB, stay in a
#: core's 512 kB L2 through its 16 Dijkstras: 17 % less time a landmark set); a larger one in 64 bits (32 and 32)
_SMALL = 1 << 16
#: :func:`dijkstra`'s distance of a node it has not reached (not :data:`.astar.UNREACHED`, a 16-bit mark's)
_UNREACHED_UNITS = np.uint32(0xFFFFFFFF)
#: :func:`dijkstra`'s buckets (a ring, a power of two): a key beyond the ring's span waits in its slot until
#: the sweep comes round (bucket counted whole, so it is not taken early)
_RING = 1 << 12


@njit(cache=True, nogil=True)
def dijkstra(indptr, packed, bits, limit, shift, source, out, ring_head, entry_node, entry_bucket, entry_next,
             better):  # fmt: skip
    """The roadmap distance from ``source`` to every node into ``out`` (:data:`_UNREACHED_UNITS` where unreachable), in
    the integer units of the edges' weights, over CSR rows whose entries are ``packed``: the far node in the low
    ``bits`` bits, the edge's cost in units above them (:func:`_pack`; 16 and 32 bits, or 32 and 64). Buckets of
    ``2**shift`` units in a ring (``ring_head``, -1 when empty, left so); within a bucket nodes come out in any
    order and one improved after it came out is expanded again, so every node ends with its exact distance once the
    buckets are empty (an entry older than its node's last improvement is skipped).
    Integer sums are exact: no round-off to bound. Returns the entries used, -1 when ``entry_*`` ran out (call
    again with more), -2 when a node beyond ``limit`` (the largest distance that any edge's weight keeps within
    32 bits) is expanded (call again with coarser units). ``better``: room for a node's edges: the ones that
    improve their node are picked out first, without a branch, and only they are followed (most edges improve
    nothing, and a branch on each mispredicts on the few that do: 11 % less time a landmark set)."""
    n = indptr.shape[0] - 1
    for v in range(n):
        out[v] = _UNREACHED_UNITS
    bits = np.uint64(bits)  # every field in unsigned 64-bit arithmetic (a signed operand would make it float)
    low = (np.uint64(1) << bits) - np.uint64(1)
    mask = ring_head.shape[0] - 1
    capacity = entry_node.shape[0]
    out[source] = 0
    entry_node[0] = source
    entry_bucket[0] = 0
    entry_next[0] = -1
    ring_head[0] = 0
    used = 1
    pending = 1
    current = 0
    while pending > 0:
        slot = current & mask
        previous = -1
        e = ring_head[slot]
        while e >= 0 and entry_bucket[e] != current:  # entries of a later turn of the ring stay
            previous = e
            e = entry_next[e]
        if e < 0:
            current += 1
            continue
        if previous < 0:
            ring_head[slot] = entry_next[e]
        else:
            entry_next[previous] = entry_next[e]
        pending -= 1
        v = entry_node[e]
        g = out[v]
        if np.int64(g >> shift) != current:
            continue  # improved since: a later entry of v holds its distance
        if g > limit:
            for s in range(ring_head.shape[0]):
                ring_head[s] = -1
            return -2
        found = 0
        for k in range(indptr[v], indptr[v + 1]):
            p = np.uint64(packed[k])
            better[found] = p
            found += g + (p >> bits) < out[p & low]
        for x in range(found):
            p = np.uint64(better[x])
            w = p & low
            c = g + (p >> bits)
            if c < out[w]:  # an earlier edge of v to w (a repeated one) may have improved it since
                if used == capacity:
                    for s in range(ring_head.shape[0]):
                        ring_head[s] = -1
                    return -1
                out[w] = c
                bucket = max(np.int64(c >> shift), current)
                entry_node[used] = w
                entry_bucket[used] = bucket
                entry_next[used] = ring_head[bucket & mask]
                ring_head[bucket & mask] = used
                used += 1
                pending += 1
    return used


@njit(cache=True, nogil=True)
def _pack(indices, data, unit, bits, packed):
    """Each edge into ``packed``: its far node, and above it (``bits`` up) its cost in whole units of ``unit``,
    rounded down (a sum of them never exceeds the costs' sum); returns the largest distance from which every edge
    stays within 32 bits, -1 when a weight does not fit its ``bits`` (or 32) bits."""
    heaviest = 0.0
    most = min(2.0**bits - 1.0, np.float64(_UNREACHED_UNITS))
    for k in range(data.shape[0]):
        units = np.floor(data[k] / unit)
        if not units < most:
            return -1
        packed[k] = np.uint64(indices[k]) | (np.uint64(units) << np.uint64(bits))
        heaviest = max(heaviest, units)
    return np.int64(_UNREACHED_UNITS) - 1 - np.int64(heaviest)


def landmark_distances(indptr, indices, data, scaled, labels, count, delta, bits=None):
    """``count`` landmarks of the largest component (farthest strategy) and every node's roadmap distance to
    each: (n, count), ``inf`` where a node cannot reach it; fewer columns when the component is smaller, none when
    its distances do not fit :func:`dijkstra`'s coarsest units (``indptr``, ``indices``: unsigned; ``delta``: the
    buckets' width). The distances are of the costs rounded down to :data:`_SHIFTS`' units (the finest whose
    weights fit): never above the true ones, below them by less than a unit an edge; every edge (v, w) keeps
    ``far[w] <= far[v] + cost``, so the landmarks' bounds stay admissible. ``bits``: each edge's far node in 16
    bits (up to :data:`_SMALL` milestones) or 32 (None: the smaller that holds them; 32 too when no weight
    fits 16 bits)."""
    small = len(scaled) <= _SMALL
    chosen = bits or (16 if small else 32)
    if chosen not in (16, 32) or (chosen == 16 and not small):
        raise ValueError(f"a roadmap of {len(scaled)} milestones cannot pack its edges in {bits} bits")
    packed = np.empty(len(indices), dtype=np.uint32 if chosen == 16 else np.uint64)
    far = _landmark_distances(indptr, indices, data, scaled, labels, count, delta, packed, chosen)
    if bits is None and chosen == 16 and far.shape[1] == 0 and count > 0 and len(scaled) > 0:
        # Empty only because no unit's weights fit 16 bits: a shortest path has at most _SMALL - 1 edges of under
        # 2**16 - 1 units each, so its distance stays within dijkstra's limit (2**32 - 2 less the heaviest
        # weight) in any unit whose weights fit; a too-long roadmap cannot be the cause here, as it can at 32 bits
        return landmark_distances(indptr, indices, data, scaled, labels, count, delta, 32)
    return far


@njit(cache=True, nogil=True)
def _landmark_distances(indptr, indices, data, scaled, labels, count, delta, packed, bits):
    """:func:`landmark_distances` with each edge packed into ``packed`` (its dtype twice ``bits`` wide)."""
    n = scaled.shape[0]
    if n == 0 or count == 0:
        return np.empty((n, 0))
    sizes = np.zeros(n, dtype=np.int64)
    for v in range(n):
        sizes[labels[v]] += 1
    largest = np.argmax(sizes)
    count = min(count, sizes[largest])
    # the first landmark: the component's node farthest from its centroid
    d = scaled.shape[1]
    centre = np.zeros(d)
    for v in range(n):
        if labels[v] == largest:
            for k in range(d):
                centre[k] += scaled[v, k]
    for k in range(d):
        centre[k] /= sizes[largest]
    first, best = -1, -1.0
    for v in range(n):
        if labels[v] == largest:
            total = 0.0
            for k in range(d):
                total += (scaled[v, k] - centre[k]) ** 2
            if total > best:
                first, best = v, total
    far = np.empty((n, count))
    column = np.empty(n, dtype=np.uint32)
    ring_head = np.full(_RING, -1, dtype=np.int32)
    entries = indices.shape[0] // 4 + n + 64
    entry_node = np.empty(entries, dtype=np.uint32)
    entry_bucket = np.empty(entries, dtype=np.int64)
    entry_next = np.empty(entries, dtype=np.int32)
    degree = 0
    for v in range(n):
        degree = max(degree, np.int64(indptr[v + 1]) - np.int64(indptr[v]))
    better = np.empty(degree, dtype=packed.dtype)
    for shift in _SHIFTS:
        unit = delta / 2.0**shift
        limit = _pack(indices, data, unit, bits, packed)
        if limit < 0:
            continue
        nearest = np.full(n, np.inf)  # each node's distance to the nearest landmark so far
        landmark = first
        j = 0
        while j < count:
            used = dijkstra(indptr, packed, bits, np.uint32(limit), np.uint32(shift), landmark, column, ring_head,
                            entry_node, entry_bucket, entry_next, better)  # fmt: skip
            if used == -2:
                break  # too long for these units: all again in coarser ones
            if used == -1:
                entries *= 2  # ran out of entries (re-expansions): again with twice as many
                entry_node = np.empty(entries, dtype=np.uint32)
                entry_bucket = np.empty(entries, dtype=np.int64)
                entry_next = np.empty(entries, dtype=np.int32)
                continue
            landmark, best = -1, -1.0
            for v in range(n):
                distance = column[v] * unit if column[v] != _UNREACHED_UNITS else np.inf
                far[v, j] = distance
                nearest[v] = min(nearest[v], distance)
                if labels[v] == largest and nearest[v] > best:
                    landmark, best = v, nearest[v]
            j += 1
        if j == count:
            return far
    return np.empty((n, 0))


def _compile() -> None:
    indptr = np.array([0, 1, 2], dtype=np.uint32)
    indices = np.array([1, 0], dtype=np.uint32)
    for bits in (16, 32):  # both packings (the second for roadmaps of more than _SMALL milestones)
        landmark_distances(indptr, indices, np.ones(2), np.zeros((2, 3)), np.zeros(2, dtype=np.int64), 2, 0.1, bits)


_compile()
