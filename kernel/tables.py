"""Manifest tables read into their frozen msgspec Structs, each field's bounds checked.

The mechanism is :mod:`drivers.settings` (the lowest layer both readers share: a driver's
``[driver]`` settings type and warden's own tables are read by the same function). A table's
type is declared beside the component that uses it (``[policy]`` in
:mod:`kernel.shell.link_settings`, ``[cell]``, ``[trial]``... in :mod:`kernel.settings`,
``[safety]`` in :mod:`kernel.safety.settings`), and each numeric field carries its range once,
on the field itself::

    max_chunks_per_s: Annotated[float, Meta(ge=0.1, le=10_000.0)] = 100.0

Pass a :class:`kernel.scenario.fields.Where` and a refusal is a ``ScenarioError`` naming
``file: table.key: why`` (the manifest loader makes it a ManifestError, the CLI exits 2).
"""

from drivers.settings import bounds_of, check_bounds, read_table, typed

__all__ = ["bounds_of", "check_bounds", "read_table", "typed"]
