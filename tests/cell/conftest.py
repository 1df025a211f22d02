"""Cell runs shared by several tests: a whole cycle through a vendor driver is seconds of wall
clock and an emulator's start, so each driver's is run once and every test that only reads
what it left (its summary, its journal, the sockets it had open) asserts on that one."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import msgspec
import pytest

from kernel.app.live import run_live
from kernel.shell.loop import run
from tests.cell.harness import DriverCycle, SocketsWhileRunning, manifest, run_dir


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
