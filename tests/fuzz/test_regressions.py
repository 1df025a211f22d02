"""Inputs the fuzzers found, kept as regression tests (each failed before its fix)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from kernel import wire
from kernel.cli import main
from kernel.wire import MessageType, ProtocolViolation
from tests.fuzz import targets

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("frame", [
    b"\x92\xab\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x80",  # the type: invalid UTF-8
    b"\x92\xa5chunk" + b"\x91" * 200_000 + b"\xc0",  # a body nested deeper than the stack
], ids=["type not UTF-8", "body nested 200000 deep"])
def test_an_undecodable_frame_is_a_protocol_violation(frame: bytes) -> None:
    """decode_frame let UnicodeDecodeError and RecursionError escape."""
    with pytest.raises(ProtocolViolation, match="undecodable frame"):
        wire.decode_frame(frame)


def test_a_body_with_invalid_utf8_is_a_protocol_violation() -> None:
    """decode_body let UnicodeDecodeError escape (an offer whose text is not UTF-8)."""
    frame = wire.decode_frame(b"\x92\xa5offer\x82\xa9server_id\xa2\xc2\xc2\xa5offer\x80")
    with pytest.raises(ProtocolViolation, match="bad offer body"):
        wire.decode_body(frame, MessageType.OFFER)


def test_the_wire_targets_accept_both() -> None:
    targets.wire_frame(b"\x92\xab\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x80")
    targets.wire_frame(b"\x92\xa5offer\x82\xa9server_id\xa2\xc2\xc2\xa5offer\x80")


def test_an_event_kind_with_a_newline_keeps_the_message_on_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The kind was quoted raw in the place (``events[1] (\\n).kind``): a two-line message."""
    doc = json.loads((ROOT / "manifests" / "scenarios" / "calibration_mismatch.json").read_text())
    doc["events"][1]["kind"] = "\n"
    path = tmp_path / "scenario.json"
    path.write_text(json.dumps(doc))
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "events[1] ('\\n').kind: unknown event kind" in err
