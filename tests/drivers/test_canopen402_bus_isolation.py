"""Simulated CANopen buses are separate buses: a ``udp_multicast`` bus is its group and port.

Linux hands a socket bound to a port every multicast group joined on that port unless
``IP_MULTICAST_ALL`` is off, so a bus with nothing on it heard, and enabled, the drives of
another emulator on the same port. And two emulators on one group and port are two sets of
drives with the same node ids on one bus: the second refuses to start.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kernel.cli import main
from kernel.signing import generate_keypair, sign
from stubs.cia402_drive.launch import unique_udp_bus
from stubs.fault_control import inject
from stubs.process import EmulatorProcess, EmulatorStartError
from tests.cell.harness import MANIFESTS
from tests.drivers.cia402_testbed import emulator_args

pytestmark = pytest.mark.slow
MODULE = "stubs.cia402_drive"


def _other_group(group: str) -> str:
    head, last = group.rsplit(".", 1)
    return f"{head}.{int(last) % 254 + 1}"


def _signed_manifest(tmp_path: Path, group: str, port: int) -> tuple[Path, Path]:
    """The shipped CiA 402 cell as a real bus's at ``group``/``port``; (manifest, trusted)."""
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    generate_keypair(tmp_path / "signer.key", trusted / "signer.pub")
    text = (MANIFESTS / "sim-canopen.toml").read_text()
    bus = {"interface": "udp_multicast", "channel": group, "udp_port": port,
           "boot_timeout_s": 1.0}
    lines = "".join(f"{key} = {json.dumps(value)}\n" for key, value in bus.items())
    text = text.replace("[driver]\n", f"[driver]\n{lines}", 1)
    text = text.replace("[emulator]\n", "[emulator]\nlaunch = false\n", 1)
    text = text.replace("[cell]\n", "[cell]\nsimulated_operator = false\n", 1)
    path = tmp_path / "cell.toml"
    path.write_text(text)
    sign(path, tmp_path / "signer.key")
    return path, trusted


def test_a_check_of_an_empty_channel_leaves_the_drives_on_another_channel_alone(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    group, port = unique_udp_bus()
    emulator = EmulatorProcess(MODULE, *emulator_args(group, port, gripper_node=7)).start()
    try:
        control = ("127.0.0.1", int(emulator.info["fault_port"]))
        before = inject(control, "drives")["drives"]
        path, trusted = _signed_manifest(tmp_path, _other_group(group), port)
        code = main(["check", str(path), "--keys", str(trusted), "--seconds", "1"])
        err = capsys.readouterr().err
        assert code == 2 and "does not answer" in err, err  # nobody is on the empty channel
        after = inject(control, "drives")["drives"]
        assert after == before, (before, after)
        assert {drive["nmt"] for drive in after.values()} == {"PRE-OPERATIONAL"}
        assert inject(control, "motion")["motion_commands"] == 0
    finally:
        emulator.stop()


def test_a_second_emulator_on_a_used_bus_refuses_and_another_group_on_its_port_starts(
        capfd: pytest.CaptureFixture[str]) -> None:
    group, port = unique_udp_bus()
    first = EmulatorProcess(MODULE, *emulator_args(group, port)).start()
    try:
        with pytest.raises(EmulatorStartError):
            EmulatorProcess(MODULE, *emulator_args(group, port)).start()
        err = capfd.readouterr().err
        assert f"bus {group} port {port} already has emulated drives" in err, err
        assert "emulator pid" in err
        assert "Traceback" not in err
        EmulatorProcess(MODULE, *emulator_args(_other_group(group), port)).start().stop()
    finally:
        first.stop()
    EmulatorProcess(MODULE, *emulator_args(group, port)).start().stop()  # free once it exited
