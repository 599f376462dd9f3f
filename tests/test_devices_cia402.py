"""The CiA 402 profile: state machine, statusword, object dictionary, against the standard's tables."""

from __future__ import annotations

import pytest
from surgiplan.plugins.devices.canopen import cia402

# CiA 402-2 (IEC 61800-7-201) Table 28: statusword bits 0-3, 5, 6 per state, as (mask, value) written
# from the standard's "xxxx xxxx x0xx 0000"-style patterns, not from canopen or the code under test
STATUSWORD_PATTERNS = {
    cia402.NOT_READY: ("x0xx0000", 0b0000000),
    cia402.SWITCH_ON_DISABLED: ("x1xx0000", 0b1000000),
    cia402.READY: ("x01x0001", 0b0100001),
    cia402.SWITCHED_ON: ("x01x0011", 0b0100011),
    cia402.OPERATION_ENABLED: ("x01x0111", 0b0100111),
    cia402.QUICK_STOP_ACTIVE: ("x00x0111", 0b0000111),
    cia402.FAULT_REACTION_ACTIVE: ("x0xx1111", 0b0001111),
    cia402.FAULT: ("x0xx1000", 0b0001000),
}

# CiA 402-2 Table 27 / Figure 8: (state, command) -> next state; commands by controlword
SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP, DISABLE_OPERATION, RESET = (
    0x06,
    0x07,
    0x0F,
    0x00,
    0x02,
    0x07,
    0x80,
)
TRANSITIONS = [
    (cia402.SWITCH_ON_DISABLED, SHUTDOWN, cia402.READY),  # 2
    (cia402.READY, SWITCH_ON, cia402.SWITCHED_ON),  # 3
    (cia402.SWITCHED_ON, ENABLE, cia402.OPERATION_ENABLED),  # 4
    (cia402.OPERATION_ENABLED, DISABLE_OPERATION, cia402.SWITCHED_ON),  # 5
    (cia402.SWITCHED_ON, SHUTDOWN, cia402.READY),  # 6
    (cia402.READY, DISABLE_VOLTAGE, cia402.SWITCH_ON_DISABLED),  # 7
    (cia402.READY, QUICK_STOP, cia402.SWITCH_ON_DISABLED),  # 7
    (cia402.OPERATION_ENABLED, SHUTDOWN, cia402.READY),  # 8
    (cia402.OPERATION_ENABLED, DISABLE_VOLTAGE, cia402.SWITCH_ON_DISABLED),  # 9
    (cia402.SWITCHED_ON, DISABLE_VOLTAGE, cia402.SWITCH_ON_DISABLED),  # 10
    (cia402.SWITCHED_ON, QUICK_STOP, cia402.SWITCH_ON_DISABLED),  # 10
    (cia402.OPERATION_ENABLED, QUICK_STOP, cia402.QUICK_STOP_ACTIVE),  # 11
    (cia402.QUICK_STOP_ACTIVE, DISABLE_VOLTAGE, cia402.SWITCH_ON_DISABLED),  # 12
    (cia402.FAULT, RESET, cia402.SWITCH_ON_DISABLED),  # 15 (rising edge of bit 7)
    (cia402.QUICK_STOP_ACTIVE, ENABLE, cia402.OPERATION_ENABLED),  # 16
    # commands that do not apply in a state leave it unchanged
    (cia402.SWITCH_ON_DISABLED, ENABLE, cia402.SWITCH_ON_DISABLED),
    (cia402.FAULT, ENABLE, cia402.FAULT),
    (cia402.OPERATION_ENABLED, ENABLE, cia402.OPERATION_ENABLED),
    (cia402.QUICK_STOP_ACTIVE, QUICK_STOP, cia402.QUICK_STOP_ACTIVE),
]


def _matches(pattern: str, word: int) -> bool:
    bits = {6: pattern[1], 5: pattern[2], 3: pattern[4], 2: pattern[5], 1: pattern[6], 0: pattern[7]}
    return all(want == "x" or ((word >> bit) & 1) == int(want) for bit, want in bits.items())


@pytest.mark.parametrize("state", list(STATUSWORD_PATTERNS))
def test_statusword_of_each_state_matches_the_standard_and_decodes_back(state):
    word = cia402.STATUSWORD[state]
    pattern, _ = STATUSWORD_PATTERNS[state]
    assert _matches(pattern, word)
    # bits a drive adds (remote, target reached, following error, voltage enabled) do not change the state
    for extra in (0, cia402.SW_REMOTE, cia402.SW_FOLLOWING_COMMAND | cia402.SW_REMOTE, cia402.SW_FOLLOWING_ERROR):
        assert cia402.state_of(word | extra) == state


@pytest.mark.parametrize(("state", "command", "expected"), TRANSITIONS)
def test_state_machine_follows_the_standard_transitions(state, command, expected):
    assert cia402.next_state(state, command, 0) == expected


def test_fault_reset_needs_a_rising_edge_of_bit_7():
    assert cia402.next_state(cia402.FAULT, RESET, RESET) == cia402.FAULT  # bit 7 held high: no edge
    assert cia402.next_state(cia402.FAULT, RESET, 0x00) == cia402.SWITCH_ON_DISABLED
    # the master's enabling sequence sends 0 first when the last command already had bit 7
    assert cia402.enabling_controlword(cia402.FAULT, RESET) == 0x00
    assert cia402.enabling_controlword(cia402.FAULT, 0x00) == RESET


def test_enabling_sequence_reaches_operation_enabled_from_every_state():
    for start in (cia402.SWITCH_ON_DISABLED, cia402.READY, cia402.SWITCHED_ON, cia402.QUICK_STOP_ACTIVE, cia402.FAULT):
        state, previous = start, 0
        for _ in range(6):
            word = cia402.enabling_controlword(state, previous)
            state, previous = cia402.next_state(state, word, previous), word
            if state == cia402.OPERATION_ENABLED:
                break
        assert state == cia402.OPERATION_ENABLED, start


@pytest.mark.parametrize("period", [0.004, 0.001, 0.0005, 0.02, 0.25, 0.000125])
def test_interpolation_period_is_value_times_ten_to_the_index(period):
    value, index = cia402.interpolation_period(period)
    assert 1 <= value <= 255 and -128 <= index <= 63  # UNSIGNED8 value, INTEGER8 index (0x60C2)
    assert value * 10.0**index == pytest.approx(period, rel=1e-12)


def test_interpolation_period_that_0x60C2_cannot_express_is_refused():
    with pytest.raises(ValueError, match="not representable"):
        cia402.interpolation_period(1 / 300)


def test_object_dictionary_has_the_profile_objects_at_their_standard_indices():
    od = cia402.cia402_object_dictionary(5)
    assert od[0x1000].default & 0xFFFF == 402
    expected = {0x6040: "Controlword", 0x6041: "Statusword", 0x6060: "Modes of operation", 0x6064: None}
    for index, name in expected.items():
        assert index in od
        if name:
            assert od[index].name == name
    # default PDO mapping: RPDO1 = controlword (16 bit) + target position (32 bit), TPDO1 = statusword + position
    assert od[0x1400][1].default == 0x205 and od[0x1800][1].default == 0x40000185  # bit 30: no RTR
    assert [od[0x1600][i].default for i in (1, 2)] == [0x60400010, 0x607A0020]
    assert [od[0x1A00][i].default for i in (1, 2)] == [0x60410010, 0x60640020]
    assert cia402.CSP == 8
