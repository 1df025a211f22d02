"""``[geometry]`` is read into typed solids, and a mis-specified solid is named by its key."""

from __future__ import annotations

import tomllib

import pytest

from kernel.cell_geometry import GeometrySettings, Shape, geometry_table
from kernel.scenario.fields import ScenarioError, Where

CELL = """
[geometry]
margin_m = 0.01
[geometry.phase_margin_m]
FREE_SPACE = 0.03
CONTACT = 0.0
[geometry.part]
shape = "box"
size = [0.01, 0.01, 0.03]
position = [0.0, 0.0, 0.0175]
[[geometry.obstacles]]
name = "table"
shape = "box"
size = [0.6, 0.6, 0.025]
position = [-0.35, 0.0, -0.025]
[[geometry.obstacles]]
name = "fixture"
shape = "box"
size = [0.026, 0.026, 0.015]
position = [-0.55, -0.15, 0.015]
allow_contact = ["CONTACT"]
[[geometry.keep_out]]
name = "bench"
shape = "sphere"
size = [0.2]
position = [0.3, 0.8, 0.5]
"""


def read(text: str) -> GeometrySettings | None:
    return geometry_table(tomllib.loads(text), Where("cell.toml", ""))


def test_a_cell_reads_into_typed_solids() -> None:
    geometry = read(CELL)
    assert geometry is not None
    assert [o.name for o in geometry.obstacles] == ["table", "fixture"]
    assert geometry.obstacles[1].allow_contact == ("CONTACT",)
    assert geometry.keep_out[0].shape is Shape.SPHERE
    assert geometry.margin("FREE_SPACE") == 0.03
    assert geometry.margin("PRE_CONTACT") == 0.01
    assert geometry.part is not None and geometry.part.size == (0.01, 0.01, 0.03)


def test_no_table_is_none() -> None:
    assert read("[cell]\ncycles = 1\n") is None


@pytest.mark.parametrize(("change", "message"), [
    (("size = [0.026, 0.026, 0.015]", "size = [0.026, -0.026, 0.015]"),
     "cell.toml: geometry.obstacles[1].size[1]: must be positive, got -0.026"),
    (("size = [0.2]", "size = [0.2, 0.1]"),
     "cell.toml: geometry.keep_out[0].size: a sphere takes a radius (1 value), got 2"),
    (('name = "bench"', 'name = "table"'),
     "cell.toml: geometry.keep_out[0].name: 'table' already names obstacles[0]"),
    (('name = "bench"', 'name = "a b"'), "cell.toml: geometry.keep_out[0].name: 'a b' is not a"),
    (('shape = "sphere"', 'shape = "cone"'),
     "cell.toml: geometry.keep_out[0].shape: unknown value 'cone'"),
    (("CONTACT = 0.0", "CONTACT = 5.0"),
     "cell.toml: geometry.phase_margin_m.CONTACT: must be at most 0.5, got 5"),
    (("margin_m = 0.01", "margin_m = 0.01\nframe = 'tool'"),
     "cell.toml: geometry.frame: unknown key"),
    (('position = [0.3, 0.8, 0.5]', 'position = [0.3, 0.8]'),
     "cell.toml: geometry.keep_out[0].position: has 2 values, expected 3"),
])
def test_a_mis_specified_solid_is_named(change: tuple[str, str], message: str) -> None:
    with pytest.raises(ScenarioError) as raised:
        read(CELL.replace(*change))
    assert str(raised.value).startswith(message)
