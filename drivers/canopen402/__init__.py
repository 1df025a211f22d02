"""CANopen CiA 402 servo drives (canopen + python-can), cyclic synchronous position mode.

``driver`` has the lifecycle hooks; ``bringup`` the blocking bring-up steps; ``cycle`` the bus
cycle (RPDOs + SYNC); ``drive_state`` the 402 state walks; ``health`` what the drives report
between calls (heartbeats, EMCY, TPDOs); ``watchdog`` the drives' watchdog on warden (warden's
heartbeat, each drive's consumer of it and its reaction to a lost connection); ``gripper`` the
gripper drive; ``targets`` the joints' CSP targets (where each command puts them);
``supervision`` the checks every call makes and the errors of a blocking step; ``link`` the only
code that builds canopen objects; ``tables``, ``units`` and ``settings`` CiA 301/402 as data,
unit conversions and the manifest table.

The driver is imported from ``drivers.canopen402.driver`` (as the registry names it), not from
here: the safety monitor imports this package's bus and table modules, and importing the
package must not load the driver and what it relies on of warden's core (the plausibility
check its readings go through, ``drivers.plausible``).
"""

from drivers.canopen402.settings import CiA402Settings

__all__ = ["CiA402Settings"]
