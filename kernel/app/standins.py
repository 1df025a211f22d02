"""The stand-ins for the world, found by name through entry points, never imported.

Simulation needs things a real cell provides itself: the plant and the device emulators (a
*world*), the reference policy (a *policy*), an operator who accepts recovery (an *operator*).
They live in ``stubs/``, above the kernel; the kernel reaches them only through the entry-point
groups below, which the project's own package declares (``pyproject.toml``) and any other
package may extend. A robot PC without the stand-ins installed runs real devices only, and a
manifest that asks for a stand-in that is not installed is refused with its name.

- ``warden.worlds``, by driver name (``sim``, ``ur_rtde``, ...): ``factory(manifest) -> World``,
  the plant, or the driver's emulator with the plant behind it;
- ``warden.policies``: ``reference`` (the reference policy server as a process on loopback),
  ``local`` (the reference policy in process, on the virtual clock), ``serve`` (the same server
  in the foreground, for ``warden serve-policy``: ``serve(context, host, port) -> exit code``);
- ``warden.operators``: ``simulated`` (the simulated operator).
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import Any

from kernel.manifest import ManifestError

WORLDS = "warden.worlds"
POLICIES = "warden.policies"
OPERATORS = "warden.operators"


def available(group: str) -> dict[str, str]:
    """Every stand-in of ``group`` by name, and where it lives."""
    return {point.name: point.value for point in entry_points(group=group)}


def load(group: str, name: str) -> Any:
    """The stand-in ``name`` of ``group`` (a class or factory).

    Raises:
        ManifestError: no stand-in of that name is installed.
    """
    found = [point for point in entry_points(group=group) if point.name == name]
    if not found:
        known = ", ".join(sorted(available(group))) or "none installed"
        raise ManifestError(f"no stand-in {name!r} in {group} (known: {known})")
    return found[0].load()
