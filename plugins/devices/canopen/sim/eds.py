"""EDS files (CiA 306) of the simulated drives, exported from the object dictionary they serve.

One source of truth: :func:`..cia402.drive_object_dictionary` builds the
dictionary a simulated drive serves; this module writes it as an electronic
data sheet with canopen's exporter, so that any CANopen tool (canopen's
``RemoteNode``/``BaseNode402``, a PLC's configurator) loads the drive's
dictionary as it would a vendor's file. The files ship in each device package
(``<device>/eds/<device>_<joint>.eds``, one per simulated drive: the defaults
differ per joint: travel, speed, encoder resolution); a test checks that they
are exactly what this module writes today. Regenerate them after changing the
dictionary::

    python -m surgiplan.plugins.devices.canopen.sim.eds --write

Relative values use ``$NODEID`` (COB-IDs, the serial number), so a file
serves any node id.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

from canopen import objectdictionary as od
from surgiplan.storage import write_text_atomic

from .. import cia402
from .drives import axis_hardware, simulated_devices

#: FileInfo of every exported file (fixed: the file changes only when the dictionary does)
FILE_INFO = {
    "FileVersion": 2,
    "FileRevision": 0,
    "EDSVersion": "4.0",
    "CreatedBy": "surgiplan",
    "CreationDate": "11-23-2026",
    "CreationTime": "12:00PM",
    "ModifiedBy": "surgiplan",
    "ModificationDate": "11-23-2026",
    "ModificationTime": "12:00PM",
}


def eds_text(dictionary: od.ObjectDictionary, file_name: str, description: str) -> str:
    """The EDS of ``dictionary`` (canopen's exporter, fixed file information)."""
    from canopen.objectdictionary import eds

    info = {"FileName": file_name, "Description": description, **FILE_INFO}
    # canopen's exporter takes the file information of a dictionary it imported from this attribute (else it
    # adds its own, with the time of export and a second EDS version key)
    setattr(dictionary, "__edsFileInfo", info)
    buffer = io.StringIO()
    eds.export_eds(dictionary, buffer, dict(info))
    return buffer.getvalue()


def eds_name(device: str, joint: str) -> str:
    return f"{device}_{joint}.eds"


def device_eds(device_cls, device: str) -> dict[Path, str]:
    """The EDS text of each simulated drive of a CiA 402 device class (its default settings)."""
    instance = device_cls(device_cls.Settings.model_validate({}))
    instance.model = instance.build_model()
    hardware = axis_hardware(instance)
    sync = instance.settings.simulation.sync_timeout
    out = {}
    folder = instance.eds_folder()
    for axis in hardware:
        dictionary = cia402.drive_object_dictionary(axis.node_id, axis.defaults(device, sync))
        name = eds_name(device, axis.name)
        description = f"{device} joint {axis.name}: surgiplan's simulated CiA 402 servo drive"
        out[folder / name] = eds_text(dictionary, name, description)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="write (or check) the simulated drives' EDS files")
    parser.add_argument("--write", action="store_true", help="write the files (default: check them)")
    args = parser.parse_args(argv)
    stale = []
    for name, cls in sorted(simulated_devices().items()):
        for path, text in device_eds(cls, name).items():
            current = path.read_text() if path.exists() else None
            if current == text:
                continue
            if args.write:
                write_text_atomic(path, text)
                print(f"wrote {path}")
            else:
                stale.append(path)
    for path in stale:
        print(f"out of date: {path} (python -m surgiplan.plugins.devices.canopen.sim.eds --write)", file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
