"""Douglas-Peucker thinning of a path whose every kept chord is certified clear.

Used wherever a dense certified path becomes a few waypoints: safe_prm's
smoothing drops the redundant waypoints of straight stretches, and the
MAVLink vehicle turns a planned path into mission items.
"""

from __future__ import annotations

import numpy as np
from surgiplan.spaces.base import Space


def thin(
    space: Space, path: np.ndarray, segment_margins: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray]:
    """Douglas-Peucker on the tip positions; every kept chord certified against the strictest
    margin of the segments it replaces. Returns the thinned path and its segment margins."""
    tips = space.tip(path)
    keep = np.zeros(len(path), dtype=bool)
    keep[[0, -1]] = True
    stack = [(0, len(path) - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = tips[i], tips[j]
        ab = b - a
        length_sq = float(ab @ ab)
        t = np.clip(((tips[i + 1 : j] - a) @ ab) / length_sq, 0, 1) if length_sq > 0 else np.zeros(j - i - 1)
        deviation = np.linalg.norm(tips[i + 1 : j] - (a + t[:, None] * ab), axis=1)
        worst = int(np.argmax(deviation))
        margin = float(segment_margins[i:j].max())
        if deviation[worst] <= tolerance and space.motion_is_clear(path[i][None], path[j][None], margin)[0]:
            continue
        split = i + 1 + worst
        keep[split] = True
        stack += [(i, split), (split, j)]
    index = np.flatnonzero(keep)
    margins = np.maximum.reduceat(segment_margins, index[:-1])
    return path[index], margins
