"""Settings of one Dynamixel bus (a manifest's ``[drivers.<name>]`` table)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Annotated

from msgspec import Meta

from drivers.dynamixel.tables import (
    BAUD_RATES,
    BUS_WATCHDOG_MAX_UNITS,
    BUS_WATCHDOG_UNIT_S,
    GOAL_CURRENT_MAX_UNITS,
    POSITION_MODE_TICKS,
)
from drivers.settings import Settings

SIX_SERVO_ARM_IDS = (1, 2, 3, 4, 5, 6)
GRIPPER_MAX_OPENING_M = 0.085
"""Opening between the pads (m) at ``gripper_open_ticks``; commands are clipped to [0, this]."""
OFFSET_MAX_RAD = 2 * math.pi
"""``offsets_rad`` is a shaft angle: one turn either way is more than a position-mode servo
has (its ticks span one turn around the centre)."""
MAX_RETRIES = 10
MAX_WATCHDOG_PERIODS = 10_000
"""A generous cap; the exact one (127 units of 20 ms) needs the control period (configure)."""
ServoId = Annotated[int, Meta(ge=0, le=252)]
Tick = Annotated[int, Meta(ge=POSITION_MODE_TICKS[0], le=POSITION_MODE_TICKS[1])]
"""A position-mode Goal/Present Position."""

# Every float setting is finite, above its low bound and at most its high one: a second of
# packet latency is a broken adapter; a device call over a minute is a hung one; the X series
# counts 1 to 2.69 mA per current unit and 1 to 3 N·m per ampere.


class DynamixelSettings(Settings, frozen=True):
    port: str
    """Serial device of the adapter (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, a pty)."""
    baud: int = 1_000_000
    """Must be in dynamixel_sdk's fixed list and match every servo's Baud Rate (address 8)."""
    ids: tuple[ServoId, ...] = SIX_SERVO_ARM_IDS
    """Servo id of each joint, in joint order."""
    offsets_rad: tuple[Annotated[float, Meta(ge=-OFFSET_MAX_RAD, le=OFFSET_MAX_RAD)], ...] = (
        (0.0,) * len(SIX_SERVO_ARM_IDS))
    """Per joint: the shaft angle (rad from centre tick 2048) at which the joint reads zero."""
    directions: tuple[int, ...] = (1,) * len(SIX_SERVO_ARM_IDS)
    """Per joint: +1, or -1 for a servo mounted the other way round."""
    latency_budget_ms: Annotated[float, Meta(gt=0.0, le=1000.0)] = 34.0
    """Added to the wire time of every packet timeout. The SDK hard-codes 34 ms (a 16 ms FTDI
    latency timer, twice, plus 2); with the latency timer set to 1 ms, 4 ms is enough."""
    retries: Annotated[int, Meta(ge=0, le=MAX_RETRIES)] = 2
    """Extra attempts after a timed-out or corrupt reply before the link counts as lost."""
    call_timeout_s: Annotated[float, Meta(gt=0.0, le=60.0)] = 1.0
    """Deadline of one call on the device thread, retries and diagnosis included."""
    fast_sync_read: bool = True
    """Try Fast Sync Read (0x8A) first; falls back to Sync Read if the servos do not answer."""
    current_unit_ma: Annotated[float, Meta(gt=0.01, le=100.0)] = 2.69
    """mA per Present Current count: 2.69 on XM430/XM540, 1.0 on XL330."""
    torque_per_amp_nm: Annotated[float, Meta(gt=0.0, le=100.0)] = 1.78
    """Torque constant used to report effort (XM430-W350 at 12 V: 4.1 N·m at 2.3 A)."""
    gripper_id: ServoId | None = None
    """Servo id of the gripper (not one of ``ids``); None: this bus has no gripper."""
    gripper_open_ticks: Tick = 2048
    """Goal/Present Position at the fully open opening (0.085 m). The defaults assume an XM430
    gripper assembled open at the shaft's centre tick that closes over a quarter turn (1024
    ticks, about 0.08 mm of opening per tick); they are not a vendor figure: read both ends off
    your gripper with Dynamixel Wizard and set them."""
    gripper_closed_ticks: Tick = 3072
    """Goal/Present Position at opening 0.0 m (pads touching); may be below the open ticks for a
    servo that closes the other way round. Openings map linearly between the two."""
    gripper_current_ma: Annotated[float, Meta(gt=0.0)] = 300.0
    """Current the gripper squeezes with: its Goal Current in current-based position mode. A
    grasp stalls the fingers short of their goal and draws this much, not the Current Limit
    (an XM430 at 300 mA squeezes with roughly a quarter of its stall torque). Set it for the
    part: too little lets it slip, too much crushes it or trips the overload alert."""

    watchdog_periods: Annotated[int, Meta(ge=0, le=MAX_WATCHDOG_PERIODS)] = 10
    """Bus Watchdog (98) of every servo: they stop (and refuse goals until re-activated) when no
    instruction packet reaches them for this many control periods. Rounded up to the servo's
    20 ms unit, and never shorter than one retried packet (``latency_budget_ms`` plus a period),
    so that one lost reply cannot stop the arm: 120 ms at 125 Hz with a 100 ms budget. Armed by
    the first setpoint after activation, disabled on deactivate; 0 switches it off."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.port:
            raise ValueError("port: empty; name the serial device of the U2D2/adapter")
        if not self.ids:
            raise ValueError("ids: no servos listed")
        if len(set(self.ids)) != len(self.ids):
            raise ValueError(f"ids: need distinct servo ids in 0..252, got {list(self.ids)}")
        for key, values in (("offsets_rad", self.offsets_rad), ("directions", self.directions)):
            if len(values) != len(self.ids):
                raise ValueError(f"{key}: {len(values)} values for {len(self.ids)} servo ids")
        if any(d not in (1, -1) for d in self.directions):
            raise ValueError(f"directions: each must be 1 or -1, got {list(self.directions)}")
        if self.baud not in BAUD_RATES:
            raise ValueError(f"baud: {self.baud} is not a rate both dynamixel_sdk and the X "
                             f"series support (one of {', '.join(map(str, BAUD_RATES))})")
        self._check_gripper()

    @property
    def gripper_current_units(self) -> int:
        """``gripper_current_ma`` in Goal Current units (``current_unit_ma`` each)."""
        return round(self.gripper_current_ma / self.current_unit_ma)

    def watchdog_units(self, period_s: float) -> int:
        """Bus Watchdog value for this control period (0: off; see ``watchdog_periods``).

        Raises:
            ValueError: it would exceed the servo's 127 units (2.54 s).
        """
        if self.watchdog_periods == 0:
            return 0
        seconds = max(self.watchdog_periods * period_s, self.latency_budget_ms / 1e3 + period_s)
        units = math.ceil(seconds / BUS_WATCHDOG_UNIT_S - 1e-9)
        if units > BUS_WATCHDOG_MAX_UNITS:
            raise ValueError(
                f"watchdog_periods: {self.watchdog_periods} periods of {period_s * 1e3:g} ms "
                f"(or one retried packet) is {seconds:.3f} s, more than the Bus Watchdog's "
                f"{BUS_WATCHDOG_MAX_UNITS * BUS_WATCHDOG_UNIT_S:.2f} s; lower it")
        return units

    @property
    def all_ids(self) -> tuple[int, ...]:
        """Every servo on the bus: the joints in joint order, then the gripper if there is one."""
        return self.ids if self.gripper_id is None else (*self.ids, self.gripper_id)

    def _check_gripper(self) -> None:
        if self.gripper_id is not None and self.gripper_id in self.ids:
            raise ValueError(f"gripper_id: {self.gripper_id} is also a joint in `ids` "
                             f"{list(self.ids)}; the gripper needs its own servo id")
        ceiling_ma = (GOAL_CURRENT_MAX_UNITS + 1) * self.current_unit_ma  # before dividing
        if not (math.isfinite(self.gripper_current_ma) and 0 < self.gripper_current_ma
                <= ceiling_ma and 0 < self.gripper_current_units <= GOAL_CURRENT_MAX_UNITS):
            raise ValueError(f"gripper_current_ma: must be above 0 and at most "
                             f"{GOAL_CURRENT_MAX_UNITS * self.current_unit_ma:.0f} mA "
                             f"({GOAL_CURRENT_MAX_UNITS} units of {self.current_unit_ma} mA), "
                             f"got {self.gripper_current_ma}")
        if self.gripper_open_ticks == self.gripper_closed_ticks:
            raise ValueError(f"gripper_closed_ticks: equals gripper_open_ticks "
                             f"({self.gripper_open_ticks}); open and closed need distinct ticks")


def device_identity(settings: DynamixelSettings) -> str:
    """The serial bus ``settings`` address: its port with symlinks resolved, so
    ``/dev/serial/by-id/...`` and the ``/dev/ttyUSB0`` it points at are one bus."""
    return f"Dynamixel bus {os.path.realpath(settings.port)}"


def device_watchdog(settings: DynamixelSettings) -> str | None:
    """What stops the arm when warden's commands stop, as ``settings`` configure it; None: off."""
    if settings.watchdog_periods <= 0:
        return None
    return (f"every servo's Bus Watchdog: no instruction packet for {settings.watchdog_periods} "
            "control periods and it stops")


def device_watchdog_ms(settings: DynamixelSettings, control_period_ms: float) -> float | None:
    """How long after warden's last command :func:`device_watchdog` stops the arm, in ms;
    None: off."""
    if settings.watchdog_periods <= 0:
        return None
    return settings.watchdog_periods * control_period_ms


ADDRESS_KEYS: Mapping[str, str] = {"port": "/dev/null"}
"""The settings that say where the device is, with placeholders (``Driver.address_keys``)."""
