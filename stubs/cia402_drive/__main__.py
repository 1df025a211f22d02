"""Run emulated CiA 402 drives as a process: ``python -m stubs.cia402_drive --channel ...``.

Prints ``READY {json}`` (fault port, bus, nodes) once the drives have booted, then serves the
bus until SIGTERM/SIGINT. Faults arrive on a loopback line-JSON port (stubs.fault_control):
``emcy`` (node, code), ``heartbeat_stop`` (node), ``quick_stop`` (node), ``ignore_mode`` (node),
``clear``; the same port answers ``drives`` (each drive's 402 and NMT state, heartbeat consumer,
abort connection option and the lost connections it reacted to), ``motion`` (the motion
commands each drive was given: see ``EmulatedDrive.motion_commands``) and the plant's
``ground_truth``. With ``--gripper-node N`` one more drive (node N) moves the plant's gripper:
its CSP target is the opening in counts (``--gripper-counts-per-m``), and faults name it like a
joint.
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
from typing import Any

from stubs.child import wait_for_stop_signal
from stubs.cia402_drive.bus_claim import BusInUse
from stubs.cia402_drive.emulator import (
    GRIPPER_COUNTS_PER_M,
    MAX_PROFILE_VELOCITY_RAD_S,
    DriveEmulator,
    EmulatorConfig,
    encoders_for,
)
from stubs.fault_control import FaultControlServer
from stubs.plant.base import Plant
from stubs.plant.world_port import world_handlers


def _ints(text: str) -> tuple[int, ...]:
    return tuple(int(part, 0) for part in text.split(",") if part.strip())


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m stubs.cia402_drive", description=__doc__)
    parser.add_argument("--interface", default="udp_multicast",
                        help="python-can interface (udp_multicast across processes)")
    parser.add_argument("--channel", required=True, help="multicast group, e.g. 239.0.0.1")
    parser.add_argument("--port", type=int, default=43113, help="udp_multicast port")
    parser.add_argument("--nodes", type=_ints, default=(1, 2, 3, 4, 5, 6),
                        help="node ids, one drive per joint in joint order")
    parser.add_argument("--plant", choices=("kinematic", "mujoco"), default="kinematic")
    parser.add_argument("--counts-per-rev", type=int, default=2**23)
    parser.add_argument("--directions", type=_ints, default=(),
                        help="1 or -1 per joint (default all 1)")
    parser.add_argument("--offsets", type=_ints, default=(), help="counts at q = 0 per joint")
    parser.add_argument("--gripper-node", type=int, default=None,
                        help="node id of a gripper drive (position = opening); default none")
    parser.add_argument("--gripper-counts-per-m", type=float, default=GRIPPER_COUNTS_PER_M,
                        help="gripper position counts per metre of opening")
    parser.add_argument("--max-profile-velocity", type=float, default=MAX_PROFILE_VELOCITY_RAD_S,
                        help="every joint drive's 0x607F, in rad/s (reported, not enforced)")
    parser.add_argument("--fault-port", type=int, default=0, help="0: any free port")
    return parser.parse_args(argv)


def make_plant(name: str) -> Plant | None:
    """None means the emulator's default kinematic plant; MuJoCo is imported only if asked."""
    if name == "kinematic":
        return None
    from stubs.plant.mujoco_plant import MujocoPlant

    return MujocoPlant()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    config = EmulatorConfig(
        interface=args.interface, channel=args.channel, udp_port=args.port,
        node_ids=args.nodes,
        encoders=encoders_for(args.nodes, args.counts_per_rev, args.directions, args.offsets),
        gripper_node=args.gripper_node, gripper_counts_per_m=args.gripper_counts_per_m,
        max_profile_velocity=args.max_profile_velocity,
    )
    try:
        emulator = DriveEmulator(config, make_plant(args.plant)).start()
    except BusInUse as error:
        print(f"cia402_drive: {error}", file=sys.stderr)
        return 2
    gc.freeze()  # object dictionaries and the plant live forever: keep full GC passes short
    handlers = {name: _handler(emulator, name) for name in emulator.faults}
    handlers.update(world_handlers(emulator.plant, emulator.lock))
    handlers["drives"] = lambda _: {"drives": emulator.report()}
    handlers["motion"] = lambda _: emulator.motion()
    faults = FaultControlServer("127.0.0.1", args.fault_port, handlers).start()
    ready = {"fault_port": faults.address[1], "interface": args.interface,
             "channel": args.channel, "port": args.port, "nodes": list(args.nodes),
             "gripper_node": args.gripper_node, "plant": args.plant}
    print("READY " + json.dumps(ready), flush=True)
    try:
        wait_for_stop_signal()
    finally:
        # The fault port closes with the process; FaultControlServer.stop() would first wait
        # out serve_forever's 0.5 s poll, on every test's teardown.
        emulator.stop()
    return 0


def _handler(emulator: DriveEmulator, name: str) -> Any:
    def handle(request: dict[str, Any]) -> None:
        emulator.inject(name, **{k: v for k, v in request.items() if k != "fault"})

    return handle


if __name__ == "__main__":
    sys.exit(main())
