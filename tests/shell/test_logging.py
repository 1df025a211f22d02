"""configure_logging: valid JSON lines, timestamps, and bounded values."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from datetime import datetime

import pytest
import structlog

from assurance.reasons import ReasonCode
from kernel.shell.logging import UNLISTED_REASON, LabelLimits, configure_logging


@pytest.fixture(autouse=True)
def _restore_structlog() -> Iterator[None]:
    yield
    structlog.reset_defaults()


def _lines(stream: io.StringIO) -> list[dict]:
    return [json.loads(line) for line in stream.getvalue().splitlines()]


def _configured(**kwargs: object) -> io.StringIO:
    stream = io.StringIO()
    configure_logging("INFO", stream, True, **kwargs)  # type: ignore[arg-type]
    return stream


def test_json_lines_carry_iso_and_monotonic_stamps() -> None:
    stream = _configured()
    log = structlog.get_logger()
    log.info("tick", seq=1, ok=True, ratio=0.5)
    log.warning("late", by_us=812)
    first, second = _lines(stream)
    assert (first["event"], first["level"], first["seq"], first["ok"]) == ("tick", "info", 1, True)
    assert datetime.fromisoformat(first["ts"]).tzinfo is not None
    assert isinstance(first["mono_ns"], int) and first["mono_ns"] <= second["mono_ns"]


def test_level_filter_and_bad_level() -> None:
    stream = _configured()
    structlog.get_logger().debug("hidden")
    assert stream.getvalue() == ""
    with pytest.raises(ValueError, match="unknown log level"):
        configure_logging("LOUD", io.StringIO())


def test_exception_text_never_reaches_a_reason() -> None:
    stream = _configured()
    secret = "socket closed at frame 98765 " * 50
    structlog.get_logger().error("link", reason=ConnectionError(secret), error=ValueError(secret))
    (line,) = _lines(stream)
    assert line["reason"] == "ConnectionError"
    assert line["error"] == "ValueError"
    assert "98765" not in stream.getvalue()


def test_reasons_keep_only_reason_codes() -> None:
    stream = _configured()
    log = structlog.get_logger()
    log.info("refused", reason=ReasonCode.OBSERVATION_STALE,
             reasons=[ReasonCode.EXPIRED, "EXPIRED", "chunk C123 too old"])
    log.info("fallback", reason="free text with id 4242", trigger="LINK_LOST")
    first, second = _lines(stream)
    assert first["reason"] == "OBSERVATION_STALE"
    assert first["reasons"] == ["EXPIRED", "EXPIRED", UNLISTED_REASON]
    assert (second["reason"], second["trigger"]) == (UNLISTED_REASON, "LINK_LOST")


def test_sizes_are_bounded() -> None:
    limits = LabelLimits(max_str=20, max_items=3, max_fields=8)
    stream = _configured(limits=limits)
    structlog.get_logger().info("x" * 100, ids=list(range(1000)), blob={"k": "v" * 500},
                                **{f"f{i}": i for i in range(20)})
    (line,) = _lines(stream)
    assert line["event"].startswith("x" * 20) and len(line["event"]) < 40
    assert line["ids"] == [0, 1, 2]
    assert len(line["blob"]["k"]) < 40
    assert len(line) <= 8 + 4 + 1 and line["dropped_fields"] > 0
    assert {"event", "level", "ts", "mono_ns"} <= set(line)


def test_exc_info_becomes_type_and_location_only() -> None:
    stream = _configured()
    try:
        raise RuntimeError("very long private detail " * 20)
    except RuntimeError:
        structlog.get_logger().exception("driver_fault")
    (line,) = _lines(stream)
    assert line["exc_type"] == "RuntimeError"
    assert line["exc_where"].endswith(f"test_logging.py:{line['exc_where'].rsplit(':', 1)[1]}")
    assert "private detail" not in stream.getvalue()
    assert "Traceback" not in stream.getvalue()


def test_unknown_objects_are_rendered_as_bounded_text() -> None:
    stream = _configured(limits=LabelLimits(max_str=10))
    structlog.get_logger().info("obj", thing=object(), when=b"\x00" * 100)
    (line,) = _lines(stream)
    assert len(line["thing"]) < 30 and len(line["when"]) < 30


def test_console_renderer() -> None:
    stream = io.StringIO()
    configure_logging("DEBUG", stream, json=False)
    structlog.get_logger().debug("plain", reason=KeyError("k"))
    text = stream.getvalue()
    assert "plain" in text and "KeyError" in text
