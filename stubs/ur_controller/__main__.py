"""Run an emulated UR controller: ``python -m stubs.ur_controller --host 127.0.0.2``.

Prints ``READY {json}`` on stdout once every port listens (ports, fault-control address,
version, plant), then runs until SIGTERM or SIGINT. Exit code 3 means an address was taken
(another emulator on the same 127.0.0.x): pick another host.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import sys

from stubs.child import wait_for_stop_signal
from stubs.fault_control import FaultControlServer
from stubs.plant.base import KinematicPlant, Plant
from stubs.plant.world_port import world_handlers
from stubs.ur_controller.controller import (
    DASHBOARD_PORT,
    RTDE_PORT,
    SCRIPT_PORT,
    ControllerConfig,
    URController,
)
from stubs.ur_controller.io_board import GripperWiring

EXIT_ADDRESS_IN_USE = 3
EXIT_BAD_ARGUMENT = 2


def parse_version(text: str) -> tuple[int, int, int, int]:
    """"5.11.1" or "5.11.1.108318" → (major, minor, bugfix, build)."""
    pieces = text.split(".")
    if not 3 <= len(pieces) <= 4 or not all(piece.isdigit() for piece in pieces):
        raise argparse.ArgumentTypeError(f"version {text!r} is not MAJOR.MINOR.BUGFIX[.BUILD]")
    major, minor, bugfix, build = (*(int(piece) for piece in pieces), 0)[:4]
    return major, minor, bugfix, build


def loopback_host(text: str) -> str:
    """Only loopback: the fault-control port has no authentication, it is test tooling."""
    try:
        if ipaddress.ip_address(text).is_loopback:
            return text
    except ValueError:
        pass
    raise argparse.ArgumentTypeError(f"{text!r} is not a loopback address (127.0.0.0/8)")


def make_plant(kind: str) -> Plant:
    if kind == "mujoco":
        # Imported here: MuJoCo is heavy, and the kinematic plant must not depend on it.
        from stubs.plant.mujoco_plant import MujocoPlant

        return MujocoPlant()
    return KinematicPlant(dof=6, timestep_ns=2_000_000)


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m stubs.ur_controller", description=__doc__)
    parser.add_argument("--host", required=True, type=loopback_host,
                        help="loopback address, e.g. 127.0.0.2")
    parser.add_argument("--plant", choices=("kinematic", "mujoco"), default="kinematic")
    parser.add_argument("--version", type=parse_version, default=(5, 11, 1, 108318),
                        help="URControl version the controller reports (default 5.11.1)")
    parser.add_argument("--control-port", type=int, default=0,
                        help="fault-control port (default: any free port)")
    parser.add_argument("--gripper-output", type=int, choices=(0, 1), default=0,
                        help="tool digital output the gripper closes on (default 0)")
    parser.add_argument("--gripper-feedback-input", type=int, choices=(0, 1), default=0,
                        help="standard analog input carrying its 0-10 V opening (default 0)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    plant = make_plant(args.plant)
    if plant.dof != 6:
        print(f"ur_controller: a UR arm has 6 joints, the plant has {plant.dof}", file=sys.stderr)
        return EXIT_BAD_ARGUMENT
    wiring = GripperWiring(args.gripper_output, args.gripper_feedback_input)
    controller = URController(ControllerConfig(args.host, args.version, wiring), plant)
    try:
        controller.start()
        handlers = {**controller.fault_handlers(),
                    **world_handlers(plant, controller.plant_lock)}
        control = FaultControlServer(args.host, args.control_port, handlers)
    except OSError as error:
        print(f"ur_controller: cannot listen on {args.host}: {error}", file=sys.stderr)
        controller.stop()
        return EXIT_ADDRESS_IN_USE
    control.start()
    _announce(args, control.address)
    wait_for_stop_signal()
    control.stop()
    controller.stop()
    return 0


def _announce(args: argparse.Namespace, control_address: tuple[str, int]) -> None:
    ready = {
        "host": args.host, "rtde_port": RTDE_PORT, "dashboard_port": DASHBOARD_PORT,
        "script_port": SCRIPT_PORT, "control_port": control_address[1],
        "version": ".".join(str(part) for part in args.version), "plant": args.plant,
    }
    print("READY " + json.dumps(ready), flush=True)


if __name__ == "__main__":
    sys.exit(main())
