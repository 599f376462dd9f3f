"""Simulated CiA 402 drives in a process of their own, on any python-can bus.

``surgiplan-sim-drives`` (or ``python -m surgiplan.plugins.devices.canopen.sim.process``)
runs the drives of a device (``cast_gimbal``: 4 axes, ``gripper6``: 6) in real
time on the bus you name, as real drives would be: outside the process of the
master, reached only through CAN frames. A pipeline then talks to them with
exactly the settings it would use for hardware. The default interface is
surgiplan's ``loopback`` (a python-can interface: a hub on 127.0.0.1 that
this process hosts, relayed by the drives' own thread as it receives, so that
a SYNC reaches the drives without a hand-over between threads; no CAN
hardware or kernel module needed, and nothing leaves the machine)::

    surgiplan-sim-drives --device cast_gimbal --channel 43113 --initial 0 0.6 0.12 0

    # in the pipeline's execute stage
    settings: {bus: {interface: loopback, channel: 43113}}

or on a virtual SocketCAN interface (``ip link add dev vcan0 type vcan``) with
``--interface socketcan --channel vcan0``. The drives use the device's
defaults (encoder resolution, current and speed limits) unless told
otherwise; ``--initial`` is where the axes stand at power-up (SI units per
joint). It prints ``ready`` once the nodes are up and runs until interrupted.

``--state-dir DIR`` is the drives' non-volatile memory: what a master stores
(CiA 301 0x1010, LSS *store configuration*) is written there, one file per
drive, and found again when the drives are started with the same folder (a
power cycle); without it a restart forgets. ``--unconfigured`` starts the
drives without node-IDs (unless LSS stored one in the state dir): they wait
for a master to give them one by LSS (CiA 305, :mod:`.lss`).
"""

from __future__ import annotations

import argparse
import gc
import json
import signal
import sys
import threading
from pathlib import Path

import numpy as np
from surgiplan.errors import SurgiplanError
from surgiplan.scheduling import SWITCH_INTERVAL

from ..bus import ArmedFaults, BusSettings, open_bus
from ..clock import RealTimeClock
from .drives import DriveSimulator, axis_hardware, simulated_devices
from .motor import HandMotion, MotorModel


def _option(text: str) -> tuple[str, object]:
    key, _, value = text.partition("=")
    if not key or not value:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got '{text}'")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def build_simulator(args: argparse.Namespace) -> DriveSimulator:
    """The drives of ``args.device`` on the bus the arguments name (raises SurgiplanError)."""
    devices = simulated_devices()
    if args.device not in devices:
        raise SurgiplanError(
            f"no CiA 402 device plugin named '{args.device}' (installed: {', '.join(sorted(devices))})"
        )
    cls = devices[args.device]
    options = dict(args.option)
    if args.interface == "loopback":  # hosting the hub: the drives' thread relays as it receives (one thread)
        options.setdefault("hub_thread", False)
    settings = {"bus": {"interface": args.interface, "channel": args.channel, "options": options}}
    if args.node_ids:
        settings["node_ids"] = args.node_ids
    settings["simulation"] = {}
    if args.initial:
        settings["simulation"]["initial"] = args.initial
    if args.sync_timeout:
        settings["simulation"]["sync_timeout"] = args.sync_timeout
    device = cls(cls.Settings.model_validate(settings))
    device.model = device.build_model()
    hardware = axis_hardware(device)  # the settings are checked before the bus is opened
    model = MotorModel.of(device.settings.simulation)
    hand = read_hand(args.hand, len(hardware)) if args.hand else None  # refused before the bus is opened
    for name, values in (("--hand-stiffness", args.hand_stiffness), ("--hand-damping", args.hand_damping)):
        if values is not None and (len(values) not in (1, len(hardware)) or min(values) < 0):
            raise SurgiplanError(f"{name}: one value >= 0, or one per axis ({len(hardware)}); got {values}")
    bus, _ = open_bus(BusSettings.model_validate(settings["bus"]))
    clock = RealTimeClock()
    state = Path(args.state_dir) if args.state_dir else None
    simulator = DriveSimulator(bus, hardware, model, clock, ArmedFaults([], clock.now), link=None,
                               device=args.device, memory=state, unconfigured=args.unconfigured)  # fmt: skip
    if hand is not None:
        hold_hand(simulator, *hand, args.hand_stiffness, args.hand_damping)
    return simulator


def read_hand(path: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The times (s) and joints (n axes) of ``--hand``'s .npz file (raises SurgiplanError naming it)."""
    try:
        with np.load(path) as data:
            times, joints = np.asarray(data["times"], dtype=float), np.asarray(data["joints"], dtype=float)
    except (OSError, KeyError, ValueError) as exc:
        raise SurgiplanError(f"--hand {path}: not an .npz file with arrays 'times' and 'joints' ({exc})") from None
    if times.ndim != 1 or len(times) < 2 or joints.shape != (len(times), n) or np.any(np.diff(times) <= 0):
        raise SurgiplanError(
            f"--hand {path}: 'times' must be increasing (at least 2) and 'joints' ({len(times)}, {n}) for the "
            f"device's {n} axes; got times {times.shape}, joints {joints.shape}"
        )
    return times, joints


def hold_hand(simulator: DriveSimulator, times: np.ndarray, joints: np.ndarray, stiffness, damping) -> None:
    """The trainee's hand on the drives (:meth:`DriveSimulator.move_by_hand`), its time 0 the first SYNC."""
    hand = HandMotion(times, joints)

    def first_sync(*_frame) -> None:
        if hand.start is None:
            hand.start = simulator.clock.now()

    simulator.network.subscribe(0x80, first_sync)
    simulator.move_by_hand(hand, stiffness, damping)


def main(argv: list[str] | None = None) -> int:
    from surgiplan.processes import exit_with_parent

    exit_with_parent()  # started by a run or a test with surgiplan.processes.child_env(): never outlive it
    parser = argparse.ArgumentParser(prog="surgiplan-sim-drives", description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cast_gimbal", help="a CiA 402 device plugin (cast_gimbal, gripper6, ...)")
    parser.add_argument(
        "--interface", default="loopback", help="python-can interface (default loopback: 127.0.0.1 only)"
    )
    parser.add_argument("--channel", required=True, help="loopback: a port on 127.0.0.1; socketcan: vcan0, ...")
    parser.add_argument("--option", type=_option, action="append", default=[], help="bus option KEY=VALUE")
    parser.add_argument("--node-ids", type=int, nargs="+")
    parser.add_argument("--initial", type=float, nargs="+", help="joint positions at power-up (SI)")
    parser.add_argument("--sync-timeout", type=float, help="s without SYNC before an enabled drive quick-stops")
    parser.add_argument(
        "--realtime-priority", type=int, help="run the drives' threads under SCHED_FIFO at this priority (1-99)"
    )
    parser.add_argument("--state-dir", help="the drives' non-volatile memory (0x1010 stores, LSS configuration)")
    parser.add_argument("--hand", help="simulation: the trainee's hand, an .npz of times (s) and joints; 0 = 1st SYNC")
    parser.add_argument("--hand-stiffness", type=float, nargs="+", help="the hand's spring per axis (N·m/rad, N/m)")
    parser.add_argument("--hand-damping", type=float, nargs="+", help="the hand's damper per axis (N·m·s/rad, N·s/m)")
    parser.add_argument(
        "--unconfigured", action="store_true", help="start without node-IDs (unless LSS stored one): set them by LSS"
    )
    args = parser.parse_args(argv)
    try:
        simulator = build_simulator(args)
    except SurgiplanError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    try:
        simulator.start(args.realtime_priority)
    except SurgiplanError as exc:  # a malformed SURGIPLAN_CPU_LATENCY_US
        print(f"error: {exc}", file=sys.stderr)
        simulator.close()
        return 2
    except OSError as exc:
        print(f"error: --realtime-priority {args.realtime_priority}: {exc}", file=sys.stderr)
        simulator.close()
        return 2
    # what start-up made (imports, the nodes and their dictionaries: some 10^5 objects) is kept out of the cyclic
    # garbage collector: a full collection of it stopped every drive thread for 75-150 ms (measured at start-up),
    # twice the SYNC watchdog's patience at 1 kHz were it to fall in a run; the frames handled afterwards are freed
    # by reference counting (no collection at all was seen in 12 s at 1 kHz once frozen)
    gc.collect()
    gc.freeze()
    # a thread that wants the GIL (a hub's thread, asked for with --option hub_thread=true) waits at most this long
    # behind the drives' work, not Python's 5 ms
    sys.setswitchinterval(SWITCH_INTERVAL)
    print("ready", flush=True)
    try:
        stop.wait()
    finally:
        simulator.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
