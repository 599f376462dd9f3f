"""The CiA conformance test families on every drive of the built-in CiA 402 devices (the README's table).

Runs ``surgiplan canopen-conformance DEVICE`` (its function: the device class's ``conformance``, found by
registered name) for ``cast_gimbal`` (4 drives) and ``gripper6`` (6), each on its simulated drives in a
process of their own on the loopback bus, with the command's default settings (the standard object
dictionary scan), and writes ``results/canopen_conformance.json``: per device the verdict and evidence
of every case on every drive, the counts, and how long each case and the whole run took::

    python benchmarks/bench_canopen_conformance.py            # both devices (about 2 minutes)
    python benchmarks/bench_canopen_conformance.py --quick    # the NMT family only, not saved
"""

from __future__ import annotations

import argparse
import os
import time
from importlib.metadata import version

from common import save

DEVICES = ("cast_gimbal", "gripper6")


def run(device: str, families: list[str] | None) -> dict:
    from surgiplan.registry import default_registry

    cls = default_registry().get("device", device).cls
    load = os.getloadavg()
    started = time.perf_counter()
    report = cls.conformance(device, {"families": families}, progress=lambda text: print(f"  {device}: {text}"))
    payload = report.as_dict()
    payload["wall_s"] = round(time.perf_counter() - started, 1)
    payload["load_average_at_start"] = [round(x, 2) for x in load]
    payload["drives"] = len({row["node"] for row in payload["rows"]})
    return payload


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the NMT family only, not saved (a check of the script)")
    args = parser.parse_args()
    rows = [run(device, ["NMT"] if args.quick else None) for device in DEVICES]
    for row in rows:
        print(f"{row['device']}: {row['counts']} in {row['wall_s']} s")
    if args.quick:
        return
    notes = (
        "surgiplan canopen-conformance DEVICE, default settings (standard scan 0x1000-0x1FFF and 0x6000-0x67FF, "
        "SDO time-out 1 s, LSS fast scan step time-out 0.15 s); the simulated drives in a process of their own "
        "(surgiplan-sim-drives --unconfigured), canopen's master here, on the loopback python-can interface "
        "(127.0.0.1); one device after the other; wall_s includes the drives' two process starts"
    )
    peers = {
        "canopen": {
            "version": version("canopen"),
            "configuration": "master classes: Network, RemoteNode, SdoClient, PdoMap, LssMaster",
        },
        "python-can": {"version": version("python-can"), "configuration": "interface loopback (surgiplan's)"},
    }
    print(f"written {save('canopen_conformance', rows, notes, peers=peers)}")


if __name__ == "__main__":
    main()
