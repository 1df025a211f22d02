"""Fuzz targets: each takes bytes and enforces one loader's contract on them.

A target returns normally when the loader either accepts the input or refuses it the documented
way; any other exception escapes and is a bug (hypothesis reports it in ``make test``, atheris
in ``make fuzz``). The same functions serve both.

- ``wire_frame``: :func:`kernel.wire.decode_frame`, then the message type and the body, as the
  policy link does: a :class:`~kernel.wire.Frame` and a message, or ``ProtocolViolation``.
- ``wire_chunk``: :func:`assurance.envelope.decode_wire_chunk`: a chunk or a malformed chunk,
  never an exception (a broken chunk is a refusal with reason codes, not a crash).
- ``scenario``: :func:`kernel.scenario.load.load_scenario` (scenario or journal): a scenario or
  ``ScenarioError``.
- ``manifest``: :func:`preflight`, everything ``warden run`` checks before anything starts
  (:func:`kernel.cli_run.checked_manifest`, then the world's own checks: the ``[driver]``
  settings against the driver's settings table, the clock, the operator): it passes, or
  raises ``ManifestError`` or ``DriverInitError`` (both exit 2).
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any
from unittest import mock

from assurance.envelope import Chunk, MalformedChunk, decode_wire_chunk
from drivers.base import DriverInitError
from kernel import wire
from kernel.app.compose import world_for
from kernel.cli_run import checked_manifest
from kernel.manifest import Manifest, ManifestError
from kernel.scenario.load import ScenarioError, load_scenario
from kernel.wire import MessageType, ProtocolViolation

CLIENT_RECEIVE_NS = 5_000_000_000


class UnexpectedResult(AssertionError):
    """A decoder returned something its contract does not allow."""


def wire_frame(data: bytes) -> None:
    try:
        frame = wire.decode_frame(data)
        kind = wire.message_type(frame, version=max(wire.PROTOCOL_RANGE))
        if kind is MessageType.CHUNK:
            _check_chunk(decode_wire_chunk(frame.body, CLIENT_RECEIVE_NS))
        else:
            wire.decode_body(frame, kind)
    except ProtocolViolation:
        return


def wire_chunk(data: bytes) -> None:
    _check_chunk(decode_wire_chunk(data, CLIENT_RECEIVE_NS))


def _check_chunk(result: object) -> None:
    if not isinstance(result, Chunk | MalformedChunk):
        raise UnexpectedResult(f"decode_wire_chunk returned {type(result).__name__}")


_DIRECTORY = Path(tempfile.mkdtemp(prefix="warden-fuzz-"))
atexit.register(shutil.rmtree, _DIRECTORY, ignore_errors=True)


def scenario(data: bytes) -> None:
    path = _DIRECTORY / "input.json"
    path.write_bytes(data)
    try:
        load_scenario(path)
    except ScenarioError:
        return


def manifest(data: bytes) -> None:
    path = _DIRECTORY / "input.toml"
    path.write_bytes(data)
    try:
        preflight(path)
    except (ManifestError, DriverInitError):
        return


class WouldStart(Exception):
    """The world got as far as starting an emulator process or the in-process plant: every
    check ``warden run`` makes before that passed."""


def _would_start(*_: Any, **__: Any) -> Any:
    raise WouldStart


def preflight(path: Path) -> Manifest:
    """Everything ``warden run`` checks before a device, an emulator, a plant or a server
    starts: :func:`checked_manifest` (manifest, ``[policy]`` settings, ``[task]``, the clock),
    then :func:`kernel.app.compose.world_for` (the ``[driver]`` table against the driver's
    settings, with the emulator's address stood in, and the emulator's arguments) with the
    emulator process and the MuJoCo plant replaced by a stand-in that stops there. With
    ``emulator.launch = false`` the driver is built and never connected.

    Returns:
        The manifest, when every check passed.

    Raises:
        ManifestError, DriverInitError: the refusals ``warden run`` turns into exit 2.
    """
    loaded = checked_manifest(path)
    with (mock.patch("stubs.cell.emulated.EmulatorProcess", _would_start),
          mock.patch("stubs.cell.sim_world.SimWorld", _would_start)):
        try:
            world = world_for(loaded)
        except WouldStart:
            return loaded
    world.close()  # a DeviceWorld: its driver was built, never connected
    return loaded


TARGETS: dict[str, Callable[[bytes], None]] = {
    "wire_frame": wire_frame, "wire_chunk": wire_chunk, "scenario": scenario,
    "manifest": manifest,
}
