"""The safety monitor's own view of a deployment manifest: the joint limits, ``[safety]``,
``[driver]``, whether warden launches the device's emulator, ``[geometry]`` and the arm's model
file, and nothing else.

The monitor reads the manifest file itself, with the very parsers warden's configuration uses
for these tables (:mod:`kernel.manifest_tables`, and :mod:`kernel.model_file` for which model
file ``[robot]`` names), so a limit means the same to both and a bad value is refused with the
same "file: table.key: why" message. It does not build warden's core configuration: no phase
cards, policy or session is read, and the robot model is only located here (the space check,
:mod:`kernel.safety.space`, loads it with MuJoCo, not with warden's Pinocchio code), so nothing
of warden's core is imported, and a mistake there is not one here.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import msgspec

from kernel.cell_geometry import GeometrySettings, geometry_table
from kernel.manifest_tables import (
    ROBOT_KEYS,
    EmulatorSettings,
    RobotLimits,
    control_period_ms,
    decode_driver_settings,
    driver_table,
    parse_toml,
    robot_limits_table,
    run_name,
    safety_table,
    table,
)
from kernel.model_file import ModelSpec, model_spec
from kernel.safety.settings import SafetySettings
from kernel.scenario.document import check_document, decoded, read_bytes
from kernel.scenario.fields import ScenarioError, Where, mapping
from kernel.tables import read_table


class ViewError(ScenarioError):
    """The manifest cannot be watched by; the message names the file and the key (exit 2)."""


class MonitorView(msgspec.Struct, frozen=True):
    name: str
    """The run's name (``name``, else the file's stem), as warden names its run."""
    path: Path
    digest: str
    """SHA-256 of the exact bytes read: ``warden safety status`` reports it, and a trial checks
    the monitor watches by its own manifest."""
    limits: RobotLimits
    safety: SafetySettings | None
    """``[safety]``; None: no such table (the monitor refuses to start)."""
    driver_name: str
    driver_settings: Any
    """``[driver]`` without ``name``, decoded into the named driver's own settings type (the
    device's address, the bus, the drives)."""
    emulator: EmulatorSettings
    geometry: GeometrySettings | None = None
    """``[geometry]``; None: no such table (the monitor checks no space)."""
    arm_model: ModelSpec | None = None
    """The arm's model file (``[robot] kinematics`` or ``model``), read with ``[geometry]``;
    None: none named, or no ``[geometry]``."""


def read_view(path: str | Path) -> MonitorView:
    """The monitor's view of the manifest at ``path``.

    Raises:
        ViewError: naming the file and the key, for anything in the tables the monitor reads.
    """
    path = Path(path)
    try:
        data = read_bytes(path, str(path))
        return _view(path, decoded(data, str(path)), hashlib.sha256(data).hexdigest())
    except ViewError:
        raise
    except ScenarioError as error:
        raise ViewError(str(error)) from None


def _view(path: Path, raw: str, digest: str) -> MonitorView:
    where = Where(str(path), "")
    doc = parse_toml(raw, str(path))
    check_document(doc, where)
    robot = mapping(doc, "robot", where)
    for key in robot:
        if key not in ROBOT_KEYS:
            raise where.at("robot").at(key).error(
                f"unknown key (known: {', '.join(sorted(ROBOT_KEYS))})")
    period_ms = control_period_ms(mapping(doc, "timing", where, required=False),
                                  where.at("timing"))
    driver_name, driver = driver_table(doc, where)
    emulator = _emulator(doc, where)
    geometry = geometry_table(doc, where)
    return MonitorView(
        name=run_name(doc, path, where), path=path, digest=digest,
        limits=robot_limits_table(robot, where.at("robot")),
        safety=safety_table(doc, where, round(period_ms * 1e6)),  # as assurance.clock rounds
        driver_name=driver_name,
        driver_settings=decode_driver_settings(driver_name, driver, emulator.launch, where),
        emulator=emulator, geometry=geometry,
        # The model matters to the monitor only for the space check: without [geometry] a
        # mistake in naming it is warden's refusal, not the monitor's.
        arm_model=model_spec(robot, where.at("robot")) if geometry is not None else None)



def _emulator(doc: Mapping[str, Any], where: Where) -> EmulatorSettings:
    return read_table(EmulatorSettings, table(doc, "emulator", where), where.at("emulator"))


__all__ = ["MonitorView", "SafetySettings", "ViewError", "read_view"]
