"""The pickles LeRobot's PolicyServer reads, written without LeRobot.

The server unpickles ``RemotePolicyConfig`` and ``TimedObservation`` objects of
``lerobot.async_inference.helpers`` (dataclasses). The sidecar has stand-ins of the same name
and fields, and a pickler that writes each stand-in's class by its LeRobot name without
importing LeRobot (Python's pickler would first check that the class is importable). So the
bytes are what LeRobot's own client writes: protocol 4 (its default on Python 3.11 to 3.13),
the class, ``NEWOBJ``, the field dict and ``BUILD``. The fields are plain Python values and
NumPy arrays (LeRobot's client sends the robot's raw NumPy frames; the server makes tensors).
"""

from __future__ import annotations

import io
import pickle  # writing only: these pickles go to the server, none is read here
from dataclasses import dataclass, field
from typing import Any

import numpy as np

HELPERS = "lerobot.async_inference.helpers"
PROTOCOL = 4


@dataclass
class RemotePolicyConfig:
    policy_type: str
    pretrained_name_or_path: str
    lerobot_features: dict[str, dict]
    actions_per_chunk: int
    device: str = "cpu"
    rename_map: dict[str, str] = field(default_factory=dict)


@dataclass
class TimedObservation:
    timestamp: float
    timestep: int
    observation: dict[str, Any]
    """LeRobot's raw keys (each joint's name, each camera's key, ``task``) → float,
    ``H×W×3`` uint8 array or text."""
    must_go: bool = False


_STAND_INS = (RemotePolicyConfig, TimedObservation)
for _stand_in in _STAND_INS:
    _stand_in.__module__ = HELPERS


def dumps(value: RemotePolicyConfig | TimedObservation) -> bytes:
    if isinstance(value, TimedObservation):
        for key, item in value.observation.items():
            if not isinstance(item, float | str | np.ndarray):
                raise TypeError(f"observation[{key!r}] is a {type(item).__name__}")
    buffer = io.BytesIO()
    _LeRobotPickler(buffer, protocol=PROTOCOL).dump(value)
    return buffer.getvalue()


class _LeRobotPickler(pickle._Pickler):  # the Python pickler: its save_global can be overridden
    def save_global(self, obj: Any, name: str | None = None) -> None:
        if obj not in _STAND_INS:
            super().save_global(obj, name)
            return
        self.save(HELPERS)
        self.save(obj.__qualname__)
        self.write(pickle.STACK_GLOBAL)
        self.memoize(obj)
