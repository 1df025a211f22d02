"""What a simulated cell needs from an emulator's plant besides the device protocol.

An emulator process owns its plant; the cell's independent evaluator and its parts feeder are
not part of any robot's wire protocol, so they go over the emulator's test-only control port:
``ground_truth`` answers the insertion depth, the joints' true position and velocity and the
wrist wrench, ``feed_peg`` presents a new peg.
"""

from __future__ import annotations

import threading
from contextlib import AbstractContextManager
from typing import Any

from stubs.fault_control import Handler
from stubs.plant.base import Plant


def world_handlers(plant: Plant, lock: AbstractContextManager[Any] | threading.Lock
                   ) -> dict[str, Handler]:
    def ground_truth(_: dict[str, Any]) -> dict[str, Any]:
        with lock:
            truth = plant.ground_truth()
            state = plant.state()
        return {"insertion_depth": truth.insertion_depth, "peg_grasped": truth.peg_grasped,
                "q": list(state.q), "qd": list(state.qd), "wrench": list(state.wrench),
                "t_ns": state.t_ns}

    def feed_peg(_: dict[str, Any]) -> None:
        respawn = getattr(plant, "respawn_peg", None)
        if respawn is None:
            raise ValueError("this plant has no parts feeder (use --plant mujoco)")
        with lock:
            respawn()

    return {"ground_truth": ground_truth, "feed_peg": feed_peg}
