"""What CiA 301, 305 and 306 say, written here from the standards, not taken from the code under test.

The abort codes a case accepts are the sets CiA's conformance test tool accepts, as its published test
reports show them (CANopenNode's CTT 3.0.3.10 run in CANopenDemo's ``test/test_report_CCT.md``): where the
standard leaves the code to the device, any code of the set passes.
"""

from __future__ import annotations

# ----------------------------------------------------------------------------- SDO abort codes (CiA 301 §7.2.4.3.17)
TOGGLE_NOT_ALTERNATED = 0x05030000
PROTOCOL_TIMED_OUT = 0x05040000
UNKNOWN_COMMAND = 0x05040001
INVALID_BLOCK_SIZE = 0x05040002
INVALID_SEQUENCE = 0x05040003
CRC_ERROR = 0x05040004
UNSUPPORTED_ACCESS = 0x06010000
READ_WRITE_ONLY = 0x06010001
WRITE_READ_ONLY = 0x06010002
NO_OBJECT = 0x06020000
CANNOT_MAP = 0x06040041
PDO_TOO_LONG = 0x06040042
INCOMPATIBLE = 0x06040043
LENGTH_MISMATCH = 0x06070010
LENGTH_TOO_HIGH = 0x06070012
LENGTH_TOO_LOW = 0x06070013
NO_SUB_INDEX = 0x06090011
VALUE_RANGE = 0x06090030
VALUE_TOO_HIGH = 0x06090031
VALUE_TOO_LOW = 0x06090032
GENERAL = 0x08000000
CANNOT_STORE = 0x08000020
DEVICE_STATE = 0x08000022
NO_DATA = 0x08000024

#: the codes each refusal may carry (CTT's sets; 0x08000000 "general error" is accepted everywhere it is)
ACCEPT = {
    "write read-only": {UNSUPPORTED_ACCESS, WRITE_READ_ONLY, GENERAL},
    "read write-only": {UNSUPPORTED_ACCESS, READ_WRITE_ONLY, GENERAL},
    "no sub-index": {NO_SUB_INDEX, GENERAL},
    "no object": {NO_OBJECT, GENERAL},
    "unknown command": {UNKNOWN_COMMAND, GENERAL},
    "too long": {LENGTH_MISMATCH, LENGTH_TOO_HIGH, GENERAL},
    "too short": {LENGTH_MISMATCH, LENGTH_TOO_LOW, GENERAL},
    "too high": {VALUE_RANGE, VALUE_TOO_HIGH, GENERAL},
    "too low": {VALUE_RANGE, VALUE_TOO_LOW, GENERAL},
    "toggle": {TOGGLE_NOT_ALTERNATED, GENERAL},
    "block size": {UNKNOWN_COMMAND, INVALID_BLOCK_SIZE, GENERAL},
    "block sequence": {UNKNOWN_COMMAND, INVALID_SEQUENCE, GENERAL},
    "crc": {CRC_ERROR, GENERAL},
    # the mapping procedure skipped (CTT PDO 23/24), a mapping too long (PDO 25/26), a wrong object (PDO 28-32)
    "mapping procedure": {UNSUPPORTED_ACCESS, CANNOT_MAP, GENERAL},
    "mapping too long": {UNSUPPORTED_ACCESS, NO_OBJECT, CANNOT_MAP, PDO_TOO_LONG},
    "cannot map": {NO_OBJECT, CANNOT_MAP},
    "heartbeat consumer twice": {INCOMPATIBLE},
    "restricted CAN-ID": {VALUE_RANGE, INCOMPATIBLE, GENERAL},
    "signature": {CANNOT_STORE},
    "error history": {VALUE_RANGE, VALUE_TOO_HIGH, GENERAL},
    "no error": {NO_DATA, GENERAL},
    # an object the device refuses to change in the present NMT state (PDO parameters in OPERATIONAL)
    "device state": {DEVICE_STATE, UNSUPPORTED_ACCESS},
}

# ----------------------------------------------------------------------------- NMT (CiA 301 §7.2.8)
START, STOP, ENTER_PRE_OPERATIONAL, RESET_NODE, RESET_COMMUNICATION = 0x01, 0x02, 0x80, 0x81, 0x82
#: the state a heartbeat reports (CiA 301 Table 51)
BOOT_UP, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0x00, 0x04, 0x05, 0x7F
STATE_NAMES = {BOOT_UP: "boot-up", STOPPED: "STOPPED", OPERATIONAL: "OPERATIONAL", PRE_OPERATIONAL: "PRE-OPERATIONAL"}
COMMAND_NAMES = {
    START: "start",
    STOP: "stop",
    ENTER_PRE_OPERATIONAL: "enter pre-operational",
    RESET_NODE: "reset node",
    RESET_COMMUNICATION: "reset communication",
}
#: the state each command leads to (resets: through INITIALISING, the boot-up message, to PRE-OPERATIONAL)
AFTER = {
    START: OPERATIONAL,
    STOP: STOPPED,
    ENTER_PRE_OPERATIONAL: PRE_OPERATIONAL,
    RESET_NODE: PRE_OPERATIONAL,
    RESET_COMMUNICATION: PRE_OPERATIONAL,
}

# ----------------------------------------------------------------------------- COB-IDs (predefined connection set)
SYNC = 0x080
LSS_REQUEST, LSS_RESPONSE = 0x7E5, 0x7E4


def emcy(node: int) -> int:
    return 0x080 + node


def tpdo(n: int, node: int) -> int:
    return 0x080 + 0x100 * n + node


def rpdo(n: int, node: int) -> int:
    return 0x100 + 0x100 * n + node


def sdo_request(node: int) -> int:
    return 0x600 + node


def sdo_response(node: int) -> int:
    return 0x580 + node


def heartbeat(node: int) -> int:
    return 0x700 + node


PDO_INVALID = 1 << 31
PDO_NO_RTR = 1 << 30
#: CAN-IDs no configurable COB-ID may use (CiA 301 §7.3.5: NMT, reserved, the default SDOs, NMT error control)
RESTRICTED_IDS = (
    0x000,
    0x001,
    0x07F,
    0x101,
    0x180,
    0x581,
    0x5FF,
    0x601,
    0x67F,
    0x6E0,
    0x6FF,
    0x701,
    0x77F,
    0x780,
    0x7FF,
)

# ----------------------------------------------------------------------------- errors (CiA 301 §7.2.7, Table 21)
EMCY_NO_ERROR = 0x0000
EMCY_HEARTBEAT = 0x8130  # life guard error or heartbeat error
REGISTER_GENERIC = 0x01
REGISTER_COMMUNICATION = 0x10

# ----------------------------------------------------------------------------- store and restore (§7.5.2.13/14)
SAVE = int.from_bytes(b"save", "little")
LOAD = int.from_bytes(b"load", "little")
WRONG = int.from_bytes(b"wron", "little")  # the CTT's wrong signature
#: 0x1010/0x1011 sub-index -> the indices it covers
AREAS = {1: (0x1000, 0x9FFF), 2: (0x1000, 0x1FFF), 3: (0x6000, 0x9FFF)}

# ----------------------------------------------------------------------------- data types (CiA 301 Table 44)
#: data type -> (name, size in bits; None: variable)
DATA_TYPES = {
    0x0001: ("BOOLEAN", 1),
    0x0002: ("INTEGER8", 8),
    0x0003: ("INTEGER16", 16),
    0x0004: ("INTEGER32", 32),
    0x0005: ("UNSIGNED8", 8),
    0x0006: ("UNSIGNED16", 16),
    0x0007: ("UNSIGNED32", 32),
    0x0008: ("REAL32", 32),
    0x0009: ("VISIBLE_STRING", None),
    0x000A: ("OCTET_STRING", None),
    0x000B: ("UNICODE_STRING", None),
    0x000C: ("TIME_OF_DAY", 48),
    0x000D: ("TIME_DIFFERENCE", 48),
    0x000F: ("DOMAIN", None),
    0x0010: ("INTEGER24", 24),
    0x0011: ("REAL64", 64),
    0x0012: ("INTEGER40", 40),
    0x0013: ("INTEGER48", 48),
    0x0014: ("INTEGER56", 56),
    0x0015: ("INTEGER64", 64),
    0x0016: ("UNSIGNED24", 24),
    0x0018: ("UNSIGNED40", 40),
    0x0019: ("UNSIGNED48", 48),
    0x001A: ("UNSIGNED56", 56),
    0x001B: ("UNSIGNED64", 64),
}
SIGNED = {0x0002, 0x0003, 0x0004, 0x0010, 0x0012, 0x0013, 0x0014, 0x0015}
INTEGERS = SIGNED | {0x0001, 0x0005, 0x0006, 0x0007, 0x0016, 0x0018, 0x0019, 0x001A, 0x001B}
#: object types (CiA 306 §4.6.3, CiA 301 Table 42)
VAR, ARRAY, RECORD, DOMAIN_OBJECT, DEFTYPE, DEFSTRUCT = 0x7, 0x8, 0x9, 0x2, 0x5, 0x6
ACCESS_TYPES = {"ro", "wo", "rw", "rwr", "rww", "const"}


def integer_range(data_type: int) -> tuple[int, int]:
    """The values an integer type holds."""
    bits = DATA_TYPES[data_type][1]
    if data_type in SIGNED:
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


#: the communication objects whose type and access CiA 301 fixes: index -> {sub-index: (data type, accesses)};
#: sub-index None: every sub-index but 0; PDO objects are keyed by their first index
COMMUNICATION = {
    0x1000: {0: (0x0007, {"ro", "const"})},
    0x1001: {0: (0x0005, {"ro"})},
    0x1003: {0: (0x0005, {"rw"}), None: (0x0007, {"ro"})},
    0x1005: {0: (0x0007, {"ro", "rw", "const"})},
    0x1006: {0: (0x0007, {"rw"})},
    0x1008: {0: (0x0009, {"ro", "const"})},
    0x100A: {0: (0x0009, {"ro", "const"})},
    0x100C: {0: (0x0006, {"rw"})},
    0x100D: {0: (0x0005, {"rw"})},
    0x1010: {0: (0x0005, {"ro", "const"}), None: (0x0007, {"rw"})},
    0x1011: {0: (0x0005, {"ro", "const"}), None: (0x0007, {"rw"})},
    0x1014: {0: (0x0007, {"ro", "rw", "const"})},
    0x1015: {0: (0x0006, {"rw"})},
    0x1016: {0: (0x0005, {"ro", "const"}), None: (0x0007, {"rw"})},
    0x1017: {0: (0x0006, {"rw"})},
    0x1018: {0: (0x0005, {"ro", "const"}), None: (0x0007, {"ro", "const"})},
    0x1200: {0: (0x0005, {"ro", "const"}), 1: (0x0007, {"ro", "const"}), 2: (0x0007, {"ro", "const"})},
    0x1400: {0: (0x0005, {"ro", "const"}), 1: (0x0007, {"rw", "ro"}), 2: (0x0005, {"rw", "ro"})},
    0x1600: {0: (0x0005, {"rw", "ro", "const"}), None: (0x0007, {"rw", "ro", "const"})},
    0x1800: {
        0: (0x0005, {"ro", "const"}),
        1: (0x0007, {"rw", "ro"}),
        2: (0x0005, {"rw", "ro"}),
        3: (0x0006, {"rw", "ro"}),
        5: (0x0006, {"rw", "ro"}),
        6: (0x0005, {"rw", "ro"}),
    },
    0x1A00: {0: (0x0005, {"rw", "ro", "const"}), None: (0x0007, {"rw", "ro", "const"})},
}
#: the ranges of the PDO objects (communication and mapping parameters)
PDO_RANGES = {0x1400: (0x1400, 0x15FF), 0x1600: (0x1600, 0x17FF), 0x1800: (0x1800, 0x19FF), 0x1A00: (0x1A00, 0x1BFF)}


def communication_rule(index: int) -> dict | None:
    """The CiA 301 rule for object ``index`` (PDO objects by their range), or None."""
    for first, (lo, hi) in PDO_RANGES.items():
        if lo <= index <= hi:
            return COMMUNICATION[first]
    return COMMUNICATION.get(index)


# ----------------------------------------------------------------------------- LSS (CiA 305)
LSS_SWITCH_GLOBAL = 0x04
LSS_CONFIGURE_NODE_ID = 0x11
LSS_CONFIGURE_BIT_TIMING = 0x13
LSS_ACTIVATE_BIT_TIMING = 0x15
LSS_STORE = 0x17
LSS_SWITCH_SELECTIVE = (0x40, 0x41, 0x42, 0x43)
LSS_SELECTED = 0x44
LSS_IDENTIFY_REMOTE = (0x46, 0x47, 0x48, 0x49, 0x4A, 0x4B)
LSS_IDENTIFY_NON_CONFIGURED = 0x4C
LSS_IDENTIFIED = 0x4F
LSS_NON_CONFIGURED = 0x50
LSS_INQUIRE = {"vendor-ID": 0x5A, "product code": 0x5B, "revision number": 0x5C, "serial number": 0x5D}
LSS_INQUIRE_NODE_ID = 0x5E
LSS_UNCONFIGURED = 0xFF
#: CiA 305 bit timing table 0: index -> bit rate (kbit/s), and the EDS key that says whether it is supported
BIT_TIMING = {0: 1000, 1: 800, 2: 500, 3: 250, 4: 125, 6: 50, 7: 20, 8: 10}
