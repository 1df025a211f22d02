"""Cell runs shared by several tests: a whole cycle on the wall clock is seconds (and, through a
vendor driver, an emulator's start), so the simulated cell's and each driver's are run once and
every test that only reads what one left (its summary, its journal, the sockets it had open,
what the service manager heard) asserts on that one."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path

import msgspec
import pytest

from kernel.app.live import run_live
from kernel.shell.loop import run
from tests.cell.harness import (
    DriverCycle,
    ServiceManager,
    SimCycle,
    SocketsWhileRunning,
    manifest,
    run_dir,
)


@pytest.fixture(scope="session")
def driver_cycle(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], DriverCycle]:
    """``driver_cycle(name)``: one cycle of the shipped manifest ``name`` through its driver and
    emulator, on the wall clock, as a real cell would judge it (VERIFY on measured evidence
    alone: the simulator's ground truth switched off); run the first time a test asks."""
    done: dict[str, DriverCycle] = {}

    def cycle(name: str) -> DriverCycle:
        if name not in done:
            cell = manifest(name, cycles=1)
            cell = dataclasses.replace(cell, cell=msgspec.structs.replace(cell.cell,
                                                                          ground_truth=False))
            root = tmp_path_factory.mktemp(name.removesuffix(".toml"))
            sockets = SocketsWhileRunning(after_ticks=200)
            with pytest.MonkeyPatch.context() as env:
                # the operator socket: ours alone (the default one may be another warden's)
                env.setenv("RUNTIME_DIRECTORY", str(root))
                summary = run(run_live(cell, root / "runs", hook=sockets))
            done[name] = DriverCycle(summary, run_dir(root / "runs"), sockets.sockets())
        return done[name]

    return cycle


@pytest.fixture(scope="session")
def sim_cycle(tmp_path_factory: pytest.TempPathFactory) -> SimCycle:
    """One cycle of the shipped simulated cell (in-process plant, the policy server as a
    process, a real websocket) on the wall clock, as systemd runs it: a stand-in service
    manager at NOTIFY_SOCKET with a 2 s watchdog hears what warden tells it."""
    root = tmp_path_factory.mktemp("sim-ur5e")
    return _sim_cycle(root)


def _sim_cycle(root: Path) -> SimCycle:
    address = str(root / "notify.sock")
    systemd = ServiceManager(address)
    sockets = SocketsWhileRunning(after_ticks=200)
    try:
        with pytest.MonkeyPatch.context() as env:
            env.setenv("NOTIFY_SOCKET", address)
            env.setenv("WATCHDOG_USEC", "2000000")
            env.setenv("WATCHDOG_PID", str(os.getpid()))
            env.setenv("RUNTIME_DIRECTORY", str(root))  # the operator socket: ours alone
            summary = run(run_live(manifest("sim-ur5e.toml", cycles=1), root / "runs",
                                   hook=sockets))
    finally:
        messages = systemd.close()
    return SimCycle(summary, run_dir(root / "runs"), sockets.sockets(), messages)
