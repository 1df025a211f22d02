"""Plants: what an emulator drives. ``base`` has the protocol and a kinematic stand-in."""
