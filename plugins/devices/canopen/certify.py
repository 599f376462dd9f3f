"""Certified clearance of a timed joint trajectory, over the whole motion the drives will make.

In cyclic synchronous position mode the drives interpolate linearly between
the samples they receive, one per control period: the motion is the joint-
space polyline through the timed samples, and *that* is what is certified,
between the samples too, not only at them.

For a body (the gimbal's shaft, the gripper's jaws, its links, the tip) given
its exact clearance ``c(q)`` at configurations and a bound ``s`` on how far any
of its points moves along a joint-space segment (its speed bound), the
clearance along the segment from ``q_a`` to ``q_b`` is at least
``(c(q_a) + c(q_b) - s) / 2`` (each point moves at most ``s t`` by the
parameter ``t``, and distance to the obstacles is 1-Lipschitz). Segments
whose bound falls below the margin are bisected, all at once per round,
until the bound clears the margin or the pieces are shorter than twice the
tolerance, where the bound is within ``tolerance`` of the true minimum: so the
result is never optimistic, and at most ``tolerance`` pessimistic where it
matters (near or below the margin).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: how far (m) a certified clearance may be below the true minimum, where it is close to the margin
TOLERANCE = 1e-5


@dataclass
class Certificate:
    """The lowest certified clearance of one body along a timed trajectory."""

    body: str
    #: certified lower bound of the body's clearance over the whole motion (m)
    lowest: float
    #: the segment (sample index k: from sample k to k+1) where it is, and the parameter along it
    segment: int
    fraction: float
    #: clearance at each sample (m), exact
    at_samples: np.ndarray


def certify(
    body: str,
    clearance: Callable[[np.ndarray], np.ndarray],
    speed: Callable[[np.ndarray, np.ndarray], np.ndarray],
    q: np.ndarray,
    margin: float,
    tolerance: float = TOLERANCE,
    max_rounds: int = 40,
) -> Certificate:
    """Certify the joint-space polyline through ``q`` (n, nq) for one body (see the module docstring).

    ``clearance(q)``: exact clearance (m) at configurations (k, nq); ``speed(q_a, q_b)``: bound (m) on the
    motion of any point of the body along each joint-linear segment.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    at = np.asarray(clearance(q), dtype=float)
    if len(q) < 2:
        return Certificate(body, float(at.min()), 0, 0.0, at)
    a, b = q[:-1], q[1:]
    s = np.asarray(speed(a, b), dtype=float)
    bound = (at[:-1] + at[1:] - s) / 2
    bound = np.minimum(bound, np.minimum(at[:-1], at[1:]))  # never above a sampled value
    result = bound.copy()
    where = np.full(len(bound), 0.5)  # parameter of each segment's lowest point (approximate)
    tight = np.zeros(len(bound), dtype=bool)

    def refine(segments, goal):
        lo, t_at = _bisect(clearance, speed, a[segments], b[segments], at[:-1][segments], at[1:][segments], goal,
                           tolerance, max_rounds)  # fmt: skip
        result[segments] = lo
        where[segments] = t_at

    # where the bound could hide a clearance below the margin: refine until decided
    low = np.flatnonzero(bound < margin + tolerance)
    if len(low):
        refine(low, margin)
    # what is reported, the lowest: refined to the tolerance, until the lowest segment is a refined one (a fast
    # segment's plain bound is loose by up to half its motion)
    for _ in range(50):
        candidates = np.argsort(np.where(tight, np.inf, result))[:8]
        candidates = candidates[~tight[candidates]]
        if not len(candidates) or tight[int(np.argmin(result))]:
            break
        refine(candidates, np.inf)
        tight[candidates] = True
    k = int(np.argmin(result))
    return Certificate(body, float(result[k]), k, float(where[k]), at)


def _bisect(clearance, speed, a, b, ca, cb, margin, tolerance, max_rounds):
    """Per segment, a certified lower bound (within ``tolerance`` where it is below ``margin``)."""
    m = len(a)
    best = np.full(m, np.inf)
    best_t = np.zeros(m)
    # pieces: owner segment, t0, t1, configurations and clearances at both ends, speed bound
    owner = np.arange(m)
    t0, t1 = np.zeros(m), np.ones(m)
    qa, qb, c0, c1 = a, b, ca, cb
    s = np.asarray(speed(qa, qb), dtype=float)
    for _ in range(max_rounds):
        bound = np.minimum((c0 + c1 - s) / 2, np.minimum(c0, c1))
        final = (bound >= margin) | (s <= 2 * tolerance)
        if np.any(final):
            _record(best, best_t, owner[final], bound[final], 0.5 * (t0[final] + t1[final]))
        keep = ~final
        # a piece whose bound is above the owner's best known value cannot lower it: drop it too
        keep &= bound < best[owner]
        if not np.any(keep):
            return best, best_t
        owner, t0, t1, qa, qb, c0, c1 = owner[keep], t0[keep], t1[keep], qa[keep], qb[keep], c0[keep], c1[keep]
        qm = 0.5 * (qa + qb)
        cm = np.asarray(clearance(qm), dtype=float)
        tm = 0.5 * (t0 + t1)
        _record(best, best_t, owner, cm, tm)  # sampled values are exact: an upper bound of the minimum
        owner = np.concatenate([owner, owner])
        t0, t1 = np.concatenate([t0, tm]), np.concatenate([tm, t1])
        qa, qb = np.concatenate([qa, qm]), np.concatenate([qm, qb])
        c0, c1 = np.concatenate([c0, cm]), np.concatenate([cm, c1])
        s = np.asarray(speed(qa, qb), dtype=float)
    # not resolved within max_rounds: the plain bound stands (conservative)
    bound = np.minimum((c0 + c1 - s) / 2, np.minimum(c0, c1))
    _record(best, best_t, owner, bound, 0.5 * (t0 + t1))
    return best, best_t


def _record(best, best_t, owner, value, t) -> None:
    order = np.argsort(value)[::-1]  # assign the lowest last, so it wins on repeated owners
    owner, value, t = owner[order], value[order], t[order]
    better = value < best[owner]
    best[owner[better]] = value[better]
    best_t[owner[better]] = t[better]
