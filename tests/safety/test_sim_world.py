"""The simulated world's side of the safety monitor: its control port and its brake, and the
monitor's watch on it (kernel/safety/sim.py), in one process over real loopback TCP."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest

from drivers.base import Command, CommandKind, ControlConfig
from kernel.safety.sim import SimWorldWatch
from kernel.safety.watch import DeviceLost
from stubs.cell.sim_world import SimWorld
from stubs.plant.base import UR5E_HOME, KinematicPlant
from stubs.plant.brake import BrakedPlant
from tests.safety.support import free_port

PERIOD_NS = 2_000_000


def test_an_engaged_brake_holds_and_ignores_joint_commands_but_not_the_gripper() -> None:
    plant = KinematicPlant()
    braked = BrakedPlant(plant)
    braked.command_velocity([1.0, 0, 0, 0, 0, 0])
    braked.step(10)
    braked.engage()
    caught = plant.state().q
    braked.command_position([0.5] * 6)
    braked.command_velocity([1.0] * 6)
    braked.command_impedance([0.5] * 6, [1.0] * 6, [1.0] * 6)
    braked.hold()
    braked.command_gripper(0.01)
    braked.step(50)
    assert plant.state().q == pytest.approx(caught) and braked.ignored == 3
    assert plant.state().gripper == 0.01


@pytest.fixture
def world() -> Iterator[SimWorld]:
    made = SimWorld(PERIOD_NS, plant=KinematicPlant(), control_port=free_port())  # type: ignore
    yield made
    made.close()


def _control() -> ControlConfig:
    return ControlConfig(dof=6, period_ns=PERIOD_NS, q_lower=(-6.3,) * 6, q_upper=(6.3,) * 6,
                         v_max=(3.0,) * 6)


def test_the_monitors_watch_reads_the_world_and_brakes_it(world: SimWorld) -> None:
    assert world.control is not None
    watch = SimWorldWatch(world.control.address[1], timeout_s=1.0)
    watch.connect()
    driver = world.driver()

    async def drive() -> None:
        await driver.connect()
        await driver.configure(_control())
        await driver.activate()
        for _ in range(20):
            await driver.write(Command(kind=CommandKind.POSITION, q=(0.3, *UR5E_HOME[1:])))
            world.advance()

    asyncio.run(drive())
    sample = watch.sample()
    assert 0.0 < sample.q[0] < 0.3 and sample.qd[0] > 0.0 and sample.force_n == 0.0
    assert watch.stop().done
    caught = watch.sample().q

    async def keep_driving() -> None:
        for _ in range(50):
            await driver.write(Command(kind=CommandKind.POSITION, q=(0.3, *UR5E_HOME[1:])))
            world.advance()

    asyncio.run(keep_driving())
    assert watch.sample().q[0] == pytest.approx(caught[0], abs=1e-3)  # braked where it was
    watch.close()


def test_a_world_that_went_away_is_a_lost_device(world: SimWorld) -> None:
    assert world.control is not None
    watch = SimWorldWatch(world.control.address[1], timeout_s=0.5)
    watch.connect()
    world.close()  # no new connection is taken; warden's process ending closes the rest
    watch.close()
    with pytest.raises(DeviceLost, match="does not answer"):
        watch.sample()
    assert not watch.reconnect()
    assert not watch.stop().done
