"""Certifying many motions at once, mostly without distance queries (covering balls).

Every planner that builds a graph of motions needs the same check: does the
motion q1 -> q2 keep ``margin`` from every obstacle? Clearances already
measured at the two ends bound how far any body point may travel from each
end before it could lose the margin; if the two reaches cover the motion's
speed bound (the space's :meth:`~surgiplan.spaces.base.Space.motion_speed_bound`)
the motion is certified for free, else the space's own certified
:meth:`~surgiplan.spaces.base.Space.motion_is_clear` decides.
"""

from __future__ import annotations

import numpy as np
from surgiplan.spaces.base import Space


def certify_edges(
    space: Space, q1: np.ndarray, q2: np.ndarray, slack1: np.ndarray, slack2: np.ndarray, margin: float
) -> tuple[np.ndarray, int]:
    """Which motions q1[i] → q2[i] keep ``margin``; certified, mostly without distance queries.

    ``slack1``/``slack2``: the clearance beyond ``margin`` at each end. If
    they add up to the motion's speed bound (how far any body point travels),
    the balls around the two ends cover the motion. The others get
    ``space.motion_is_clear``. Returns the decisions and how many were
    covered for free.
    """
    ok = np.zeros(len(q1), dtype=bool)
    ends = (slack1 > 0) & (slack2 > 0) if margin <= 0 else (slack1 >= 0) & (slack2 >= 0)
    reach = space.motion_speed_bound(q1, q2)
    covered = ends & (slack1 + slack2 > reach)
    ok[covered] = True
    rest = ends & ~covered
    if np.any(rest):
        ok[rest] = space.motion_is_clear(q1[rest], q2[rest], margin)
    return ok, int(np.count_nonzero(covered))
