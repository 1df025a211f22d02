"""``warden --version``: the installed package's version and the revision it runs from."""

from __future__ import annotations

import subprocess
from importlib.metadata import version
from pathlib import Path

from kernel.provenance import revision

ROOT = Path(__file__).resolve().parents[2]
WARDEN = ROOT / ".venv" / "bin" / "warden"


def test_version_names_the_package_version_and_the_revision() -> None:
    done = subprocess.run([str(WARDEN), "--version"], capture_output=True, text=True,
                          check=False, cwd=ROOT, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"warden {version('warden')} (revision {revision()})"
    assert len(revision()) == 40  # this test runs from a checkout: the revision is known
