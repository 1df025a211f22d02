"""The emulated UR controller, checked with the real ur_rtde client (no driver in between).

What a wrong emulator would break: the exact wire types (a mistyped variable garbles every
later one in the package), NOT_FOUND and IN_USE refusals, the register handshake of blocking
commands, the dashboard texts, and independence of emulators side by side.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Iterator
from typing import TypeVar

import pytest
import rtde_control
import rtde_receive

from stubs.plant.base import UR5E_HOME
from stubs.ur_controller.frame import tcp_pose
from stubs.ur_controller.launch import EmulatedController
from stubs.ur_controller.ur_types import URType, input_type, output_type

Interface = TypeVar("Interface")


@contextlib.contextmanager
def released(interface: Interface) -> Iterator[Interface]:
    """Disconnect at once on failure. On success the destructor disconnects when the test
    returns: calling disconnect() as well would cost its 0.5 s sleep twice."""
    try:
        yield interface
    except BaseException:
        interface.disconnect()  # type: ignore[attr-defined]
        raise


@pytest.fixture(scope="module")
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


@pytest.fixture(autouse=True)
def _cleared(emulator: EmulatedController) -> None:
    emulator.clear()


def test_default_recipe_of_58_variables_unpacks_to_the_true_values(
    emulator: EmulatedController,
) -> None:
    full_recipe = rtde_receive.RTDEReceiveInterface(emulator.host)  # the library's default
    with released(full_recipe) as receive:
        assert receive.getActualQ() == pytest.approx(UR5E_HOME)
        assert receive.getActualTCPPose() == pytest.approx(tcp_pose(UR5E_HOME), abs=1e-9)
        assert receive.getRobotMode() == 7  # RUNNING
        assert receive.getJointTemperatures() == pytest.approx([30.0] * 6)
        # Last in the package: any mistyped variable before them would garble these.
        assert receive.getSafetyStatusBits() == 1  # NORMAL
        assert receive.getPayloadInertia() == pytest.approx([0.0] * 6)
        assert receive.getActualMainVoltage() == pytest.approx(48.0)
        first = receive.getTimestamp()
        time.sleep(0.05)
        assert 0.03 < receive.getTimestamp() - first < 0.2  # the controller clock advances


def test_unknown_output_variable_is_refused_as_not_found(emulator: EmulatedController) -> None:
    with pytest.raises(RuntimeError, match=r"not found by the controller: \[no_such_variable\]"):
        rtde_receive.RTDEReceiveInterface(emulator.host, 500.0, ["actual_q", "no_such_variable"])


def test_the_type_table_follows_the_controller_version() -> None:
    assert output_type("payload_inertia", (5, 10, 0)) is None
    assert output_type("payload_inertia", (5, 11, 0)) is URType.VECTOR6D
    assert output_type("joint_mode", (5, 11, 0)) is URType.VECTOR6INT32
    assert output_type("actual_digital_input_bits", (5, 11, 0)) is URType.UINT64
    assert output_type("output_int_register_30", (5, 2, 0)) is None  # upper range from 5.3
    assert input_type("output_int_register_0", (5, 11, 0)) is None  # clients cannot write it
    assert input_type("input_double_register_47", (5, 11, 0)) is URType.DOUBLE


def test_registers_taken_by_one_client_are_in_use_for_another(
    emulator: EmulatedController,
) -> None:
    control = rtde_control.RTDEControlInterface(emulator.host)
    with released(control) as first:
        with pytest.raises(RuntimeError, match="already in use"):
            rtde_control.RTDEControlInterface(emulator.host)
        assert first.isProgramRunning()
        first.stopScript()


def test_blocking_command_runs_the_ready_done_handshake(emulator: EmulatedController) -> None:
    receiver = rtde_receive.RTDEReceiveInterface(emulator.host, 500.0, ["actual_q"])
    controller = rtde_control.RTDEControlInterface(emulator.host)
    with released(receiver) as receive, released(controller) as control:
        target = list(UR5E_HOME)
        target[0] += 0.3
        assert control.moveJ(target, 1.0, 1.0)  # returns once the script signals "done"
        assert receive.getActualQ()[0] == pytest.approx(target[0], abs=2e-3)
        assert control.moveJ(list(UR5E_HOME), 1.0, 1.0)
        control.stopScript()
        assert not control.isProgramRunning()


def dashboard(host: str, *commands: str) -> list[str]:
    """The welcome line and one answer per command, from the dashboard server at ``host``."""
    with socket.create_connection((host, 29999), timeout=2.0) as sock:
        lines = sock.makefile("rwb", buffering=0)
        answers = [lines.readline().decode().rstrip("\n")]
        for command in commands:
            lines.write(command.encode() + b"\n")
            answers.append(lines.readline().decode().rstrip("\n"))
    return answers


def test_dashboard_answers_like_the_manual(emulator: EmulatedController) -> None:
    welcome, version, remote, unknown = dashboard(
        emulator.host, "PolyscopeVersion", "is in remote control", "fly")
    assert welcome == "Connected: Universal Robots Dashboard Server"
    assert version.startswith("URSoftware 5.11.1.108318")
    assert remote == "true"
    assert unknown == "Could not understand: 'fly'"


def test_emulators_side_by_side_are_independent(emulator: EmulatedController) -> None:
    with EmulatedController() as other:
        assert other.host != emulator.host
        other.inject("protective_stop")
        receiver = rtde_receive.RTDEReceiveInterface(other.host, 500.0, ["safety_status_bits"])
        with released(receiver) as theirs:
            assert theirs.getSafetyStatusBits() == 1 << 2  # PROTECTIVE_STOP only
        assert dashboard(emulator.host, "safetymode")[1] == "Safetymode: NORMAL"
        assert dashboard(other.host, "safetymode")[1] == "Safetymode: PROTECTIVE_STOP"
