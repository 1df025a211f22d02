"""The 402 tables of the driver and of the emulated drive (written separately), each checked
against canopen's own tables, and the emulated state machine against canopen's transitions."""

from __future__ import annotations

import struct

import pytest
from canopen.objectdictionary import ODVariable
from canopen.profiles.p402 import State402

from drivers.base import DriverInitError
from drivers.canopen402.bringup import bus_load, check_bus_load, frame_bits, interpolation_period
from drivers.canopen402.link import _parse_eds, _variables, load_object_dictionary
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.tables import (
    DEFAULT_EDS,
    PDO_FORMATS,
    STATE_BITS,
    Controlword,
    DriveState,
    Index,
    decode_state,
)
from drivers.settings import SettingsError
from stubs.cia402_drive.profile import STATE_STATUS, PowerState, StatusBit
from stubs.cia402_drive.state_machine import PowerStateMachine

ENTERABLE = {s.value for s in PowerState} - {"NOT READY TO SWITCH ON", "FAULT REACTION ACTIVE"}


@pytest.mark.parametrize("state", list(STATE_BITS))
def test_statusword_of_each_state_decodes_to_it_here_and_in_canopen(state: DriveState) -> None:
    word = STATE_BITS[state] | 0x0200  # plus "remote", which must not matter
    assert decode_state(word) is state
    canopen_names = [name for name, (mask, bits) in State402.SW_MASK.items()
                     if word & mask == bits]
    assert canopen_names[0] == state.value


@pytest.mark.parametrize("state", list(STATE_STATUS))
def test_the_emulated_drive_reports_each_state_as_canopen_and_the_driver_read_it(
    state: PowerState,
) -> None:
    word = STATE_STATUS[state] | StatusBit.REMOTE | StatusBit.FOLLOWS_COMMAND
    canopen_names = [name for name, (mask, bits) in State402.SW_MASK.items()
                     if word & mask == bits]
    assert canopen_names[0] == state.value
    assert decode_state(word).value == state.value


@pytest.mark.parametrize(("transition", "controlword"), [
    (pair, cw) for pair, cw in State402.TRANSITIONTABLE.items()
    if pair[0] in ENTERABLE and pair[1] in ENTERABLE
])
def test_canopen_transition_commands_move_the_emulated_drive(
    transition: tuple[str, str], controlword: int,
) -> None:
    machine = PowerStateMachine()
    machine.quick_stop_option = 6  # transition 16 (QUICK STOP ACTIVE → OPERATION ENABLED)
    machine.state = PowerState(transition[0])
    machine.on_controlword(controlword)
    assert machine.state.value == transition[1]


def test_fault_reset_needs_a_rising_edge_and_a_cleared_cause() -> None:
    machine = PowerStateMachine()
    machine.fault()
    assert not machine.on_controlword(Controlword.FAULT_RESET, fault_cleared=False)
    assert machine.state is PowerState.FAULT
    assert not machine.on_controlword(Controlword.FAULT_RESET)  # still high: no new edge
    machine.on_controlword(Controlword.DISABLE_VOLTAGE)
    assert machine.on_controlword(Controlword.FAULT_RESET)
    assert machine.state is PowerState.SWITCH_ON_DISABLED


def test_a_drive_side_quick_stop_holds_until_its_input_is_released() -> None:
    machine = PowerStateMachine()
    machine.quick_stop_option = 6
    machine.state = PowerState.OPERATION_ENABLED
    machine.quick_stop_input()
    machine.on_controlword(Controlword.ENABLE_OPERATION)
    assert machine.state is PowerState.QUICK_STOP_ACTIVE
    machine.quick_stop_input(active=False)
    machine.on_controlword(Controlword.ENABLE_OPERATION)
    assert machine.state is PowerState.OPERATION_ENABLED


@pytest.mark.parametrize(("option", "after"), [(2, PowerState.SWITCH_ON_DISABLED),
                                                (6, PowerState.QUICK_STOP_ACTIVE)])
def test_quick_stop_option_decides_what_follows_standstill(option: int,
                                                           after: PowerState) -> None:
    machine = PowerStateMachine()
    machine.quick_stop_option = option
    machine.state = PowerState.OPERATION_ENABLED
    machine.on_controlword(Controlword.QUICK_STOP)
    machine.after_standstill()
    assert machine.state is after


@pytest.mark.parametrize(("period_us", "expected"), [
    (1000, (1, -3)), (2000, (2, -3)), (4000, (4, -3)), (250, (25, -5)), (1500, (15, -4)),
    (300_000, (255, -3)),
])
def test_interpolation_period_is_exact_when_it_can_be(period_us: int,
                                                      expected: tuple[int, int]) -> None:
    assert interpolation_period(period_us) == expected


def test_frame_bits_match_the_worst_case_of_iso_11898() -> None:
    assert (frame_bits(0), frame_bits(8)) == (55, 135)  # SYNC; a full 8-byte PDO


def test_six_drives_fit_a_1_mbit_bus_at_250_hz_but_not_at_500_hz() -> None:
    assert bus_load(6, 1 / 250, 1_000_000) < 0.6
    assert bus_load(6, 1 / 500, 1_000_000) > 1.0
    physical = CiA402Settings(interface="socketcan", channel="can0", node_ids=(1, 2, 3, 4, 5, 6),
                              counts_per_rev=(4096.0,) * 6)
    check_bus_load(physical, 1 / 250)
    with pytest.raises(DriverInitError, match=r"6 drives at 500 Hz need 11\d% of 1000000"):
        check_bus_load(physical, 1 / 500)
    emulated = CiA402Settings(interface="virtual", channel="x", node_ids=(1, 2, 3, 4, 5, 6),
                              counts_per_rev=(4096.0,) * 6)
    check_bus_load(emulated, 1 / 1000)  # no bitrate: CPU time is the limit there


@pytest.mark.parametrize("node_id", [1, 6, 127])
def test_shared_eds_parse_gives_each_node_its_own_cob_ids(node_id: int) -> None:
    import canopen

    fast = {(v.index, v.subindex): v.default for v in
            _variables(load_object_dictionary(DEFAULT_EDS, node_id))}
    full = {(v.index, v.subindex): v.default for v in
            _variables(canopen.import_od(str(DEFAULT_EDS), node_id))}
    assert fast == full
    assert fast[(0x1800, 1)] == 0x180 + node_id
    cached = _parse_eds(str(DEFAULT_EDS), DEFAULT_EDS.stat().st_mtime_ns)
    assert isinstance(cached[0x1000], ODVariable) and cached[0x1800][1].default == 0x180


def test_settings_from_a_manifest_table() -> None:
    table = {"interface": "socketcan", "channel": "can0", "node_ids": [1, 2],
             "counts_per_rev": [4096, 4096.0], "direction": [1, -1]}
    settings = CiA402Settings.from_mapping(table)
    assert settings.node_ids == (1, 2)
    assert [s.direction for s in settings.joint_scales()] == [1, -1]
    assert settings.bus_options() == {"bitrate": 1_000_000}


@pytest.mark.parametrize(("change", "message"), [
    ({"speed": 3}, "canopen402.speed: unknown key"),
    ({"counts_per_rev": [4096]}, "counts_per_rev has 1 values for 2 node ids"),
    ({"direction": [1, 2]}, "direction values must be 1 or -1"),
    ({"node_ids": [1, 1]}, "node ids must be unique"),
    ({"node_ids": [0, 200]}, r"canopen402\.node_ids\[0\]: must be at least 1, got 0"),
    ({"heartbeat_timeout_ms": 10}, "heartbeat_period_ms < heartbeat_timeout_ms"),
])
def test_bad_settings_name_the_key(change: dict[str, object], message: str) -> None:
    table = {"interface": "socketcan", "channel": "can0", "node_ids": [1, 2],
             "counts_per_rev": [4096, 4096], **change}
    with pytest.raises(SettingsError, match=message):
        CiA402Settings.from_mapping(table)


@pytest.mark.parametrize("index", list(PDO_FORMATS))
def test_each_mapped_object_is_encoded_as_the_eds_types_it(index: Index) -> None:
    """What a PDO listener (the safety monitor's) decodes is what the drives' EDS says."""
    variable = load_object_dictionary(DEFAULT_EDS)[index]
    assert isinstance(variable, ODVariable)
    eds = variable.STRUCT_TYPES[variable.data_type]
    ours = struct.Struct("<" + PDO_FORMATS[index])
    assert ours.size == eds.size
    for data in (b"\xff" * ours.size, b"\x01" + b"\x80" * (ours.size - 1)):  # sign, order
        assert ours.unpack(data) == eds.unpack(data)
