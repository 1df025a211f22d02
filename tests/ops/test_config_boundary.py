"""One definition per knob and per box (issue 16, item 1): the same box and the same wrist force
are judged by the same rule wherever a file writes them, and ``[policy]`` is one type the link
holds as read. Loader-only: nothing is started.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgspec
import pytest

from kernel.manifest import load_manifest
from kernel.scenario.config import build_config
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
