"""PathRepair (paper 000, Algorithm 4): replace every stretch of R's path through the risk region
that R_safe can replace; what no repair spans is a critical region."""

from __future__ import annotations

import numpy as np

from .search import SAFE, Query, edge_kinds, search


def repair(
    path: list[int], safe_node: np.ndarray, q: Query, kinds: list[str], avoided: list[list[int]] | None = None
) -> tuple[list[int], list[str], int]:
    """Algorithm 4 (PathRepair) on node indices; returns the path, its edge kinds, repairs made.

    From each safe milestone p_l, the last safe milestone p_m of the path in
    the same R_safe component is found; unless P[l..m] is already safe it is
    replaced by the shortest R_safe path from p_l to p_m. Risk milestones
    that no repair spans stay: they are the critical regions. ``kinds``: the
    kind of each edge of ``path``. ``avoided``, when given, collects the nodes of each risky stretch a
    repair replaced (the passages a detour avoided: paper 000 Fig. 4's dashed ovals).
    """
    n_path = len(path)
    # the R_safe component of every safe node of the path, and the last position of each component
    on_path_safe = safe_node[np.asarray(path)]
    label = [q.components.find(p) if s else -1 for p, s in zip(path, on_path_safe, strict=True)]
    last: dict[int, int] = {}
    for k, c in enumerate(label):
        if c >= 0:
            last[c] = k
    out: list[int] = []
    repaired = 0
    l = 0
    while l < n_path:
        m = last[label[l]] if label[l] >= 0 else l
        if m <= l:
            out.append(path[l])
            l += 1
            continue
        original = path[l : m + 1]
        if all(kind == SAFE for kind in kinds[l:m]):
            sub = original
        else:
            sub = search(q.roadmap.safe_csr, path[l], q, path[m], safe=True)
            if sub is None:  # pragma: no cover - same component guarantees a path
                sub = original
            else:
                repaired += 1
                if avoided is not None:
                    risky = [
                        k for k in range(l, m + 1) if (k > l and kinds[k - 1] != SAFE) or (k < m and kinds[k] != SAFE)
                    ]
                    avoided.append([path[k] for k in risky])
        out.extend(sub[:-1])
        l = m  # p_m is the last of its component on the path: the next round appends it and moves on
    return out, edge_kinds(out, safe_node, q), repaired
