"""An emulated Universal Robots e-Series controller that the real ``ur_rtde`` library talks to.

Run it as a separate process (``python -m stubs.ur_controller --host 127.0.0.2``): ur_rtde's
constructors hold the GIL, so a client and an emulator in one process deadlock. It serves RTDE
(30004, any number of independent clients), the dashboard (29999; its ``stop`` decelerates the
arm, see ``program_stop``) and the script port (30003) on one loopback address, runs the
register handshake of ur_rtde's uploaded ``rtde_control`` program over a plant (with the RTDE
watchdog its ``setWatchdog`` arms, see ``watchdog``), switches its
digital outputs for RTDE clients (ur_rtde's IO interface) with a two-finger gripper wired to tool
output 0 and standard analog input 0, and takes faults on a line-JSON control port.
:mod:`stubs.ur_controller.launch` finds a free 127.0.0.x and starts one.
"""
