"""CiA 301 / CiA 402 (the CANopen drive profile): object dictionary, statusword, controlword, modes.

Shared by the master (:mod:`.master`) and the simulated drives
(:mod:`.sim`). The simulated drive's object dictionary is built here, in
code (:func:`drive_object_dictionary`), and that one dictionary is both what
the simulator serves and what its EDS files say (:mod:`.sim.eds` exports it; a
test checks that the shipped files are that export). The objects are at
their standard indices, with the standard types and access, so a master that
speaks CiA 402 (ours, canopen's ``BaseNode402``, a PLC) works with it.

Communication (CiA 301): device type, error register, pre-defined error
field, SYNC and EMCY COB-IDs, communication cycle period, store and restore
(0x1010/0x1011), heartbeat consumer and producer, identity (the serial number
the drive's own, part of its LSS address), the SDO server's COB-IDs (0x1200),
four RPDOs and four TPDOs (the predefined connection set's COB-IDs: RPDO n at
0x100 + 0x100 n + node, TPDO n at 0x080 + 0x100 n + node, bit 30 set: not
served by RTR). Profile (CiA 402): controlword, statusword, modes of operation and
display, supported drive modes (0x6502: profile position 1, profile velocity
3, cyclic synchronous position 8, velocity 9 and torque 10), position, velocity and
following-error objects, the torque objects (target torque 0x6071, max torque
0x6072 and torque actual value 0x6077 in thousandths of the motor rated torque
0x6076, mN·m), software position limits, profile velocity,
acceleration and deceleration, quick stop, the interpolation period, the
abort connection and quick stop option codes. Manufacturer-specific: 0x2000,
the SYNC watchdog time (ms) of the cyclic synchronous modes.

Units: positions in encoder counts, velocities in counts/s, accelerations in
counts/s² (no factor group: the position factor is 1); times in ms unless the
object says otherwise.

Power-on process data: RPDO1 (0x200 + node) controlword 0x6040 + target
position 0x607A, transmission type 255 (acted on at reception); TPDO1 (0x180
+ node) statusword 0x6041 + position actual value 0x6064, type 1 (every
SYNC); PDOs 2-4 invalid, mapped as CiA 402 recommends. Our master maps, one
frame each way per axis per SYNC: RPDO1 controlword + target position and
TPDO1 statusword + position actual value, both transmission type 1 (the
RPDO applied at the next SYNC).

State names and statusword masks are canopen's (``canopen.profiles.p402``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from canopen import objectdictionary as od
from canopen.profiles.p402 import OperationMode, State402

#: device type 0x1000: profile 402, servo drive (bit 17)
DEVICE_TYPE = 0x00020192
#: identity 0x1018 of the simulated drive (vendor 0: not a CiA-registered vendor)
VENDOR_ID = 0x00000000
PRODUCT_CODE = 0x53500402
REVISION = 0x00020000

# ----------------------------------------------------------------------------- EMCY and errors
#: EMCY error codes (CiA 301 and CiA 402)
EMCY_NO_ERROR = 0x0000
EMCY_FOLLOWING_ERROR = 0x8611  # CiA 402: following error
EMCY_SYNC_LOST = 0x8730  # the drive's SYNC watchdog (manufacturer's choice in the monitoring range)
EMCY_HEARTBEAT_LOST = 0x8130  # CiA 301: life guard error or heartbeat error
#: error register 0x1001 bits
ERR_GENERIC = 0x01
ERR_CURRENT = 0x02
ERR_COMMUNICATION = 0x10
ERR_PROFILE = 0x20
#: the error register bits each error code sets (bit 0, generic, with every error)
ERROR_REGISTER = {
    EMCY_FOLLOWING_ERROR: ERR_GENERIC | ERR_PROFILE,
    EMCY_SYNC_LOST: ERR_GENERIC | ERR_COMMUNICATION,
    EMCY_HEARTBEAT_LOST: ERR_GENERIC | ERR_COMMUNICATION,
}

# ----------------------------------------------------------------------------- SDO abort codes (CiA 301)
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_CANNOT_MAP = 0x06040041
ABORT_PDO_TOO_LONG = 0x06040042
ABORT_INCOMPATIBLE = 0x06040043
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032
ABORT_DEVICE_STATE = 0x08000022

# ----------------------------------------------------------------------------- modes of operation
NO_MODE = OperationMode.NO_MODE
PP = OperationMode.PROFILED_POSITION  # 1
PV = OperationMode.PROFILED_VELOCITY  # 3
CSP = OperationMode.CYCLIC_SYNCHRONOUS_POSITION  # 8
CSV = OperationMode.CYCLIC_SYNCHRONOUS_VELOCITY  # 9
CST = OperationMode.CYCLIC_SYNCHRONOUS_TORQUE  # 10
SUPPORTED_MODES = (PP, PV, CSP, CSV, CST)
#: 0x6502: bit 0 pp, bit 2 pv, bit 7 csp, bit 8 csv, bit 9 cst (CiA 402-2 §6.2.2)
SUPPORTED_DRIVE_MODES = 0x0001 | 0x0004 | 0x0080 | 0x0100 | 0x0200
POSITION_MODES = (PP, CSP)
VELOCITY_MODES = (PV, CSV)
CYCLIC_MODES = (CSP, CSV, CST)
#: torques (0x6071, 0x6072, 0x6077) are in thousandths of the motor's rated torque 0x6076 (mN·m)
PER_MILLE = 1000.0
#: 0x6007 abort connection option codes the drive implements
ABORT_CONNECTION_OPTIONS = (0, 1, 2, 3)
#: 0x605A quick stop option codes: 0 disable drive; 1/2 slow-down/quick-stop ramp then SWITCH ON
#: DISABLED; 5/6 slow-down/quick-stop ramp and stay in QUICK STOP ACTIVE
QUICK_STOP_OPTIONS = (0, 1, 2, 5, 6)

# ----------------------------------------------------------------------------- state machine
# controlword commands
CW_DISABLE_VOLTAGE = State402.CW_DISABLE_VOLTAGE  # 0x00
CW_SHUTDOWN = State402.CW_SHUTDOWN  # 0x06
CW_SWITCH_ON = State402.CW_SWITCH_ON  # 0x07 (also "disable operation")
CW_ENABLE_OPERATION = State402.CW_OPERATION_ENABLED  # 0x0F
CW_QUICK_STOP = State402.CW_QUICK_STOP  # 0x02
CW_FAULT_RESET = 0x80
#: operation mode specific bits
CW_NEW_SET_POINT = 1 << 4  # pp: new set-point (rising edge)
CW_CHANGE_IMMEDIATELY = 1 << 5  # pp
CW_RELATIVE = 1 << 6  # pp
CW_HALT = 1 << 8

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
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_SET_POINT_ACKNOWLEDGE = 1 << 12  # pp: set-point acknowledge
SW_SPEED_ZERO = 1 << 12  # pv: speed is zero
SW_FOLLOWING_COMMAND = 1 << 12  # csp/csv: the drive follows the target value
SW_FOLLOWING_ERROR = 1 << 13  # pp/csp: following error

_STATE_MASKS = [(name, mask, value) for name, (mask, value) in State402.SW_MASK.items()]
#: (mask, value) of the statusword in OPERATION ENABLED
OPERATION_ENABLED_MASK = State402.SW_MASK[OPERATION_ENABLED]


def state_of(statusword: int) -> str:
    """The CiA 402 state a statusword reports."""
    for name, mask, value in _STATE_MASKS:
        if statusword & mask == value:
            return name
    return NOT_READY


def next_state(state: str, controlword: int, previous_controlword: int) -> str:
    """The drive's state after a controlword (CiA 402 state machine, transitions 2-12, 15, 16).

    A fault reset is the rising edge of bit 7; from QUICK STOP ACTIVE "enable
    operation" (16) or "disable voltage" (12) leave it.
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


# ----------------------------------------------------------------------------- NMT (CiA 301)
#: NMT states as the heartbeat reports them
NMT_INITIALISING, NMT_STOPPED, NMT_OPERATIONAL, NMT_PRE_OPERATIONAL = 0, 4, 5, 127


# ----------------------------------------------------------------------------- PDOs
def rpdo_cob_id(n: int, node_id: int) -> int:
    """The predefined connection set's COB-ID of RPDO n (1-4)."""
    return 0x100 + 0x100 * n + node_id


def tpdo_cob_id(n: int, node_id: int) -> int:
    """The predefined connection set's COB-ID of TPDO n (1-4)."""
    return 0x080 + 0x100 * n + node_id


PDO_INVALID = 1 << 31
PDO_NO_RTR = 1 << 30
#: CiA 301's restricted CAN-IDs (NMT, SDO and NMT error control of the predefined set, reserved): no PDO uses them
RESTRICTED_IDS = ((0x000, 0x07F), (0x101, 0x180), (0x581, 0x5FF), (0x601, 0x67F), (0x6E0, 0x6FF), (0x701, 0x7FF))
#: the bit rates the simulated drives support (the EDS's BaudRate_* keys, LSS bit timing)
BIT_RATES = (125_000, 250_000, 500_000, 1_000_000)
#: CiA 301 0x1010/0x1011: the signatures that save ("save") and restore defaults ("load"), as UNSIGNED32
SAVE_SIGNATURE = int.from_bytes(b"save", "little")
LOAD_SIGNATURE = int.from_bytes(b"load", "little")
#: default mappings (CiA 402's recommendations, RPDO/TPDO 1 as the master uses them); 2-4 invalid at power-up
DEFAULT_RPDO = {1: [0x60400010, 0x607A0020], 2: [0x60400010, 0x60600008], 3: [0x60400010, 0x607A0020],
                4: [0x60400010, 0x60FF0020]}  # fmt: skip
DEFAULT_TPDO = {1: [0x60410010, 0x60640020], 2: [0x60410010, 0x60610008], 3: [0x60410010, 0x60640020],
                4: [0x60410010, 0x606C0020]}  # fmt: skip


# ----------------------------------------------------------------------------- object dictionary
@dataclass(frozen=True)
class DriveDefaults:
    """The power-on values of one simulated drive (the defaults its EDS states), in SI joint units.

    Converted to counts with ``counts_per_unit`` for the dictionary.
    """

    product_name: str = "surgiplan simulated CiA 402 servo drive"
    counts_per_unit: float = 1.0
    unit: str = "count"
    #: the axis' travel: the software position limits at power-up (None: the whole INTEGER32 range)
    lower: float | None = None
    upper: float | None = None
    #: the motor's speed limit: max profile velocity 0x607F at power-up
    max_velocity: float | None = None
    #: profile velocity 0x6081 at power-up (None: max_velocity)
    profile_velocity: float | None = None
    #: profile acceleration and deceleration (0x6083/0x6084); the quick stop deceleration 0x6085 is twice it
    acceleration: float | None = None
    #: following error window 0x6065 (None: off)
    following_error_window: float | None = None
    #: the SYNC watchdog of the cyclic synchronous modes, 0x2000 (s; 0: off)
    sync_watchdog: float = 0.05
    #: the drive's serial number (0x1018:4): a property of the unit, whatever node-ID it is given; None: the
    #: node-ID (``$NODEID`` in the EDS)
    serial_number: int | None = None
    #: the motor's rated torque 0x6076 (N·m at the motor; a linear motor's rated force in N)
    rated_torque: float = 0.1
    #: max torque 0x6072 at power-up: the drive's peak torque, in thousandths of the rated torque
    peak_torque: int = 3000

    def counts(self, value: float | None, fallback: int) -> int:
        return fallback if value is None else round(value * self.counts_per_unit)


def _variable(
    name, index, subindex=0, data_type=od.UNSIGNED32, access="rw", default=0, mappable=False, raw=None, limits=None
):
    """One object; ``limits`` (low, high): the value range the EDS states (LowLimit, HighLimit) and the drive
    enforces (a value outside is aborted 0x06090031/32). Mappable objects say their direction by their access
    type (CiA 306): ``ro`` process inputs (TPDO), ``rww`` process outputs (RPDO)."""
    var = od.ODVariable(name, index, subindex)
    var.data_type = data_type
    var.access_type = access
    var.default = default
    var.pdo_mappable = mappable
    if limits is not None:
        var.min, var.max = limits
    # the EDS text of the default: exact for negative numbers (canopen writes those as "0x-..."), and
    # relative to the node id where the standard says so ($NODEID+0x180)
    if raw is not None:
        var.default_raw = raw
    elif data_type in (od.VISIBLE_STRING,):
        var.default_raw = default
    elif isinstance(default, int) and default < 0:
        var.default_raw = str(default)
    elif isinstance(default, int):
        var.default_raw = f"0x{default:X}"
    return var


def _record(name, index, members, array=False, limits=None):
    """A RECORD (or ARRAY) of ``members`` (sub, name, type, access, default[, EDS text]); ``limits``: per sub."""
    record = (od.ODArray if array else od.ODRecord)(name, index)
    top = max(sub for sub, *_ in members)
    record.add_member(_variable("Highest sub-index supported", index, 0, od.UNSIGNED8, "const", top))
    for sub, member, data_type, access, default, *raw in members:
        bounds = (limits or {}).get(sub)
        record.add_member(
            _variable(member, index, sub, data_type, access, default, raw=raw[0] if raw else None, limits=bounds)
        )
    return record


def _pdo(direction: str, n: int, node_id: int):
    receive = direction == "R"
    comm_index = (0x1400 if receive else 0x1800) + n - 1
    map_index = (0x1600 if receive else 0x1A00) + n - 1
    # TPDOs are not served on request (RTR): bit 30 says so (CiA 301); PDOs 2-4 invalid at power-up
    base = (0x100 if receive else 0x080 | PDO_NO_RTR) + 0x100 * n
    flags = 0 if n == 1 else PDO_INVALID
    cob_id = (base + node_id) | flags
    cob_raw = f"$NODEID+0x{base | flags:X}"
    members = [
        (1, "COB-ID used by PDO", od.UNSIGNED32, "rw", cob_id, cob_raw),
        (2, "Transmission type", od.UNSIGNED8, "rw", 255 if receive else 1),
    ]
    if not receive:
        members += [
            (3, "Inhibit time", od.UNSIGNED16, "rw", 0),
            (5, "Event timer", od.UNSIGNED16, "rw", 0),
        ]
    comm = _record(f"{direction}PDO{n} communication parameter", comm_index, members)
    mapping = (DEFAULT_RPDO if receive else DEFAULT_TPDO)[n]
    record = od.ODRecord(f"{direction}PDO{n} mapping parameter", map_index)
    record.add_member(_variable("Number of mapped objects", map_index, 0, od.UNSIGNED8, "rw", len(mapping)))
    for sub in range(1, 9):
        entry = mapping[sub - 1] if sub <= len(mapping) else 0
        record.add_member(_variable(f"Mapped object {sub}", map_index, sub, od.UNSIGNED32, "rw", entry))
    return comm, record


def drive_object_dictionary(node_id: int, defaults: DriveDefaults | None = None) -> od.ObjectDictionary:
    """The object dictionary of one simulated CiA 402 axis: what the simulator serves and its EDS states."""
    d = defaults or DriveDefaults()
    lowest, highest = -(2**31), 2**31 - 1
    velocity = min(d.counts(d.max_velocity, 0xFFFFFFFF), 0xFFFFFFFF)
    profile = min(d.counts(d.profile_velocity, velocity), velocity)
    acceleration = min(d.counts(d.acceleration, 0x7FFFFFFF), 0x7FFFFFFF)
    window = 0xFFFFFFFF if d.following_error_window is None else max(1, d.counts(d.following_error_window, 0))
    lower = max(lowest, math.floor(d.lower * d.counts_per_unit)) if d.lower is not None else lowest
    upper = min(highest, math.ceil(d.upper * d.counts_per_unit)) if d.upper is not None else highest

    dictionary = od.ObjectDictionary()
    dictionary.node_id = node_id
    info = dictionary.device_information
    info.vendor_name = "surgiplan (simulation)"
    info.vendor_number = VENDOR_ID
    info.product_name = d.product_name
    info.product_number = PRODUCT_CODE
    info.revision_number = REVISION
    info.order_code = "surgiplan-sim-drive"
    info.simple_boot_up_master = False
    info.simple_boot_up_slave = True
    info.granularity = 8
    info.dynamic_channels_supported = False
    info.group_messaging = False
    info.nr_of_RXPDO = 4
    info.nr_of_TXPDO = 4
    info.LSS_supported = True
    info.allowed_baudrates = set(BIT_RATES)
    dictionary.comments = (
        f"{d.product_name}.\n"
        f"Positions in encoder counts ({d.counts_per_unit:.9g} counts per {d.unit}), velocities in counts/s,\n"
        "accelerations in counts/s^2. Generated by surgiplan from the object dictionary its simulated drives serve."
    )
    add = dictionary.add_object
    U8, U16, U32, I8, I16, I32 = od.UNSIGNED8, od.UNSIGNED16, od.UNSIGNED32, od.INTEGER8, od.INTEGER16, od.INTEGER32
    # ---- communication profile area (CiA 301)
    add(_variable("Device type", 0x1000, access="ro", default=DEVICE_TYPE))
    add(_variable("Error register", 0x1001, data_type=U8, access="ro", mappable=True))
    errors = [(0, "Number of errors", U8, "rw", 0)]
    errors += [(sub, f"Standard error field {sub}", U32, "ro", 0) for sub in range(1, 9)]
    field = od.ODArray("Pre-defined error field", 0x1003)
    for sub, name, data_type, access, default in errors:
        field.add_member(_variable(name, 0x1003, sub, data_type, access, default))
    add(field)
    add(_variable("COB-ID SYNC message", 0x1005, access="ro", default=0x80))
    add(_variable("Communication cycle period", 0x1006, default=0))
    # store and restore (CiA 301): reading says "saves/restores on command" (bit 0); writing the signature acts
    for index, what, verb in ((0x1010, "Store parameters", "Save"), (0x1011, "Restore default parameters", "Restore")):
        areas = [(1, "all"), (2, "communication"), (3, "application")]
        members = [(sub, f"{verb} {area} parameters", U32, "rw", 1) for sub, area in areas]
        add(_record(what, index, members, array=True))
    add(_variable("Manufacturer device name", 0x1008, data_type=od.VISIBLE_STRING, access="const",
                  default=d.product_name))  # fmt: skip
    add(_variable("Manufacturer software version", 0x100A, data_type=od.VISIBLE_STRING, access="const",
                  default=f"simulator revision {REVISION >> 16}.{REVISION & 0xFFFF}"))  # fmt: skip
    add(_variable("COB-ID EMCY", 0x1014, access="ro", default=0x80 + node_id, raw="$NODEID+0x80"))
    consumer = od.ODArray("Consumer heartbeat time", 0x1016)
    consumer.add_member(_variable("Number of entries", 0x1016, 0, U8, "const", 2))
    for sub in (1, 2):
        consumer.add_member(_variable(f"Consumer heartbeat time {sub}", 0x1016, sub, U32, "rw", 0))
    add(consumer)
    add(_variable("Producer heartbeat time", 0x1017, data_type=U16))
    serial = (4, "Serial number", U32, "ro", node_id, "$NODEID+0")
    if d.serial_number is not None:
        serial = (4, "Serial number", U32, "ro", d.serial_number)
    identity = [
        (1, "Vendor-ID", U32, "ro", VENDOR_ID),
        (2, "Product code", U32, "ro", PRODUCT_CODE),
        (3, "Revision number", U32, "ro", REVISION),
        serial,
    ]
    add(_record("Identity object", 0x1018, identity))
    server = [
        (1, "COB-ID client to server", U32, "ro", 0x600 + node_id, "$NODEID+0x600"),
        (2, "COB-ID server to client", U32, "ro", 0x580 + node_id, "$NODEID+0x580"),
    ]
    add(_record("SDO server parameter", 0x1200, server))
    for n in (1, 2, 3, 4):
        for obj in _pdo("R", n, node_id):
            add(obj)
    for n in (1, 2, 3, 4):
        for obj in _pdo("T", n, node_id):
            add(obj)
    # ---- manufacturer-specific area
    add(_variable("SYNC watchdog time", 0x2000, data_type=U16, default=round(d.sync_watchdog * 1000)))
    # ---- device profile area (CiA 402)
    add(_variable("Error code", 0x603F, data_type=U16, access="ro", mappable=True))
    add(_variable("Abort connection option code", 0x6007, data_type=I16, default=3, limits=(0, 3)))
    add(_variable("Controlword", 0x6040, data_type=U16, access="rww", mappable=True))
    add(_variable("Statusword", 0x6041, data_type=U16, access="ro", mappable=True))
    add(_variable("Quick stop option code", 0x605A, data_type=I16, default=6, limits=(0, 6)))
    add(_variable("Modes of operation", 0x6060, data_type=I8, access="rww", default=CSP, mappable=True))
    add(_variable("Modes of operation display", 0x6061, data_type=I8, access="ro", default=CSP, mappable=True))
    add(_variable("Position demand value", 0x6062, data_type=I32, access="ro", mappable=True))
    add(_variable("Position actual value", 0x6064, data_type=I32, access="ro", mappable=True))
    add(_variable("Following error window", 0x6065, default=window))
    add(_variable("Following error time out", 0x6066, data_type=U16, default=10))
    position_window = 10 if d.following_error_window is None else max(1, window // 10)
    add(_variable("Position window", 0x6067, default=position_window))
    add(_variable("Position window time", 0x6068, data_type=U16, default=0))
    add(_variable("Velocity actual value", 0x606C, data_type=I32, access="ro", mappable=True))
    add(_variable("Velocity window", 0x606D, data_type=U16, default=min(0xFFFF, max(1, velocity // 1000))))
    add(_variable("Velocity window time", 0x606E, data_type=U16, default=0))
    add(_variable("Target position", 0x607A, data_type=I32, access="rww", mappable=True))
    limits = [(1, "Min position limit", I32, "rw", lower), (2, "Max position limit", I32, "rw", upper)]
    add(_record("Software position limit", 0x607D, limits))
    positive = (1, 0xFFFFFFFF)
    add(_variable("Max profile velocity", 0x607F, default=velocity, access="rww", mappable=True))
    add(_variable("Profile velocity", 0x6081, default=profile, access="rww", mappable=True))
    add(_variable("Profile acceleration", 0x6083, default=acceleration, access="rww", mappable=True, limits=positive))
    add(_variable("Profile deceleration", 0x6084, default=acceleration, access="rww", mappable=True, limits=positive))
    add(_variable("Quick stop deceleration", 0x6085, default=2 * acceleration, limits=positive))
    period = [(1, "Interpolation time period value", U8, "rw", 1), (2, "Interpolation time index", I8, "rw", -3)]
    add(_record("Interpolation time period", 0x60C2, period, limits={1: (1, 255), 2: (-6, 0)}))
    add(_variable("Following error actual value", 0x60F4, data_type=I32, access="ro", mappable=True))
    add(_variable("Target velocity", 0x60FF, data_type=I32, access="rww", mappable=True))
    # torque (cyclic synchronous torque): thousandths of the rated torque; the max torque is at most the peak
    add(_variable("Target torque", 0x6071, data_type=I16, access="rww", mappable=True))
    add(_variable("Max torque", 0x6072, data_type=U16, access="rww", default=d.peak_torque, mappable=True,
                  limits=(0, d.peak_torque)))  # fmt: skip
    add(_variable("Motor rated torque", 0x6076, default=max(1, round(d.rated_torque * 1000)), access="ro"))
    add(_variable("Torque actual value", 0x6077, data_type=I16, access="ro", mappable=True))
    add(_variable("Supported drive modes", 0x6502, access="ro", default=SUPPORTED_DRIVE_MODES))
    return dictionary


def cia402_object_dictionary(node_id: int) -> od.ObjectDictionary:
    """A generic simulated axis' object dictionary (counts as units, no limits)."""
    return drive_object_dictionary(node_id)
