"""Fuzz targets: each takes bytes and enforces one loader's contract on them.

A target returns normally when the loader either accepts the input or refuses it the documented
way; any other exception escapes and is a bug (hypothesis reports it in ``make test``, atheris
in ``make fuzz``). The same functions serve both.

- ``wire_frame``: :func:`kernel.wire.decode_frame`, then the message type and the body, as the
  policy link does: a :class:`~kernel.wire.Frame` and a message, or ``ProtocolViolation``.
- ``wire_chunk``: :func:`assurance.envelope.decode_wire_chunk`: a chunk or a malformed chunk,
  never an exception (a broken chunk is a refusal with reason codes, not a crash).
- ``scenario``: :func:`kernel.scenario.load_scenario` (scenario or journal): a scenario or
  ``ScenarioError``.
- ``manifest``: :func:`kernel.cli_run.checked_manifest` (what ``warden run`` checks before
  anything starts): a manifest or ``ManifestError``.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

from assurance.envelope import Chunk, MalformedChunk, decode_wire_chunk
from kernel import wire
from kernel.cli_run import checked_manifest
from kernel.manifest import ManifestError
from kernel.scenario import ScenarioError, load_scenario
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
        checked_manifest(path)
    except ManifestError:
        return


TARGETS: dict[str, Callable[[bytes], None]] = {
    "wire_frame": wire_frame, "wire_chunk": wire_chunk, "scenario": scenario,
    "manifest": manifest,
}
