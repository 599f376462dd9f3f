"""The simulated CiA 402 drives (``surgiplan-sim-drives``): what the CANopen master talks to without hardware.

The master side (:mod:`surgiplan.plugins.devices.canopen`) never imports this package (an import contract
checks it); the device packages name the simulated drives of their device
(:attr:`..device.Cia402Device.simulated_drives`). Modules:

* :mod:`.drives` — :class:`~.drives.DriveSimulator`, the drives of one device: their state, time and
  real-time loop, composed of one module per concern:
  :mod:`.node` (the CANopen node: NMT, SDO, EMCY and PDO objects), :mod:`.objects` (what reading and
  writing each object means), :mod:`.communication` (NMT events, heartbeat consumers, SYNC, the PDO
  exchange, EMCY), :mod:`.statemachine` (the CiA 402 state machine), :mod:`.modes` and
  :mod:`.reference` (the operating modes and the reference they give the servo loops), :mod:`.motor`
  (the motor model), :mod:`.faults` (injected faults);
* :mod:`.process` — the drives in a process of their own, on any python-can bus (``main``);
* :mod:`.loopback` — the ``loopback`` python-can interface: drives in another process over a hub on
  127.0.0.1, nothing leaves the machine;
* :mod:`.eds` — the drives' object dictionaries as the EDS files shipped per drive in the device packages.

Nothing is imported here, so that python-can can load :mod:`.loopback` without the rest.
"""
