"""warden's policy link as a policy server speaks it, written from ``docs/protocol.md``.

The server's side of the wire (frames, handshake, chunk envelope, TLS and token checks), kept
apart from warden's own codec (``kernel/wire.py``) so that a mistake in one side is caught by
the other in the cross-check tests instead of being copied. Two programs stand on it: the
reference policy server (``stubs/policy_server``) and the LeRobot sidecar
(``sidecars/lerobot``), which runs in its own small venv: this package imports only msgspec,
NumPy and websockets, never another warden package.
"""
