"""The openpi venv the interop tests run openpi's own server in, built from the pinned lock.

openpi pins ``numpy<2`` and warden pins NumPy 2, so openpi's packages cannot share warden's
venv. ``make test`` builds this one on first use (about 10 s from the package index) under
``build/``, keyed by the lock file's hash, so a changed lock builds a new one. A venv that
cannot be built fails the test that needs it, loudly, with pip's own words: never a skip.
"""

from __future__ import annotations

import fcntl
import hashlib
import subprocess
import sys
from pathlib import Path

LOCK = Path(__file__).with_name("requirements.lock")
ROOT = Path(__file__).resolve().parents[3]


class EnvironmentFailed(RuntimeError):
    """The openpi venv could not be built; the message holds pip's output."""


def openpi_python() -> Path:
    """The Python of the openpi venv, built from :data:`LOCK` if it is not there yet."""
    key = hashlib.sha256(LOCK.read_bytes()).hexdigest()[:12]
    venv = ROOT / "build" / f"openpi-venv-{key}"
    python = venv / "bin" / "python"
    ready = venv / ".ready"
    venv.parent.mkdir(parents=True, exist_ok=True)
    with open(venv.parent / f".openpi-venv-{key}.lock", "w") as guard:
        fcntl.flock(guard, fcntl.LOCK_EX)  # two test processes never build it at once
        if not ready.exists():
            _build(venv)
            ready.touch()
    return python


def _build(venv: Path) -> None:
    steps = [
        [sys.executable, "-m", "venv", "--clear", str(venv)],
        [str(venv / "bin" / "pip"), "install", "--quiet", "--disable-pip-version-check",
         "--no-deps", "--require-hashes", "-r", str(LOCK)],
    ]
    for step in steps:
        done = subprocess.run(step, capture_output=True, text=True, timeout=600, check=False)
        if done.returncode != 0:
            raise EnvironmentFailed(f"building the openpi venv failed: {' '.join(step)}\n"
                                    f"{done.stdout}{done.stderr}")
