"""Where a run came from: which manifest (its digest and signer), which software, which host.

A journal's header carries this, so a run can be traced to the exact manifest bytes, the key
that signed them, the revision of warden that ran them and the machine they ran on.
"""

from __future__ import annotations

import socket
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def provenance(digest: str, manifest_path: Path, signer: str | None) -> dict[str, Any]:
    """The header's ``provenance``: ``digest`` the SHA-256 of the manifest bytes that were
    parsed, ``signer`` the key id that verified them, or None when nothing verified them (a
    development run)."""
    return {
        "manifest": {"path": str(manifest_path.resolve()), "sha256": digest},
        "signer": signer,
        "software": {"version": _version(), "revision": revision()},
        "host": socket.gethostname(),
    }


def _version() -> str:
    try:
        return version("warden")
    except PackageNotFoundError:
        return "unknown"


def revision(repo: Path = REPO) -> str:
    """The git commit warden runs from, read from the repository's files (no git needed), or
    "unknown" outside a checkout; "+dirty" is not detectable this way and is not claimed."""
    head = repo / ".git" / "HEAD"
    try:
        text = head.read_text().strip()
    except OSError:
        return "unknown"
    if not text.startswith("ref: "):
        return text
    ref = text.removeprefix("ref: ")
    try:
        return (repo / ".git" / ref).read_text().strip()
    except OSError:
        return _packed(repo, ref)


def _packed(repo: Path, ref: str) -> str:
    try:
        lines = (repo / ".git" / "packed-refs").read_text().splitlines()
    except OSError:
        return "unknown"
    for line in lines:
        parts = line.split()
        if len(parts) == 2 and parts[1] == ref:
            return parts[0]
    return "unknown"
