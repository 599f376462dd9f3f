"""The CANopen layer of the CiA 402 devices (``cast_gimbal``, ``gripper6``): CiA 301/402 over python-can.

Registers no plugin; the device packages build on it. The master side:

* :mod:`.bus` — opening a python-can bus, fault injection, exact bus load;
* :mod:`.cia402` — the drive profile (controlword, statusword, modes, NMT
  states) and the simulated drive's object dictionary;
* :mod:`.network`, :mod:`.clock` — the simulated and the real-time clock,
  and the pumped network that makes a simulated run deterministic;
* :mod:`.master` — the CANopen master through the ``canopen`` package: the
  standard start-up (reset communication, boot-ups, SDO configuration from
  the EDS, PDO mapping, start), SYNC, heartbeats both ways, EMCY;
* :mod:`.control` — the supervised cyclic synchronous position loop;
* :mod:`.timing` — time-optimal parameterisation (TOPP-RA) of joint paths;
* :mod:`.certify` — certified clearance of the timed motion (between samples
  too), which a device refuses before any motion when below its margin;
* :mod:`.settings`, :mod:`.joints`, :mod:`.device`, :mod:`.refusal` — the
  settings (per joint, checked against the model), lifecycle and refusals
  every CiA 402 device shares (:class:`~.device.Cia402Device`);
* :mod:`.report` — tracking metrics, bus load, the execution figure and log;
* :mod:`.conformance` — the CiA conformance test families (EDS, SDO, PDO, EMCY and error control, NMT,
  store and restore, LSS) on every drive of a CiA 402 device, simulated or real
  (``surgiplan canopen-conformance DEVICE``).

The simulated drives, the ``loopback`` python-can interface and the EDS
files of the simulated drives are :mod:`.sim`, which the master side never
imports.
"""
