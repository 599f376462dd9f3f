"""The device blocks, which their benchmarks render themselves.

The CiA 402 control loop (``bench_devices.py``, its table in ``devices_table.py``) and the MAVLink flights
(``bench_mavlink.py``).
"""

from __future__ import annotations

from pathlib import Path

from .formatting import bench_module, load


def render_devices(results: Path) -> str:
    data = load(results, "devices")
    return bench_module("devices_table").readme_table(data)


def _mavlink_tables(results: Path) -> list[str]:
    rows = load(results, "mavlink")["rows"]
    return bench_module("bench_mavlink").markdown(rows).strip().split("\n\n")


def render_mavlink_hall(results: Path) -> str:
    return _mavlink_tables(results)[0]


def render_mavlink(results: Path) -> str:
    return "\n\n".join(_mavlink_tables(results)[1:])
