"""Running the conformance families on a device's drives, and the report: family, case, verdict, evidence.

:func:`run_conformance` takes a CiA 402 device class (a registered device plugin), finds its drives (node-IDs
and EDS files from the device's settings), starts its simulated drives in a process of their own or joins a
real bus, runs the families in order (LSS first: it gives the drives their node-IDs) and returns a
:class:`Report`, one row per case and drive.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import Field, PositiveFloat, PositiveInt
from surgiplan.errors import ConfigError
from surgiplan.models import StrictModel

from .cases import Family, Verdict, failed
from .family_eds import EDS
from .family_errors import ERRORS
from .family_lss import LSS
from .family_nmt import NMT
from .family_pdo import PDO
from .family_pdo_timing import PDO as PDO_TIMING
from .family_sdo import SDO
from .family_store import STORE
from .session import Drive, Session, Timing
from .target import BusDrives, SimulatedDrives

log = logging.getLogger(__name__)

#: the families, in the order they run
FAMILIES: list[Family] = [LSS, EDS, SDO, PDO, PDO_TIMING, ERRORS, NMT, STORE]
SCANS = {
    "none": [],
    "standard": [(0x1000, 0x1FFF), (0x6000, 0x67FF)],
    "full": [(0x1000, 0x9FFF)],
}


class ConformanceSettings(StrictModel):
    """What to test and where: the simulated drives (default) or a real bus."""

    #: python-can interface of real drives (socketcan, pcan, kvaser, ...); None: the device's simulated drives
    interface: str | None = None
    channel: str | None = None
    bitrate: PositiveInt = 1_000_000
    #: further python-can Bus arguments
    options: dict[str, Any] = Field(default_factory=dict)
    #: the drives' node-IDs, one per joint (default: the device's)
    node_ids: list[int] | None = None
    #: each drive's EDS (one for all, or one per joint; default: the device's)
    eds: list[Path] | None = None
    #: families to run (names or case-id prefixes: "SDO", "PDO", "11"); None: every family
    families: list[str] | None = None
    #: the object dictionary scan (case 4.10): "standard" (0x1000-0x1FFF, 0x6000-0x67FF), "full", "none"
    scan: str = "standard"
    #: real drives: started without node-IDs (the LSS family configures them)
    unconfigured: bool = False
    #: real drives: the store/restore family may change what they keep over a power cycle
    allow_store: bool = False
    sdo_timeout: PositiveFloat = 1.0
    lss_timeout: PositiveFloat = 0.15


@dataclass
class Row:
    family: str
    case: str
    title: str
    node: int
    joint: str
    verdict: str
    evidence: str
    ctt: str = ""
    seconds: float = 0.0


@dataclass
class Report:
    device: str
    target: str
    rows: list[Row] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def failed(self) -> list[Row]:
        return [r for r in self.rows if r.verdict == Verdict.FAIL.value]

    def counts(self) -> dict[str, int]:
        out = {verdict.value: 0 for verdict in Verdict}
        for row in self.rows:
            out[row.verdict] += 1
        return out

    def cases(self) -> list[dict[str, Any]]:
        """One entry per case: its verdict over the drives (the worst), counts, and the evidence of the
        first drive with the worst verdict."""
        order = [
            Verdict.FAIL.value,
            Verdict.WARN.value,
            Verdict.PASS.value,
            Verdict.SKIPPED.value,
            Verdict.NOT_APPLICABLE.value,
        ]
        out: dict[str, dict[str, Any]] = {}
        for row in self.rows:
            entry = out.setdefault(
                row.case, {"family": row.family, "case": row.case, "title": row.title, "ctt": row.ctt, "rows": []}
            )
            entry["rows"].append(row)
        for entry in out.values():
            rows = entry.pop("rows")
            worst = min(rows, key=lambda r: order.index(r.verdict))
            entry["verdict"] = worst.verdict
            entry["drives"] = len(rows)
            entry["passed"] = sum(1 for r in rows if r.verdict == Verdict.PASS.value)
            entry["evidence"] = (
                f"{worst.joint}: {worst.evidence}" if worst.verdict != Verdict.PASS.value else worst.evidence
            )
            entry["seconds"] = round(max(r.seconds for r in rows), 3)
        return list(out.values())

    def as_dict(self) -> dict[str, Any]:
        return {
            "device": self.device,
            "target": self.target,
            "seconds": round(self.seconds, 2),
            "counts": self.counts(),
            "cases": self.cases(),
            "rows": [row.__dict__ for row in self.rows],
        }


def drives_of(device_cls, settings: ConformanceSettings) -> list[Drive]:
    """The device's drives: joint names, node-IDs and EDS files (its settings' defaults, or those given)."""
    values: dict[str, Any] = {}
    if settings.node_ids is not None:
        values["node_ids"] = settings.node_ids
    if settings.eds is not None:
        values["eds"] = settings.eds if len(settings.eds) > 1 else settings.eds[0]
    try:
        device = device_cls(device_cls.Settings.model_validate(values))
        device.model = device.build_model()
        joints = device.joints()
        files = device.eds_files()
    except ConfigError:
        raise
    except Exception as exc:  # a settings model's own validation error
        raise ConfigError(f"the device's settings: {exc}") from None
    names = device.model.joint_names
    return [
        Drive(name, int(node_id), Path(path)) for name, node_id, path in zip(names, joints.node_ids, files, strict=True)
    ]


def _selected(settings: ConformanceSettings) -> list[tuple[Family, list]]:
    chosen = []
    wanted = [w.lower() for w in settings.families or []]
    for family in FAMILIES:
        cases = [
            c
            for c in family.cases
            if not wanted or family.name.lower() in wanted or any(c.id.startswith(w) for w in wanted)
        ]
        if cases:
            chosen.append((family, cases))
    known = {f.name.lower() for f in FAMILIES} | {c.id.split(".")[0] for f in FAMILIES for c in f.cases}
    unknown = [w for w in wanted if w not in known and not any(c.id.startswith(w) for f in FAMILIES for c in f.cases)]
    if unknown:
        raise ConfigError(
            f"unknown family or case {', '.join(unknown)}; the families: {', '.join(f.name for f in FAMILIES)}"
        )
    return chosen


def run_conformance(
    device_cls, device: str, settings: ConformanceSettings, progress: Callable[[str], None] | None = None
) -> Report:
    """Run the families on ``device``'s drives (simulated unless ``settings.interface`` names a bus)."""
    if settings.scan not in SCANS:
        raise ConfigError(f"scan: '{settings.scan}' is not one of {', '.join(SCANS)}")
    drives = drives_of(device_cls, settings)
    chosen = _selected(settings)
    if settings.interface is None:
        target = SimulatedDrives(device, [d.node_id for d in drives])
        target.unconfigured = any(family is LSS for family, _ in chosen)  # without LSS: started with node-IDs
    else:
        if settings.channel is None:
            raise ConfigError(f"interface '{settings.interface}' needs a channel")
        target = BusDrives(
            settings.interface,
            settings.channel,
            settings.bitrate,
            dict(settings.options),
            unconfigured=settings.unconfigured,
            may_store=settings.allow_store,
        )
    report = Report(device, target.description)
    timing = Timing(sdo=settings.sdo_timeout, lss=settings.lss_timeout)
    session = Session(target, drives, timing, scan=SCANS[settings.scan])
    started = time.monotonic()
    # the suite provokes refusals and silences on purpose: canopen's warnings about them are not news
    canopen_log = logging.getLogger("canopen")
    level = canopen_log.level
    canopen_log.setLevel(logging.CRITICAL)
    try:
        session.open()
        for family, cases in chosen:
            for case in cases:
                if progress is not None:
                    progress(f"{family.name} {case.id}: {case.title}")
                began = time.monotonic()
                try:
                    findings = case.run(session)
                except Exception as exc:  # a case that cannot finish fails on every drive, saying why
                    log.debug("case %s raised", case.id, exc_info=True)
                    findings = {}
                    error = f"the case could not finish: {type(exc).__name__}: {exc}"
                    for drive in drives:
                        findings[drive.node_id] = failed(error)
                took = time.monotonic() - began
                for drive in drives:
                    finding = findings.get(drive.node_id)
                    if finding is None:
                        continue
                    report.rows.append(
                        Row(
                            family.name,
                            case.id,
                            case.title,
                            drive.node_id,
                            drive.joint,
                            finding.verdict.value,
                            finding.evidence,
                            case.ctt,
                            round(took, 3),
                        )
                    )
    finally:
        session.close()
        target.close()
        canopen_log.setLevel(level)
        report.seconds = time.monotonic() - started
    return report
