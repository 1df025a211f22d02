"""A driver for an in-process plant (MuJoCo or kinematic), with injectable device faults.

The plant is stepped by whoever owns time: the lockstep cell (virtual clock) or a real-time
stepper (wall clock). The driver only commands and reads, exactly as a vendor driver would, so
the kernel cannot tell it from a real device. What it needs of a plant is ``plant.SimulatedPlant``.
"""

from __future__ import annotations

import contextlib
import threading
import time
from dataclasses import dataclass
from typing import Any

from assurance.reasons import ReasonCode
from drivers.base import (
    Applied,
    Command,
    CommandKind,
    ControlConfig,
    DeviceFault,
    Driver,
    DriverInitError,
    NotConnected,
    StateSample,
)
from drivers.sim.plant import SimulatedPlant


@dataclass(slots=True)
class SimFaults:
    """Faults a test can switch on; the driver reports them as a real device would."""

    estop: bool = False
    protective_stop: bool = False
    disconnected: bool = False
    reject_writes: bool = False


class SimDriver(Driver):
    """The in-process plant. Its ``[driver]`` table takes no keys (``NoSettings``); the plant
    comes from the world that steps it, so it is built by the world, not from settings."""

    capabilities = frozenset({CommandKind.POSITION, CommandKind.VELOCITY, CommandKind.HOLD,
                              CommandKind.STOP, CommandKind.IMPEDANCE})
    default_name = "sim"

    @classmethod
    def from_settings(cls, settings: Any, name: str | None = None) -> SimDriver:
        raise DriverInitError(name or cls.default_name, "the simulated driver is built by its "
                              "world, around the plant the world steps")

    @staticmethod
    def device_watchdog(settings: Any) -> str:
        """Simulation: warden itself."""
        return "none needed: the simulated plant runs in warden's process and stops with it"

    @staticmethod
    def device_watchdog_ms(settings: Any, control_period_ms: float) -> float:
        return 0.0

    def __init__(
        self, plant: SimulatedPlant, name: str = "sim", lock: threading.Lock | None = None,
        faults: SimFaults | None = None,
    ) -> None:
        self.name = name
        self.plant = plant
        self.faults = faults or SimFaults()
        self._lock = lock or contextlib.nullcontext()
        self._connected = False
        self._control: ControlConfig | None = None
        self._seq = 0

    async def connect(self) -> None:
        if self.faults.disconnected:
            raise DriverInitError(self.name, "plant not reachable (disconnected)")
        self._connected = True

    async def configure(self, control: ControlConfig) -> None:
        if control.dof != self.plant.dof:
            raise DriverInitError(
                self.name, f"manifest says {control.dof} joints, plant has {self.plant.dof}"
            )
        self._control = control

    async def activate(self) -> None:
        self._check_link()
        with self._lock:
            self.plant.hold()

    async def read(self) -> StateSample:
        self._check_link()
        self._check_device()
        with self._lock:
            state = self.plant.state()
        self._seq += 1
        return StateSample(
            seq=self._seq, t_mono_ns=time.monotonic_ns(), source=self.name, q=state.q,
            qd=state.qd, effort=state.effort, wrench=state.wrench, gripper=state.gripper,
        )

    async def write(self, command: Command) -> Applied:
        self._check_link()
        self._check_device()
        if self.faults.reject_writes:
            return Applied(kind=command.kind, t_mono_ns=time.monotonic_ns(), accepted=False,
                           reason=ReasonCode.CONTROLLER_REJECT)
        q = self._clip(command.q) if command.q else ()
        with self._lock:
            self._apply(command, q)
        return Applied(kind=command.kind, t_mono_ns=time.monotonic_ns(), q=q, qd=command.qd)

    async def hold(self) -> Applied:
        self._check_link()
        with self._lock:
            self.plant.hold()
            q = self.plant.state().q
        return Applied(kind=CommandKind.HOLD, t_mono_ns=time.monotonic_ns(), q=q)

    async def deactivate(self) -> None:
        if self._connected:
            with self._lock:
                self.plant.hold()

    async def aclose(self) -> None:
        self._connected = False

    def _apply(self, command: Command, q: tuple[float, ...]) -> None:
        if command.kind is CommandKind.POSITION:
            self.plant.command_position(q)
        elif command.kind is CommandKind.IMPEDANCE:
            self.plant.command_impedance(q, command.stiffness, command.damping)
        elif command.kind is CommandKind.VELOCITY:
            self.plant.command_velocity(command.qd)
        else:  # HOLD and STOP both bring the plant to rest where it is
            self.plant.hold()
        if command.gripper is not None:
            self.plant.command_gripper(command.gripper)

    def _clip(self, q: tuple[float, ...]) -> tuple[float, ...]:
        if self._control is None:
            return q
        low, high = self._control.q_lower, self._control.q_upper
        return tuple(min(max(v, lo), hi) for v, lo, hi in zip(q, low, high, strict=True))

    def _check_link(self) -> None:
        if not self._connected:
            raise NotConnected(self.name, "not connected")
        if self.faults.disconnected:
            raise NotConnected(self.name, "plant link lost")

    def _check_device(self) -> None:
        if self.faults.estop:
            raise DeviceFault(self.name, "emergency stop pressed", ReasonCode.E_STOP)
        if self.faults.protective_stop:
            raise DeviceFault(self.name, "protective stop", ReasonCode.CONTROLLER_FAULT)
