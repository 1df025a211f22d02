"""The simulated cell on the wall clock, with the policy server as a process and a real
websocket between them: the live decisions are exactly what the journal replays, and the
service manager hears READY and watchdog pings while the loop runs."""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Callable
from pathlib import Path

import pytest

from kernel.app import standins
from kernel.app.live import run_live
from kernel.app.session import RunContext
from kernel.core.lines import ADMITTED
from kernel.shell.loop import run
from skills.contact import ContactState
from skills.phases import TaskPhase
from tests.cell.harness import SimCycle, manifest, replays_identically, run_dir

pytestmark = pytest.mark.slow


def test_live_cycle_over_the_websocket_replays_exactly(sim_cycle: SimCycle) -> None:
    """The run is tests/cell/conftest.py's (under a stand-in service manager), which
    test_loopback.py reads too."""
    summary, directory, _, messages = sim_cycle
    assert summary["cycles"]["attempted"] == 1
    link = summary["link"]
    assert link["handshakes_accepted"] >= 1
    assert link["chunks_admitted"] > 5
    assert summary["loop"]["ticks"] > 1000
    assert replays_identically(directory)
    assert json.loads((directory / "summary.json").read_text())["cycles"]["attempted"] == 1
    assert any("READY=1" in m for m in messages)
    assert sum("WATCHDOG=1" in m for m in messages) >= 2
    assert "STOPPING=1" in messages[-1], messages[-3:]


class _SignalWhen:
    """Sends ``signum`` to the reference server the first tick ``now`` holds for the cell;
    records the instant (run time, ns)."""

    def __init__(self, servers: list, signum: int, now: Callable[[RunContext], bool]) -> None:
        self.servers, self.signum, self.now = servers, signum, now
        self.sent_ns: int | None = None

    def __call__(self, context: RunContext) -> bool:
        cell = context.cell
        if self.sent_ns is None and self.now(context):
            os.kill(self.servers[0].process.pid, self.signum)
            self.sent_ns = cell.gateway.now_ns()
        return False


def _descending(context: RunContext) -> bool:
    return context.cell.core.status().contact is ContactState.DESCENDING


def _recording_servers(monkeypatch: pytest.MonkeyPatch) -> list:
    """The reference servers the run launches, as it launches them."""
    servers: list = []
    load = standins.load

    def recording(group: str, name: str):  # type: ignore[no-untyped-def]
        make = load(group, name)
        if group != standins.POLICIES:
            return make
        return lambda context: servers.append(make(context)) or servers[-1]

    monkeypatch.setattr(standins, "load", recording)
    return servers


@pytest.mark.parametrize("signum", [signal.SIGSTOP, signal.SIGKILL], ids=["hung", "killed"])
def test_a_policy_server_lost_in_contact_ends_contact_and_the_cycle(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, signum: int
) -> None:
    servers = _recording_servers(monkeypatch)
    loaded = manifest("sim-ur5e.toml", cycles=1)
    hook = _SignalWhen(servers, signum, _descending)
    summary = run(run_live(loaded, tmp_path / "runs", hook=hook))
    assert hook.sent_ns is not None, "the contact phase was never reached"
    lost_ms = hook.sent_ns * 1e-6
    after = [t for t in summary["fallback_transitions"] if t["t"] >= lost_ms]
    # DEGRADED within the heartbeat timeout of the server's last frame (docs/protocol.md)
    bound_ms = loaded.policy.heartbeat_timeout_ms + loaded.policy.heartbeat_interval_ms + 100
    assert after[0]["to"] == "DEGRADED" and after[0]["trigger"] == "LINK_LOST"
    assert after[0]["t"] - lost_ms <= bound_ms
    assert all(t["to"] in ("DEGRADED", "RUNNING") for t in after), "never an operator's hold"
    lines = [json.loads(line) for line in (run_dir(tmp_path / "runs") / "decisions.jsonl").open()]
    contact_ticks = [line for line in lines if line["kind"] == "tick" and line["t"] >= lost_ms
                     and line["phase"] == "CONTACT"]
    degraded = [line for line in contact_ticks if line["mode"] == "DEGRADED"]
    assert degraded and all(line["command"] == "retreat" and line["owner"] == "contact"
                            for line in degraded)  # the card's link_loss: retract
    (cycle,) = summary["cycles"]["detail"]
    assert not cycle["verified"] and cycle["reason"] == "policy link lost in contact"
    assert not summary["timed_out"]
    # Not asserted here: the restart of the server. This one-cycle run may end (contact
    # retracted, cycle over) before a restart completes; the test below, whose cycle needs
    # the restarted server to finish, and tests/wire/test_reconnect.py show it.
    assert replays_identically(run_dir(tmp_path / "runs"))


def test_a_cartesian_cycle_maps_its_chunks_in_the_worker_and_replays_exactly(
        tmp_path: Path) -> None:
    """On the wall clock the Cartesian chunks' IK runs in the job worker process, off the
    control loop; its results are journaled events, so the replay needs no worker."""
    summary = run(run_live(manifest("sim-ur5e-cartesian.toml", cycles=1), tmp_path / "runs"))
    (cycle,) = summary["cycles"]["detail"]
    assert cycle["verified"], cycle
    assert summary["jobs"]["done"] > 5 and summary["jobs"]["failed"] == 0
    directory = run_dir(tmp_path / "runs")
    computed = [line for line in (directory / "journal.jsonl").open() if '"computed"' in line]
    assert len(computed) == summary["jobs"]["done"]
    assert replays_identically(directory)
    # Every chunk here is decided in a job: the link still counts each decision it carried.
    chunks = [json.loads(line) for line in (directory / "decisions.jsonl").open()
              if '"kind":"chunk"' in line]
    admitted = sum(line["decision"] in ADMITTED for line in chunks)
    link = summary["link"]
    assert admitted > 5
    assert (link.get("chunks_admitted", 0), link.get("chunks_refused", 0)) == (
        admitted, len(chunks) - admitted)


def test_a_policy_server_hung_before_contact_degrades_and_the_cycle_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """PRE_CONTACT is where the policy drives: a hung server must reach DEGRADED (the fallback
    a new handshake ends) within the link-loss bound, before the queue runs dry into an
    underrun's SAFE_HOLD, which only an operator ends."""
    servers = _recording_servers(monkeypatch)
    loaded = manifest("sim-ur5e.toml", cycles=1)
    hook = _SignalWhen(servers, signal.SIGSTOP,
                       lambda context: context.cell.core.status().phase is TaskPhase.PRE_CONTACT)
    summary = run(run_live(loaded, tmp_path / "runs", hook=hook))
    assert hook.sent_ns is not None, "PRE_CONTACT was never reached"
    lost_ms = hook.sent_ns * 1e-6
    after = [t for t in summary["fallback_transitions"] if t["t"] >= lost_ms]
    bound_ms = loaded.policy.heartbeat_timeout_ms + loaded.policy.heartbeat_interval_ms + 100
    assert after[0]["to"] == "DEGRADED" and after[0]["trigger"] == "LINK_LOST", after
    assert after[0]["t"] - lost_ms <= bound_ms
    assert all(t["to"] in ("DEGRADED", "RUNNING") for t in after), "never an operator's hold"
    assert summary["link"]["server_restarts"] >= 1
    (cycle,) = summary["cycles"]["detail"]
    assert cycle["verified"], cycle
    assert replays_identically(run_dir(tmp_path / "runs"))
