"""The CANopen conformance table: every case on every drive of both devices (``bench_canopen_conformance.py``)."""

from __future__ import annotations

from pathlib import Path

from .formatting import ReadmeError, load, section, table


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render_canopen_conformance(results: Path) -> str:
    data = load(results, "canopen_conformance")
    devices = {row["device"]: row for row in data["rows"]}
    if set(devices) != {"cast_gimbal", "gripper6"}:
        raise ReadmeError(f"results/canopen_conformance.json: devices {sorted(devices)}, not cast_gimbal and gripper6")
    gimbal, gripper = devices["cast_gimbal"], devices["gripper6"]
    by_case = {case["case"]: case for case in gripper["cases"]}
    rows = []
    for case in gimbal["cases"]:
        other = by_case.get(case["case"])
        if other is None:
            raise ReadmeError(f"results/canopen_conformance.json: case {case['case']} ran on cast_gimbal only")

        def verdict(entry: dict) -> str:
            shown = entry["verdict"] if entry["verdict"] != "pass" else "pass"
            return f"{shown} {entry['passed']}/{entry['drives']}" if entry["verdict"] != "n/a" else "n/a"

        ctt = f" (CTT {case['ctt']})" if case["ctt"] else ""
        rows.append([case["family"], case["case"] + ctt, _cell(case["title"]), verdict(case), verdict(other),
                     _cell(case["evidence"])])  # fmt: skip
    counts = {device: row["counts"] for device, row in devices.items()}
    failed = sum(c["fail"] for c in counts.values())
    cases = len(gimbal["cases"])
    load_text = ", ".join(f"{row['load_average_at_start'][0]:.1f}" for row in devices.values())
    head = (
        f"Measured by `benchmarks/bench_canopen_conformance.py` (`surgiplan canopen-conformance DEVICE` with its "
        f"defaults, the simulated drives in a process of their own on the loopback bus; 2 shared cores, load "
        f"average {load_text} at the start of each device; `benchmarks/results/canopen_conformance.json`): "
        f"{cases} cases on each of the gimbal's {gimbal['drives']} and the gripper's {gripper['drives']} drives, "
        f"in {gimbal['wall_s']:.0f} s and {gripper['wall_s']:.0f} s. The pass columns count drives; the "
        "evidence is the gimbal's first drive's (or the first drive that did not pass)."
    )
    body = table(["family", "case", "checked", "cast_gimbal", "gripper6", "evidence"], rows)
    verdicts = "every case passes on every drive" if not failed else f"{failed} case-drive pairs fail"
    na = sum(c["n/a"] for c in counts.values())
    tail = f"Verdicts: {verdicts}" + (
        f"; {na} case-drive pairs are n/a, where the EDS says there is nothing to check (no write-only object)."
        if na
        else "."
    )
    return section(head, body, tail)
