"""The controller-side RTDE watchdog, as ur_rtde 1.6.5 provides it and as this driver uses it.

What the library does (its source and its uploaded ``rtde_control`` script, 1.6.5):

- ``setWatchdog(min_frequency)`` is script command 35, a blocking command (it waits for the
  script's "done"): ``rtde_set_watchdog("input_int_register_0", min_frequency, "stop")``
  (register 24 with the upper register range). From then on the controller stops the program
  when no RTDE input package carrying that register arrives within 1 / min_frequency. A stopped
  program is an ordinary program stop, not a safety stop: robot mode stays RUNNING, safety
  status NORMAL, runtime state becomes STOPPED and the program-running bit clears; the arm
  comes to rest under power. Watchdogs are removed when the program stops, and only then:
  there is no "disarm" short of stopping the program.
- Every command the library sends writes ``input_int_register_0`` (its command id; 0 for "no
  command"), so every streamed servoJ or speedJ is a kick at no extra cost.
- ``kickWatchdog()`` sends one package that writes 0 to that register (measured: a one-register
  recipe). The script reads 0 as "idle": a kick that reaches the controller in the same cycle
  as a servoJ hides that setpoint. Measured against the emulator, which runs the script's
  state machine: servoJ followed by kickWatchdog every 2 ms moved the arm 0.05 rad of a
  commanded 0.25. So the driver kicks only in write cycles that send no setpoint.
- Blocking commands (servoStop, speedStop, stopJ) send nothing while the arm decelerates,
  which takes longer than a watchdog of a few periods: around them the watchdog is lengthened
  to the driver's own bound on such a command (the controller is bringing the arm to rest
  itself meanwhile) and restored afterwards.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from assurance.reasons import ReasonCode
from drivers.base import DeviceFault
from drivers.ur_rtde import _sdk


class ControlWatchdog:
    """Whether the running control script has a watchdog armed, and at what frequency.

    Runs on the device thread with the link; callers check the link is fresh before any of the
    blocking calls (setWatchdog, stopScript wait for the script's answer)."""

    def __init__(self, device: str, host: str, blocking_bound_s: float) -> None:
        self.device, self.host = device, host
        self.blocking_bound_s = blocking_bound_s
        self.frequency_hz: float | None = None
        """The armed min_frequency; None: the running script has no watchdog (as far as the
        driver knows: after ``forget`` a new script is starting)."""

    @property
    def armed(self) -> bool:
        return self.frequency_hz is not None

    @property
    def timeout_s(self) -> float | None:
        return None if self.frequency_hz is None else 1.0 / self.frequency_hz

    def arm(self, control: _sdk.ControlInterface, frequency_hz: float) -> bool:
        """False: the script did not confirm it (not running, or a safety stop meanwhile)."""
        if not control.setWatchdog(frequency_hz):
            return False
        self.frequency_hz = frequency_hz
        return True

    def forget(self) -> None:
        """The script it belonged to has ended (or is being replaced)."""
        self.frequency_hz = None

    def disarm(self, control: _sdk.ControlInterface) -> None:
        """Stop the control script: the only way to remove a watchdog. The arm stays powered;
        the next activation uploads the script again."""
        if self.armed:
            control.stopScript()
            self.forget()

    @contextlib.contextmanager
    def lengthened(self, control: _sdk.ControlInterface) -> Iterator[None]:
        """Around a command that returns only once the arm is at rest.

        Lengthening is best effort: a script that does not take it (stopped, safety stop) has
        no watchdog to fire either, and the stop must go ahead regardless. Restoring is not:
        a running script left with the long watchdog raises DeviceFault (CONTROLLER_REJECT)."""
        armed = self.frequency_hz
        if armed is None:
            yield
            return
        control.setWatchdog(1.0 / self.blocking_bound_s)
        try:
            yield
        finally:
            # A script that stopped meanwhile took its watchdog with it.
            if control.isProgramRunning() and not control.setWatchdog(armed):
                raise DeviceFault(self.device, f"the control script on the arm at {self.host} "
                                  f"did not confirm setWatchdog({armed:g} Hz) after a stop",
                                  ReasonCode.CONTROLLER_REJECT)
