"""The conformance suite against the plant driver, in lockstep with a kinematic plant."""

from __future__ import annotations

import pytest

from assurance.reasons import ReasonCode
from drivers.base import ControlConfig
from drivers.sim.driver import SimDriver, SimFaults
from drivers.sim.plant import PlantReading, SimulatedPlant
from stubs.plant.base import KinematicPlant
from stubs.plant.mujoco_plant import MujocoPlant
from tests.conformance.suite import DriverConformance, Harness

PERIOD_NS = 2_000_000


@pytest.fixture
def harness() -> Harness:
    plant = KinematicPlant(dof=6, timestep_ns=PERIOD_NS)
    faults = SimFaults()

    def inject(name: str) -> None:
        setattr(faults, name, True)

    async def advance(seconds: float) -> None:
        plant.step(max(1, round(seconds * 1e9 / PERIOD_NS)))

    control = ControlConfig(
        dof=6, period_ns=PERIOD_NS, q_lower=(-6.28,) * 6, q_upper=(6.28,) * 6, v_max=(3.14,) * 6
    )
    return Harness(
        make_driver=lambda: SimDriver(plant, faults=faults),
        control=control,
        inject=inject,
        expected_reason={
            "estop": ReasonCode.E_STOP,
            "protective_stop": ReasonCode.CONTROLLER_FAULT,
            "disconnected": ReasonCode.LINK_LOST,
        },
        advance=advance,
    )


class TestSimDriverConformance(DriverConformance):
    FAULTS = ("estop", "protective_stop", "disconnected")


@pytest.mark.parametrize("make_plant", [KinematicPlant, MujocoPlant])
def test_the_stand_in_plants_are_what_the_driver_needs(make_plant: type) -> None:
    """The driver names what it needs of a plant; the plants provide it without importing it."""
    plant = make_plant()
    assert isinstance(plant, SimulatedPlant)
    assert isinstance(plant.state(), PlantReading)
