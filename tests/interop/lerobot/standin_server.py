"""A stand-in for LeRobot's PolicyServer, for ``make test``: the same gRPC service, answering
with reply bytes captured from the real one (``captured/``, ``capture_replies.py``) or with
whatever a test puts in their place.

Run in the sidecar's venv (grpcio, NumPy): ``python standin_server.py --replies DIR --record
FILE``. Written from LeRobot's service descriptor and ``policy_server.py``, never from the
sidecar: it parses the protobuf messages itself and reads the sidecar's pickles the way
LeRobot's server would (``lerobot_pickles.py``). Per observation it
answers ``GetActions`` with ``DIR/reply_<timestep>.pickle`` as ``Actions.data``, or ``Empty``
when there is no such file, as LeRobot's server answers when inference fails. Everything it
receives goes to ``FILE`` as JSON lines.
"""

from __future__ import annotations

import argparse
import json
import queue
import signal
import sys
import threading
from concurrent import futures
from pathlib import Path
from typing import Any

import grpc
import numpy as np
from lerobot_pickles import Record, unpickle  # beside this file: run as a script

SERVICE = "transport.AsyncInference"
OBSERVATION_WAIT_S = 2.0
"""LeRobot's default ``obs_queue_timeout``."""


def message_fields(message: bytes) -> dict[int, int | bytes]:
    """A protobuf message's varint and length-delimited fields, by number."""
    fields: dict[int, int | bytes] = {}
    at = 0

    def varint() -> int:
        nonlocal at
        value = shift = 0
        while True:
            byte = message[at]
            at += 1
            value |= (byte & 0x7F) << shift
            if byte < 0x80:
                return value
            shift += 7

    while at < len(message):
        key = varint()
        if key & 7 == 0:
            fields[key >> 3] = varint()
        elif key & 7 == 2:
            length = varint()
            fields[key >> 3] = message[at:at + length]
            at += length
        else:
            raise ValueError(f"wire type {key & 7} in a LeRobot message")
    return fields


class StandIn:
    def __init__(self, replies: Path, record: Path) -> None:
        self.replies, self.record_file = replies, record
        self.observations: queue.Queue[Record] = queue.Queue(maxsize=1)
        self.lock = threading.Lock()

    def record(self, **entry: Any) -> None:
        with self.lock, open(self.record_file, "a") as file:
            file.write(json.dumps(entry) + "\n")

    def ready(self, request: bytes, context: grpc.ServicerContext) -> bytes:
        self.observations = queue.Queue(maxsize=1)
        self.record(call="Ready")
        return b""

    def policy_instructions(self, request: bytes, context: grpc.ServicerContext) -> bytes:
        setup = unpickle(message_fields(request)[1])  # type: ignore[arg-type]
        self.record(call="SendPolicyInstructions", type=setup.name,
                    fields=json.loads(json.dumps(setup.fields, default=list)))
        return b""

    def observations_in(self, pieces: Any, context: grpc.ServicerContext) -> bytes:
        data, states = b"", []
        for piece in pieces:
            fields = message_fields(piece)
            states.append(fields.get(1, 0))
            data += fields.get(2, b"")  # type: ignore[operator]
        observation = unpickle(data)
        raw = observation.fields["observation"]
        self.record(call="SendObservations", type=observation.name, states=states,
                    timestamp=observation.fields["timestamp"],
                    timestep=observation.fields["timestep"],
                    must_go=observation.fields["must_go"],
                    values={key: _describe(value) for key, value in raw.items()})
        if self.observations.full():
            self.observations.get_nowait()
        self.observations.put(observation)
        return b""

    def get_actions(self, request: bytes, context: grpc.ServicerContext) -> bytes:
        try:
            observation = self.observations.get(timeout=OBSERVATION_WAIT_S)
        except queue.Empty:
            self.record(call="GetActions", answered="Empty (no observation)")
            return b""
        reply = self.replies / f"reply_{observation.fields['timestep']}.pickle"
        if not reply.exists():
            self.record(call="GetActions", answered="Empty (no reply file)")
            return b""
        data = reply.read_bytes()
        self.record(call="GetActions", answered=reply.name)
        return b"\x0a" + _varint(len(data)) + data


def _describe(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return {"dtype": str(value.dtype), "shape": list(value.shape),
                "sum": int(value.astype(np.int64).sum())}
    return value


def _varint(value: int) -> bytes:
    out = bytearray()
    while value >= 0x80:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    return bytes([*out, value])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--replies", type=Path, required=True)
    parser.add_argument("--record", type=Path, required=True)
    args = parser.parse_args()
    standin = StandIn(args.replies, args.record)
    handler = grpc.method_handlers_generic_handler(SERVICE, {
        "Ready": grpc.unary_unary_rpc_method_handler(standin.ready),
        "SendPolicyInstructions": grpc.unary_unary_rpc_method_handler(
            standin.policy_instructions),
        "SendObservations": grpc.stream_unary_rpc_method_handler(standin.observations_in),
        "GetActions": grpc.unary_unary_rpc_method_handler(standin.get_actions),
    })
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4), handlers=[handler])
    port = server.add_insecure_port(f"127.0.0.1:{args.port}")
    server.start()
    print(f"READY {json.dumps({'port': port})}", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    stop.wait()
    server.stop(grace=0.5).wait()
    sys.exit(0)


if __name__ == "__main__":
    main()
