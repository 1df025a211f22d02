"""Capture what a real LeRobot 0.4.4 PolicyServer answers, for the sidecar's tests.

Run inside the LeRobot venv (``interop.py``'s ``lerobot_python()`` builds it), from the
repository's root, against a server started with ``lerobot_side.py serve`` serving the ACT of
``lerobot_side.py make-policy build/lerobot-act``::

    PYTHONPATH=tests/interop/lerobot OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1 <lerobot python> \
        tests/interop/lerobot/capture_replies.py --port 8080 --policy build/lerobot-act \
        --out tests/interop/lerobot/captured --server-command "..."

It talks the way LeRobot's own ``RobotClient`` does, with LeRobot's own classes and generated
gRPC stub: ``Ready``, ``SendPolicyInstructions`` (a pickled ``RemotePolicyConfig``), then per
observation a ``SendObservations`` stream (a pickled ``TimedObservation``, ``must_go`` set) and
a ``GetActions``. It writes every reply's bytes exactly as they arrived, the policy-setup
pickle it sent, and ``provenance.json``: versions, the server's command line, what each
observation carried (timestamps, timesteps, the state) and each reply decoded by torch itself,
so the sidecar's own decoder is judged against torch's.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle  # the real client's own format: this is what the sidecar has to read
import platform
import sys
import time
from importlib.metadata import version
from pathlib import Path

import grpc
import lerobot_side
import numpy as np
from lerobot.async_inference.helpers import RemotePolicyConfig, TimedObservation
from lerobot.transport import services_pb2, services_pb2_grpc
from lerobot.transport.utils import send_bytes_in_chunks

JOINT_NAMES = tuple(f"joint_{index}.pos" for index in range(lerobot_side.JOINTS))
STATES = ((0.0, -1.2, 1.4, -1.6, -1.57, 0.0), (0.05, -1.15, 1.35, -1.6, -1.57, 0.1))
MEASURED_NS = (12_345_678_901_234, 12_346_178_901_234)
"""When each state was measured on a robot's monotonic clock, in ns: the sidecar sends
``t / 1e9`` (not ``time.time()``) and counts timesteps from 0, so a test can send the same."""


def features() -> dict[str, dict]:
    """What ``hw_to_dataset_features`` makes of a robot with six joints and two cameras."""
    found: dict[str, dict] = {"observation.state": {
        "dtype": "float32", "shape": (len(JOINT_NAMES),), "names": list(JOINT_NAMES)}}
    for camera in lerobot_side.CAMERAS:
        found[f"observation.images.{camera}"] = {
            "dtype": "image", "shape": (lerobot_side.SIDE, lerobot_side.SIDE, 3),
            "names": ["height", "width", "channels"]}
    return found


def observation(index: int, rng: np.random.Generator) -> TimedObservation:
    raw: dict[str, object] = dict(zip(JOINT_NAMES, STATES[index], strict=True))
    for camera in lerobot_side.CAMERAS:
        raw[camera] = rng.integers(0, 256, (lerobot_side.SIDE, lerobot_side.SIDE, 3), np.uint8)
    raw["task"] = "insert the peg"
    return TimedObservation(timestamp=MEASURED_NS[index] / 1e9, timestep=index,
                            observation=raw, must_go=True)


def protobuf_examples(replies: list[bytes]) -> dict[str, str]:
    """Messages as protobuf's own generated code serializes them (hex), for the sidecar's hand
    encoding to be compared with byte for byte."""
    state = services_pb2.TransferState
    pieces = {
        "empty": services_pb2.Empty(),
        "policy_setup": services_pb2.PolicySetup(data=b"setup"),
        "observation_begin": services_pb2.Observation(transfer_state=state.TRANSFER_BEGIN,
                                                      data=b"\x00" * 300),
        "observation_middle": services_pb2.Observation(transfer_state=state.TRANSFER_MIDDLE,
                                                       data=b"m"),
        "observation_end": services_pb2.Observation(transfer_state=state.TRANSFER_END,
                                                    data=b"end"),
    }
    examples = {name: message.SerializeToString().hex() for name, message in pieces.items()}
    reply = services_pb2.Actions(data=replies[0]).SerializeToString()
    examples["actions_reply_0_before_data"] = reply[:len(reply) - len(replies[0])].hex()
    return examples


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--policy", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--server-command", default="")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    channel = grpc.insecure_channel(f"127.0.0.1:{args.port}")
    stub = services_pb2_grpc.AsyncInferenceStub(channel)
    stub.Ready(services_pb2.Empty())
    setup = pickle.dumps(RemotePolicyConfig(
        policy_type="act", pretrained_name_or_path=args.policy, lerobot_features=features(),
        actions_per_chunk=50, device="cpu"))
    (args.out / "policy_setup.pickle").write_bytes(setup)
    stub.SendPolicyInstructions(services_pb2.PolicySetup(data=setup))
    rng = np.random.default_rng(lerobot_side.SEED)
    replies, replies_data = [], []
    for index in range(len(STATES)):
        sent = observation(index, rng)
        stub.SendObservations(send_bytes_in_chunks(pickle.dumps(sent), services_pb2.Observation))
        started = time.perf_counter()
        data = stub.GetActions(services_pb2.Empty()).data
        elapsed = time.perf_counter() - started
        name = f"reply_{index}.pickle"
        (args.out / name).write_bytes(data)
        replies_data.append(data)
        chunk = pickle.loads(data)  # torch's own reading, the reference for the sidecar's
        replies.append({
            "file": name, "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data),
            "observation": {"timestamp": sent.timestamp, "measured_ns": MEASURED_NS[index],
                            "timestep": sent.timestep, "state": list(STATES[index])},
            "get_actions_s": round(elapsed, 3),
            "timestamps": [action.timestamp for action in chunk],
            "timesteps": [action.timestep for action in chunk],
            "actions": [action.action.tolist() for action in chunk],
            "dtype": str(chunk[0].action.dtype),
        })
    provenance = {
        "captured": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "python": platform.python_version(), "platform": platform.platform(),
        "versions": {name: version(name) for name in ("lerobot", "torch", "grpcio", "protobuf",
                                                      "numpy")},
        "server_command": args.server_command, "policy": "act, randomly initialised, seed "
        f"{lerobot_side.SEED}, made by lerobot_side.py make-policy",
        "client": "capture_replies.py with LeRobot's own RemotePolicyConfig, TimedObservation, "
                  "send_bytes_in_chunks and AsyncInferenceStub",
        "features": features(), "policy_setup": {"file": "policy_setup.pickle",
                                                 "sha256": hashlib.sha256(setup).hexdigest()},
        "replies": replies, "protobuf": protobuf_examples(replies_data),
    }
    (args.out / "provenance.json").write_text(json.dumps(provenance, indent=1) + "\n")
    print(f"captured {len(replies)} replies into {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
