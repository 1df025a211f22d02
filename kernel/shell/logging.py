"""structlog set-up: JSON lines with an ISO timestamp, a monotonic stamp and bounded values.

A log line is telemetry, and telemetry must stay bounded: an exception's text, a traceback or a
per-frame id pasted into a label would make every line unique and can be arbitrarily long. The
:class:`BoundLabels` processor therefore keeps only the exception *type* (plus file:line), only
:class:`~assurance.reasons.ReasonCode` values in reason fields, and caps string lengths,
collection sizes and the number of fields. Lines are encoded with ``msgspec.json``.
"""

from __future__ import annotations

import logging as stdlib_logging
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TextIO

import msgspec
import structlog
from structlog.typing import EventDict, Processor, WrappedLogger

from assurance.reasons import ReasonCode

UNLISTED_REASON = "UNLISTED"
_REASONS = frozenset(code.value for code in ReasonCode)
_PLAIN = (bool, int, float, type(None))
_ALWAYS_KEPT = frozenset({"event", "level", "ts", "mono_ns"})


@dataclass(frozen=True, slots=True)
class LabelLimits:
    max_str: int = 160
    max_items: int = 16
    max_fields: int = 32
    reason_keys: frozenset[str] = frozenset({"reason", "reasons", "trigger"})


class BoundLabels:
    """A structlog processor that makes every value in a line bounded in size and cardinality."""

    def __init__(self, limits: LabelLimits = LabelLimits()) -> None:
        self.limits = limits

    def __call__(self, logger: WrappedLogger, method: str, event_dict: EventDict) -> EventDict:
        exc_info = event_dict.pop("exc_info", None)
        bounded: EventDict = {}
        extra = 0
        for key, value in event_dict.items():
            if key not in _ALWAYS_KEPT and len(bounded) >= self.limits.max_fields:
                extra += 1  # the line's own stamps are always kept; caller fields are capped
                continue
            reason = key in self.limits.reason_keys
            bounded[str(key)] = self._reason(value) if reason else self._value(value, depth=0)
        if extra:
            bounded["dropped_fields"] = extra
        bounded.update(_exception_fields(exc_info))
        return bounded

    def _reason(self, value: Any) -> Any:
        if isinstance(value, list | tuple | set | frozenset):
            return [self._reason(item) for item in list(value)[: self.limits.max_items]]
        if isinstance(value, BaseException):
            return type(value).__name__
        return value if isinstance(value, str) and value in _REASONS else UNLISTED_REASON

    def _value(self, value: Any, depth: int) -> Any:
        if isinstance(value, _PLAIN):
            return value
        if isinstance(value, BaseException):
            return type(value).__name__
        if isinstance(value, str):
            return self._text(value)
        if depth < 2 and isinstance(value, Mapping):
            items = list(value.items())[: self.limits.max_items]
            return {self._text(str(k)): self._value(v, depth + 1) for k, v in items}
        if depth < 2 and isinstance(value, list | tuple | set | frozenset):
            return [self._value(item, depth + 1) for item in list(value)[: self.limits.max_items]]
        return self._text(str(value))

    def _text(self, text: str) -> str:
        limit = self.limits.max_str
        return text if len(text) <= limit else f"{text[:limit]}...(+{len(text) - limit})"


def _exception_fields(exc_info: Any) -> dict[str, str]:
    """The exception's type and where it was raised; never its text or the full traceback."""
    if exc_info is None or exc_info is False:
        return {}
    if exc_info is True:
        exc_info = sys.exc_info()
    exc = exc_info if isinstance(exc_info, BaseException) else exc_info[1]
    if exc is None:
        return {}
    fields = {"exc_type": type(exc).__name__}
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    if tb is not None:
        fields["exc_where"] = f"{tb.tb_frame.f_code.co_filename}:{tb.tb_lineno}"
    return fields


def add_monotonic_ns(logger: WrappedLogger, method: str, event_dict: EventDict) -> EventDict:
    """CLOCK_MONOTONIC in ns: lines order and subtract correctly across wall-clock steps."""
    event_dict["mono_ns"] = time.monotonic_ns()
    return event_dict


_ENCODER = msgspec.json.Encoder(enc_hook=repr)


def _dumps(obj: Any, **_: Any) -> str:
    # structlog passes json.dumps-style keywords (``default=``); msgspec has its own hook.
    return _ENCODER.encode(obj).decode()


def configure_logging(level: int | str = "INFO", stream: TextIO | None = None, json: bool = True,
                      *, limits: LabelLimits = LabelLimits()) -> None:
    """Configure structlog globally: JSON lines (or plain console lines) to ``stream``.

    Raises:
        ValueError: ``level`` is not a known level name.
    """
    numeric = _level(level)
    renderer: Processor = (structlog.processors.JSONRenderer(serializer=_dumps) if json
                           else structlog.dev.ConsoleRenderer(colors=False))
    structlog.configure(
        processors=[
            structlog.contextvars.merge_contextvars,
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True, key="ts"),
            add_monotonic_ns,
            BoundLabels(limits),
            renderer,
        ],
        wrapper_class=structlog.make_filtering_bound_logger(numeric),
        logger_factory=structlog.PrintLoggerFactory(file=stream or _CurrentStderr()),
        cache_logger_on_first_use=False,
    )


class _CurrentStderr:
    """Whatever ``sys.stderr`` is when a line is written, not when logging was configured (a
    test harness or a daemon wrapper may swap it, and the old one may be closed by then)."""

    def write(self, text: str) -> int:
        return sys.stderr.write(text)

    def flush(self) -> None:
        sys.stderr.flush()


def _level(level: int | str) -> int:
    if isinstance(level, int):
        return level
    numeric = stdlib_logging.getLevelNamesMapping().get(level.upper())
    if numeric is None:
        raise ValueError(f"unknown log level {level!r}")
    return numeric
