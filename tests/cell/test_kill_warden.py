"""SIGKILL of a whole `warden run` while the arm moves: the device stops it, no one else.

For each driver cell (UR over RTDE, Dynamixel, CiA 402) the test starts the emulator itself,
with the arguments warden's own launcher gives it (stubs/cell/emulated.py), so that it outlives
warden. The shipped manifest is run as on a robot PC: ``[emulator] launch = false``, the driver
pointed at that emulator, no simulated operator, an operator socket and a journal in a temporary
directory. Once the emulator's ground truth shows the arm moving (a planner move of the cycle's
first steps), warden's process is killed outright, and the ground truth must show the arm at rest
within the bound docs/operations.md states for that driver and manifest ("Device-side
watchdogs"), plus a margin for a loaded 2-core test machine; by then the device must also show
that its own watchdog fired (an arm that comes to rest at its last position setpoint, as a servo
or a CSP drive does when the setpoints stop, is at rest before its watchdog fires: that alone
does not pass).

Stop bounds (the same as the driver tests', at each manifest's defaults): UR 25 × 2 ms + one
2 ms controller cycle + the MuJoCo arm's stopping time after a program stop (80 ms); Dynamixel
6 × 20 ms + the MuJoCo arm behind a held servo (800 ms); CiA 402 300 ms + the drive's 1 ms check
+ the MuJoCo arm's stopping time after a quick stop (80 ms).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from kernel.cli import main as cli_main
from kernel.manifest import load_manifest
from stubs.cell.emulated import LAUNCHERS
from stubs.fault_control import inject
from stubs.process import EmulatorProcess
from tests.cell.harness import MANIFESTS
from tests.drivers.support import REST_RAD_S

pytestmark = pytest.mark.slow
ROOT = MANIFESTS.parent
MARGIN_S = 0.25
MOVING_RAD_S = 0.5
START_TIMEOUT_S = 90.0
SETTLED = 5
Address = tuple[str, int]


def _ur_armed(armed: dict[str, Any]) -> None:
    assert armed["watchdogs"]["armed"] == {"input_int_register_0": pytest.approx(20.0)}  # 50 ms


def _ur_fired(control: Address) -> bool:
    status = inject(control, "status")
    return status["watchdogs"]["fired"] == 1 and status["runtime_state"] == 1  # STOPPED


def _dynamixel_armed(armed: dict[int, int]) -> None:
    assert armed == dict.fromkeys(range(1, 8), 6)  # 120 ms, the gripper (7) included


def _dynamixel_fired(control: Address) -> bool:
    return _bus_watchdogs(control) == dict.fromkeys(range(1, 8), -1)


def _bus_watchdogs(control: Address) -> dict[int, int]:
    return {servo: inject(control, "peek", id=servo, item=98)["value"] for servo in range(1, 8)}


def _canopen_armed(armed: dict[str, Any]) -> None:
    assert armed == {str(node): {"producer": 127, "timeout_ms": 300} for node in range(1, 8)}


def _canopen_fired(control: Address) -> bool:
    drives = inject(control, "drives")["drives"]
    states = {node: (d["state"], d["nmt"]) for node, d in drives.items()}
    stopped = ("QUICK STOP ACTIVE", "PRE-OPERATIONAL")
    gripping = ("OPERATION ENABLED", "PRE-OPERATIONAL")  # the gripper keeps its grip
    return states == {**{str(node): stopped for node in range(1, 7)}, "7": gripping}


def _consumers(control: Address) -> dict[str, Any]:
    return {node: d["consumer"] for node, d in inject(control, "drives")["drives"].items()}


@dataclass(frozen=True)
class DriverCell:
    manifest: str
    stop_bound_s: float
    """docs/operations.md, "Device-side watchdogs", for this manifest."""
    read_armed: Callable[[Address], Any]
    """What the device says it armed, read while warden still runs..."""
    armed_as_documented: Callable[[Any], None]
    """... and the assertion that it is the manifest's default."""
    fired: Callable[[Address], bool]
    """The device's own watchdog has stopped the arm."""


CELLS = {
    "ur_rtde": DriverCell("sim-ur5e-rtde.toml", 0.050 + 0.002 + 0.080,
                          lambda control: inject(control, "status"), _ur_armed, _ur_fired),
    "dynamixel": DriverCell("sim-dynamixel.toml", 0.120 + 0.800, _bus_watchdogs,
                            _dynamixel_armed, _dynamixel_fired),
    "canopen402": DriverCell("sim-canopen.toml", 0.300 + 0.001 + 0.080, _consumers,
                             _canopen_armed, _canopen_fired),
}


def after_kill(truth: Callable[[], dict[str, Any]], fired: Callable[[], bool], since: float,
               timeout_s: float) -> tuple[float, float]:
    """Seconds from ``since`` until the arm is at rest (the first of SETTLED ground-truth samples
    in a row with every joint slower than REST_RAD_S) and until ``fired``, polled together.

    Raises:
        AssertionError: either did not happen within ``timeout_s``.
    """
    rest_at = fired_at = first_rest = None
    in_a_row = 0
    while time.monotonic() - since < timeout_s and (rest_at is None or fired_at is None):
        sample, now = truth(), time.monotonic() - since
        if max(abs(v) for v in sample["qd"]) >= REST_RAD_S:
            first_rest, in_a_row = None, 0
        elif rest_at is None:
            first_rest = now if first_rest is None else first_rest
            in_a_row += 1
            rest_at = first_rest if in_a_row == SETTLED else None
        if fired_at is None and fired():
            fired_at = time.monotonic() - since
        time.sleep(0.002)
    if rest_at is None:
        raise AssertionError(f"the arm was still moving {timeout_s:.3f} s later: {truth()['qd']}")
    if fired_at is None:
        raise AssertionError(f"the device's watchdog did not fire within {timeout_s:.3f} s")
    return rest_at, fired_at


@contextlib.contextmanager
def emulator_for(manifest_name: str) -> Iterator[tuple[EmulatorProcess, dict[str, Any], Address]]:
    """The emulator as warden's launcher would start it; the driver settings that reach it."""
    manifest = load_manifest(MANIFESTS / manifest_name)
    launch = LAUNCHERS[manifest.driver_name](manifest, str(manifest.emulator.plant))
    with EmulatorProcess(launch.module, *launch.args) as process:
        ready = process.info
        control = (launch.control_host(ready), int(ready.get("control_port",
                                                             ready.get("fault_port"))))
        yield process, launch.settings(ready), control


def real_device_manifest(manifest_name: str, settings: Mapping[str, Any], directory: Path
                         ) -> Path:
    """The shipped manifest as a robot PC runs it, its driver pointed at ``settings``."""
    text = (MANIFESTS / manifest_name).read_text()
    for old, new in (("[emulator]\nplant = \"mujoco\"\n", "[emulator]\nlaunch = false\n"),
                     ("cycle_timeout_s = 30.0\n",
                      "cycle_timeout_s = 30.0\nsimulated_operator = false\n"),
                     ("[driver]\n", "[driver]\n" + "".join(
                         f"{key} = {_toml(value)}\n" for key, value in settings.items()))):
        assert text.count(old) == 1, f"{manifest_name}: expected one {old!r}"
        text = text.replace(old, new)
    assert "[operator]" not in text
    text += f'\n[operator]\nsocket = "{directory / "operator.sock"}"\n'
    path = directory / manifest_name
    path.write_text(text)
    return path


def _toml(value: object) -> str:
    return f'"{value}"' if isinstance(value, str) else str(value)


def start_warden(manifest: Path, directory: Path) -> subprocess.Popen[bytes]:
    """`warden run` in a session of its own: its policy server and job worker go with it."""
    log = (directory / "warden.log").open("wb")
    return subprocess.Popen(
        [sys.executable, "-m", "kernel.cli", "run", str(manifest), "--cycles", "1",
         "--journal-dir", str(directory / "runs"), "--log-format", "json"],
        cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def wait_until_moving(truth: Callable[[], dict[str, Any]], warden: subprocess.Popen[bytes],
                      directory: Path) -> dict[str, Any]:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if warden.poll() is not None:
            log = (directory / "warden.log").read_text()[-3000:]
            raise AssertionError(f"warden exited with {warden.returncode}:\n{log}")
        sample = truth()
        if max(abs(v) for v in sample["qd"]) > MOVING_RAD_S:
            return sample
        time.sleep(0.002)
    raise AssertionError(f"the arm never moved faster than {MOVING_RAD_S} rad/s")


def kill_session(warden: subprocess.Popen[bytes]) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(warden.pid, signal.SIGKILL)
    warden.wait()


@pytest.mark.parametrize("driver", list(CELLS))
def test_killing_warden_leaves_the_arm_at_rest_within_the_bound(driver: str) -> None:
    cell = CELLS[driver]
    with tempfile.TemporaryDirectory(prefix="kill-") as tmp, \
            emulator_for(cell.manifest) as (_, settings, control):
        directory = Path(tmp)
        truth = lambda: inject(control, "ground_truth")  # noqa: E731
        warden = start_warden(real_device_manifest(cell.manifest, settings, directory),
                              directory)
        try:
            moving = wait_until_moving(truth, warden, directory)
            armed = cell.read_armed(control)
            os.kill(warden.pid, signal.SIGKILL)
            killed = time.monotonic()
        finally:
            kill_session(warden)
        bound = cell.stop_bound_s + MARGIN_S
        seconds, fired = after_kill(truth, lambda: cell.fired(control), killed, timeout_s=bound)
        speed = max(abs(v) for v in moving["qd"])
        print(f"\n{driver}: moving at {speed:.2f} rad/s; after SIGKILL of warden at rest "
              f"{seconds * 1e3:.0f} ms, device watchdog fired {fired * 1e3:.0f} ms (bound "
              f"{bound * 1e3:.0f} ms)")
        cell.armed_as_documented(armed)
        assert seconds < bound and fired < bound
        # What the killed run wrote replays, up to where the kill cut it (0: whole, 3: ends
        # early), never a difference or a broken file.
        (journal,) = (directory / "runs").glob("*/journal.jsonl")
        assert cli_main(["replay", str(journal)]) in (0, 3)
