"""Property: whatever a file holds, the loaders accept it or refuse it with exit 2, a message
naming the file, and no traceback.

Entry points driven:

- scenarios and journals: ``kernel.cli.main(["replay", FILE])``, the whole command (load,
  replay on the virtual clock, output): exit 0, or 2 naming the file. A journal may also exit 1,
  the replay's verdict that a mutated journal no longer reproduces its recorded commands, or 3,
  a journal whose last line damage left incomplete (replayed up to it).
- manifests: :func:`tests.fuzz.targets.preflight`, which is everything ``warden run`` does
  before it starts a device, an emulator, the plant or a server (manifest loader, ``[policy]``
  settings, ``[task]`` and robot model checks, the clock against the driver, then the world's
  own checks: the ``[driver]`` table against the driver's settings, with the emulator process
  and the plant replaced by a stand-in that stops there); running a whole cell per example is
  not a loader's test. It passes or raises ``ManifestError`` or ``DriverInitError``, which
  ``main`` turns into exit 2 (``tests/cell/test_run_cli.py`` and
  ``tests/cli/test_settings_bounds_cli.py`` check that path). A second property aims the
  mutations at the ``[driver]`` and ``[policy]`` tables, with every key of their settings
  (the ones a shipped manifest leaves at their default too) given extreme numbers.

Inputs start from the shipped files (``manifests/*.toml``, ``manifests/scenarios/*.json``) and a
journal recorded by ``warden run --clock virtual --cycles 1``, mutated by
:mod:`tests.fuzz.mutate`: keys dropped and added, types changed, extreme numbers, unicode, deep
nesting, 5000-digit integers, and byte-level damage.
"""

from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import os
import sys
import tomllib
import typing
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from drivers.base import DriverInitError
from kernel.cli import main
from kernel.manifest import Manifest, ManifestError
from kernel.shell.link_settings import PolicySettings
from tests.fuzz.mutate import byte_mutated, mutated, to_json, to_toml
from tests.fuzz.settings_use import (
    DRIVER_SETTINGS,
    use_driver_settings,
    use_policy,
)
from tests.fuzz.targets import preflight

ROOT = Path(__file__).resolve().parents[2]
SCALE = max(1, int(os.environ.get("WARDEN_FUZZ_SCALE", "1")))
PROPERTY = settings(max_examples=100 * SCALE, deadline=None, suppress_health_check=[
    HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example])
SCENARIOS = {path.name: json.loads(path.read_text())
             for path in sorted((ROOT / "manifests" / "scenarios").glob("*.json"))}
MANIFESTS = {path.name: tomllib.loads(path.read_text())
             for path in sorted((ROOT / "manifests").glob("*.toml"))}
JOURNAL_LINES = 400
"""The recorded journal is cut to its header and first events (a journal prefix is a journal):
a replay per example stays fast."""


def run_cli(argv: list[str]) -> tuple[int, str]:
    """``main(argv)`` with stdout and stderr captured (main writes bytes to stdout)."""
    out, err = io.TextIOWrapper(io.BytesIO()), io.StringIO()
    saved = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = out, err
    try:
        code = main(argv)
    finally:
        sys.stdout, sys.stderr = saved
    return code, err.getvalue()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("property")


@pytest.fixture(scope="module")
def journal(lockstep_run: Path) -> list[Any]:
    """A journal recorded by ``warden run --clock virtual --cycles 1`` (the session's shared
    record, tests/conftest.py), as parsed lines."""
    lines = (lockstep_run / "journal.jsonl").read_text().splitlines()
    events = [json.loads(line) for line in lines]
    chunks = [e for e in events if e.get("kind") in ("chunk", "observation", "computed")][:6]
    # The prefix, and a few of the run's later events a mutation may move into it.
    return [events[0], events[1:JOURNAL_LINES], chunks]


def _check_exit(code: int, err: str, path: Path, allowed: set[int]) -> None:
    event(f"exit {code}" + (f": {err.split(': ')[3][:40]}" if code == 2 else ""))
    assert "Traceback" not in err
    assert code in allowed, err
    if code == 2:
        assert err.startswith(f"warden: invalid input: {path}"), err
        assert err.count("\n") == 1, err  # one line


@PROPERTY
@given(data=st.data(), name=st.sampled_from(sorted(SCENARIOS)))
def test_mutated_scenarios_replay_or_exit_2(workdir: Path, data: st.DataObject,
                                            name: str) -> None:
    text = to_json(data.draw(mutated(SCENARIOS[name]), label="scenario"))
    raw = data.draw(_damaged(text.encode()), label="bytes")
    path = workdir / "scenario.json"
    path.write_bytes(raw)
    code, err = run_cli(["replay", str(path)])
    _check_exit(code, err, path, {0, 2})


@PROPERTY
@given(data=st.data())
def test_mutated_journals_replay_or_exit_2(workdir: Path, journal: list[Any],
                                           data: st.DataObject) -> None:
    header, events, later = journal
    doc = data.draw(mutated({"header": header, "events": events, "later": later}),
                    label="journal")
    lines = [doc.get("header"), *_as_list(doc.get("events")), *_as_list(doc.get("later"))[:1]]
    raw = "\n".join(to_json(line) for line in lines).encode()
    raw = data.draw(_damaged(raw), label="bytes")
    path = workdir / "journal.jsonl"
    path.write_bytes(raw)
    code, err = run_cli(["replay", str(path)])
    _check_exit(code, err, path, {0, 1, 2, 3})
    if code == 3:
        assert "is incomplete (the run was cut off while writing it)" in err


def _damaged(raw: bytes) -> st.SearchStrategy[bytes]:
    """The bytes as they are, or (one time in four) damaged."""
    return st.integers(0, 3).flatmap(lambda n: byte_mutated(raw) if n == 0 else st.just(raw))


def _as_list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else [value]


@PROPERTY
@given(data=st.data(), name=st.sampled_from(sorted(MANIFESTS)))
def test_mutated_manifests_load_or_are_refused(workdir: Path, data: st.DataObject,
                                               name: str) -> None:
    text = to_toml(data.draw(mutated(MANIFESTS[name]), label="manifest"))
    raw = data.draw(_damaged(text.encode()), label="bytes")
    path = workdir / "cell.toml"
    path.write_bytes(raw)
    loaded = _check_preflight(path)
    if loaded is not None:
        _assert_usable(loaded, tomllib.loads(raw.decode()))


def _assert_usable(loaded: Manifest, doc: dict[str, Any]) -> None:
    """What "loaded" must mean, so that a loader accepting everything fails the property: the
    arm's limits are finite, positive and ordered, and the numbers the file states are the
    numbers loaded (a value refused is never replaced by a default)."""
    limits = loaded.core.limits
    arm = limits.arm_mask
    assert np.all(limits.lower[arm] <= limits.upper[arm])
    for rate in (limits.velocity[arm], limits.acceleration[arm]):
        assert np.all(np.isfinite(rate)) and np.all(rate > 0), rate
    robot = doc.get("robot", {})
    for key, loaded_rates in (("velocity_limits", limits.velocity[arm]),
                              ("acceleration_limits", limits.acceleration[arm])):
        stated = robot.get(key)
        if isinstance(stated, list) and len(stated) == arm.sum():
            assert loaded_rates.tolist() == [float(v) for v in stated], key
    for key, value in doc.get("policy", {}).items():
        if key in {f.name for f in msgspec.structs.fields(PolicySettings)} and isinstance(
                value, int | float) and not isinstance(value, bool):
            assert getattr(loaded.policy, key) == value, f"policy.{key}"


def _check_preflight(path: Path) -> Manifest | None:
    """Accepted, or refused the way ``warden run`` exits 2 (naming the file); any other
    exception escapes and fails the property."""
    try:
        loaded = preflight(path)
    except ManifestError as error:
        event(f"refused: {str(error).split(': ')[1][:40]}")
        assert str(error).startswith(f"{path}") or str(error).startswith("--"), error
        return None
    except DriverInitError as error:  # "warden: cannot start the device: ..."
        event(f"refused by the driver: {error.device}")
        assert f"{path}: driver" in str(error), error
        return None
    event("passed")
    return loaded


VENDOR_MANIFESTS = sorted(name for name, doc in MANIFESTS.items()
                          if doc["driver"]["name"] in DRIVER_SETTINGS)
SETTING_NUMBERS = [0, -1, 1, 100.0, 0.5, 1e-9, 5e-324, 65536, 2**31, 2**63 - 1, 1e300, math.inf,
                   -math.inf, math.nan]
"""The class of value the audit found getting through: zero and signs, the subnormal, the
integer edges, absurd magnitudes, inf and NaN."""


def _keys(cls: type) -> list[tuple[str, bool]]:
    """(key, holds a list) for each numeric setting of ``cls`` (the driver's name left out)."""
    hints = typing.get_type_hints(cls)
    keys = []
    fields = (msgspec.structs.fields(cls) if issubclass(cls, msgspec.Struct)
              else dataclasses.fields(cls))
    for field in fields:
        hint, args = hints[field.name], typing.get_args(hints[field.name])
        if hint in (int, float) or (type(None) in args and {int, float} & set(args)):
            keys.append((field.name, False))
        elif typing.get_origin(hint) is tuple and args and args[0] in (int, float):
            keys.append((field.name, True))
    return keys


@PROPERTY
@given(data=st.data(), name=st.sampled_from(VENDOR_MANIFESTS))
def test_mutated_driver_and_policy_settings_are_refused_before_anything_starts(
        workdir: Path, data: st.DataObject, name: str) -> None:
    """Extreme numbers in ``[driver]`` and ``[policy]`` (every key of their settings, set or
    left at its default): refused with exit 2 before anything starts, or usable by the run."""
    doc = copy.deepcopy(MANIFESTS[name])
    driver = doc["driver"]["name"]
    joints = len(doc["robot"]["velocity_limits"])
    tables = {"driver": _keys(DRIVER_SETTINGS[driver]), "policy": _keys(PolicySettings)}
    for _ in range(data.draw(st.integers(1, 3), label="changes")):
        table = data.draw(st.sampled_from(sorted(tables)), label="table")
        key, is_list = data.draw(st.sampled_from(tables[table]), label="key")
        number = data.draw(st.sampled_from(SETTING_NUMBERS), label=f"{table}.{key}")
        doc[table][key] = [*doc[table].get(key, [1] * joints)[:-1], number] if is_list else (
            number)
    if data.draw(st.integers(0, 3), label="mutated further") == 0:
        doc["driver"] = data.draw(mutated(doc["driver"]), label="driver table")
    path = workdir / "settings.toml"
    path.write_text(to_toml(doc))
    loaded = _check_preflight(path)
    if loaded is not None:
        use_policy(loaded.policy, loaded.core.control_period_ns)
        assert isinstance(loaded.driver_settings, DRIVER_SETTINGS[driver])
        use_driver_settings(loaded.driver_settings, loaded.core.control_period_ns / 1e9)


def test_the_shipped_files_pass_unmutated(workdir: Path, journal: list[Any]) -> None:
    """The starting points are valid: a mutation is what a refusal is about."""
    for name in MANIFESTS:
        preflight(ROOT / "manifests" / name)
    path = workdir / "journal.jsonl"
    header, events, _ = journal
    path.write_text("\n".join(json.dumps(line) for line in [header, *events]))
    assert run_cli(["replay", str(path)])[0] == 0
    for name in SCENARIOS:
        assert run_cli(["replay", str(ROOT / "manifests" / "scenarios" / name)])[0] == 0
