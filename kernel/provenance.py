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
        "software": {"version": software_version(), "revision": revision()},
        "host": socket.gethostname(),
    }


def software_version() -> str:
    """The installed package's version (its metadata), or "unknown" when not installed."""
    try:
        return version("warden")
    except PackageNotFoundError:
        return "unknown"


def revision(repo: Path = REPO) -> str:
    """The git commit warden runs from, read from the repository's files (no git needed), or
    "unknown" outside a checkout; "+dirty" is not detectable this way and is not claimed.

    A linked worktree (``git worktree add``) has a ``.git`` file naming its own git directory
    (its HEAD) whose ``commondir`` holds the branches and ``packed-refs``."""
    git = _git_dir(repo / ".git")
    if git is None:
        return "unknown"
    try:
        text = (git / "HEAD").read_text().strip()
    except OSError:
        return "unknown"
    if not text.startswith("ref: "):
        return text
    ref = text.removeprefix("ref: ")
    common = _common_dir(git)
    for directory in dict.fromkeys((git, common)):  # per-worktree refs first, then shared
        try:
            return (directory / ref).read_text().strip()
        except OSError:
            continue
    return _packed(common, ref)


def _git_dir(dot_git: Path) -> Path | None:
    """``.git`` itself, or the directory a worktree's ``.git`` file points to."""
    if dot_git.is_dir():
        return dot_git
    try:
        text = dot_git.read_text().strip()
    except OSError:
        return None
    if not text.startswith("gitdir: "):
        return None
    return dot_git.parent / text.removeprefix("gitdir: ").strip()  # absolute stays absolute


def _common_dir(git: Path) -> Path:
    try:
        return git / (git / "commondir").read_text().strip()
    except OSError:
        return git


def _packed(common: Path, ref: str) -> str:
    try:
        lines = (common / "packed-refs").read_text().splitlines()
    except OSError:
        return "unknown"
    for line in lines:
        parts = line.split()
        if len(parts) == 2 and parts[1] == ref:
            return parts[0]
    return "unknown"
