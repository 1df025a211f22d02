"""One definition per knob and per box (issue 16, item 1): the same box and the same wrist force
are judged by the same rule wherever a file writes them, and ``[policy]`` is one type the link
holds as read. Loader-only: nothing is started.
"""

from __future__ import annotations

import math
import re
import tomllib
import typing
from pathlib import Path
from typing import Any

import msgspec
import pytest

from drivers.base import NoSettings
from drivers.canopen402.settings import CiA402Settings
from drivers.dynamixel.settings import DynamixelSettings
from drivers.settings import SettingsError, bounds_of, read_table
from drivers.ur_rtde.settings import URSettings
from kernel.app.task_settings import TaskSettings
from kernel.config.build import build_config
from kernel.manifest import SCENARIO_SECTIONS, ManifestError, load_manifest
from kernel.safety.settings import SafetySettings
from kernel.scenario.fields import ScenarioError, Where
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import ClientConfig
from tests.core.test_trial_bounds import _doc

ROOT = Path(__file__).resolve().parents[2]
SIM = ROOT / "manifests" / "sim-ur5e.toml"
GOOD = ([-0.8, -0.4, 0.0], [-0.2, 0.35, 0.5])
FLAT = ([-0.8, -0.4, 0.5], [-0.2, 0.35, 0.5])
"""A box of no height: no pose can reliably be inside it."""
WIDE = ([-0.8, -0.4, 0.0], [-0.2, 0.35, 150.0])
"""A corner beyond the ±100 m every box is bounded by."""


def _trial(lower: list[float], upper: list[float], force: float = 150.0) -> None:
    text = SIM.read_text() + (
        f"\n[trial]\nmax_cycles = 1\nmax_duration_s = 60.0\nworkspace_lower = {lower}\n"
        f"workspace_upper = {upper}\nspeed_scale = 0.5\nmax_wrist_force_n = {force}\n")
    load_manifest(SIM, content=text.encode())


def _robot_workspace(lower: list[float], upper: list[float]) -> None:
    build_config(_doc(None, workspace={"lower": lower, "upper": upper}), Where("s.json", ""))


def _envelope(lower: list[float], upper: list[float], force: float = 150.0) -> None:
    box: dict[str, Any] = {"workspace": {"lower": lower, "upper": upper},
                           "max_wrist_force_n": force}
    build_config(_doc(box), Where("s.json", ""))


SITES = [_trial, _robot_workspace, _envelope]


@pytest.mark.parametrize("site", SITES, ids=lambda f: f.__name__)
def test_every_box_is_judged_by_one_rule(site: Any) -> None:
    site(*GOOD)
    for lower, upper in (FLAT, WIDE):
        with pytest.raises(ScenarioError):
            site(lower, upper)


@pytest.mark.parametrize("site", [_trial, _envelope], ids=lambda f: f.__name__)
def test_a_wrist_force_limit_has_one_range(site: Any) -> None:
    """A heavy arm's trial may stop at 2000 N; above 100 000 N (FORCE_MAX_N, as for a
    phase's force band) it is a typo, and under 0.1 N the sensor's noise alone stops the arm."""
    site(*GOOD, force=2000.0)
    for force in (1e6, 0.01):
        with pytest.raises(ScenarioError, match="max_wrist_force_n"):
            site(*GOOD, force=force)


def test_the_link_holds_the_policy_table_as_read() -> None:
    """No knob of ``[policy]`` is defined a second time on the link's configuration (in
    another unit), and the manifest's table is what the link gets."""
    policy = {f.name.removesuffix("_ms") for f in msgspec.structs.fields(PolicySettings)}
    client = {name.removesuffix("_s") for name in ClientConfig.__dataclass_fields__}
    assert policy & client == set()
    manifest = load_manifest(SIM)
    assert ClientConfig(url="ws://x", policy=manifest.policy).policy is manifest.policy


SETTINGS_TYPES = [URSettings, DynamixelSettings, CiA402Settings, NoSettings, SafetySettings,
                  TaskSettings, PolicySettings]


@pytest.mark.parametrize("cls", SETTINGS_TYPES, ids=lambda c: c.__name__)
def test_every_settings_table_is_a_frozen_struct_with_its_bounds_on_its_fields(cls: type) -> None:
    """A driver's, the monitor's and the task's table are typed like warden's own: frozen
    Structs (a journal's header or a test encodes and decodes them exactly), each numeric
    field's range declared on the field, not in a list of checks beside it."""
    assert issubclass(cls, msgspec.Struct) and cls.__struct_config__.frozen
    numeric = [f.name for f in msgspec.structs.fields(cls)
               if typing.get_type_hints(cls)[f.name] in (int, float)]
    declared = [name for name in numeric if bounds_of(cls, name) != (None, None)]
    assert len(declared) >= len(numeric) - 1, f"{cls.__name__}: {set(numeric) - set(declared)}"


@pytest.mark.parametrize(("cls", "table", "where"), [
    (URSettings, {"host": "10.0.0.7", "servo_gain": 50.0}, "driver.servo_gain"),
    (SafetySettings, {"max_wrist_force_n": 1e9}, "safety.max_wrist_force_n"),
    (DynamixelSettings, {"port": "/dev/x", "retries": 11}, "driver.retries"),
])
def test_one_bound_is_checked_when_read_when_built_and_when_decoded(
        cls: type, table: dict[str, Any], where: str) -> None:
    """The reader names the key; code that builds the value itself and a decoder of an encoded
    one meet the same bound (no second copy of it)."""
    with pytest.raises(SettingsError, match=rf"cell\.toml: {re.escape(where)}: must be"):
        read_table(cls, table, Where("cell.toml", where.split(".")[0]))
    with pytest.raises(ValueError, match="must be"):
        cls(**table)
    with pytest.raises(msgspec.ValidationError):
        msgspec.json.decode(msgspec.json.encode(table), type=cls)


def _with_task(change: tuple[str, str]) -> bytes:
    return SIM.read_text().replace(*change, 1).encode()


@pytest.mark.parametrize(("change", "message"), [
    (("hole_depth = 0.03", "hole_depth = 1e9"), "task.hole_depth: must be at most 1"),
    (("gripper_open = 0.085", "gripper_open = 0.085\nmax_insertion_force_n = nan"),
     "task.max_insertion_force_n: must be a finite number"),
    (("gripper_open = 0.085", "gripper_open = 0.085\nlateral_tolerance_m = -0.002"),
     "task.lateral_tolerance_m: must be positive"),
    (("home_q = [0.0,", "home_q = [100.0,"), "task.home_q[0]: 100 is outside"),
])
def test_a_bad_task_table_is_refused_when_the_manifest_is_read(change: tuple[str, str],
                                                               message: str) -> None:
    """``[task]`` is typed at load like every other table: the manifest itself is refused
    (a NaN force bar used to pass and then fail every VERIFY)."""
    with pytest.raises(ManifestError, match=re.escape(message)):
        load_manifest(SIM, content=_with_task(change))
    assert load_manifest(SIM).task == TaskSettings(
        home_q=(0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0),
        tool_rotation=((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)),
        part_position=(-0.4, 0.1, 0.03), hole_top=(-0.55, -0.15, 0.03), hole_depth=0.03,
        part_centre_below_tcp=0.0175, part_half_height=0.03, gripper_open=0.085)


def test_the_written_sections_cross_as_one_immutable_record() -> None:
    """What the journal's header repeats is the document as written, and no reader can change
    what the next one reads."""
    manifest = load_manifest(SIM)
    robot = manifest.sections.table("robot")
    robot["dof"] = 99
    assert manifest.sections.table("robot")["dof"] == 6
    with pytest.raises(AttributeError):
        manifest.sections.encoded = b"{}"  # type: ignore[misc]
    written = tomllib.loads(SIM.read_text())
    assert manifest.sections.document() == {key: written[key] for key in SCENARIO_SECTIONS
                                             if key in written}
