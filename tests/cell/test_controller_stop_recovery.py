"""After a CONTROLLER_STOP and an accepted recovery the CiA 402 cell goes on from where it stopped.

The whole CANopen cell (manifests/sim-canopen.toml: the real canopen driver over udp_multicast,
the drive emulator process stepping the MuJoCo plant on every SYNC), one cycle. While the
planner's transport move is under way the device refuses one setpoint (the run's driver
answers it ``CONTROLLER_REJECT``, as a drive in a transient state would): the core stops the arm
(CONTROLLER_STOP, every drive in QUICK STOP ACTIVE), the simulated operator sees it at rest and
accepts recovery, and the core's first command after that is a setpoint from where the arm
stopped. Before the fix the driver refused every setpoint after a quick stop until it got a
HOLD, which the core never sends there: accept-recovery → CONTROLLER_REJECT → CONTROLLER_STOP
→ accept-recovery ... until the cycle's time ran out (46 times in 30 s). Asserted: no write
refused after the recovery, one CONTROLLER_REJECT only, the journal replaying identically, no
jump when the drives are enabled again (the plant's true joints, from the emulator, stay where
the stop left them while the resumed move starts from rest), and the transport moving the arm
on afterwards. The run ends once it has: the rest of the cycle is other tests' business (and
on the loaded 2-core test host a CANopen cell's loop may stall past its state watchdog, a
WATCHDOG stop of its own that the simulated operator recovers from the same way).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from assurance.fallback import Mode
from assurance.reasons import ReasonCode
from drivers.base import Applied, Command, CommandKind
from kernel.app.live import run_live
from kernel.app.session import RunContext
from kernel.shell.loop import run
from tests.cell.harness import manifest, replays_identically, run_dir

pytestmark = pytest.mark.slow

TRANSPORT_UNDER_WAY_S = 0.25
"""The refusal comes this long into the transport move: the quick stop stops a moving arm."""
RESUME_WINDOW_S = 0.05
"""Plant time after the recovery over which the arm must not have jumped: a resumed planner
move starts from rest (jerk 60 rad/s³: 1.3 mrad in 50 ms); a drive enabled with a stale
target would be on its way to it."""
JUMP_RAD = 0.005
MOVED_ON_RAD = 0.05
"""The run ends once a joint is this far from where the stop left it: the transport went on."""


class _RefuseOnce:
    """The run's managed driver, refusing the next setpoint once (nothing reaches the drives
    that period), then passing everything through."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.refused = False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    async def write(self, command: Command) -> Applied:
        if not self.refused and command.kind is CommandKind.POSITION:
            self.refused = True
            return Applied(kind=command.kind, t_mono_ns=0, accepted=False,
                           reason=ReasonCode.CONTROLLER_REJECT)
        return await self.inner.write(command)


class _StopAndRecover:
    """The tick hook: refuses one setpoint in the transport, then watches the modes and the
    plant's true joints; ends the run at a second refused write (the loop of refusals) or
    once the arm has moved on (``MOVED_ON_RAD``)."""

    def __init__(self) -> None:
        self.transport_since: int | None = None
        self.refusing: _RefuseOnce | None = None
        self.modes: list[Mode] = []
        self.stopped_q: np.ndarray | None = None
        self.recovered_t: int | None = None
        self.resumed_q: list[np.ndarray] = []
        self.moved_on = 0.0

    def __call__(self, context: RunContext) -> bool:
        cell = context.cell
        now = cell.gateway.now_ns()
        mode = cell.core.status().mode
        if not self.modes or self.modes[-1] is not mode:
            self.modes.append(mode)
        if self.refusing is None and cell.controller.runner.step == "transport":
            self.transport_since = self.transport_since or now
            if (now - self.transport_since) * 1e-9 >= TRANSPORT_UNDER_WAY_S:
                self.refusing = _RefuseOnce(cell.controller.driver)
                cell.controller.driver = self.refusing  # type: ignore[assignment]
        self._watch(cell, mode)
        return cell.controller.counters.refused_writes > 1 or self.moved_on > MOVED_ON_RAD

    def _watch(self, cell: Any, mode: Mode) -> None:
        if Mode.CONTROLLER_STOP not in self.modes:
            return
        truth = cell.world.inject("ground_truth")
        t, q = int(truth["t_ns"]), np.array(truth["q"])
        if self.recovered_t is None and mode is Mode.CONTROLLER_STOP:
            self.stopped_q = q  # the last one before the recovery: where the stop left it
        elif self.recovered_t is None:
            self.recovered_t = t
        if self.recovered_t is None or self.stopped_q is None:
            return
        if (t - self.recovered_t) * 1e-9 <= RESUME_WINDOW_S:
            self.resumed_q.append(q)
        self.moved_on = max(self.moved_on, float(np.max(np.abs(q - self.stopped_q))))


def test_the_canopen_cell_resumes_after_a_controller_stop_and_recovery(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RUNTIME_DIRECTORY", str(tmp_path))  # the operator socket: ours alone
    hook = _StopAndRecover()
    summary = run(run_live(manifest("sim-canopen.toml", cycles=1), tmp_path, hook=hook))

    assert hook.refusing is not None and hook.refusing.refused, hook.modes
    transitions = [(t["to"], t["trigger"]) for t in summary["fallback_transitions"]]
    assert summary["driver"]["refused_writes"] == 1, transitions  # ours: none after recovery
    assert transitions.count(("CONTROLLER_STOP", "CONTROLLER_REJECT")) == 1, transitions
    assert ("RUNNING", "RECOVERY_ACCEPTED") in transitions, transitions
    assert summary["driver"]["faults"] == "none"
    assert hook.stopped_q is not None and hook.resumed_q
    jump = float(np.max(np.abs(np.array(hook.resumed_q) - hook.stopped_q)))
    assert jump < JUMP_RAD, f"the arm moved {jump:.4f} rad as the drives were enabled again"
    assert hook.moved_on > MOVED_ON_RAD, f"after the recovery the arm moved {hook.moved_on} rad"
    assert replays_identically(run_dir(tmp_path))
