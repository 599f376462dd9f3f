"""PathRepair (paper 000, Algorithm 4): replace every stretch of R's path through the risk region
that R_safe can replace; what no repair spans is a critical region."""

from __future__ import annotations

import numpy as np

from .search import SAFE, Query, edge_kinds, search


def repair(path: list[int], safe_node: np.ndarray, q: Query, nodes: np.ndarray) -> tuple[list[int], list[str], int]:
    """Algorithm 4 (PathRepair) on node indices; returns the path, its edge kinds, repairs made.

    From each safe milestone p_l, the last safe milestone p_m of the path in
    the same R_safe component is found; unless P[l..m] is already safe it is
    replaced by the shortest R_safe path from p_l to p_m. Risk milestones
    that no repair spans stay: they are the critical regions.
    """
    space = q.roadmap.space
    n_path = len(path)
    out: list[int] = []
    repaired = 0
    l = 0
    while l < n_path:
        p_l = path[l]
        m = l
        if safe_node[p_l]:
            for k in range(n_path - 1, l, -1):
                if safe_node[path[k]] and q.components.same(p_l, path[k]):
                    m = k
                    break
        if m == l:
            out.append(p_l)
            l += 1
            continue
        original = path[l : m + 1]
        if all(kind == SAFE for kind in edge_kinds(original, safe_node, q)):
            sub = original
        else:
            stretch = float(np.sum(space.distance(nodes[original[:-1]], nodes[original[1:]])))
            sub = search(q.roadmap.safe_csr, p_l, q, path[m], 1.5 * stretch, safe=True)
            if sub is None:  # pragma: no cover - same component guarantees a path
                sub = original
            else:
                repaired += 1
        out.extend(sub[:-1])
        l = m  # p_m is the last of its component on the path: the next round appends it and moves on
    return out, edge_kinds(out, safe_node, q), repaired
