"""The control loop: it writes what the core decided, journals it with the driver's answer,
reports a refusing device to the core, and never leaves the last command live after a bug."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from assurance.fallback import Mode
from assurance.reasons import ReasonCode
from drivers.base import Applied, Command, CommandKind
from kernel.app.live import task_failed
from kernel.app.session import bring_up, open_run
from kernel.core.events import HandshakeEvent
from kernel.manifest import ClockKind
from kernel.shell.timer import VirtualClock
from stubs.cell.reference import offer_for
from tests.cell.harness import manifest


class _Recording:
    """The managed driver, with every command it is given kept for the test to read, and
    (``refuse``) the device refusing every write as a controller in protective stop does."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.written: list[Command] = []
        self.refuse = False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    async def write(self, command: Command) -> Any:
        self.written.append(command)
        if self.refuse:
            return Applied(kind=command.kind, t_mono_ns=0, accepted=False,
                           reason=ReasonCode.CONTROLLER_REJECT)
        return await self.inner.write(command)


class _BrokenRunner:
    done = False

    def update(self, *args: Any) -> None:
        raise RuntimeError("cycle runner bug")


def _context(tmp: Path):  # type: ignore[no-untyped-def]
    return open_run(manifest("sim-ur5e.toml", 1, ClockKind.VIRTUAL), VirtualClock(), tmp, None)


def _run(context: Any, scenario: Any) -> None:
    try:
        asyncio.run(scenario())
    finally:
        context.cell.world.close()
        context.recorder.close()
        context.files.close()


def test_a_software_fault_in_the_tick_stops_the_device_before_the_error_ends_the_run(
        tmp_path: Path) -> None:
    context = _context(tmp_path)
    controller = context.cell.controller

    async def scenario() -> None:
        await bring_up(context)
        controller.start()
        recording = _Recording(controller.driver)
        controller.driver = recording  # type: ignore[assignment]
        controller.runner = _BrokenRunner()  # type: ignore[assignment]
        with pytest.raises(RuntimeError, match="cycle runner bug"):
            await controller.tick()
        assert [c.kind for c in recording.written] == [CommandKind.STOP]

    _run(context, scenario)
    journal = (context.files.directory / "journal.jsonl").read_text()
    assert '"origin":"shell"' in journal  # journaled as the shell's stop, not a decision


def test_every_command_is_journaled_with_the_drivers_answer(tmp_path: Path) -> None:
    context = _context(tmp_path)
    controller = context.cell.controller

    async def scenario() -> None:
        await bring_up(context)
        controller.start()
        for _ in range(5):
            await controller.tick()

    _run(context, scenario)
    lines = (context.files.directory / "journal.jsonl").read_text().splitlines()
    commands = [line for line in lines if '"kind":"command"' in line]
    assert len(commands) == 5 and all('"accepted":true' in line for line in commands)


def test_a_refusing_device_stops_the_arm_through_the_core(tmp_path: Path) -> None:
    """Applied(accepted=False) is an event for the core: CONTROLLER_REJECT → CONTROLLER_STOP,
    after which every tick sends the device a stop."""
    context = _context(tmp_path)
    controller = context.cell.controller

    async def scenario() -> None:
        await bring_up(context)
        controller.start()
        recording = _Recording(controller.driver)
        controller.driver = recording  # type: ignore[assignment]
        await controller.tick()
        recording.refuse = True
        for _ in range(3):
            await controller.tick()
        status = context.cell.core.status()
        assert status.mode is Mode.CONTROLLER_STOP
        assert status.cause is ReasonCode.CONTROLLER_REJECT
        assert recording.written[-1].kind is CommandKind.STOP
        recording.refuse = False
        await controller.tick()
        assert context.cell.core.inspect_state().controller_ok  # the device accepts again

    _run(context, scenario)


def test_the_first_command_holds_a_device_parked_away_from_home(tmp_path: Path) -> None:
    context = _context(tmp_path)
    cell = context.cell
    parked = np.array(cell.context.layout.home_q) + np.array([0.3, -0.2, 0.25, 0.1, -0.15, 0.2])
    cell.world.plant.reset(parked)  # type: ignore[attr-defined]
    recording = _Recording(cell.controller.driver)

    async def scenario() -> None:
        await bring_up(context)
        cell.controller.driver = recording  # type: ignore[assignment]
        cell.controller.start()
        for _ in range(10):
            await cell.controller.tick()

    _run(context, scenario)
    assert all(np.abs(np.array(c.q) - parked).max() < 0.01 for c in recording.written)


def test_a_dead_policy_link_task_is_a_lost_link_for_the_core(tmp_path: Path) -> None:
    context = _context(tmp_path)
    gateway = context.cell.gateway
    try:
        gateway.feed(HandshakeEvent(t=gateway.now_ns(), offer=offer_for(context.manifest)))
        assert context.cell.core.inspect_state().session is not None
        failures: list[str] = []
        task_failed(context, failures, "policy-link", ConnectionResetError("peer vanished"))
        assert failures == ["policy-link: ConnectionResetError: peer vanished"]
        assert context.cell.core.inspect_state().session is None
        assert context.cell.core.status().mode is Mode.DEGRADED
    finally:
        context.cell.world.close()
        context.recorder.close()
        context.files.close()


def test_a_refused_command_is_journaled_with_the_refusal(tmp_path: Path) -> None:
    """The journal keeps each command with the device's answer: a refusal as not accepted,
    with its reason, on the very command it refused (issue 15, item 14)."""
    context = _context(tmp_path)
    controller = context.cell.controller

    async def scenario() -> None:
        await bring_up(context)
        controller.start()
        recording = _Recording(controller.driver)
        controller.driver = recording  # type: ignore[assignment]
        await controller.tick()
        recording.refuse = True
        await controller.tick()

    _run(context, scenario)
    lines = (context.files.directory / "journal.jsonl").read_text().splitlines()
    answers = [json.loads(line)["applied"] for line in lines if '"kind":"command"' in line]
    assert answers[0]["accepted"] is True
    assert (answers[1]["accepted"], answers[1].get("reason")) == (False, "CONTROLLER_REJECT")
