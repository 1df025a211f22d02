"""The openpi venv the interop tests run openpi's own server in, built from the pinned lock.

openpi pins ``numpy<2`` and warden pins NumPy 2, so openpi's packages cannot share warden's
venv. ``make test`` builds this one on first use (about 10 s from the package index) under
``build/`` (``tools/venvs.py``). A venv that cannot be built fails the test that needs it,
loudly, with pip's own words: never a skip.
"""

from __future__ import annotations

from pathlib import Path

from tools.venvs import locked_venv

LOCK = Path(__file__).with_name("requirements.lock")


def openpi_python() -> Path:
    """The Python of the openpi venv, built from :data:`LOCK` if it is not there yet."""
    return locked_venv("openpi", LOCK)
