"""Driver conformance checks: what every warden driver must do, runnable by any driver package.

Trio's ``check_*_stream`` pattern: a driver package describes how to build its driver and how
to make its device (real or emulated) misbehave in a :class:`Harness`, then runs the checks:

- ``await check_driver(harness)`` runs all of them (any event loop, any test runner), raising
  :class:`ConformanceError` with the check's name and what the driver did;
- or, under pytest, subclass :class:`DriverConformance` and provide a ``harness`` fixture: one
  test per check and per fault. Its test methods are coroutines, so pytest needs an asyncio
  plugin (pytest-asyncio with ``asyncio_mode = "auto"``, or ``pytestmark =
  pytest.mark.asyncio`` on the subclass). This module does not import pytest.

Every check builds its own driver through ``harness.make_driver`` and closes it before it
returns, whatever happened.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, Driver, DriverError, DriverState
from drivers.lifecycle import LifecycleError, ManagedDriver

FAULT_TIMEOUT_S = 5.0
"""How long the control loop runs after an injected fault before the driver must be in FAULT."""


class ConformanceError(Exception):
    """The driver broke the driver contract; the message names the check and what was seen."""


def _nothing() -> None:
    return None


@dataclass(frozen=True)
class Harness:
    """How the checks reach one driver and its device."""

    make_driver: Callable[[], Driver]
    """A new, unconnected driver for the device; every check builds its own."""
    control: ControlConfig
    inject: Callable[[str], None]
    """Switch a named fault on in the device (each name is a key of ``expected_reason``)."""
    expected_reason: Mapping[str, ReasonCode | frozenset[ReasonCode]]
    """The reason each fault must map to; a set where the device's own detection order is a
    race (a socket closed under load is seen as gone, or first as silent)."""
    advance: Callable[[float], Awaitable[None]]
    """Let ``seconds`` of device time pass (a real sleep, or plant steps in lockstep)."""
    clear: Callable[[], None] = _nothing
    """Switch every injected fault off again; ``check_driver`` calls it before each check (a
    pytest fixture that builds a fresh device per test does not need it)."""
    hold_tolerance: float = 0.01
    """How far a held joint may drift (rad or m)."""
    move_tolerance: float = 0.02
    """How close a streamed target must be reached."""
    applied_tolerance: float = 1e-6
    """How far the applied setpoint may be from the commanded one (a quantised device rounds)."""
    stiffness: float = 100.0
    """Joint stiffness (N·m/rad) of the IMPEDANCE commands sent to a driver that declares it."""
    damping: float = 10.0
    """Joint damping (N·m·s/rad) of those commands."""


def _expect(condition: bool, check: str, message: str) -> None:
    if not condition:
        raise ConformanceError(f"{check}: {message}")


async def _configured(harness: Harness) -> ManagedDriver:
    driver = ManagedDriver(harness.make_driver())
    try:
        await driver.configure(harness.control)
    except BaseException:
        await driver.aclose()
        raise
    return driver


async def _stream(driver: ManagedDriver, harness: Harness, q: tuple[float, ...],
                  seconds: float) -> None:
    """Send the same position setpoint every control period for ``seconds``."""
    period = harness.control.period_ns * 1e-9
    for _ in range(max(1, int(seconds / period))):
        await driver.write(Command(kind=CommandKind.POSITION, q=q))
        await harness.advance(period)


async def _q(driver: ManagedDriver) -> np.ndarray:
    return np.array((await driver.read()).q)


async def check_lifecycle_order(harness: Harness) -> None:
    """UNCONFIGURED → INACTIVE → ACTIVE → INACTIVE → CLOSED; activating first is refused."""
    check = "lifecycle order"
    driver = ManagedDriver(harness.make_driver())
    try:
        try:
            await driver.activate()
        except LifecycleError:
            pass
        else:
            raise ConformanceError(f"{check}: activate() before configure() was not refused")
        await driver.configure(harness.control)
        _expect(driver.state is DriverState.INACTIVE, check,
                f"state {driver.state} after configure(), not INACTIVE")
        await driver.activate()
        _expect(driver.state is DriverState.ACTIVE, check,
                f"state {driver.state} after activate(), not ACTIVE")
        await driver.deactivate()
        _expect(driver.state is DriverState.INACTIVE, check,
                f"state {driver.state} after deactivate(), not INACTIVE")
    finally:
        await driver.aclose()
    _expect(driver.state is DriverState.CLOSED, check, f"state {driver.state} after aclose()")


async def check_write_only_when_active(harness: Harness) -> None:
    """A write while INACTIVE is refused with NO_AUTHORITY and moves nothing."""
    check = "write only when active"
    driver = await _configured(harness)
    try:
        start = await _q(driver)
        applied = await driver.write(Command(kind=CommandKind.POSITION,
                                             q=tuple((start + 0.1).tolist())))
        _expect(not applied.accepted, check, "a write while INACTIVE was accepted")
        _expect(applied.reason is ReasonCode.NO_AUTHORITY, check,
                f"refused with {applied.reason}, not NO_AUTHORITY")
        await harness.advance(0.2)
        drift = float(np.abs(await _q(driver) - start).max())
        _expect(drift < harness.hold_tolerance, check, f"the arm moved {drift:.4g} while INACTIVE")
    finally:
        await driver.aclose()


async def check_active_write_moves_and_reports_applied(harness: Harness) -> None:
    """An ACTIVE position write is accepted, reports the setpoint, and the joint gets there."""
    check = "active write moves"
    driver = await _configured(harness)
    try:
        await driver.activate()
        target = await _q(driver)
        target[0] += 0.05
        applied = await driver.write(Command(kind=CommandKind.POSITION, q=tuple(target)))
        _expect(applied.accepted, check, f"refused ({applied.reason})")
        _expect(np.allclose(applied.q, target, atol=harness.applied_tolerance), check,
                f"applied {applied.q}, commanded {tuple(target)}")
        await _stream(driver, harness, tuple(target.tolist()), 0.6)
        error = abs((await _q(driver))[0] - target[0])
        _expect(error < harness.move_tolerance, check,
                f"joint 0 is {error:.4g} from its target after 0.6 s of streaming")
    finally:
        await driver.aclose()


async def check_hold_keeps_position(harness: Harness) -> None:
    """``hold`` is accepted and the arm stays where it was."""
    check = "hold keeps position"
    driver = await _configured(harness)
    try:
        await driver.activate()
        held = await driver.hold()
        _expect(held.accepted, check, f"hold refused ({held.reason})")
        before = await _q(driver)
        await harness.advance(0.3)
        drift = float(np.abs(await _q(driver) - before).max())
        _expect(drift < harness.hold_tolerance, check, f"the arm moved {drift:.4g} while held")
    finally:
        await driver.aclose()


async def check_aclose_twice(harness: Harness) -> None:
    """Closing an active driver twice is harmless and leaves it CLOSED."""
    driver = await _configured(harness)
    try:
        await driver.activate()
        await driver.aclose()
    finally:
        await driver.aclose()
    _expect(driver.state is DriverState.CLOSED, "aclose twice", f"state {driver.state}")


async def check_timing_recorded(harness: Harness) -> None:
    """Every call the lifecycle makes is counted and timed; the last good call is stamped."""
    check = "timing recorded"
    driver = await _configured(harness)
    try:
        await driver.activate()
        await _stream(driver, harness, (await driver.read()).q, 0.05)
        for call in ("connect", "configure", "activate", "read", "write"):
            stats = driver.stats[call]
            _expect(stats.count > 0 and stats.last_ns > 0, check, f"no timing for {call}()")
        _expect(driver.last_ok_ns > 0, check, "last_ok_ns was never set")
    finally:
        await driver.aclose()


MINIMUM_CAPABILITIES = frozenset({CommandKind.POSITION, CommandKind.HOLD, CommandKind.STOP})
"""What every driver must execute: the core's setpoints and its two ways to bring the arm to
rest."""
PROBE_STEP = 0.05
"""rad (or m): how far joint 0 is asked to go by a probing command."""


async def check_capabilities(harness: Harness) -> None:
    """``capabilities`` says what the driver does: every declared kind is accepted and acts
    (VELOCITY and IMPEDANCE move joint 0 the way they say, STOP leaves the arm at rest), every
    other kind is refused by the driver itself without moving the arm, and by the lifecycle
    with CONTROLLER_MODE_MISMATCH before it reaches the driver."""
    check = "capabilities"
    driver = await _configured(harness)
    try:
        declared = driver.driver.capabilities
        _expect(declared >= MINIMUM_CAPABILITIES, check, f"declares {sorted(declared)}, "
                f"not every one of {sorted(MINIMUM_CAPABILITIES)}")
        await driver.activate()
        for kind in (CommandKind.VELOCITY, CommandKind.IMPEDANCE):
            if kind in declared:
                await _acts(driver, harness, kind)
        for kind in sorted(set(CommandKind) - declared):
            await _refused_whole(driver, harness, kind)
        await _stops(driver, harness)
    finally:
        await driver.aclose()


def _probe(kind: CommandKind, q: np.ndarray, harness: Harness) -> Command:
    """A ``kind`` command that would move joint 0 by about :data:`PROBE_STEP` if obeyed."""
    target = q.copy()
    target[0] += PROBE_STEP
    qd = np.zeros_like(q)
    qd[0] = PROBE_STEP / 0.3
    gains = (len(q) * (harness.stiffness,), len(q) * (harness.damping,))
    if kind is CommandKind.VELOCITY:
        return Command(kind=kind, qd=tuple(qd.tolist()))
    if kind is CommandKind.IMPEDANCE:
        return Command(kind=kind, q=tuple(target.tolist()), stiffness=gains[0],
                       damping=gains[1])
    return Command(kind=kind, q=tuple(target.tolist()), qd=tuple(qd.tolist()),
                   stiffness=gains[0], damping=gains[1])


async def _acts(driver: ManagedDriver, harness: Harness, kind: CommandKind) -> None:
    """A declared VELOCITY or IMPEDANCE command, streamed for 0.3 s, moves joint 0 forward."""
    check = f"capabilities: declared {kind}"
    await _settled(driver, harness)
    start = await _q(driver)
    command = _probe(kind, start, harness)
    period = harness.control.period_ns * 1e-9
    for _ in range(max(1, int(0.3 / period))):
        applied = await driver.write(command)
        _expect(applied.accepted, check, f"refused ({applied.reason})")
        await harness.advance(period)
    moved = float((await _q(driver))[0] - start[0])
    _expect(moved > PROBE_STEP / 4, check, f"joint 0 moved {moved:.4g} of about {PROBE_STEP}")


async def _refused_whole(driver: ManagedDriver, harness: Harness, kind: CommandKind) -> None:
    """An undeclared kind: the lifecycle refuses it, and so does the driver if called around
    the lifecycle (no declaration understates what the driver would do with it)."""
    check = f"capabilities: undeclared {kind}"
    await _settled(driver, harness)
    start = await _q(driver)
    command = _probe(kind, start, harness)
    refused = await driver.write(command)
    _expect(not refused.accepted and refused.reason is ReasonCode.CONTROLLER_MODE_MISMATCH,
            check, f"the lifecycle answered {refused.accepted} ({refused.reason})")
    period = harness.control.period_ns * 1e-9
    for _ in range(max(1, int(0.15 / period))):
        applied = await driver.driver.write(command)
        _expect(not applied.accepted, check, f"the driver accepted it (as {applied.kind})")
        await driver.read()
        await harness.advance(period)
    drift = float(np.abs(await _q(driver) - start).max())
    _expect(drift < harness.hold_tolerance, check, f"the arm moved {drift:.4g}")


async def _stops(driver: ManagedDriver, harness: Harness) -> None:
    """STOP is accepted and the arm comes to rest (sent every period, as the core does)."""
    check = "capabilities: declared stop"
    period = harness.control.period_ns * 1e-9
    stop = Command(kind=CommandKind.STOP)
    for _ in range(max(1, int(0.2 / period))):
        applied = await driver.write(stop)
        _expect(applied.accepted, check, f"refused ({applied.reason})")
        await harness.advance(period)
    before = await _q(driver)
    for _ in range(max(1, int(0.1 / period))):
        await driver.write(stop)
        await harness.advance(period)
    drift = float(np.abs(await _q(driver) - before).max())
    _expect(drift < harness.hold_tolerance, check, f"the arm moved {drift:.4g} while stopped")


async def _settled(driver: ManagedDriver, harness: Harness) -> None:
    """Hold where the arm is, every period for 0.2 s (a device watchdog stays fed)."""
    period = harness.control.period_ns * 1e-9
    for _ in range(max(1, int(0.2 / period))):
        await driver.write(Command(kind=CommandKind.HOLD))
        await harness.advance(period)


async def check_fault(harness: Harness, fault: str) -> None:
    """After ``fault`` is injected the driver goes to FAULT with the expected reason, still
    reads (the sample lists the fault) and refuses writes."""
    check = f"fault {fault!r}"
    if fault not in harness.expected_reason:
        raise ConformanceError(f"{check}: not in the harness's expected_reason "
                               f"({', '.join(harness.expected_reason)})")
    expected = harness.expected_reason[fault]
    allowed = expected if isinstance(expected, frozenset) else frozenset({expected})
    driver = await _configured(harness)
    try:
        await driver.activate()
        await driver.read()
        harness.inject(fault)
        await _until_fault(driver, harness)
        _expect(driver.state is DriverState.FAULT, check,
                f"state {driver.state} {FAULT_TIMEOUT_S} s after the fault")
        _expect(driver.fault in allowed, check, f"reason {driver.fault} ({driver.fault_detail}),"
                f" expected {' or '.join(sorted(allowed))}")
        sample = await driver.read()
        _expect(driver.fault in sample.faults, check,
                f"a read after the fault lists {sample.faults}, not {driver.fault}")
        refused = await driver.write(Command(kind=CommandKind.POSITION, q=sample.q))
        _expect(not refused.accepted, check, "a write in FAULT was accepted")
    finally:
        await driver.aclose()
    _expect(driver.state is DriverState.CLOSED, check, f"state {driver.state} after aclose()")


async def _until_fault(driver: ManagedDriver, harness: Harness) -> None:
    """Read and write as the control loop would until the lifecycle reports FAULT."""
    deadline = time.monotonic() + FAULT_TIMEOUT_S
    period = harness.control.period_ns * 1e-9
    while driver.state is not DriverState.FAULT and time.monotonic() < deadline:
        try:
            sample = await driver.read()
            await driver.write(Command(kind=CommandKind.POSITION, q=sample.q))
        except DriverError:
            break
        await harness.advance(period)


CHECKS: dict[str, Callable[[Harness], Awaitable[None]]] = {
    "lifecycle_order": check_lifecycle_order,
    "write_only_when_active": check_write_only_when_active,
    "active_write_moves_and_reports_applied": check_active_write_moves_and_reports_applied,
    "hold_keeps_position": check_hold_keeps_position,
    "aclose_twice": check_aclose_twice,
    "timing_recorded": check_timing_recorded,
    "capabilities": check_capabilities,
}
"""Every check that needs no fault, by name; ``check_fault`` runs once per fault."""


async def check_driver(harness: Harness, faults: Iterable[str] | None = None) -> None:
    """Run every check, then ``check_fault`` for each fault (default: every key of
    ``harness.expected_reason``), calling ``harness.clear()`` before each.

    Raises:
        ConformanceError: at the first check the driver fails, naming it.
    """
    for check in CHECKS.values():
        harness.clear()
        await check(harness)
    for fault in harness.expected_reason if faults is None else faults:
        harness.clear()
        await check_fault(harness, fault)
    harness.clear()


class DriverConformance:
    """The checks as pytest tests: subclass it, set ``FAULTS``, provide a ``harness`` fixture.

    ``pytest_generate_tests`` (a hook pytest also looks up on test classes) makes one
    ``test_fault`` per name in ``FAULTS``.
    """

    FAULTS: tuple[str, ...] = ()

    def pytest_generate_tests(self, metafunc: Any) -> None:
        if "fault_name" in metafunc.fixturenames:
            metafunc.parametrize("fault_name", self.FAULTS)

    async def test_lifecycle_order(self, harness: Harness) -> None:
        await check_lifecycle_order(harness)

    async def test_write_only_when_active(self, harness: Harness) -> None:
        await check_write_only_when_active(harness)

    async def test_active_write_moves_and_reports_applied(self, harness: Harness) -> None:
        await check_active_write_moves_and_reports_applied(harness)

    async def test_hold_keeps_position(self, harness: Harness) -> None:
        await check_hold_keeps_position(harness)

    async def test_aclose_twice(self, harness: Harness) -> None:
        await check_aclose_twice(harness)

    async def test_timing_recorded(self, harness: Harness) -> None:
        await check_timing_recorded(harness)

    async def test_capabilities(self, harness: Harness) -> None:
        await check_capabilities(harness)

    async def test_fault_maps_to_reason_and_read_after_fault(
        self, harness: Harness, fault_name: str
    ) -> None:
        await check_fault(harness, fault_name)
