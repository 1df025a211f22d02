"""The gateway hands out a step's decisions and effects before it steps the core again: an
effect handler that feeds an event of its own (a job run inline, an observation taken) never
re-enters the core while the step it answers is still being handed out."""

from __future__ import annotations

from typing import Any

from assurance.handshake import HandshakeDecision, offer_in
from kernel.core.effects import MOTION_TYPES
from kernel.core.events import HandshakeEvent, LinkEvent, LinkStatus, TickEvent
from kernel.core.runtime import Core
from kernel.shell.gateway import CoreGateway
from kernel.shell.timer import VirtualClock
from tests.runtime.machine_setup import core_config


def test_an_event_fed_by_a_handler_waits_until_the_step_is_handed_out() -> None:
    gateway = CoreGateway(Core(core_config()), VirtualClock())
    seen: list[str] = []
    gateway.listeners.append(lambda lines: seen.append("step"))

    def first(_: Any) -> None:
        seen.append("first handler")
        nested = gateway.feed(LinkEvent(t=gateway.now_ns(), status=LinkStatus.UP))
        assert not nested.lines and not nested.effects  # not stepped yet

    for kind in MOTION_TYPES:
        gateway.on(kind, first)
        gateway.on(kind, lambda _: seen.append("second handler"))
    step = gateway.feed(TickEvent(t=0))
    assert step.motion is not None
    assert seen == ["step", "first handler", "second handler", "step"]


def test_decisions_reach_the_handlers_of_their_type() -> None:
    gateway = CoreGateway(Core(core_config()), VirtualClock())
    decided: list[HandshakeDecision] = []
    gateway.on(HandshakeDecision, decided.append)
    step = gateway.feed(HandshakeEvent(t=0, offer=offer_in({"policy_checkpoint": "x"})))
    assert decided == list(step.decisions) and decided[0].decision == "REJECT"
