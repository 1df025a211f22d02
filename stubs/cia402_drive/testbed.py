"""Kept only because kernel/cell/emulated.py imports ``unique_udp_bus`` from here.

The emulated test arm (driver settings included) moved to tests/drivers/cia402_testbed.py: an
emulator package must not build drivers. Delete this module once kernel/cell/emulated.py imports
``stubs.cia402_drive.launch`` instead.
"""

from stubs.cia402_drive.launch import unique_udp_bus

__all__ = ["unique_udp_bus"]
