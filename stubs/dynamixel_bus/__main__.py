"""``python -m stubs.dynamixel_bus --ids 1,2,3,4,5,6 [--baud 1000000] [--plant kinematic|mujoco]
[--gripper-id 7 [--gripper-open-ticks 2048] [--gripper-closed-ticks 3072]]``.

Opens a pseudo-terminal, puts one emulated X-series servo per id behind it (plus the gripper's
servo, which drives the plant's gripper), steps the plant in real time, and prints
``READY {"port": ..., "fault_port": ...}``. Runs until SIGTERM/SIGINT or
until its parent dies (so a crashed test run does not leave a bus spinning on a shared core).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import signal
import sys
import termios
import threading
import time
import tty

from stubs.dynamixel_bus.bus import Bus
from stubs.dynamixel_bus.control_table import ServoTable
from stubs.dynamixel_bus.packet import Frame, FrameDecoder
from stubs.dynamixel_bus.plant_link import (
    GRIPPER_CLOSED_TICKS,
    GRIPPER_OPEN_TICKS,
    GripperLink,
    PlantLink,
)
from stubs.fault_control import FaultControlServer
from stubs.plant.base import KinematicPlant, Plant
from stubs.plant.realtime import RealtimeStepper
from stubs.plant.world_port import world_handlers

BAUD_CODES = {
    9600: 0, 57600: 1, 115200: 2, 1_000_000: 3, 2_000_000: 4, 3_000_000: 5, 4_000_000: 6,
    4_500_000: 7,
}
"""Baud Rate (address 8) values of the X-series."""
IDLE_POLL_S = 0.1
"""How often an idle bus looks at the stop flag and its parent."""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m stubs.dynamixel_bus", description=__doc__)
    parser.add_argument("--ids", default="1,2,3,4,5,6", help="comma-separated servo ids")
    parser.add_argument("--baud", type=int, default=1_000_000, choices=sorted(BAUD_CODES))
    parser.add_argument("--plant", choices=("kinematic", "mujoco"), default="kinematic")
    parser.add_argument("--model", type=int, default=1020, help="model number (1020: XM430-W350)")
    parser.add_argument("--fault-port", type=int, default=0, help="0 picks a free port")
    parser.add_argument("--no-fast-sync-read", action="store_true",
                        help="behave like firmware without Fast Sync Read (0x8A)")
    parser.add_argument("--gripper-id", type=int, default=None,
                        help="add a gripper servo with this id (drives the plant's gripper)")
    parser.add_argument("--gripper-open-ticks", type=int, default=GRIPPER_OPEN_TICKS,
                        help="gripper position at the fully open 0.085 m")
    parser.add_argument("--gripper-closed-ticks", type=int, default=GRIPPER_CLOSED_TICKS,
                        help="gripper position at 0 m (closed)")
    args = parser.parse_args(argv)
    try:
        args.ids = tuple(int(part) for part in args.ids.split(","))
    except ValueError:
        parser.error(f"--ids: expected comma-separated integers, got {args.ids!r}")
    if not args.ids or len(set(args.ids)) != len(args.ids) or not all(
        0 <= i <= 252 for i in args.ids
    ):
        parser.error(f"--ids: need distinct ids in 0..252, got {args.ids}")
    _check_gripper(parser, args)
    return args


def _check_gripper(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.gripper_id is not None and (args.gripper_id in args.ids
                                        or not 0 <= args.gripper_id <= 252):
        parser.error(f"--gripper-id: need an id in 0..252 that is not in --ids, "
                     f"got {args.gripper_id}")
    ends = (args.gripper_open_ticks, args.gripper_closed_ticks)
    if ends[0] == ends[1] or not all(0 <= tick <= 4095 for tick in ends):
        parser.error(f"--gripper-open-ticks/--gripper-closed-ticks: need two distinct ticks "
                     f"in 0..4095, got {ends}")


def make_gripper(args: argparse.Namespace) -> GripperLink | None:
    if args.gripper_id is None:
        return None
    return GripperLink(args.gripper_id, args.gripper_open_ticks, args.gripper_closed_ticks)


def make_plant(kind: str, dof: int) -> Plant:
    if kind == "mujoco":
        from stubs.plant.mujoco_plant import MujocoPlant  # heavy: only when asked for

        return MujocoPlant()
    return KinematicPlant(dof=dof)


def _speed_names() -> dict[int, int]:
    """termios speed constants to baud rates (B1000000 → 1000000) for the rates we emulate."""
    return {getattr(termios, f"B{rate}"): rate for rate in BAUD_CODES
            if hasattr(termios, f"B{rate}")}


class PtyServer:
    """Reads instruction packets from the pty master and writes the bus's replies back."""

    def __init__(self, bus: Bus, baud: int) -> None:
        self.bus = bus
        self.baud = baud
        self.master, self._slave = os.openpty()
        # Raw mode before any client opens the slave: with the default line discipline the
        # master's replies would be echoed back to us as if the host had sent them.
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._speeds = _speed_names()
        self.stop = threading.Event()

    def serve(self) -> None:
        decoder = FrameDecoder()
        parent = os.getppid()
        while not self.stop.is_set() and os.getppid() == parent:
            if self._input_within(self._until_next_watchdog()):
                data = os.read(self.master, 4096)
                if self._line_baud() != self.baud:
                    decoder = FrameDecoder()  # at the wrong rate the servos only see noise
                    continue
                for frame in decoder.feed(data):
                    self._answer(frame)
            # Judged at an instant after which nothing was pending: the packets that were
            # already in the pty buffer (after a stall of this process) reach the servos first.
            now = time.monotonic()
            if not self._input_within(0.0):
                self.bus.check_watchdogs(now)

    def _until_next_watchdog(self) -> float:
        deadline = self.bus.next_watchdog_deadline()
        if deadline is None:
            return IDLE_POLL_S
        return min(IDLE_POLL_S, max(0.0, deadline - time.monotonic()))

    def _input_within(self, timeout_s: float) -> bool:
        readable, _, _ = select.select([self.master], [], [], timeout_s)
        return bool(readable)

    def _answer(self, frame: Frame) -> None:
        try:
            reply = self.bus.handle(frame)
        except Exception as error:  # one packet the emulator mishandles must not end the bus
            print(f"dynamixel_bus: {frame} failed: {error!r}", file=sys.stderr)
            return
        if reply:
            os.write(self.master, reply)

    def close(self) -> None:
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _line_baud(self) -> int:
        # On Linux the master reports the termios of the slave, i.e. the rate the host chose.
        speed = termios.tcgetattr(self.master)[4]
        return self._speeds.get(speed, -1)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    plant = make_plant(args.plant, len(args.ids))
    stepper = RealtimeStepper(plant)
    gripper = make_gripper(args)
    every = (*args.ids, gripper.servo_id) if gripper else args.ids
    servos = {i: ServoTable(i, args.model, BAUD_CODES[args.baud]) for i in every}
    link = PlantLink(stepper, args.ids, gripper)
    bus = Bus(servos, link, fast_sync_read=not args.no_fast_sync_read)
    bus.power_on()
    server = PtyServer(bus, args.baud)
    handlers = {**bus.fault_handlers(), **world_handlers(plant, stepper.lock)}
    faults = FaultControlServer("127.0.0.1", args.fault_port, handlers)
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: server.stop.set())
    stepper.start()
    faults.start()
    try:
        ready = {"port": server.port, "fault_port": faults.address[1], "ids": list(args.ids),
                 "gripper_id": args.gripper_id, "baud": args.baud, "plant": args.plant}
        print("READY " + json.dumps(ready), flush=True)
        server.serve()
    finally:
        faults.stop()
        stepper.stop()
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
