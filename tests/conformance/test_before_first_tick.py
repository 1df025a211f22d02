"""A driver's ``before_first_tick`` that fails is a driver fault the loop reports through its
samples (the core stops the arm: CONTROLLER_STOP), not an exception that aborts the run before
its first tick (the CiA 402 drives' watchdog arming, an SDO round trip per drive, times out on
a loaded host)."""

from __future__ import annotations

import asyncio

from assurance.reasons import ReasonCode
from drivers.base import ControlConfig, DriverError
from drivers.lifecycle import DriverState, ManagedDriver
from drivers.sim.driver import SimDriver
from stubs.plant.base import KinematicPlant

PERIOD_NS = 2_000_000


class _ArmingTimesOut(SimDriver):
    async def before_first_tick(self) -> None:
        raise DriverError(self.name, "arm the drives' watchdog: SDO failed: No SDO response")


def test_a_failed_before_first_tick_is_a_fault_seen_in_the_samples() -> None:
    async def scenario() -> tuple[DriverState, tuple[ReasonCode, ...]]:
        managed = ManagedDriver(_ArmingTimesOut(KinematicPlant(dof=6, timestep_ns=PERIOD_NS)))
        await managed.configure(ControlConfig(dof=6, period_ns=PERIOD_NS, q_lower=(-3.0,) * 6,
                                              q_upper=(3.0,) * 6, v_max=(3.0,) * 6))
        await managed.activate()
        await managed.before_first_tick()  # must not raise: the loop starts and sees the fault
        sample = await managed.read()
        return managed.state, sample.faults

    state, faults = asyncio.run(scenario())
    assert state is DriverState.FAULT
    assert faults == (ReasonCode.CONTROLLER_FAULT,)
