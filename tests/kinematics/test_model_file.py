"""The robot model file is read once: the digest a run records and checks is that of the very
bytes parsed, whatever happens to the file (or a symlink to it) during start-up.

The swap is made deterministic with a Python audit hook: it flips the symlink at the moment
Python opens the model path, before the open happens. A loader that lets the parser open the
file itself (Pinocchio's C++ does, unseen by the hook) and then reads it again to hash it pairs
the first model with the second's digest; a loader that reads once parses what it hashed.
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from kernel.config.build import robot_limits
from kernel.config.kinematics import robot_kinematics
from kernel.model_file import BUILTIN, ModelSpec
from kernel.robot_model import load_kinematics
from kernel.scenario.fields import ScenarioError, Where

TOOL_OFFSET_M = 0.30
HOME = np.array([0.0, -1.5707963267948966, 1.5707963267948966, -1.5707963267948966,
                 -1.5707963267948966, 0.0])
ROBOT: dict[str, Any] = {"dof": 6, "tcp_frame": "tcp",
                         "position_limits": [[-6.2832, 6.2832]] * 6,
                         "velocity_limits": [3.1416] * 6, "acceleration_limits": [20.0] * 6}

_on_open: list[Callable[[str], None]] = []


def _audit(event: str, args: tuple[Any, ...]) -> None:
    if event == "open" and _on_open and isinstance(args[0], str | os.PathLike):
        _on_open[0](os.fspath(args[0]))


sys.addaudithook(_audit)  # cannot be removed: inert while _on_open is empty


@pytest.fixture
def models(tmp_path: Path) -> tuple[Path, Path, Path]:
    """``arm.xml`` (the shipped arm), ``other.xml`` (its tool point 0.30 m further out) and a
    symlink ``model.xml`` to the first."""
    text = BUILTIN["ur5e"].path.read_text()
    site = '<site name="tcp" pos="0 0 0.1275"/>'
    assert site in text
    first, second = tmp_path / "arm.xml", tmp_path / "other.xml"
    first.write_text(text)
    second.write_text(text.replace(site, f'<site name="tcp" pos="0 0 {0.1275 + TOOL_OFFSET_M}"/>'))
    link = tmp_path / "model.xml"
    link.symlink_to(first)
    return link, first, second


def _flip_at_first_open(link: Path, target: Path) -> list[str]:
    """Point ``link`` at ``target`` just before the first Python open of it; what was opened."""
    opened: list[str] = []

    def flip(path: str) -> None:
        if path == str(link):
            if not opened:
                link.unlink()
                link.symlink_to(target)
            opened.append(path)

    _on_open.append(flip)
    return opened


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _tool_point(robot: dict[str, Any]) -> np.ndarray:
    where = Where("test.toml", "robot")
    kinematics = robot_kinematics(robot, where, robot_limits(robot, where))
    assert kinematics is not None
    return kinematics.forward(HOME).position


def test_a_symlink_flipped_during_loading_never_pairs_one_model_with_the_others_digest(
        models: tuple[Path, Path, Path]) -> None:
    link, first, second = models
    robot = {**ROBOT, "model": str(link), "model_sha256": _sha256(second)}
    expected = _tool_point({**ROBOT, "model": str(second)})
    other = _tool_point({**ROBOT, "model": str(first)})
    assert np.linalg.norm(expected - other) == pytest.approx(TOOL_OFFSET_M)
    opened = _flip_at_first_open(link, second)
    try:
        loaded = _tool_point(robot)  # accepted: the digest names the model ...
    finally:
        _on_open.clear()
    assert opened == [str(link)]  # ... read once, ...
    np.testing.assert_allclose(loaded, expected, atol=1e-9)  # ... and that model is the one run


def test_a_symlink_flipped_away_from_the_signed_model_is_refused(
        models: tuple[Path, Path, Path]) -> None:
    link, first, second = models
    robot = {**ROBOT, "model": str(link), "model_sha256": _sha256(first)}
    _flip_at_first_open(link, second)
    try:
        with pytest.raises(ScenarioError, match=r"model_sha256.*changed"):
            _tool_point(robot)
    finally:
        _on_open.clear()


def test_the_loaded_model_carries_the_digest_of_its_bytes_after_the_file_changes(
        models: tuple[Path, Path, Path]) -> None:
    link, first, second = models
    kinematics = load_kinematics(ModelSpec(link, "tcp"), 6)
    link.unlink()
    link.symlink_to(second)
    assert kinematics.config.sha256 == _sha256(first) != _sha256(link)
    reloaded = load_kinematics(ModelSpec(link, "tcp"), 6)
    assert reloaded.config.sha256 == _sha256(second)
    gap = reloaded.forward(HOME).position - kinematics.forward(HOME).position
    assert np.linalg.norm(gap) == pytest.approx(TOOL_OFFSET_M)


def test_a_urdf_is_parsed_from_the_bytes_read(tmp_path: Path) -> None:
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(
        '<robot name="one"><link name="base"/><link name="tip"/>'
        '<joint name="j" type="revolute"><parent link="base"/><child link="tip"/>'
        '<origin xyz="0 0 0.5"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>')
    kinematics = load_kinematics(ModelSpec(urdf, "tip"), 1)
    assert kinematics.config.sha256 == _sha256(urdf)
    np.testing.assert_allclose(kinematics.forward(np.zeros(1)).position, [0.0, 0.0, 0.5])
