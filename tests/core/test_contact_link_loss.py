"""A policy link lost during contact ends contact the way the phase card says, on the first
tick after the core learns of it (docs/protocol.md, "Link loss in contact"); driven through
``Core.step`` only: a descent is started, the link goes down, the ticks say what the arm gets."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from assurance.fallback import Mode
from kernel.config.build import build_config
from kernel.core.effects import Retreat, Setpoint
from kernel.core.events import InsertEvent, LinkEvent
from kernel.core.lines import TickLine
from kernel.scenario.fields import ScenarioError, Where
from skills.contact import ContactState
from tests.core.test_motion import Drive
from tools.scenarios.base import ScenarioSpec


def contact_core(**card: Any) -> Drive:
    spec = ScenarioSpec(name="contact", description="", events=[], until=0, expect=[],
                        phase="CONTACT", phases={"CONTACT": {"executor": "contact", **card}},
                        timing={"control_period_ms": 2, "clock_uncertainty_ms": 0})
    doc = spec.document()
    doc["robot"]["kinematics"] = "ur5e"
    return Drive(build_config(doc, Where("contact", "")))


def descending(drive: Drive) -> float:
    """Start a 5 cm descent from where the tool is and run it for 0.1 s; the tool's height."""
    drive.tick(follow=True)
    kinematics, arm = drive.core.config.kinematics, drive.core.config.limits.arm_mask
    pose = kinematics.forward(drive.core.inspect_state().measured_q[arm])
    drive.feed(InsertEvent, xy=tuple(pose.position[:2]), z_end=float(pose.position[2]) - 0.05,
               rotation=tuple(pose.rotation.ravel()))
    drive.tick(50, follow=True)
    assert drive.core.status().contact is ContactState.DESCENDING
    return float(pose.position[2])


def height(drive: Drive, q: tuple[float, ...]) -> float:
    arm = drive.core.config.limits.arm_mask
    return float(drive.core.config.kinematics.forward(np.asarray(q)[arm]).position[2])


STOP_S = 0.05
"""The commanded descent stops within this after the first DEGRADED tick: the target reverses
at once, the interpolator brakes the 3 cm/s descent inside the arm's jerk limits."""
SETTLE_S = 0.3
"""A relaxed hold's target is where the tool was at that tick; the interpolator brings the
braking arm back onto it (an overshoot under 1 mm) within this."""


def test_by_default_a_lost_link_retracts_the_contact_owner_on_the_next_tick() -> None:
    drive = contact_core()
    start_z = descending(drive)
    pressed = height(drive, drive.motions[-1].q)
    drive.feed(LinkEvent, status="down")
    after = [drive.tick(follow=True) for _ in range(1500)]  # 3 s: a 5 cm lift at 4 cm/s
    line = next(x for x in drive.lines if isinstance(x, TickLine) and x.mode == "DEGRADED")
    assert drive.core.status().mode is Mode.DEGRADED
    assert (line.command, line.owner, line.reason) == ("retreat", "contact", "LINK_LOST")
    assert all(isinstance(m, Retreat) and str(m.owner) == "contact" and m.stiffness
               for m in after)
    heights = [height(drive, m.q) for m in after]
    lowest = int(np.argmin(heights))
    assert lowest * drive.period * 1e-9 <= STOP_S and heights[lowest] >= pressed - 1e-3
    assert drive.core.status().contact is ContactState.RETREATED
    assert heights[-1] >= start_z - 1e-3  # back at the height the descent began


def test_a_hold_card_stops_pressing_and_holds_softly_where_the_tool_is() -> None:
    drive = contact_core(link_loss="hold", link_loss_hold_factor=0.25)
    descending(drive)
    pressing = drive.motions[-1]
    drive.feed(LinkEvent, status="down")
    held = [drive.tick(follow=True) for _ in range(250)]
    assert drive.core.status().contact is ContactState.RELAXED
    assert all(isinstance(m, Setpoint) and str(m.owner) == "contact" for m in held)
    settled = round(SETTLE_S * 1e9 / drive.period)
    assert all(np.allclose(m.q, held[settled].q, atol=1e-9) for m in held[settled:])
    assert min(height(drive, m.q) for m in held) >= height(drive, pressing.q) - 1e-3
    assert np.allclose(held[0].stiffness, np.array(pressing.stiffness) * 0.25)
    assert np.allclose(held[0].damping, np.array(pressing.damping) * 0.5)


@pytest.mark.parametrize(("card", "needle"), [
    ({"link_loss": "let_go"}, "link_loss: unknown value 'let_go'"),
    ({"link_loss_hold_factor": 0}, "link_loss_hold_factor: must be positive"),
    ({"link_loss_hold_factor": 1.5}, "link_loss_hold_factor: must be at most 1"),
])
def test_a_bad_link_loss_key_is_refused_by_name(card: dict[str, Any], needle: str) -> None:
    with pytest.raises(ScenarioError, match=needle):
        contact_core(**card)
