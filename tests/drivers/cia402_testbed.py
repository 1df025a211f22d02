"""The emulated arm the tests and the benchmark share, and the driver settings that match it.

Two joints are mounted reversed and every encoder has its own zero, so a sign or offset mistake
in the driver's unit conversion shows up as motion in the wrong place, not as a passing test.
Bus names are unique per call: parallel test runs on one machine must not hear each other.
Test support, not part of the emulator: it builds driver settings too.
"""

from __future__ import annotations

import uuid
from typing import Any

import msgspec

from drivers.base import ControlConfig
from drivers.canopen402.settings import CiA402Settings
from stubs.cia402_drive.emulator import EmulatorConfig, encoders_for

NODE_IDS = (1, 2, 3, 4, 5, 6)
COUNTS_PER_REV = 2**23
"""A 23-bit joint encoder: one count is 0.75 µrad, below the suite's 1e-6 rad tolerance."""
DIRECTIONS = (1, -1, 1, 1, -1, 1)
OFFSETS = (0, 1000, -5000, 123456, 0, 42)
GRIPPER_NODE = 7
"""The gripper drive, when a test asks for one: the next node id after the arm's, as in
manifests/sim-canopen.toml."""


TEST_WATCHDOG_MS = 1000
"""The drives' watchdog on warden in these tests: tests pause between writes (a real control
loop never does), and on the shared 2-core test machine a test process was once silent for
0.47 s; the watchdog tests set the default where they check it."""

TEST_PERIOD_NS = 4_000_000
"""250 Hz in tests: half the bus traffic of 500 Hz on a shared 2-core host; bench/ measures
the faster rates."""


def control(period_ns: int = TEST_PERIOD_NS) -> ControlConfig:
    return ControlConfig(dof=len(NODE_IDS), period_ns=period_ns, q_lower=(-6.28,) * 6,
                         q_upper=(6.28,) * 6, v_max=(3.14,) * 6)


def unique_virtual_channel() -> str:
    return f"cia402-{uuid.uuid4().hex}"


def emulator_config(interface: str, channel: str, udp_port: int = 43113,
                    node_ids: tuple[int, ...] = NODE_IDS,
                    gripper_node: int | None = None) -> EmulatorConfig:
    return EmulatorConfig(
        interface=interface, channel=channel, udp_port=udp_port, node_ids=node_ids,
        encoders=encoders_for(node_ids, COUNTS_PER_REV, DIRECTIONS[: len(node_ids)],
                              OFFSETS[: len(node_ids)]),
        gripper_node=gripper_node,
    )


def emulator_args(group: str, port: int, gripper_node: int | None = None) -> tuple[str, ...]:
    """Command-line arguments of ``python -m stubs.cia402_drive`` for the same arm."""
    gripper = () if gripper_node is None else ("--gripper-node", str(gripper_node))
    return ("--channel", group, "--port", str(port),
            "--nodes", ",".join(map(str, NODE_IDS)), "--counts-per-rev", str(COUNTS_PER_REV),
            "--directions", ",".join(map(str, DIRECTIONS)),
            "--offsets", ",".join(map(str, OFFSETS)), *gripper)


def driver_settings(interface: str, channel: str, udp_port: int = 43113,
                    **overrides: Any) -> CiA402Settings:
    """Settings matching the emulated arm, with timeouts wide enough for a busy 2-core host."""
    settings = CiA402Settings(
        interface=interface, channel=channel, udp_port=udp_port, node_ids=NODE_IDS,
        counts_per_rev=(float(COUNTS_PER_REV),) * len(NODE_IDS), direction=DIRECTIONS,
        offset_counts=OFFSETS, sdo_timeout_s=1.0, state_timeout_s=2.0,
        watchdog_ms=TEST_WATCHDOG_MS,
    )
    return msgspec.structs.replace(settings, **overrides)
