"""The manifest tables that both warden's core configuration and the safety monitor read.

One parser per knob, below both readers: :mod:`kernel.manifest` and
:mod:`kernel.config.build` build the core's configuration with these functions, and the
safety monitor's own view (:mod:`kernel.safety.view`) reads the same tables with the same
functions, so the limits the monitor checks are the limits warden was given, parsed once and
refused with the same "file: table.key: why" messages. This module imports nothing of the core
(``kernel.core``, ``assurance``, ``skills``) and no robot model: tests/test_layers.py checks
that the monitor reaches none of them through it.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from enum import StrEnum
from pathlib import Path
from typing import Any

import msgspec

from drivers import registry
from drivers.settings import read_table
from kernel.safety.settings import SafetySettings, check_against_period
from kernel.scenario import bounds
from kernel.scenario.fields import (
    ScenarioError,
    Where,
    integer,
    is_number,
    number,
    shown,
    text,
    vector,
)

ROBOT_KEYS = frozenset({"dof", "position_limits", "velocity_limits", "acceleration_limits",
                        "gripper_index", "gripper_event_threshold", "kinematics", "model",
                        "tcp_frame", "joints", "model_sha256", "workspace"})
"""The keys ``[robot]`` may hold (anything else is refused by name)."""


class PlantKind(StrEnum):
    MUJOCO = "mujoco"
    KINEMATIC = "kinematic"


class EmulatorSettings(msgspec.Struct, frozen=True, kw_only=True):
    """``[emulator]``: simulation only. ``launch``: warden starts the device's emulator itself
    (so no other process, the safety monitor included, can address that device)."""

    launch: bool = True
    plant: PlantKind = PlantKind.MUJOCO
    host: str = ""


class RobotLimits(msgspec.Struct, frozen=True):
    """``[robot]``'s joint limits as plain numbers, one entry per robot dimension (the arm
    joints and, where ``gripper_index`` names one, the gripper, whose missing limits are
    unbounded)."""

    lower: tuple[float, ...]
    upper: tuple[float, ...]
    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]
    gripper_index: int | None
    gripper_event_threshold: float

    @property
    def arm(self) -> tuple[int, ...]:
        """The indices of the arm joints (every dimension but the gripper's)."""
        return tuple(i for i in range(len(self.lower)) if i != self.gripper_index)


def robot_limits_table(robot: Mapping[str, Any], where: Where) -> RobotLimits:
    """Every arm joint's position, velocity and acceleration limit: required, finite, within
    :mod:`kernel.scenario.bounds` (a limit never defaults to unbounded)."""
    dof = integer(robot, "dof", where, minimum=1, maximum=bounds.DOF_MAX)
    grip = robot.get("gripper_index")
    if grip is not None:
        grip = integer(robot, "gripper_index", where, minimum=0)
        if grip > dof:
            raise where.at("gripper_index").error(f"must be at most dof ({dof}), got {grip}")
    dim = dof + 1 if grip == dof else dof
    lower, upper = _position_limits(robot, where, dim, grip)
    return RobotLimits(
        lower=lower, upper=upper,
        velocity=_rate_limits(robot, "velocity_limits", where, dim, grip,
                              bounds.VELOCITY_LIMIT_MAX),
        acceleration=_rate_limits(robot, "acceleration_limits", where, dim, grip,
                                  bounds.ACCELERATION_LIMIT_MAX),
        gripper_index=grip,
        gripper_event_threshold=number(robot, "gripper_event_threshold", where, 1e-3,
                                       minimum=0, maximum=bounds.POSITION_LIMIT_MAX))


def _pad_gripper(values: list[float], dim: int, grip: int | None, fill: float) -> list[float]:
    if len(values) == dim - 1 and grip is not None:
        return [*values[:grip], fill, *values[grip:]]
    return values


def _position_limits(robot: Mapping[str, Any], where: Where, dim: int,
                     grip: int | None) -> tuple[tuple[float, ...], tuple[float, ...]]:
    here = where.at("position_limits")
    raw = robot.get("position_limits")
    if raw is None:
        raise where.error("missing required key 'position_limits' (every joint needs one: "
                          "a limit never defaults to unbounded)")
    if is_number(raw):
        bound = abs(number(robot, "position_limits", where, maximum=bounds.POSITION_LIMIT_MAX,
                           minimum=-bounds.POSITION_LIMIT_MAX))
        return (-bound,) * dim, (bound,) * dim
    if isinstance(raw, dict):
        low_key = "lower" if "lower" in raw else "min"
        high_key = "upper" if "upper" in raw else "max"
        lower = vector(raw.get(low_key), here.at(low_key), bound=bounds.POSITION_LIMIT_MAX)
        upper = vector(raw.get(high_key), here.at(high_key), bound=bounds.POSITION_LIMIT_MAX)
    elif isinstance(raw, list) and all(isinstance(p, list) and len(p) == 2 for p in raw) and (
        len(raw) in (dim, dim - 1)
    ):
        pairs = [vector(p, here.at(i), 2, bound=bounds.POSITION_LIMIT_MAX)
                 for i, p in enumerate(raw)]
        lower, upper = [p[0] for p in pairs], [p[1] for p in pairs]
    else:
        raise here.error("must be a list of [lower, upper] pairs, {lower, upper}, or a number")
    lower = _pad_gripper(lower, dim, grip, -math.inf)
    upper = _pad_gripper(upper, dim, grip, math.inf)
    if len(lower) != dim or len(upper) != dim:
        raise here.error(f"has {len(lower)} entries, the robot has {dim} dimensions")
    for index, (low, high) in enumerate(zip(lower, upper, strict=True)):
        if low > high:
            raise here.at(index).error(f"lower limit {low} exceeds upper limit {high}")
    return tuple(map(float, lower)), tuple(map(float, upper))


def _rate_limits(robot: Mapping[str, Any], key: str, where: Where, dim: int, grip: int | None,
                 bound: float) -> tuple[float, ...]:
    raw = robot.get(key)
    here = where.at(key)
    if raw is None:
        raise where.error(f"missing required key {key!r} (every joint needs one: a limit "
                          "never defaults to unbounded)")
    if is_number(raw):
        values = [number(robot, key, where, positive=True, maximum=bound)] * dim
    else:
        values = _pad_gripper(vector(raw, here, bound=bound), dim, grip, math.inf)
    if len(values) != dim:
        raise here.error(f"has {len(values)} entries, the robot has {dim} dimensions")
    if any(v <= 0 for v in values):
        raise here.error("must be positive")
    return tuple(map(float, values))


def control_period_ms(timing: Mapping[str, Any], where: Where) -> float:
    """``[timing] control_period_ms`` (``where``: the timing table), 2 ms when not set."""
    return number(timing, "control_period_ms", where, default=2.0,
                  minimum=bounds.PERIOD_MIN_MS, maximum=bounds.PERIOD_MAX_MS)


def safety_table(doc: Mapping[str, Any], where: Where, period_ns: int) -> SafetySettings | None:
    """``[safety]``, checked against the control period its heartbeats are spaced by; None
    when the manifest has no such table."""
    if "safety" not in doc:
        return None
    settings = read_table(SafetySettings, table(doc, "safety", where), where.at("safety"))
    problem = check_against_period(settings, period_ns)
    if problem:
        raise ScenarioError(f"{where.file}: safety.heartbeat_timeout_ms: {problem}")
    return settings


def driver_table(doc: Mapping[str, Any], where: Where) -> tuple[str, dict[str, Any]]:
    """``[driver]``: its ``name`` (required, text), and the rest of the table as written (the
    named driver's own settings type reads it)."""
    driver = dict(table(doc, "driver", where))
    name = text(driver, "name", where.at("driver"), numbers_ok=False)
    del driver["name"]
    return name, driver


def table(doc: Mapping[str, Any], key: str, where: Where) -> Mapping[str, Any]:
    """The table ``doc[key]`` (empty when absent), refused unless it is a table."""
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise where.at(key).error("must be a table")
    return value


# -- the document and the run's name -----------------------------------------------------------


def parse_toml(raw: str, name: str) -> dict[str, Any]:
    """``raw`` as a TOML document; ``name``: the file, for the message of a refusal."""
    try:
        return tomllib.loads(raw)
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{name}: not valid TOML: {error}") from None
    except RecursionError:
        raise ScenarioError(f"{name}: nested too deeply (at most {bounds.MAX_DEPTH} levels of "
                            "tables and arrays)") from None
    except ValueError:  # tomllib converts an integer of more than 4300 digits and fails
        raise ScenarioError(f"{name}: {_wide_literal_place(raw)}: an integer of thousands of "
                            "digits: integers are at most 64 bits") from None


_WIDE_LITERAL = re.compile(r"[0-9][0-9_]{999,}")
_TABLE_HEADER = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]", re.MULTILINE)
_KEY = re.compile(r"[ \t]*([^=\s]+)[ \t]*=")


def _wide_literal_place(raw: str) -> str:
    """Where the integer literal tomllib could not convert is: its line, and the key it
    belongs to when the line starts with one (the parser itself cannot say)."""
    found = _WIDE_LITERAL.search(raw)
    if found is None:
        return "somewhere"
    line_start = raw.rfind("\n", 0, found.start()) + 1
    line = raw.count("\n", 0, found.start()) + 1
    key = _KEY.match(raw, line_start)
    if key is None or key.end() > found.start():
        return f"line {line}"
    tables = _TABLE_HEADER.findall(raw, 0, line_start)
    prefix = f"{tables[-1]}." if tables else ""
    return f"line {line}: {prefix}{key.group(1)}"


_NAME = re.compile(bounds.NAME_PATTERN)
_NAME_RULE = ("1 to 64 ASCII letters, digits, '.', '_' or '-', not starting with '.' or '-': "
              "it names the run's directory")


def run_name(doc: Mapping[str, Any], path: Path, where: Where) -> str:
    """The run's name: a directory name under the journal directory, so never a path."""
    if "description" in doc and not isinstance(doc["description"], str):
        raise where.at("description").error(f"must be a string, got {shown(doc['description'])}")
    if "name" not in doc:
        if _NAME.fullmatch(path.stem):
            return path.stem
        raise where.at("name").error(
            f"missing, and the file name {shown(path.stem)} is not a safe run name: set "
            f"'name' ({_NAME_RULE})")
    name = doc["name"]
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise where.at("name").error(f"{shown(name)} is not a safe run name ({_NAME_RULE})")
    return name


def decode_driver_settings(name: str, driver: Mapping[str, Any], emulator_launch: bool,
                    where: Where) -> Any:
    """``[driver]`` (without ``name``) decoded into the settings type the named driver declares,
    for warden's loader and the monitor's view alike; with ``[emulator] launch`` the run fills in
    the device's address from the emulator, so the table may leave it out."""
    try:
        return registry.settings_for(name, driver, where.at("driver"),
                                     address_filled_in=emulator_launch)
    except registry.UnknownDriver as error:
        raise where.at("driver").at("name").error(str(error)) from None
