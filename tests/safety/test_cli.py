"""``warden safety``: what it refuses to start on (exit 2, nothing commanded), and ``warden safety
status`` answering from a live monitor only."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import pytest

from kernel.cli import main
from kernel.shell.heartbeat import HeartbeatSender
from stubs.ur_controller.launch import EmulatedController, free_loopback_host
from tests.safety.support import (
    MANIFESTS,
    Monitor,
    canopen_manifest,
    free_port,
    safety_table,
    sim_manifest,
    ur_manifest,
    wait_for,
)


def _refusal(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    assert main(["safety", *argv]) == 2
    return capsys.readouterr().err


def test_a_manifest_without_a_safety_table_is_refused(capsys) -> None:  # type: ignore
    err = _refusal(capsys, str(MANIFESTS / "sim-ur5e.toml"))
    assert "sim-ur5e.toml: safety: no [safety] table" in err


def test_a_missing_force_limit_is_refused(tmp_path: Path, capsys) -> None:  # type: ignore
    path = sim_manifest(tmp_path, free_port(), max_wrist_force_n=None)
    err = _refusal(capsys, str(path))
    assert "cell.toml: safety.max_wrist_force_n: required key is missing" in err


def test_a_canopen_cell_whose_emulator_warden_starts_has_no_bus(tmp_path: Path,
                                                                capsys) -> None:  # type: ignore
    path = tmp_path / "canopen.toml"
    path.write_text((MANIFESTS / "sim-canopen.toml").read_text() + safety_table(tmp_path))
    err = _refusal(capsys, str(path))
    assert "canopen.toml: emulator.launch: true, so warden picks the emulated drives' bus" in err
    assert not (tmp_path / "status.sock").exists()


@pytest.mark.parametrize(("driver", "expected"), [
    ({"watchdog_ms": 0}, "cannot watch the device: {}/cell.toml: driver.watchdog_ms: 0, so "
     "warden's driver leaves each drive's abort connection option code (0x6007) as the drive "
     "has it"),
    # Settings that fit no drive are the manifest's own mistake, refused when it is loaded.
    ({"node_ids": [1, 2, 2]}, "warden safety: {}/cell.toml: driver: node ids must be unique"),
])
def test_canopen_driver_settings_the_monitor_cannot_watch_by_are_refused(
        tmp_path: Path, capsys, driver: dict, expected: str) -> None:  # type: ignore
    bus = {"interface": "udp_multicast", "channel": "239.1.2.3", "udp_port": 41234}
    err = _refusal(capsys, str(canopen_manifest(tmp_path, bus, driver=driver)))
    assert expected.format(tmp_path) in err
    assert not (tmp_path / "status.sock").exists()


def test_a_canopen_bus_that_does_not_open_is_refused(tmp_path: Path, capsys) -> None:  # type: ignore
    bus = {"interface": "socketcan", "channel": "can-nowhere"}
    err = _refusal(capsys, str(canopen_manifest(tmp_path, bus)))
    assert "cannot watch the device: canopen402: cannot open the CAN bus (interface " \
           "'socketcan' channel 'can-nowhere')" in err
    assert "check interface and channel in [driver]" in err


def test_a_ur_cell_whose_emulator_warden_starts_has_no_address(tmp_path: Path,
                                                               capsys) -> None:  # type: ignore
    path = tmp_path / "ur.toml"
    path.write_text((MANIFESTS / "sim-ur5e-rtde.toml").read_text() + safety_table(tmp_path))
    assert "driver.host: not set" in _refusal(capsys, str(path))


def test_an_unreachable_controller_is_refused(tmp_path: Path, capsys) -> None:  # type: ignore
    host = free_loopback_host()
    err = _refusal(capsys, str(ur_manifest(tmp_path, host)))
    assert f"cannot watch the device: cannot reach the UR dashboard server at {host}:29999" in err
    assert "check host in the manifest" in err
    assert not (tmp_path / "status.sock").exists() and not (tmp_path / "hb.sock").exists()


def test_a_controller_without_rtde_is_refused_and_nothing_is_stopped(
        tmp_path: Path, capsys) -> None:  # type: ignore
    with EmulatedController() as emulator:
        emulator.inject("data_stall")  # RTDE refuses new sessions; the dashboard still answers
        err = _refusal(capsys, str(ur_manifest(tmp_path, emulator.host)))
        assert f"cannot reach the UR RTDE server at {emulator.host}:30004" in err
        from stubs.fault_control import inject
        status = inject((emulator.host, int(emulator.info["control_port"])), "status")
    assert status["dashboard_stops"] == 0


def test_a_simulated_world_that_is_not_running_is_refused(tmp_path: Path,
                                                          capsys) -> None:  # type: ignore
    port = free_port()
    err = _refusal(capsys, str(sim_manifest(tmp_path, port)))
    assert f"cannot reach the simulated world's control port at 127.0.0.1:{port}" in err
    assert "start `warden run` with this manifest first" in err


def test_status_without_a_monitor_is_exit_2(tmp_path: Path, capsys) -> None:  # type: ignore
    path = tmp_path / "status.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as dead:
        dead.bind(str(path))  # a socket file nobody serves: a monitor that died
    assert main(["safety", "status", "--socket", str(path)]) == 2
    assert "no safety monitor answers" in capsys.readouterr().err


def test_a_missing_socket_directory_is_named(tmp_path: Path, capsys) -> None:  # type: ignore
    """Outside systemd's RuntimeDirectory= nobody makes the sockets' directory: the refusal
    names the socket, its missing directory and the key, not a bare "[Errno 2]"."""
    missing = tmp_path / "warden-safety"
    path = sim_manifest(tmp_path, free_port(), heartbeat_socket=str(missing / "hb.sock"),
                        status_socket=str(missing / "status.sock"))
    err = _refusal(capsys, str(path))
    assert (f"cannot serve the heartbeat socket {missing / 'hb.sock'}: its directory {missing} "
            f"does not exist ({path}: safety.heartbeat_socket;") in err
    assert "Errno" not in err
    assert not missing.exists()


def test_status_names_a_missing_socket_directory(tmp_path: Path, capsys) -> None:  # type: ignore
    missing = tmp_path / "warden-safety"
    assert main(["safety", "status", "--socket", str(missing / "status.sock")]) == 2
    err = capsys.readouterr().err
    assert (f"no safety monitor answers: {missing / 'status.sock'}: its directory {missing} "
            "does not exist") in err
    assert "Errno" not in err


def test_a_dynamixel_monitor_watches_the_heartbeat_and_only_reports(
        tmp_path: Path, capsys) -> None:  # type: ignore
    path = tmp_path / "dynamixel.toml"
    path.write_text((MANIFESTS / "sim-dynamixel.toml").read_text() + safety_table(tmp_path))
    monitor = Monitor(path, tmp_path)
    try:
        status = monitor.wait_watching()
        assert status["ok"] and not status["can_stop"]
        assert "Bus Watchdog" in status["stop_path"]
        assert main(["safety", "status", str(path)]) == 0
        sender = HeartbeatSender(tmp_path / "hb.sock")
        assert sender.beat()  # then silence: a warden that died
        failed = wait_for(lambda: monitor.events("safety stop failed"), "the report")
    finally:
        assert monitor.stop() == 0
    assert failed[0]["violations"][0].startswith(f"heartbeat_lost: no heartbeat from warden "
                                                 f"(pid {os.getpid()})")
    assert "this monitor cannot stop the arm: the servos' Bus Watchdog" in failed[0]["answer"]
    assert not (tmp_path / "status.sock").exists()  # removed on the way out


def test_status_reports_a_lost_device_as_not_ok(tmp_path: Path, capsys) -> None:  # type: ignore
    with EmulatedController() as emulator:
        path = ur_manifest(tmp_path, emulator.host)
        monitor = Monitor(path, tmp_path)
        try:
            assert monitor.wait_watching()["connected"]
            assert main(["safety", "status", str(path)]) == 0
            emulator.inject("data_stall")
            wait_for(lambda: not monitor.status()["connected"], "the stall to be seen")
            capsys.readouterr()
            assert main(["safety", "status", str(path)]) == 1
            err = capsys.readouterr().err
        finally:
            assert monitor.stop() == 0
    assert "not ok: no new RTDE data from" in err


def test_the_status_answer_is_computed_when_asked(tmp_path: Path) -> None:
    path = tmp_path / "dynamixel.toml"
    path.write_text((MANIFESTS / "sim-dynamixel.toml").read_text() + safety_table(tmp_path))
    monitor = Monitor(path, tmp_path)
    try:
        first = monitor.wait_watching()
        time.sleep(0.1)
        second = monitor.status()
    finally:
        monitor.stop()
    assert second["checks"] > first["checks"] and second["nonce"] != first["nonce"]
    assert second["pid"] == monitor.process.pid
