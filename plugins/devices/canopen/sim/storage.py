"""The simulated drive's non-volatile memory: parameters stored by CiA 301's 0x1010, defaults restored by
0x1011, and the LSS configuration (CiA 305's *store configuration*).

* 0x1010 sub-index 1 (all parameters, 0x1000-0x9FFF), 2 (communication, 0x1000-0x1FFF), 3 (application,
  0x6000-0x9FFF): writing the signature "save" (0x65766173) stores the current values of the area's
  parameters; any other value is aborted 0x08000020. Reading says the drive saves on command (1).
* 0x1011 the same sub-indices: "load" (0x64616F6C) forgets the stored values of the area, so that the next
  reset (NMT reset node; for sub-index 2 also reset communication) or power-up brings back the defaults of
  the EDS; any other value is aborted 0x08000020.
* Stored values take effect at power-up, at *reset node* (every area) and at *reset communication* (the
  communication area), after the defaults: what a reset restores is what was stored.

A parameter is a writable object, except 0x1003 (the error history), 0x1010/0x1011 themselves and the
process outputs the default RPDO mappings carry (controlword, targets, mode of operation: set-points, not
settings).

With a file (``surgiplan-sim-drives --state-dir``) the memory survives the drives' process: one JSON file
per drive, written atomically at every store, as an EEPROM keeps its contents over a power cycle; without
one it lasts as long as the process (a power cycle forgets it).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from canopen.sdo import SdoAbortedError
from surgiplan.storage import write_json_atomic

from .. import cia402

log = logging.getLogger(__name__)

#: the areas of 0x1010/0x1011's sub-indices (inclusive index ranges)
AREAS = {1: (0x1000, 0x9FFF), 2: (0x1000, 0x1FFF), 3: (0x6000, 0x9FFF)}
#: CiA 301: the data cannot be transferred or stored to the application (a wrong signature)
ABORT_CANNOT_STORE = 0x08000020
#: objects that are not parameters
_NOT_STORED = {0x1003, 0x1010, 0x1011}
_PROCESS_OUTPUTS = {entry >> 16 for entries in cia402.DEFAULT_RPDO.values() for entry in entries}


def storable(obj) -> bool:
    """Whether object ``obj`` (an ODVariable) is a parameter 0x1010 stores."""
    return obj.writable and obj.index not in _NOT_STORED and obj.index not in _PROCESS_OUTPUTS


class Memory:
    """One drive's non-volatile memory: stored parameter values (raw bytes by index and sub-index) and the
    LSS configuration (pending node-ID and bit rate stored by CiA 305)."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.parameters: dict[tuple[int, int], bytes] = {}
        self.lss: dict[str, int] = {}
        if path is not None and path.is_file():
            try:
                content = json.loads(path.read_text())
                self.parameters = {
                    (int(index, 16), int(sub)): bytes.fromhex(raw)
                    for key, raw in content.get("parameters", {}).items()
                    for index, sub in [key.split(":")]
                }
                self.lss = {key: int(value) for key, value in content.get("lss", {}).items()}
            except (ValueError, OSError, AttributeError) as exc:  # a damaged memory: the drive starts from defaults
                log.warning("%s: unreadable (%s); starting from the defaults", path, exc)
                self.parameters, self.lss = {}, {}

    def _write(self) -> None:
        if self.path is None:
            return
        parameters = {f"{index:04X}:{sub}": raw.hex() for (index, sub), raw in sorted(self.parameters.items())}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.path, {"parameters": parameters, "lss": self.lss})

    # ------------------------------------------------------------------ 0x1010, 0x1011
    def command(self, node, index: int, subindex: int, value: int) -> None:
        """A write to 0x1010 (store) or 0x1011 (restore): act on the signature or abort 0x08000020."""
        area = AREAS.get(subindex)
        if area is None:
            raise SdoAbortedError(0x06090011)
        signature = cia402.SAVE_SIGNATURE if index == 0x1010 else cia402.LOAD_SIGNATURE
        if value != signature:
            raise SdoAbortedError(ABORT_CANNOT_STORE)
        lo, hi = area
        if index == 0x1011:
            self.parameters = {key: raw for key, raw in self.parameters.items() if not lo <= key[0] <= hi}
        else:
            for obj in _variables(node.object_dictionary):
                if lo <= obj.index <= hi and storable(obj):
                    self.parameters[(obj.index, obj.subindex)] = bytes(node.get_data(obj.index, obj.subindex))
        try:
            self._write()
        except OSError as exc:
            log.warning("%s: cannot store (%s)", self.path, exc)
            raise SdoAbortedError(ABORT_CANNOT_STORE) from None

    def apply(self, node, lo: int, hi: int) -> None:
        """Put the stored values of indices ``lo``-``hi`` into ``node``'s data store (after a reset)."""
        for (index, sub), raw in self.parameters.items():
            if lo <= index <= hi:
                node.data_store.setdefault(index, {})[sub] = raw

    # ------------------------------------------------------------------ LSS
    def store_lss(self, node_id: int, bit_rate: int) -> None:
        self.lss = {"node_id": node_id, "bit_rate": bit_rate}
        self._write()


def _variables(dictionary):
    for obj in dictionary.values():
        if hasattr(obj, "subindices"):
            yield from obj.values()
        else:
            yield obj
