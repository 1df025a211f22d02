"""A Dynamixel Protocol 2.0 bus of X-series servos on a pseudo-terminal, backed by a plant.

Run it as ``python -m stubs.dynamixel_bus --ids 1,2,3,4,5,6``: it prints
``READY {"port": "/dev/pts/N", "fault_port": P}`` once the pty answers. ``--gripper-id N``
adds one more servo that drives the plant's gripper instead of a joint. The real
``dynamixel_sdk`` opens ``port`` like a U2D2 adapter. Faults are injected over ``fault_port``
(:func:`stubs.fault_control.inject`): ``silent``, ``crc``, ``hardware_error``, ``clear``;
``peek`` reads one control-table item, ``motion`` counts the goal writes each servo applied
with torque on (the commands that can move it). Each servo runs its Bus Watchdog (98) as the
e-Manual describes (``watchdog``).

The codec here (``crc``, ``packet``) and the control table (``control_table``) are written from
the Robotis e-Manual, independently of ``drivers.dynamixel``: an emulator that shared the
driver's tables would hide the driver's mistakes instead of catching them.
"""
