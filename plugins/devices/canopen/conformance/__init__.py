"""The CiA conformance test families, for the drives of a CiA 402 device: simulated or real.

The families and their cases follow what CiA's conformance test tool (CTT) checks of a CANopen device
(its families are public, the tool is not), driven by canopen's own master classes (``Network``,
``RemoteNode``, ``SdoClient``, ``PdoMap``, ``LssMaster``) over any python-can interface:

* :mod:`.family_lss` — LSS (CiA 305): fast scan, node-ID and bit timing, store, the other services;
* :mod:`.family_eds` — the EDS parses with canopen, is consistent (:mod:`.eds_check`, CiA 306) and is the
  drive's dictionary (objects, access, defaults; nothing more in the drive);
* :mod:`.family_sdo` — expedited, segmented and block transfers, and every abort;
* :mod:`.family_pdo` — the mapping procedure and its refusals, the transmission types, inhibit time and
  event timer, RPDOs;
* :mod:`.family_errors` — EMCY against 0x1001/0x1003, error reset, heartbeat producer and consumer,
  node guarding;
* :mod:`.family_nmt` — every NMT command from every state, resets, STOPPED;
* :mod:`.family_store` — store and restore, over a power cycle.

The expectations come from the EDS and from the standards (:mod:`.standard`), never from the drives'
code. :func:`.suite.run_conformance` runs them (``surgiplan canopen-conformance DEVICE``); the simulated
drives run in a process of their own (:mod:`.target`), so this package imports nothing of the simulator.
"""

from .suite import FAMILIES, ConformanceSettings, Report, run_conformance

__all__ = ["FAMILIES", "ConformanceSettings", "Report", "run_conformance"]
