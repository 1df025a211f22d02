"""Manifests for cell tests: the shipped ones, with a test's overrides and a temp journal."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import msgspec

from kernel.core.lines import encode
from kernel.manifest import ClockKind, Manifest, load_manifest
from kernel.replay import Replay
from kernel.scenario.load import load_scenario

MANIFESTS = Path(__file__).resolve().parents[2] / "manifests"


def manifest(name: str, cycles: int = 1, clock: ClockKind | None = None) -> Manifest:
    loaded = load_manifest(MANIFESTS / name)
    cell = msgspec.structs.replace(loaded.cell, cycles=cycles, clock=clock or loaded.cell.clock)
    return dataclasses.replace(loaded, cell=cell)


def run_dir(journal_root: Path) -> Path:
    (directory,) = [p for p in journal_root.iterdir() if p.is_dir()]
    return directory


def replays_identically(directory: Path) -> bool:
    """The journal of a run, replayed, gives the run's decision log byte for byte and every
    command the run wrote to its driver bit for bit."""
    replay = Replay(load_scenario(directory / "journal.jsonl"))
    replayed = b"".join(encode(line) + b"\n" for line in replay.lines())
    return (replayed == (directory / "decisions.jsonl").read_bytes()
            and replay.first_difference is None and replay.commands_checked > 0)
