"""The LeRobot sidecar: warden's wire on one side, LeRobot's AsyncInference gRPC on the other.

LeRobot's PolicyServer (0.4.4 to 0.6.1 share its gRPC service) speaks pickles: the robot's
policy instructions and observations go as pickled LeRobot objects, and the actions come back
as a pickled ``list[TimedAction]`` with torch tensors inside. A process that unpickles a reply
with Python's own unpickler lets the server run any code it likes on the robot PC. The sidecar
keeps pickles away from warden: it writes its own (stand-ins that pickle under LeRobot's class
names, ``pickles.py``) and reads the replies with an unpickler that builds only what a reply may
hold (``replies.py``). It runs in its own venv (grpcio, NumPy, msgspec, websockets: no torch,
no LeRobot); warden connects to it as to any policy server of its own protocol.

``python -m sidecars.lerobot CONFIG.toml`` (``docs/protocol.md``, "LeRobot through the sidecar").
"""
