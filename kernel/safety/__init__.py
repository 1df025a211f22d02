"""The independent safety monitor: ``warden safety MANIFEST`` (docs/operations.md, "Safety
monitor").

A process of its own, beside warden: its own connection to the device where the device allows
a second one, its own stop path, its own checks of joints, speeds and wrist force against the
manifest's limits and of the arm's place against ``[geometry]`` (its own MuJoCo model), and
warden's heartbeat. None of warden's core, gates, motion layer or
driver control code runs in it (the CiA 402 listener takes the driver's settings, bus opening,
PDO mapping and unit conversion: data and arithmetic); it reads the manifest through its own
view (:mod:`kernel.safety.view`) with the parsers warden's loader uses for those tables (the
very limits warden was given), and imports nothing of warden's core (tests/test_layers.py).
"""
