"""The conformance suite against the plant driver, in lockstep with a kinematic plant; and the
suite's own entry points (``drivers.testing.check_driver``) against it and against drivers that
break the contract."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from assurance.reasons import ReasonCode
from drivers.base import (
    Applied,
    Command,
    CommandKind,
    ControlConfig,
    DeviceFault,
    Driver,
    StateSample,
)
from drivers.sim.driver import SimDriver, SimFaults
from drivers.sim.plant import PlantReading, SimulatedPlant
from drivers.testing import CHECKS, ConformanceError, DriverConformance, Harness, check_driver
from stubs.plant.base import KinematicPlant
from stubs.plant.mujoco_plant import MujocoPlant

PERIOD_NS = 2_000_000
FAULTS = ("estop", "protective_stop", "disconnected")


def sim_harness(driver_type: Callable[..., Driver] = SimDriver) -> Harness:
    plant = KinematicPlant(dof=6, timestep_ns=PERIOD_NS)
    faults = SimFaults()

    def inject(name: str) -> None:
        setattr(faults, name, True)

    def clear() -> None:
        for name in FAULTS:
            setattr(faults, name, False)

    async def advance(seconds: float) -> None:
        plant.step(max(1, round(seconds * 1e9 / PERIOD_NS)))

    control = ControlConfig(
        dof=6, period_ns=PERIOD_NS, q_lower=(-6.28,) * 6, q_upper=(6.28,) * 6, v_max=(3.14,) * 6
    )
    return Harness(
        make_driver=lambda: driver_type(plant, faults=faults),
        control=control,
        inject=inject,
        expected_reason={
            "estop": ReasonCode.E_STOP,
            "protective_stop": ReasonCode.CONTROLLER_FAULT,
            "disconnected": ReasonCode.LINK_LOST,
        },
        advance=advance,
        clear=clear,
    )


@pytest.fixture
def harness() -> Harness:
    return sim_harness()


class TestSimDriverConformance(DriverConformance):
    FAULTS = FAULTS


@pytest.mark.parametrize("make_plant", [KinematicPlant, MujocoPlant])
def test_the_stand_in_plants_are_what_the_driver_needs(make_plant: type) -> None:
    """The driver names what it needs of a plant; the plants provide it without importing it."""
    plant = make_plant()
    assert isinstance(plant, SimulatedPlant)
    assert isinstance(plant.state(), PlantReading)


async def test_check_driver_passes_a_conforming_driver() -> None:
    cleared = []
    harness = sim_harness()
    counting = dataclasses.replace(harness, clear=lambda: (cleared.append(1), harness.clear()))
    await check_driver(counting)
    assert len(cleared) == len(CHECKS) + len(FAULTS) + 1  # before each check, and at the end


class _StuckDriver(SimDriver):
    """Accepts position writes and reports them applied, but never passes them on."""

    async def write(self, command: Command) -> Applied:
        applied = await super().write(command)
        self.plant.hold()
        return applied


class _EstopAsProtectiveStop(SimDriver):
    """Reports a pressed emergency stop as an ordinary controller fault."""

    async def read(self) -> StateSample:
        if self.faults.estop:
            raise DeviceFault(self.name, "stopped", ReasonCode.CONTROLLER_FAULT)
        return await super().read()


class _VelocityUndeclared(SimDriver):
    """Leaves VELOCITY out of its declaration, yet obeys it."""

    capabilities = SimDriver.capabilities - {CommandKind.VELOCITY}


class _ImpedanceIgnored(SimDriver):
    """Declares IMPEDANCE and reports it applied, but holds instead."""

    async def write(self, command: Command) -> Applied:
        if command.kind is CommandKind.IMPEDANCE:
            await self.hold()
            return Applied(kind=command.kind, t_mono_ns=0, q=command.q)
        return await super().write(command)


@pytest.mark.parametrize(("driver_type", "message"), [
    (_StuckDriver, r"^active write moves: joint 0 is 0\.05 from its target"),
    (_VelocityUndeclared, r"^capabilities: undeclared velocity: the driver accepted it"),
    (_ImpedanceIgnored, r"^capabilities: declared impedance: joint 0 moved 0 of about 0\.05"),
    (_EstopAsProtectiveStop, r"^fault 'estop': reason CONTROLLER_FAULT .* expected E_STOP$"),
])
async def test_check_driver_names_the_broken_rule(driver_type: Callable[..., Driver],
                                                  message: str) -> None:
    with pytest.raises(ConformanceError, match=message):
        await check_driver(sim_harness(driver_type))
