"""Small venvs built from a pinned, hashed lock file, for programs whose pins cannot share
warden's (openpi's server pins NumPy 1; LeRobot's needs torch) or that must stay small (the
LeRobot sidecar: grpcio, NumPy, msgspec, websockets).

Each is built under ``build/`` on first use, keyed by its lock file's hash, so a changed lock
builds a new one; a lock file held while building keeps two processes from building one venv at
once. ``path_entries`` go into the venv's ``site-packages`` as a ``.pth`` file: the sidecar
imports its own package and ``peer`` from this repository without installing warden. A venv
that cannot be built raises :class:`VenvFailed` with pip's own words: never a silent skip.

``python -m tools.venvs lerobot-sidecar`` builds the sidecar's and prints its Python.
"""

from __future__ import annotations

import fcntl
import hashlib
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIDECAR_LOCK = ROOT / "sidecars" / "lerobot" / "requirements.lock"


class VenvFailed(RuntimeError):
    """The venv could not be built; the message holds the command and pip's output."""


def locked_venv(name: str, lock: Path, path_entries: tuple[Path, ...] = (),
                pip_options: tuple[str, ...] = ()) -> Path:
    """The Python of venv ``name`` built from ``lock`` (``--require-hashes``, ``--no-deps``)."""
    key = hashlib.sha256(lock.read_bytes()).hexdigest()[:12]
    venv = ROOT / "build" / f"{name}-venv-{key}"
    python = venv / "bin" / "python"
    ready = venv / ".ready"
    venv.parent.mkdir(parents=True, exist_ok=True)
    with open(venv.parent / f".{name}-venv-{key}.lock", "w") as guard:
        fcntl.flock(guard, fcntl.LOCK_EX)
        if not ready.exists():
            _build(name, venv, lock, pip_options)
            _add_paths(python, path_entries)
            ready.touch()
    return python


def sidecar_python() -> Path:
    """The LeRobot sidecar's venv: its lock, and this repository on its path."""
    return locked_venv("lerobot-sidecar", SIDECAR_LOCK, path_entries=(ROOT,))


def _build(name: str, venv: Path, lock: Path, pip_options: tuple[str, ...]) -> None:
    steps = [
        [sys.executable, "-m", "venv", "--clear", str(venv)],
        [str(venv / "bin" / "pip"), "install", "--quiet", "--disable-pip-version-check",
         "--no-deps", "--require-hashes", *pip_options, "-r", str(lock)],
    ]
    for step in steps:
        done = subprocess.run(step, capture_output=True, text=True, timeout=900, check=False)
        if done.returncode != 0:
            raise VenvFailed(f"building the {name} venv failed: {' '.join(step)}\n"
                             f"{done.stdout}{done.stderr}")


def _add_paths(python: Path, entries: tuple[Path, ...]) -> None:
    if not entries:
        return
    found = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()"
                            "['purelib'])"], capture_output=True, text=True, check=True)
    site = Path(found.stdout.strip())
    (site / "warden-repository.pth").write_text("".join(f"{entry}\n" for entry in entries))


def main(argv: list[str]) -> int:
    builders = {"lerobot-sidecar": sidecar_python}
    if len(argv) != 1 or argv[0] not in builders:
        print(f"usage: python -m tools.venvs {{{','.join(builders)}}}", file=sys.stderr)
        return 2
    try:
        print(builders[argv[0]]())
    except VenvFailed as error:
        print(error, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
