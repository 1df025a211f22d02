"""``[geometry]`` in a manifest: a mis-specified solid or phase exits 2 naming its key, a real
device needs the table, and the shipped cells carry the same geometry as the scenarios."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from kernel.cli import main
from kernel.manifest import ManifestError, load_manifest
from kernel.scenario.fields import ScenarioError
from tools.scenarios.catalog_collision import GEOMETRY

ROOT = Path(__file__).resolve().parents[2]
MANIFESTS = sorted((ROOT / "manifests").glob("*.toml"))
SIM = ROOT / "manifests" / "sim-ur5e.toml"
DEVICES = ["sim-ur5e-rtde.toml", "sim-dynamixel.toml", "sim-canopen.toml",
           "ur5e-real.example.toml"]


def refused(path: Path, old: str, new: str) -> str:
    text = path.read_text()
    assert text.count(old) == 1, old
    with pytest.raises((ManifestError, ScenarioError)) as caught:
        load_manifest(path, content=text.replace(old, new).encode())
    return str(caught.value)


@pytest.mark.parametrize(("old", "new", "message"), [
    ('allow_contact = ["CONTACT", "VERIFY", "RETREAT"]',
     'allow_contact = ["CONTACT", "INSERT", "RETREAT"]',
     "geometry.obstacles[1].allow_contact[1]: unknown phase 'INSERT'"),
    ("PRE_CONTACT = 0.002", "PRECONTACT = 0.002",
     "geometry.phase_margin_m.PRECONTACT: unknown phase 'PRECONTACT'"),
    ("size = [0.6, 0.6, 0.025]", "size = [0.6, -0.6, 0.025]",
     "geometry.obstacles[0].size[1]: must be positive"),
    ('name = "fixture"', 'name = "table"', "geometry.obstacles[1].name: 'table' already names"),
    ("size = [0.01, 0.01, 0.03]", "size = [0.01, 0.03]",
     "geometry.part.size: a box takes three half extents"),
    ('kinematics = "ur5e"           # the arm', 'kinematicz = "ur5e"           # the arm',
     "robot.kinematicz: unknown key"),
])
def test_a_mis_specified_geometry_is_named(old: str, new: str, message: str) -> None:
    error = refused(SIM, old, new)
    assert str(SIM) in error and message in error, error


def test_geometry_needs_the_robots_model() -> None:
    text = SIM.read_text().replace('kinematics = "ur5e"           # the arm', "# no model")
    with pytest.raises(ManifestError) as caught:
        load_manifest(SIM, content=text.encode())
    assert "geometry: needs the robot's model" in str(caught.value)


@pytest.mark.parametrize("name", DEVICES)
def test_a_real_device_needs_the_geometry(name: str) -> None:
    path = ROOT / "manifests" / name
    text = path.read_text()
    cut = text[:text.index("\n[geometry]")]
    with pytest.raises(ManifestError) as caught:
        load_manifest(path, content=cut.encode())
    assert "geometry: missing required table: a real device needs the cell's geometry" in str(
        caught.value)


def test_the_cli_exits_2_naming_the_key(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    text = SIM.read_text().replace('allow_contact = ["FREE_SPACE"]',
                                   'allow_contact = ["FREESPACE"]')
    path = tmp_path / "cell.toml"
    path.write_text(text)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "geometry.obstacles[0].allow_contact[0]: unknown phase 'FREESPACE'" in err
    assert "Traceback" not in err


@pytest.mark.parametrize("path", MANIFESTS, ids=lambda p: p.stem)
def test_every_shipped_cell_carries_the_scenarios_geometry(path: Path) -> None:
    assert tomllib.loads(path.read_text())["geometry"] == GEOMETRY
    assert load_manifest(path).core.collision is not None
