"""Emulated CiA 402 servo drives on CANopen, for the canopen402 driver (see emulator.py; what a
drive does when its master goes away: supervision.py)."""

from stubs.cia402_drive.drive import EmulatedDrive
from stubs.cia402_drive.emulator import DriveEmulator, EmulatorConfig, encoders_for
from stubs.cia402_drive.encoders import Encoder, LinearEncoder

__all__ = ["DriveEmulator", "EmulatedDrive", "EmulatorConfig", "Encoder", "LinearEncoder",
           "encoders_for"]
