"""CiA 402 (the CANopen drive profile): object dictionary, statusword, controlword.

Shared by the master (:mod:`.master`) and the simulated drives
(:mod:`.drives`). The object dictionary is built in code (no EDS file to
ship): the CiA 301 communication objects and the CiA 402 objects a drive in
cyclic synchronous position mode (CSP, mode 8) needs, at their standard
indices, so the master works with any drive that implements them.

Process data, one frame each way per axis per SYNC (the predefined
connection set's COB-IDs):

* RPDO1 (0x200 + node): controlword 0x6040 (16 bit) + target position 0x607A
  (32 bit), transmission type 1: applied at the next SYNC;
* TPDO1 (0x180 + node): statusword 0x6041 (16 bit) + position actual value
  0x6064 (32 bit), transmission type 1: sent on every SYNC.

State names and statusword masks are canopen's (``canopen.profiles.p402``).
"""

from __future__ import annotations

from canopen import objectdictionary as od
from canopen.profiles.p402 import OperationMode, State402

#: device type 0x1000: profile 402, servo drive (bit 17)
DEVICE_TYPE = 0x00020192
#: EMCY error codes (CiA 402)
EMCY_FOLLOWING_ERROR = 0x8611
EMCY_SYNC_LOST = 0x8730  # communication: SYNC / lifeguard timeout
CSP = OperationMode.CYCLIC_SYNCHRONOUS_POSITION

# controlword commands
CW_DISABLE_VOLTAGE = State402.CW_DISABLE_VOLTAGE  # 0x00
CW_SHUTDOWN = State402.CW_SHUTDOWN  # 0x06
CW_SWITCH_ON = State402.CW_SWITCH_ON  # 0x07 (also "disable operation")
CW_ENABLE_OPERATION = State402.CW_OPERATION_ENABLED  # 0x0F
CW_QUICK_STOP = State402.CW_QUICK_STOP  # 0x02
CW_FAULT_RESET = 0x80

NOT_READY = "NOT READY TO SWITCH ON"
SWITCH_ON_DISABLED = "SWITCH ON DISABLED"
READY = "READY TO SWITCH ON"
SWITCHED_ON = "SWITCHED ON"
OPERATION_ENABLED = "OPERATION ENABLED"
QUICK_STOP_ACTIVE = "QUICK STOP ACTIVE"
FAULT_REACTION_ACTIVE = "FAULT REACTION ACTIVE"
FAULT = "FAULT"

#: the statusword's state bits (0-3, 5, 6) per state, with "voltage enabled" (bit 4) where powered
STATUSWORD = {
    NOT_READY: 0x0000,
    SWITCH_ON_DISABLED: 0x0040,
    READY: 0x0031,
    SWITCHED_ON: 0x0033,
    OPERATION_ENABLED: 0x0037,
    QUICK_STOP_ACTIVE: 0x0017,
    FAULT_REACTION_ACTIVE: 0x001F,
    FAULT: 0x0008,
}
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_FOLLOWING_COMMAND = 1 << 12  # CSP: the drive follows the target value
SW_FOLLOWING_ERROR = 1 << 13  # CSP: following error


def state_of(statusword: int) -> str:
    """The CiA 402 state a statusword reports."""
    for name, (mask, value) in State402.SW_MASK.items():
        if statusword & mask == value:
            return name
    return NOT_READY


def next_state(state: str, controlword: int, previous_controlword: int) -> str:
    """The drive's state after a controlword (CiA 402 state machine, transitions 2-12, 15, 16).

    A fault reset is the rising edge of bit 7; quick stop option code 6 keeps
    the drive in QUICK STOP ACTIVE, from where "enable operation" (16) or
    "disable voltage" (12) leave it.
    """
    if state == FAULT:
        if controlword & CW_FAULT_RESET and not previous_controlword & CW_FAULT_RESET:
            return SWITCH_ON_DISABLED
        return FAULT
    if state in (NOT_READY, FAULT_REACTION_ACTIVE):
        return state
    if controlword & CW_FAULT_RESET:
        return state  # a fault reset command outside FAULT does nothing
    disable_voltage = not controlword & 0x02
    quick_stop = controlword & 0x06 == 0x02
    shutdown = controlword & 0x07 == 0x06
    switch_on = controlword & 0x0F == 0x07
    enable = controlword & 0x0F == 0x0F
    if state == SWITCH_ON_DISABLED:
        return READY if shutdown else state
    if state == READY:
        if disable_voltage or quick_stop:
            return SWITCH_ON_DISABLED
        if switch_on:
            return SWITCHED_ON
        if enable:  # 3 then 4 in one step, as most drives accept
            return OPERATION_ENABLED
        return state
    if state == SWITCHED_ON:
        if disable_voltage or quick_stop:
            return SWITCH_ON_DISABLED
        if shutdown:
            return READY
        return OPERATION_ENABLED if enable else state
    if state == OPERATION_ENABLED:
        if disable_voltage:
            return SWITCH_ON_DISABLED
        if quick_stop:
            return QUICK_STOP_ACTIVE
        if shutdown:
            return READY
        return SWITCHED_ON if switch_on else state
    if state == QUICK_STOP_ACTIVE:
        if disable_voltage:
            return SWITCH_ON_DISABLED
        return OPERATION_ENABLED if enable else state
    return state


def enabling_controlword(state: str, previous_controlword: int) -> int:
    """The controlword that moves a drive one step toward OPERATION ENABLED (a fault reset from FAULT)."""
    if state == FAULT:
        # a rising edge on bit 7: send 0 first if the last command already had it
        return CW_DISABLE_VOLTAGE if previous_controlword & CW_FAULT_RESET else CW_FAULT_RESET
    if state == SWITCH_ON_DISABLED:
        return CW_SHUTDOWN
    if state == READY:
        return CW_SWITCH_ON
    if state in (SWITCHED_ON, OPERATION_ENABLED):
        return CW_ENABLE_OPERATION
    if state == QUICK_STOP_ACTIVE:
        return CW_DISABLE_VOLTAGE
    return CW_DISABLE_VOLTAGE


def interpolation_period(period: float) -> tuple[int, int]:
    """0x60C2 (value, index) with value * 10^index = ``period`` s; ValueError if not exact to 1e-9."""
    for index in range(-6, 1):
        value = round(period / 10.0**index)
        if 1 <= value <= 255 and abs(value * 10.0**index - period) <= 1e-9 * max(period, 1e-12):
            return value, index
    raise ValueError(
        f"control period {period * 1000:g} ms is not representable as value x 10^index s (value 1-255) in 0x60C2"
    )


# ----------------------------------------------------------------------------- object dictionary
def _variable(name, index, subindex=0, data_type=od.UNSIGNED32, access="rw", default=0, mappable=False):
    var = od.ODVariable(name, index, subindex)
    var.data_type = data_type
    var.access_type = access
    var.default = default
    var.pdo_mappable = mappable
    return var


def _record(name, index, members):
    record = od.ODRecord(name, index)
    record.add_member(_variable("Highest sub-index supported", index, 0, od.UNSIGNED8, "ro", len(members)))
    for sub, (member, data_type, access, default) in enumerate(members, start=1):
        record.add_member(_variable(member, index, sub, data_type, access, default))
    return record


def _pdo(comm_index, map_index, cob_id, mapping, direction):
    comm = _record(
        f"{direction}PDO1 communication parameter",
        comm_index,
        [("COB-ID", od.UNSIGNED32, "rw", cob_id), ("Transmission type", od.UNSIGNED8, "rw", 1)],
    )
    entries = [
        (f"Mapping entry {i}", od.UNSIGNED32, "rw", mapping[i - 1] if i <= len(mapping) else 0) for i in range(1, 9)
    ]
    mapping_record = od.ODRecord(f"{direction}PDO1 mapping parameter", map_index)
    mapping_record.add_member(_variable("Number of mapped objects", map_index, 0, od.UNSIGNED8, "rw", len(mapping)))
    for sub, (member, data_type, access, default) in enumerate(entries, start=1):
        mapping_record.add_member(_variable(member, map_index, sub, data_type, access, default))
    return comm, mapping_record


def cia402_object_dictionary(node_id: int) -> od.ObjectDictionary:
    """The object dictionary of one CiA 402 axis (CSP), for master and simulated drive alike."""
    d = od.ObjectDictionary()
    d.node_id = node_id
    d.add_object(_variable("Device type", 0x1000, access="ro", default=DEVICE_TYPE))
    d.add_object(_variable("Error register", 0x1001, data_type=od.UNSIGNED8, access="ro"))
    d.add_object(_variable("Producer heartbeat time", 0x1017, data_type=od.UNSIGNED16))
    d.add_object(
        _record(
            "Identity object",
            0x1018,
            [
                ("Vendor-ID", od.UNSIGNED32, "ro", 0),
                ("Product code", od.UNSIGNED32, "ro", 0x402),
                ("Revision number", od.UNSIGNED32, "ro", 1),
                ("Serial number", od.UNSIGNED32, "ro", node_id),
            ],
        )
    )
    for obj in _pdo(0x1400, 0x1600, 0x200 + node_id, [0x60400010, 0x607A0020], "R"):
        d.add_object(obj)
    for obj in _pdo(0x1800, 0x1A00, 0x180 + node_id, [0x60410010, 0x60640020], "T"):
        d.add_object(obj)
    d.add_object(_variable("Error code", 0x603F, data_type=od.UNSIGNED16, access="ro", mappable=True))
    d.add_object(_variable("Controlword", 0x6040, data_type=od.UNSIGNED16, mappable=True))
    d.add_object(_variable("Statusword", 0x6041, data_type=od.UNSIGNED16, access="ro", mappable=True))
    d.add_object(_variable("Abort connection option code", 0x6007, data_type=od.INTEGER16, default=3))
    d.add_object(_variable("Quick stop option code", 0x605A, data_type=od.INTEGER16, default=6))
    d.add_object(_variable("Modes of operation", 0x6060, data_type=od.INTEGER8, mappable=True))
    d.add_object(_variable("Modes of operation display", 0x6061, data_type=od.INTEGER8, access="ro", mappable=True))
    d.add_object(_variable("Position actual value", 0x6064, data_type=od.INTEGER32, access="ro", mappable=True))
    d.add_object(_variable("Following error window", 0x6065, default=0xFFFFFFFF))
    d.add_object(_variable("Following error time out", 0x6066, data_type=od.UNSIGNED16, default=10))
    d.add_object(_variable("Target position", 0x607A, data_type=od.INTEGER32, mappable=True))
    d.add_object(
        _record(
            "Software position limit",
            0x607D,
            [
                ("Min position limit", od.INTEGER32, "rw", -(2**31)),
                ("Max position limit", od.INTEGER32, "rw", 2**31 - 1),
            ],
        )
    )
    d.add_object(_variable("Max profile velocity", 0x607F, default=0xFFFFFFFF))
    d.add_object(_variable("Quick stop deceleration", 0x6085, default=0xFFFFFFFF))
    d.add_object(
        _record(
            "Interpolation time period",
            0x60C2,
            [
                ("Interpolation time period value", od.UNSIGNED8, "rw", 1),
                ("Interpolation time index", od.INTEGER8, "rw", -3),
            ],
        )
    )
    return d
