"""The README's command lines against what ships: every emulator command is the one `warden run`
starts for its shipped manifest (same ids, nodes, gripper), every `warden` command's options
exist, every manifest it names is there, and it says where the commands live (`.venv/bin`)."""

from __future__ import annotations

import argparse
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from kernel.cli import _parser
from kernel.manifest import Manifest, load_manifest
from stubs.cell.emulated import LAUNCHERS

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
PICKED_AT_START = frozenset({"--host", "--channel", "--port"})
"""Addresses a launcher picks free at each start (a loopback address, a multicast group and
port): any value in the README is as good as the launcher's."""


def _emulator_lines() -> dict[str, list[str]]:
    lines = [shlex.split(line) for line in README.splitlines()
             if line.startswith("python -m stubs.")]
    return {words[2]: words[3:] for words in lines}


def _shipped() -> dict[str, Manifest]:
    """Each vendor driver's shipped simulated manifest, by its emulator's module."""
    found: dict[str, Manifest] = {}
    for path in sorted((ROOT / "manifests").glob("sim-*.toml")):
        manifest = load_manifest(path)
        if manifest.driver_name in LAUNCHERS:
            module = LAUNCHERS[manifest.driver_name](manifest, manifest.emulator.plant).module
            found.setdefault(module, manifest)
    return found


def _options(words: list[str]) -> dict[str, str]:
    pairs = dict(zip(words[::2], words[1::2], strict=True))
    assert all(flag.startswith("--") for flag in pairs), words
    return pairs


def test_the_readme_says_where_the_commands_live() -> None:
    assert ". .venv/bin/activate" in README
    assert ".venv/bin/warden" in README


@pytest.mark.parametrize("module", sorted(_shipped()))
def test_each_emulator_command_is_the_one_its_shipped_manifest_starts(module: str) -> None:
    readme = _emulator_lines()
    assert module in readme, f"the README has no `python -m {module}` line"
    manifest = _shipped()[module]
    launch = LAUNCHERS[manifest.driver_name](manifest, manifest.emulator.plant)
    expected = {flag: value for flag, value in _options(list(launch.args)).items()
                if flag not in PICKED_AT_START}
    given = _options(readme[module])
    assert {flag: value for flag, value in given.items() if flag not in PICKED_AT_START} == (
        expected), f"README's {module} line differs from {manifest.path.name}'s emulator"
    assert set(given) <= _help_flags(module), f"{module} --help lacks one of {sorted(given)}"


PASSED_ON = {"serve-policy": "stubs.policy_server"}
"""Commands that hand their arguments to another program's parser."""


def _help_flags(module: str) -> set[str]:
    shown = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True,
                           text=True, cwd=ROOT, timeout=120, check=True).stdout
    return set(re.findall(r"--[a-z-]+", shown))


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _flags(parser: argparse.ArgumentParser) -> set[str]:
    """Every option of ``parser`` and of its own subcommands (``manifest sign --out``)."""
    flags = {flag for action in parser._actions for flag in action.option_strings}
    for child in _subparsers(parser).values():
        flags |= _flags(child)
    return flags


def _warden_commands() -> list[str]:
    return [text for text in re.findall(r"`(warden[^`]*)`", README) if text != "warden"]


def test_every_warden_command_in_the_readme_exists_with_its_options() -> None:
    parser = _parser()
    commands = _subparsers(parser)
    checked = 0
    for text in _warden_commands():
        words = text.split()
        if words[1].startswith("-"):  # warden --version
            own = {flag for action in parser._actions for flag in action.option_strings}
            assert words[1] in own, f"`{text}`: warden has no option {words[1]}"
            continue
        assert words[1] in commands, f"`{text}`: no command {words[1]!r}"
        known = (_help_flags(PASSED_ON[words[1]]) if words[1] in PASSED_ON
                 else _flags(commands[words[1]]))
        unknown = set(re.findall(r"--[a-z-]+", text)) - known
        assert not unknown, f"`{text}`: {sorted(unknown)} are not options of {words[1]}"
        for path in re.findall(r"manifests/[\w./-]+\.(?:toml|json)", text):
            assert (ROOT / path).is_file(), f"`{text}`: {path} does not ship"
        checked += 1
    assert checked >= 20
