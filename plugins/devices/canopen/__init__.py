"""The CANopen layer of the CiA 402 devices (``cast_gimbal``, ``gripper6``): CiA 301/402 over python-can.

Registers no plugin; the device packages build on it. Modules:

* :mod:`.loopback` — the ``loopback`` python-can interface: drives in another
  process over a hub on 127.0.0.1, nothing leaves the machine;
* :mod:`.bus` — opening a python-can bus, fault injection, exact bus load;
* :mod:`.cia402` — the drive profile (controlword, statusword, modes) and the
  simulated drive's object dictionary; :mod:`.eds` — that dictionary as the
  EDS files shipped per drive in the device packages;
* :mod:`.network`, :mod:`.clock` — a simulated clock and the pumped network
  that makes a simulated run deterministic;
* :mod:`.master` — the CANopen master through the ``canopen`` package: the
  standard start-up (reset communication, boot-ups, SDO configuration from
  the EDS, PDO mapping, start), SYNC, heartbeats both ways, EMCY;
* :mod:`.control` — the supervised cyclic synchronous position loop;
* :mod:`.drives` — simulated CiA 402 drives (``canopen.LocalNode``), CiA
  301/402 as real servo drives do them;
  :mod:`.sim_drives` runs them in a process of their own;
* :mod:`.timing` — time-optimal parameterisation (TOPP-RA) of joint paths;
* :mod:`.certify` — certified clearance of the timed motion (between samples
  too), which a device refuses before any motion when below its margin;
* :mod:`.settings`, :mod:`.device` — the settings and lifecycle every CiA 402
  device shares (:class:`~.device.Cia402Device`);
* :mod:`.report` — tracking metrics, bus load, the execution figure and log.

Nothing is imported here, so that python-can can load :mod:`.loopback`
without the rest.
"""
