"""What a run computes from settings it accepted, without starting anything.

A setting that passes its checks is used in arithmetic once the device and the policy server
are up: rates become token buckets, timeouts become nanoseconds, encoder scales become counts.
An ``inf`` that slips through fails there, with a traceback, after the plant has moved. The
property tests call :func:`use_policy` and :func:`use_driver_settings` on whatever the loaders
accept; each does the same computations the run does (the same functions where they are pure),
and an exception other than the documented period-dependent refusals is a bug.
"""

from __future__ import annotations

from typing import Any

from assurance.clock import ms_to_ns
from drivers.canopen402.bringup import bus_load
from drivers.canopen402.settings import CiA402Settings
from drivers.dynamixel.driver import DynamixelDriver
from drivers.dynamixel.settings import DynamixelSettings
from drivers.ur_rtde.settings import URSettings
from kernel.shell.link_budget import AdmissionPacer
from kernel.shell.link_protocol_budget import RequestWindow, TokenBucket
from kernel.shell.link_settings import PolicySettings
from kernel.shell.link_types import ClientConfig

DRIVER_SETTINGS: dict[str, type] = {
    "ur_rtde": URSettings, "dynamixel": DynamixelSettings, "canopen402": CiA402Settings,
}
ADDRESS_STAND_INS: dict[str, dict[str, Any]] = {
    "ur_rtde": {"host": "127.0.0.1"},
    "dynamixel": {"port": "/dev/null"},
    "canopen402": {"interface": "udp_multicast", "channel": "239.0.0.1"},
}
"""What an emulator fills in (as ``stubs.cell.emulated`` stands them in before it starts)."""


def use_policy(policy: PolicySettings, period_ns: int) -> None:
    """The policy link's budget, as ``kernel.app.live`` and ``kernel.shell.client`` build it."""
    timing = ClientConfig(url="ws://127.0.0.1:1", policy=policy).timing
    TokenBucket(timing.max_frames_per_s)
    TokenBucket(timing.max_chunks_per_s)
    RequestWindow(timing.max_requests_in_flight, timing.request_timeout_ns)
    assert 0 < timing.heartbeat_interval_ns < timing.heartbeat_timeout_ns
    AdmissionPacer(policy.admissions_per_period, period_ns // 2)
    ms_to_ns(policy.link_loss_bound_ms)


def use_driver_settings(settings: Any, period_s: float) -> None:
    """The driver's derived numbers at ``period_s``. A ``ValueError`` that only the control
    period can reveal (a watchdog too long for it) is the driver's refusal at configure."""
    if isinstance(settings, CiA402Settings):
        for scale in settings.joint_scales():
            scale.to_rad(scale.to_counts(0.0))
            scale.torque_to_nm(1000, 1000)
        settings.gripper_scale().to_counts(0.085)
        int(settings.counts_per_rev[0])  # the emulator's --counts-per-rev
        interval_s = settings.heartbeat_interval_s(period_s)
        bus_load(len(settings.drive_ids), period_s, settings.bitrate, interval_s)
        try:
            settings.check_watchdog(period_s)
        except ValueError as error:
            assert str(error).startswith("watchdog_ms:"), error
    elif isinstance(settings, DynamixelSettings):
        DynamixelDriver(settings)  # the calibration and the position-mode range
        assert settings.gripper_current_units > 0
        try:
            settings.watchdog_units(period_s)
        except ValueError as error:
            assert str(error).startswith("watchdog_periods:"), error
    elif isinstance(settings, URSettings):
        assert 0 < settings.stall_after_s < settings.call_timeout_s
        settings.watchdog_frequency_hz(period_s)
    else:
        raise TypeError(f"no use for {type(settings).__name__}")
