"""One conformance suite for every driver (trio's check_*_stream pattern).

A driver's test module subclasses :class:`DriverConformance`, sets ``FAULTS`` to the names of the
faults its emulator can inject, and provides a ``harness`` fixture. The same assertions then run
against the plant driver, UR RTDE, Dynamixel and CiA 402 — each over its real transport.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

import numpy as np
import pytest

from assurance.reasons import ReasonCode
from drivers.base import Command, CommandKind, ControlConfig, Driver, DriverError, DriverState
from drivers.lifecycle import LifecycleError, ManagedDriver


@dataclass
class Harness:
    make_driver: Callable[[], Driver]
    control: ControlConfig
    inject: Callable[[str], None]
    """Switch a named fault on in the emulator."""
    expected_reason: dict[str, ReasonCode | frozenset[ReasonCode]]
    """The reason each fault must map to; a set where the device's own detection order is a
    race (a socket closed under load is seen as gone, or first as silent)."""
    advance: Callable[[float], Awaitable[None]]
    """Let ``seconds`` of device time pass (a real sleep, or plant steps in lockstep)."""
    hold_tolerance: float = 0.01
    move_tolerance: float = 0.02
    applied_tolerance: float = 1e-6
    """How far the applied setpoint may be from the commanded one (a quantised device rounds)."""
    closers: list[Callable[[], None]] = field(default_factory=list)


async def _stream(driver: ManagedDriver, harness: Harness, q: tuple[float, ...], s: float) -> None:
    """Send the same position setpoint every control period for ``s`` seconds."""
    period = harness.control.period_ns * 1e-9
    for _ in range(max(1, int(s / period))):
        await driver.write(Command(kind=CommandKind.POSITION, q=q))
        await harness.advance(period)


async def _configured(harness: Harness) -> ManagedDriver:
    driver = ManagedDriver(harness.make_driver())
    await driver.configure(harness.control)
    return driver


class DriverConformance:
    FAULTS: tuple[str, ...] = ()

    async def test_lifecycle_order(self, harness: Harness) -> None:
        driver = ManagedDriver(harness.make_driver())
        with pytest.raises(LifecycleError):
            await driver.activate()
        await driver.configure(harness.control)
        assert driver.state is DriverState.INACTIVE
        await driver.activate()
        assert driver.state is DriverState.ACTIVE
        await driver.deactivate()
        assert driver.state is DriverState.INACTIVE
        await driver.aclose()
        assert driver.state is DriverState.CLOSED

    async def test_write_only_when_active(self, harness: Harness) -> None:
        driver = await _configured(harness)
        try:
            start = np.array((await driver.read()).q)
            target = tuple((start + 0.1).tolist())
            applied = await driver.write(Command(kind=CommandKind.POSITION, q=target))
            assert not applied.accepted
            assert applied.reason is ReasonCode.NO_AUTHORITY
            await harness.advance(0.2)
            after = np.array((await driver.read()).q)
            assert np.abs(after - start).max() < harness.hold_tolerance
        finally:
            await driver.aclose()

    async def test_active_write_moves_and_reports_applied(self, harness: Harness) -> None:
        driver = await _configured(harness)
        try:
            await driver.activate()
            start = np.array((await driver.read()).q)
            target = start.copy()
            target[0] += 0.05
            applied = await driver.write(Command(kind=CommandKind.POSITION, q=tuple(target)))
            assert applied.accepted
            assert np.allclose(applied.q, target, atol=harness.applied_tolerance)
            await _stream(driver, harness, tuple(target.tolist()), 0.6)
            reached = np.array((await driver.read()).q)
            assert abs(reached[0] - target[0]) < harness.move_tolerance
        finally:
            await driver.aclose()

    async def test_hold_keeps_position(self, harness: Harness) -> None:
        driver = await _configured(harness)
        try:
            await driver.activate()
            held = await driver.hold()
            assert held.accepted
            before = np.array((await driver.read()).q)
            await harness.advance(0.3)
            after = np.array((await driver.read()).q)
            assert np.abs(after - before).max() < harness.hold_tolerance
        finally:
            await driver.aclose()

    async def test_aclose_twice(self, harness: Harness) -> None:
        driver = await _configured(harness)
        await driver.activate()
        await driver.aclose()
        await driver.aclose()
        assert driver.state is DriverState.CLOSED

    async def test_fault_maps_to_reason_and_read_after_fault(
        self, harness: Harness, fault_name: str
    ) -> None:
        driver = await _configured(harness)
        try:
            await driver.activate()
            await driver.read()
            harness.inject(fault_name)
            await _until_fault(driver, harness)
            assert driver.state is DriverState.FAULT
            expected = harness.expected_reason[fault_name]
            allowed = expected if isinstance(expected, frozenset) else frozenset({expected})
            assert driver.fault in allowed, (driver.fault, driver.fault_detail)
            sample = await driver.read()
            assert driver.fault in sample.faults
            refused = await driver.write(Command(kind=CommandKind.POSITION, q=sample.q))
            assert not refused.accepted
        finally:
            await driver.aclose()
        assert driver.state is DriverState.CLOSED

    async def test_timing_recorded(self, harness: Harness) -> None:
        driver = await _configured(harness)
        try:
            await driver.activate()
            q = (await driver.read()).q
            await _stream(driver, harness, q, 0.05)
            for call in ("connect", "configure", "activate", "read", "write"):
                assert driver.stats[call].count > 0, call
                assert driver.stats[call].last_ns > 0, call
            assert driver.last_ok_ns > 0
        finally:
            await driver.aclose()


async def _until_fault(driver: ManagedDriver, harness: Harness, timeout_s: float = 5.0) -> None:
    """Read and write as the control loop would until the lifecycle reports FAULT."""
    deadline = time.monotonic() + timeout_s
    period = harness.control.period_ns * 1e-9
    while driver.state is not DriverState.FAULT and time.monotonic() < deadline:
        try:
            sample = await driver.read()
            await driver.write(Command(kind=CommandKind.POSITION, q=sample.q))
        except DriverError:
            break
        await harness.advance(period)
