"""A real-device run recovers from a fallback only a human may end, through `warden operator`.

The UR cell as a robot PC runs it: the RTDE controller emulator started by the test (as warden's
launcher would start it), the shipped manifest with ``[emulator] launch = false`` and no
simulated operator (so warden treats it as a real device, and the operator socket is
required), one cycle of a real ``python -m kernel.cli run``. Warden does not launch the policy
server either: the test serves the reference policy itself, and hangs its inference once the
decision log shows the first chunk of the approach admitted (every chunk asked for from then on
is dropped, the ``drop=1`` fault, while the server's heartbeats keep the link alive). Once that
chunk has run out, the pre-contact approach holds on an empty queue (UNDERRUN) and, after
``max_underrun_ms``, the core enters SAFE_HOLD: a fault-driven fallback that only an operator
ends (the link never looked dead, so it is not DEGRADED, which a new handshake would end). The
test then does what the operator does once the policy answers again: ``warden operator
accept-recovery`` over the real socket, through the CLI's entry point (in this process: a new
interpreter costs seconds of imports on a loaded test machine). The decision log must show the
way back: SAFE_HOLD → RUNNING on RECOVERY_ACCEPTED, a new queue epoch that the chunks admitted
afterwards carry, and the cycle verified; the journal replays identically.
"""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from kernel.app.context import CellContext
from kernel.app.task import task_settings
from kernel.cli import main as cli_main
from kernel.cli_operator import send
from kernel.core.lines import ADMITTED
from kernel.core.runtime import Core
from kernel.manifest import Manifest, load_manifest
from skills.planner import Planner
from stubs.cell.reference import ReferenceServer
from stubs.fault_control import inject
from stubs.policy_server.__main__ import parse_args
from stubs.policy_server.faults import FaultConfig, FaultPlan
from stubs.policy_server.server import PolicyServer
from tests.cell.harness import MANIFESTS, replays_identically, run_dir
from tests.cell.test_kill_warden import emulator_for, real_device_manifest
from tests.drivers.support import REST_RAD_S
from tests.safety.support import free_port

pytestmark = pytest.mark.slow
ROOT = MANIFESTS.parent
HUNG_INFERENCE = FaultConfig(drop=1.0)
"""Every chunk the server computes is dropped, none sent; heartbeats go on."""
TIMEOUT_S = 60.0


class _Policy:
    """The manifest's reference policy server on a thread of the test: its inference hangs
    from :meth:`hang` until :meth:`resume` (it keeps serving: the link and session stay up)."""

    def __init__(self, manifest: Manifest) -> None:
        self.config = parse_args(ReferenceServer(_context(manifest))._args())
        self.server: PolicyServer | None = None
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._loop.run_until_complete,
                                        args=(self._serve(),), daemon=True)

    def start(self) -> None:
        self._thread.start()
        assert self._ready.wait(10), "the policy server did not start"

    def hang(self) -> None:
        assert self.server is not None
        self.server.faults = FaultPlan(HUNG_INFERENCE)  # one assignment, for the next chunk

    def resume(self) -> None:
        assert self.server is not None
        self.server.faults = FaultPlan(FaultConfig())

    def stop(self) -> None:
        if self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        async with PolicyServer(self.config) as server:
            self.server = server
            self._ready.set()
            await self._stop.wait()


def _context(manifest: Manifest) -> CellContext:
    """What the reference server needs of a cell: the task's layout and the arm's model."""
    kinematics = manifest.core.kinematics
    assert kinematics is not None
    limits = Core(manifest.core).planner_limits
    layout = task_settings(manifest).layout()
    planner = Planner(kinematics, limits, layout.tool_down)
    return CellContext(manifest, layout, planner, kinematics, None)  # type: ignore[arg-type]


def _manifest(settings: dict[str, Any], directory: Path, port: int) -> Path:
    """The UR cell as a robot PC runs it, its policy server an external one at ``port``."""
    path = real_device_manifest("sim-ur5e-rtde.toml", settings, directory)
    text = path.read_text()
    for old, new in (("launch = true ", "launch = false"), ("port = 0 ", f"port = {port}")):
        assert text.count(old) == 1, f"expected one {old!r} in [policy]"
        text = text.replace(old, new)
    path.write_text(text)
    return path


class _Admitted:
    """Whether the decision log, as far as the recorder has written it, shows an admitted
    chunk (read on from where the last call stopped: the test shares two cores with the run)."""

    def __init__(self, directory: Path) -> None:
        self.directory, self.offset = directory, 0

    def __call__(self) -> bool:
        found = list((self.directory / "runs").glob("*/decisions.jsonl"))
        if not found:
            return False
        with found[0].open("rb") as stream:
            stream.seek(self.offset)
            text = stream.read()
        whole = text[:text.rfind(b"\n") + 1]
        self.offset += len(whole)
        return any(json.loads(line).get("decision") in ADMITTED
                   for line in whole.splitlines() if line.startswith(b'{"kind":"chunk"'))


def _wait(condition: Callable[[], Any], what: str, warden: subprocess.Popen[bytes],
          directory: Path) -> Any:
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        if warden.poll() is not None:
            raise AssertionError(f"warden exited {warden.returncode} waiting for {what}:\n"
                                 + (directory / "warden.log").read_text()[-3000:])
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _mode(socket: Path) -> str | None:
    try:
        return send(str(socket), "status", 2.0).get("mode")
    except (OSError, ValueError):
        return None  # not serving yet


def _at_rest(control: tuple[str, int]) -> bool:
    """The emulated arm's ground truth: every joint slower than ``REST_RAD_S``, twice."""
    for _ in range(2):
        if max(map(abs, inject(control, "ground_truth")["qd"])) >= REST_RAD_S:
            return False
        time.sleep(0.05)
    return True


def test_a_real_device_run_recovers_after_an_underrun_safe_hold(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    port = free_port()
    socket = tmp_path / "operator.sock"
    with emulator_for("sim-ur5e-rtde.toml") as (_, settings, control):
        path = _manifest(settings, tmp_path, port)
        manifest = load_manifest(path)
        assert not manifest.emulator.launch and not manifest.cell.simulated_operator
        policy = _Policy(manifest)
        policy.start()
        warden = subprocess.Popen(
            [sys.executable, "-m", "kernel.cli", "run", str(path), "--cycles", "1",
             "--journal-dir", str(tmp_path / "runs"), "--json", str(tmp_path / "summary.json"),
             "--log-format", "json"],
            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=(tmp_path / "warden.log").open("wb"))
        try:
            _wait(_Admitted(tmp_path), "an admitted chunk", warden, tmp_path)
            policy.hang()
            _wait(lambda: _mode(socket) == "SAFE_HOLD", "SAFE_HOLD", warden, tmp_path)
            # The operator sees the arm held at rest and the policy answering again, then
            # accepts recovery.
            _wait(lambda: _at_rest(control), "the arm at rest", warden, tmp_path)
            policy.resume()
            capsys.readouterr()
            assert cli_main(["operator", "accept-recovery", "--socket", str(socket)]) == 0
            accepted = capsys.readouterr()
            code = warden.wait(timeout=TIMEOUT_S)
        finally:
            if warden.poll() is None:
                warden.send_signal(signal.SIGTERM)
                warden.wait(timeout=30)
            policy.stop()
    log = (tmp_path / "warden.log").read_text()
    assert code == 0, log[-3000:]  # the one cycle verified

    answer = json.loads(accepted.out)
    recovered = [line for line in answer["lines"] if line["kind"] == "transition"
                 and line["machine"] == "fallback"]
    assert recovered and recovered[0]["from"] == "SAFE_HOLD"
    assert recovered[0]["to"] == "RUNNING" and recovered[0]["trigger"] == "RECOVERY_ACCEPTED"

    lines = [json.loads(line) for line in (run_dir(tmp_path / "runs") / "decisions.jsonl").open()]
    fallbacks = [line for line in lines if line["kind"] == "transition"
                 and line["machine"] == "fallback" and line.get("accepted", True)]
    # The fallback happened, for the reason the hung server gives, and only a human ended it.
    assert [(t["from"], t["to"], t["trigger"]) for t in fallbacks] == [
        ("RUNNING", "SAFE_HOLD", "UNDERRUN"), ("SAFE_HOLD", "RUNNING", "RECOVERY_ACCEPTED")]
    hold, back = fallbacks
    assert any(line["kind"] == "tick" and line["reason"] == "UNDERRUN"
               and line["mode"] == "RUNNING" for line in lines if line["t"] < hold["t"])
    held_ticks = [line for line in lines if line["kind"] == "tick"
                  and hold["t"] <= line["t"] < back["t"]]
    assert held_ticks and all(line["mode"] == "SAFE_HOLD" and line["owner"] == "fallback"
                              for line in held_ticks)
    # A new queue epoch with the recovery, and the chunks admitted after it carry it.
    epochs = [line["queue_epoch"] for line in lines if line["kind"] == "queue"
              and line["action"] == "new_epoch" and line["t"] == back["t"]]
    before = max(line["queue_epoch"] for line in lines if line["kind"] == "chunk"
                 and line["decision"] in ADMITTED and line["t"] < hold["t"])
    assert epochs and epochs[-1] > before
    admitted_after = [line for line in lines if line["kind"] == "chunk"
                      and line["decision"] in ADMITTED and line["t"] > back["t"]]
    assert admitted_after and {line["queue_epoch"] for line in admitted_after} == {epochs[-1]}
    with capsys.disabled():
        print(f"\nSAFE_HOLD (UNDERRUN) at {hold['t']:.0f} ms, RUNNING again (RECOVERY_ACCEPTED) at "
              f"{back['t']:.0f} ms; queue epoch {before} -> {epochs[-1]}, {len(admitted_after)} "
              "chunks admitted after it")

    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["cycles"]["attempted"] == summary["cycles"]["verified"] == 1
    journal = [json.loads(line) for line in
               (run_dir(tmp_path / "runs") / "journal.jsonl").open()][1:]
    operator = [event for event in journal if event["kind"] == "operator"]
    assert [event["action"] for event in operator] == ["accept_recovery"]
    assert "operator command" in log and "accept-recovery" in log
    assert replays_identically(run_dir(tmp_path / "runs"))
