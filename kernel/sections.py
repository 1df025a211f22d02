"""The scenario sections of a manifest as written: one immutable, encoded record.

A manifest shares ``robot``, ``timing``, ``phases``, ``session``, ``allowlist`` and ``motion``
with a scenario file (and a live trial adds ``envelope``). The loader turns them into the
core's typed configuration (:class:`kernel.core.config.CoreConfig`) at once; this record is the
other thing they become, for the three readers that need the text and not the types:

- the journal's header repeats them, so that ``warden replay`` rebuilds the run's core with
  the scenario reader (:func:`kernel.config.build.build_config`), the very code that read
  them at load; a typed tree re-encoded would write the reader's defaults into the header as
  if the file had said them, and a recorded journal would no longer be the same document;
- the job worker process builds its own configuration from them (the same reader again);
- a run adds what only it knows (the device's impedance capability, the model file's digest,
  a trial's envelope) as new tables of the same document.

So what crosses the boundary is the document itself, encoded once (JSON, as the header carries
it) and frozen: every reader decodes a fresh copy, and nobody can change what another reads.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import msgspec


class ScenarioSections(msgspec.Struct, frozen=True):
    encoded: bytes
    """``{section: table}`` as JSON, in the order written."""

    @classmethod
    def of(cls, document: Mapping[str, Any]) -> ScenarioSections:
        return cls(json.dumps(dict(document)).encode())

    def document(self) -> dict[str, Any]:
        """Every section, decoded afresh (the caller's to change)."""
        result: dict[str, Any] = json.loads(self.encoded)
        return result

    def table(self, key: str) -> Any:
        """One section decoded afresh, or None when the manifest has none."""
        return self.document().get(key)

    def __contains__(self, key: str) -> bool:
        return key in self.document()

    def replaced(self, **tables: Any) -> ScenarioSections:
        """The same document with ``tables`` set (added, or in place of the written ones)."""
        return ScenarioSections.of({**self.document(), **tables})
