"""Reading a file as text and checking what any parser produced, before a key is looked at.

Shared by scenarios and journals (JSON) and manifests (TOML). Whatever the bytes are, the result
is a document or a :class:`ScenarioError` naming the file and the place: never a traceback.

- The file must be UTF-8; an invalid byte is named by line and column.
- A JSON integer wider than 64 bits is read as :class:`WideInteger` (the standard library would
  otherwise refuse one of more than 4300 digits without saying where, and a float conversion of
  a smaller one overflows deep inside a check); the document check then refuses it by key.
- Nesting deeper than :data:`~kernel.scenario.bounds.MAX_DEPTH` is refused by key; nesting so
  deep that the parser's own stack runs out is refused for the file.
- A string that is not valid Unicode (a lone surrogate escape, ``"\\ud800"``) is refused by key:
  it could be neither printed in a message nor written to a decision log.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kernel.scenario.bounds import INT64_MAX, INT64_MIN, MAX_DEPTH
from kernel.scenario.fields import ScenarioError, Where, shown


@dataclass(frozen=True, slots=True)
class WideInteger:
    """A JSON integer literal of more than 64 bits, kept as its digit count only."""

    digits: int

    def __repr__(self) -> str:
        return f"an integer of {self.digits} digits"


WIDE_DIGITS = 19
"""Integer literals with more digits than this may not fit 64 bits: they are converted
exactly only if they do (converting is cheap at this length)."""


def read_text(path: Path, name: str) -> str:
    """The file's text.

    Raises:
        ScenarioError: the file cannot be read, or is not UTF-8.
    """
    return decoded(read_bytes(path, name), name)


def read_bytes(path: Path, name: str) -> bytes:
    """The file's bytes.

    Raises:
        ScenarioError: the file cannot be read.
    """
    try:
        return path.read_bytes()
    except (OSError, ValueError) as error:  # ValueError: a NUL byte in the path
        message = getattr(error, "strerror", None) or error
        raise ScenarioError(f"{name}: cannot read file: {message}") from None


def decoded(data: bytes, name: str) -> str:
    """``data`` as UTF-8 text.

    Raises:
        ScenarioError: it is not UTF-8, with the place of the first bad byte.
    """
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = data.count(b"\n", 0, error.start) + 1
        column = error.start - (data.rfind(b"\n", 0, error.start) + 1) + 1
        raise ScenarioError(
            f"{name}: line {line} column {column}: not UTF-8 text (byte "
            f"0x{data[error.start]:02x}); save the file as UTF-8") from None


def _integer(literal: str) -> int | WideInteger:
    digits = len(literal.lstrip("-"))
    if digits <= WIDE_DIGITS:
        return int(literal)
    if digits > WIDE_DIGITS + 1:
        return WideInteger(digits)
    value = int(literal)
    return value if INT64_MIN <= value <= INT64_MAX else WideInteger(digits)


def parse_json(text: str, name: str, line: int | None = None) -> Any:
    """One JSON document (``line``: its line number in a JSON-lines file, for messages).

    Raises:
        ScenarioError: not JSON, or nested deeper than the parser can follow.
        json.JSONDecodeError: passed through so a caller can try JSON lines instead.
    """
    place = f"line {line}: " if line is not None else ""
    try:
        return json.loads(text, parse_int=_integer)
    except json.JSONDecodeError:
        raise
    except RecursionError:
        raise ScenarioError(f"{name}: {place}nested too deeply (at most {MAX_DEPTH} levels of "
                            "objects and arrays)") from None
    except ValueError as error:  # e.g. a float literal the float parser refuses
        raise ScenarioError(f"{name}: {place}not valid JSON: {error}") from None


def check_document(doc: Any, where: Where) -> None:
    """Refuse what no key may hold: wide integers, deep nesting, invalid Unicode.

    Raises:
        ScenarioError: naming the first offending place.
    """
    if not _acceptable(doc):
        _locate(doc, where)
        raise where.error("holds a value no key may hold")  # _locate names it first


def _acceptable(doc: Any) -> bool:
    """The fast walk (a journal has millions of values): no places kept, only a verdict."""
    pending: list[tuple[Any, int]] = [(doc, 0)]
    while pending:
        value, depth = pending.pop()
        if isinstance(value, dict):
            if depth >= MAX_DEPTH or not all(_valid_text(key) for key in value):
                return False
            pending.extend((item, depth + 1) for item in value.values())
        elif isinstance(value, list):
            if depth >= MAX_DEPTH:
                return False
            pending.extend((item, depth + 1) for item in value)
        elif isinstance(value, str):
            if not _valid_text(value):
                return False
        elif isinstance(value, WideInteger) or (
                isinstance(value, int) and not INT64_MIN <= value <= INT64_MAX):
            return False
    return True


def _valid_text(value: Any) -> bool:
    if not isinstance(value, str) or value.isascii():
        return True
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _locate(doc: Any, where: Where) -> None:
    """The slow walk: the first offending place, named."""
    pending: list[tuple[Any, Where, int]] = [(doc, where, 0)]
    while pending:
        value, here, depth = pending.pop()
        if isinstance(value, dict):
            items: Any = value.items()
        elif isinstance(value, list):
            items = enumerate(value)
        else:
            _check_scalar(value, here)
            continue
        if depth >= MAX_DEPTH:
            raise here.error(f"nested too deeply (at most {MAX_DEPTH} levels of objects and "
                             "arrays)")
        for key, item in reversed(list(items)):  # reversed: the first problem pops first
            if isinstance(key, str):
                _check_text(key, here, "a key here")
            pending.append((item, here.at(key), depth + 1))


def _check_scalar(value: Any, where: Where) -> None:
    if isinstance(value, WideInteger):
        raise where.error(f"{value!r}: {_INT64}")
    if isinstance(value, int) and not INT64_MIN <= value <= INT64_MAX:
        raise where.error(f"{shown(value)}: {_INT64}")
    if isinstance(value, str):
        _check_text(value, where, "the value")


_INT64 = f"integers are at most 64 bits ({INT64_MIN} to {INT64_MAX})"


def _check_text(value: str, where: Where, what: str) -> None:
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as error:
        raise where.error(f"{what} is not valid Unicode text (a lone surrogate "
                          f"\\u{ord(value[error.start]):04x})") from None
