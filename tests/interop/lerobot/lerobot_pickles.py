"""The sidecar's pickles read the way LeRobot's server reads them, without LeRobot: LeRobot's two
dataclasses resolve to a record of their fields, NumPy's array reconstruction to NumPy's own,
and any other global is refused. Used by the stand-in server (in the sidecar's venv) and by the
tests that compare the sidecar's pickles with the ones LeRobot's own client wrote.
"""

from __future__ import annotations

import io
import pickle  # reading the sidecar's pickles (and LeRobot's captured one), restricted below
from typing import Any, ClassVar

import numpy as np


class Record:
    """What ``NEWOBJ`` + ``BUILD`` of a LeRobot dataclass makes here: its class name and its
    fields (``BUILD`` hands them to ``__setstate__``)."""

    fields: dict[str, Any]

    @property
    def name(self) -> str:
        return type(self).__name__

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.fields = state


class _LeRobotPickle(pickle.Unpickler):
    CLASSES: ClassVar[frozenset[str]] = frozenset({"RemotePolicyConfig", "TimedObservation"})
    NUMPY: ClassVar[dict[tuple[str, str], Any]] = {
        ("numpy._core.multiarray", "_reconstruct"): np._core.multiarray._reconstruct,
        ("numpy.core.multiarray", "_reconstruct"): np._core.multiarray._reconstruct,
        ("numpy", "ndarray"): np.ndarray, ("numpy", "dtype"): np.dtype,
    }

    def find_class(self, module: str, name: str) -> Any:
        if module == "lerobot.async_inference.helpers" and name in self.CLASSES:
            return type(name, (Record,), {})
        found = self.NUMPY.get((module, name))
        if found is None:
            raise pickle.UnpicklingError(f"{module}.{name} is not what the sidecar may send")
        return found


def unpickle(data: bytes) -> Record:
    value = _LeRobotPickle(io.BytesIO(data)).load()
    if not isinstance(value, Record):
        raise pickle.UnpicklingError(f"a {type(value).__name__}, not a LeRobot dataclass")
    return value
