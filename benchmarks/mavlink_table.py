"""bench_mavlink.py's tables: the README's MAVLink blocks, rendered from results/mavlink.json's rows.

Light on purpose (no simulator): benchmarks/readme_tables.py renders the README's ``mavlink_hall`` and
``mavlink`` blocks with :func:`markdown` (through bench_mavlink, which re-exports it).
"""

from __future__ import annotations


def markdown(rows: list[dict]) -> str:
    """The MAVLink page's tables, from this run's rows (docs/howto/mavlink.md quotes them; a test checks)."""
    out = []
    hall = [r for r in rows if r["benchmark"] == "hall"]
    if hall:
        out += [
            "| flight | tracking error max / rms | flown min clearance: door (planned "
            f"{hall[0]['planned_door_clearance_m']:.2f}) | outside the door (threshold {hall[0]['threshold_m']:g}) "
            "| geofence (verified on the vehicle) |",
            "|---|---|---|---|---|",
        ]
        for r in hall:
            breaches = r["fence_breaches"]
            fence = f"{r['fence_items']} items, {breaches} breach{'es' if breaches != 1 else ''}"
            out.append(
                f"| {r['flight']} | {r['tracking_error_max_m']:.3f} / {r['tracking_error_rms_m']:.3f} m | "
                f"{r['door_min_clearance_m']:.3f} m | {r['outside_min_clearance_m']:.3f} m | {fence} |"
            )
        out.append("")
    upload = [r for r in rows if r["benchmark"] == "upload"]
    if upload:
        losses = sorted({r["loss"] for r in upload})
        out += [
            "| loss each way | " + " | ".join(f"{100 * p:g} %" if p else "0" for p in losses) + " |",
            "|---|" + "---|" * len(losses),
        ]
        for n in sorted({r["items"] for r in upload}):
            cells = []
            for p in losses:
                r = next(r for r in upload if r["items"] == n and r["loss"] == p)
                cells.append(f"{r['upload_s_median']:.3g} s ({r['predicted_s']:.3g})")
            out.append(f"| {n} items: upload (predicted) | " + " | ".join(cells) + " |")
        for n in sorted({r["items"] for r in upload}):
            cells = []
            for p in losses:
                r = next(r for r in upload if r["items"] == n and r["loss"] == p)
                cells.append(f"{r['download_s_median']:.3g} s, {r['verified']}")
            out.append(f"| {n} items: download back, verified | " + " | ".join(cells) + " |")
        out.append("")
    links = [r for r in rows if r["benchmark"] == "links"]
    if links:
        lossy = max(r["loss"] for r in links)
        out += [
            f"| transfer | no loss | {100 * lossy:g} % loss each way: completed | attempts (worst) "
            "| time median / worst | bound per attempt |",
            "|---|---|---|---|---|---|",
        ]
        for r in (r for r in links if r["loss"] == lossy):
            clean = next(c for c in links if c["loss"] == 0 and c["transfer"] == r["transfer"])
            if r["requests_median"] is not None:
                tries = (
                    f"{r['attempts_max']} ({r['requests_median']:g} requests, {r['retransmissions_median']:g} re-sent)"
                )
            elif r["read_requests_median"] is not None:
                tries = f"{r['attempts_max']} ({r['read_requests_median']:g} read again by index)"
            else:
                tries = f"{r['attempts_max']}"
            out.append(
                f"| {r['transfer']} | {clean['s_median']:.3g} s | {r['completed']} | {tries} | "
                f"{r['s_median']:.3g} / {r['s_max']:.3g} s | {r['bound_s']:g} s |"
            )
        out.append("")
    fence = [r for r in rows if r["benchmark"] == "fence"]
    if fence:
        r = fence[0]
        out += [
            "| fence rehearsal | the vehicle said | flown min clearance (threshold) | at rest | look-ahead |",
            "|---|---|---|---|---|",
            f"| offboard setpoints through {r['obstacle']} at {r['cruise_mps']:g} m/s: {r['status']} | "
            f"{r['vehicle_said']} | {r['flight_min_clearance_m']:.3f} m ({r['threshold_m']:g}) | "
            f"{r['final_fence_distance_m']:.2f} m before the fence | {r['look_ahead_m']:.2f} m "
            f"(braking {r['braking_distance_m']:.2f} m) |",
            "",
        ]
    tracking = [r for r in rows if r["benchmark"] == "tracking"]
    if tracking:
        gusts = sorted({r["gust_mps"] for r in tracking})
        out += [
            "| gusts (m/s, 0.5 m/s breeze) | " + " | ".join(f"{g:g}" for g in gusts) + " |",
            "|---|" + "---|" * len(gusts),
        ]
        for mode in ("mission", "offboard"):
            by = {r["gust_mps"]: r for r in tracking if r["mode"] == mode}
            out.append(f"| {mode}: completed | " + " | ".join(by[g]["completed"] for g in gusts) + " |")
            out.append(
                f"| {mode}: tracking error max | " + " | ".join(f"{by[g]['tracking_error_max_m']:.2f} m" for g in gusts)
                + " |"
            )  # fmt: skip
            out.append(
                f"| {mode}: door clearance | " + " | ".join(f"{by[g]['door_min_clearance_m']:.2f} m" for g in gusts)
                + " |"
            )  # fmt: skip
        out.append("")
    speed = [r for r in rows if r["benchmark"] == "speed"]
    lockstep = [r for r in rows if r["benchmark"] == "lockstep"]
    if speed or lockstep:
        out += ["| measure | value |", "|---|---|"]
        for r in speed:
            out.append(f"| simulator speed, telemetry {r['streams']} | {r['sustained_x_real_time']:g}x real time |")
        for r in lockstep:
            out.append(
                f"| offboard flight repeated, ground station stalling, lockstep_horizon {r['lockstep_horizon_s']:g} s |"
                f" setpoint error spread {1000 * r['spread_m']:.1f} mm, {r['wall_s_median']:g} s per flight |"
            )
        out.append("")
    loads = sorted({tuple(r["load_average_at_start"]) for r in rows})
    out.append("Load average (1, 5, 15 min) at the start of the sections: " + "; ".join(map(str, loads)) + ".")
    return "\n".join(out) + "\n"
