"""CANopen CiA 402 servo drives (canopen + python-can), cyclic synchronous position mode."""

from drivers.canopen402.driver import CiA402Driver
from drivers.canopen402.settings import CiA402Settings

__all__ = ["CiA402Driver", "CiA402Settings"]
