"""What the safety monitor needs of the emulated UR controller, checked with the real ur_rtde:
the dashboard's ``stop`` decelerates the arm and answers once it is at rest, and RTDE clients
are independent (one that stops reading holds back neither the controller nor another)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import pytest
import rtde_control
import rtde_receive

from kernel.safety.dashboard import Dashboard
from stubs.fault_control import inject
from stubs.ur_controller.launch import EmulatedController
from stubs.ur_controller.program_stop import DECELERATION_RAD_S2

SPEED = 1.0


@pytest.fixture
def emulator() -> Iterator[EmulatedController]:
    with EmulatedController() as controller:
        yield controller


def _truth(emulator: EmulatedController) -> dict:  # type: ignore[type-arg]
    return inject((emulator.host, int(emulator.info["control_port"])), "ground_truth")


def _status(emulator: EmulatedController) -> dict:  # type: ignore[type-arg]
    return inject((emulator.host, int(emulator.info["control_port"])), "status")


def _moving(emulator: EmulatedController) -> rtde_control.RTDEControlInterface:
    control = rtde_control.RTDEControlInterface(emulator.host)
    assert control.speedJ([SPEED, 0, 0, 0, 0, 0], 5.0, 0.0)
    deadline = time.monotonic() + 5
    while abs(_truth(emulator)["qd"][0]) < SPEED * 0.99:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    return control


def test_the_dashboard_stop_decelerates_the_arm_then_ends_the_program(
        emulator: EmulatedController) -> None:
    control = _moving(emulator)
    dashboard = Dashboard(emulator.host, 2.0, 5.0)
    dashboard.connect()
    before = _truth(emulator)["q"][0]
    assert dashboard.stop() == "Stopped"  # answered once stopping is complete
    after = _truth(emulator)
    status = _status(emulator)
    assert status["runtime_state"] == 1 and status["dashboard_stops"] == 1  # STOPPED
    assert max(map(abs, after["qd"])) == 0.0
    # It came to rest over v^2 / 2a (0.05 rad), not where it stood when the stop arrived, plus
    # what it turned while the request travelled.
    braking = SPEED ** 2 / (2 * DECELERATION_RAD_S2)
    assert braking * 0.8 < after["q"][0] - before < braking + 0.05
    assert not control.speedJ([SPEED, 0, 0, 0, 0, 0], 5.0, 0.0)  # the program is gone
    time.sleep(0.1)
    assert _truth(emulator)["q"] == after["q"]
    assert dashboard.stop() == "Stopped"  # a stopped program stops again without a fuss
    assert _status(emulator)["dashboard_stops"] == 1
    dashboard.close()
    control.disconnect()


def test_while_it_decelerates_the_controller_reports_stopping(
        emulator: EmulatedController) -> None:
    control = _moving(emulator)
    receive = rtde_receive.RTDEReceiveInterface(emulator.host, -1.0, ["runtime_state"])
    dashboard = Dashboard(emulator.host, 2.0, 5.0)
    dashboard.connect()
    stopper = threading.Thread(target=dashboard.stop)
    seen: list[int] = []
    stopper.start()
    while stopper.is_alive():
        seen.append(receive.getRuntimeState())
        time.sleep(0.001)
    seen.append(receive.getRuntimeState())
    deadline = time.monotonic() + 1.0  # the data stream may be a cycle behind the answer
    while seen[-1] != 1 and time.monotonic() < deadline:
        seen.append(receive.getRuntimeState())
        time.sleep(0.001)
    assert 0 in seen and seen[-1] == 1  # STOPPING, then STOPPED
    assert set(seen) <= {0, 1, 2}
    dashboard.close()
    control.disconnect()


@pytest.mark.slow
def test_a_client_that_stops_reading_holds_back_no_other(emulator: EmulatedController) -> None:
    # Before each session had its own writer, the controller's cycle blocked on a stopped
    # client's full socket after about 5 s here, and every client went without data for 1 s.
    child = subprocess.Popen(
        [sys.executable, "-c", "import rtde_receive, sys, time; "
         f"r = rtde_receive.RTDEReceiveInterface({emulator.host!r}); print('ok', flush=True); "
         "time.sleep(60)"], stdout=subprocess.PIPE)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == b"ok"
        os.kill(child.pid, signal.SIGSTOP)
        receive = rtde_receive.RTDEReceiveInterface(emulator.host, -1.0, ["timestamp"])
        started = time.monotonic()
        last, last_change, worst = receive.getTimestamp(), started, 0.0
        while time.monotonic() - started < 8.0:
            stamp, now = receive.getTimestamp(), time.monotonic()
            if stamp != last:
                worst, last, last_change = max(worst, now - last_change), stamp, now
            time.sleep(0.002)
        assert receive.isConnected() and worst < 0.5, worst
    finally:
        child.kill()
        child.wait()


def test_a_stop_from_a_measured_speed_above_the_joint_limit_still_brings_the_arm_to_rest(
        ) -> None:
    """A trial stopped mid-motion measured 3.4 rad/s at the elbow (limit pi) for an instant:
    the stop's first velocity command was refused by the plant and the controller's cycle
    died, leaving the arm moving. The ramp now starts from the joint's limit."""
    from stubs.plant._cell_index import CellIndex
    from stubs.plant.mujoco_plant import MujocoPlant
    from stubs.ur_controller.program_stop import ProgramStop

    plant = MujocoPlant()
    arm = CellIndex.of(plant.model).arm_dof
    plant.data.qvel[arm] = [0.0, 0.0, 3.4, 0.0, 0.0, 0.0]
    assert plant.state().qd[2] == 3.4
    stop = ProgramStop(plant, 0.002)
    for _ in range(1000):  # pi / 10 rad/s^2: 0.31 s of 2 ms cycles, with room
        if stop.step():
            break
        plant.step()
    assert stop.done.is_set()
