"""Resource estimates: refuse, at validation, work the machine's memory cannot hold.

``milestones: 1000000000`` is valid YAML and a positive integer; run, it
allocates until the machine swaps or the kernel kills it. So every plugin
class may say, from its settings alone and before any work starts, how much
memory its stage will need (:meth:`Planner.estimate_resources
<surgiplan.planning.Planner.estimate_resources>` and the same class method on
deformable models and devices). ``surgiplan validate`` and ``run`` compare
each estimate with :func:`memory_limit` and refuse the file, naming the
setting, the estimate and the limit, when one exceeds
:data:`USABLE_FRACTION` of it.

Estimates are meant to be right within a small factor, not exact: they
stop the order-of-magnitude mistakes (an extra zero, a unit slip), not a
run that would need 110 % of the machine.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

#: the part of the memory limit one stage may plan to use
USABLE_FRACTION = 0.8

_SIZE = re.compile(r"^\s*([0-9.]+)\s*([kKmMgGtT]?)i?[bB]?\s*$")


@dataclass(frozen=True)
class ResourceEstimate:
    """What a stage will need: ``memory_bytes`` for ``what``, driven by the setting named ``setting``."""

    memory_bytes: float
    what: str
    #: the key under the stage's ``settings`` that drives it (``milestones``), for the error's location
    setting: str = ""


def parse_size(text: str) -> int:
    """``"8G"``, ``"512M"``, ``"4 GiB"``, ``"1000000"`` -> bytes."""
    match = _SIZE.match(str(text))
    if not match:
        raise ValueError(f"not a memory size: {text!r} (e.g. 8G, 512M)")
    number, unit = match.groups()
    return int(float(number) * 1024 ** " KMGT".index(unit.upper() or " "))


def memory_limit() -> int:
    """Bytes this process may use: the physical memory, or a lower cgroup limit, or
    ``SURGIPLAN_MEMORY_LIMIT`` (e.g. ``8G``) when set."""
    override = os.environ.get("SURGIPLAN_MEMORY_LIMIT")
    if override:
        return parse_size(override)
    limit = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for cgroup in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(cgroup).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            limit = min(limit, int(text))
    return int(limit)


def human(n: float) -> str:
    """1.5e9 -> '1.4 GiB'."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024.0
    return f"{n:.3g} PiB"  # pragma: no cover


def too_large(estimates: list[ResourceEstimate], limit: int | None = None) -> list[tuple[ResourceEstimate, str]]:
    """The estimates above the usable memory, each with the sentence saying so."""
    limit = memory_limit() if limit is None else limit
    usable = USABLE_FRACTION * limit
    out = []
    for estimate in estimates:
        if estimate.memory_bytes > usable:
            out.append(
                (
                    estimate,
                    f"{estimate.what} needs about {human(estimate.memory_bytes)} of memory; this machine allows "
                    f"{human(usable)} ({USABLE_FRACTION:.0%} of {human(limit)}); reduce it",
                )
            )
    return out
