"""The clearance checker of the collision catalogue's cell (the held peg), and the
independent oracle on the same scene, shared by the geometry tests (each built once)."""

from __future__ import annotations

import pytest

from assurance.collision import CellCollision
from kernel.config.build import robot_limits
from kernel.config.geometry import cell_collision
from kernel.config.kinematics import robot_kinematics
from kernel.scenario.fields import Where
from tests.geometry.oracle import MujocoOracle
from tools.scenarios.base import robot
from tools.scenarios.catalog_collision import GEOMETRY


@pytest.fixture(scope="session")
def checker() -> CellCollision:
    where = Where("test", "")
    doc = {"robot": {**robot(), "kinematics": "ur5e"}, "geometry": GEOMETRY}
    limits = robot_limits(doc["robot"], where.at("robot"))
    kinematics = robot_kinematics(doc["robot"], where.at("robot"), limits)
    return cell_collision(doc, where, kinematics)


@pytest.fixture(scope="session")
def oracle() -> MujocoOracle:
    return MujocoOracle(GEOMETRY, held=True)
