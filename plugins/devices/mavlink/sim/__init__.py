"""The simulated PX4-like vehicle (``surgiplan-sim-vehicle``): what a ground station talks to without hardware.

* :mod:`.vehicle` — the MAVLink side and the program (``main``);
* :mod:`.autopilot` — arming, modes, mission execution, RTL, land;
* :mod:`.geofence` — the geofence (feasibility, breaches, GF_ACTION) and rally points;
* :mod:`.model` — the point-mass airframe under PX4's cascaded controller, wind;
* :mod:`.offboard` — offboard setpoints in lockstep with the vehicle's clock;
* :mod:`.settings` — the simulator's settings (faults included).
"""
