"""Imports run one way: stubs → kernel → drivers, skills → assurance.

Every ``.py`` under the layered packages is parsed (not imported) and every import of a project
package is checked, including imports inside functions and under ``TYPE_CHECKING``, relative
imports (resolved) and ``importlib.import_module`` with a literal name. Three rules:

- each layer imports only the layers below it (``LAYERS``);
- the emulators and the reference policy server stand in for the other side of a protocol:
  they re-implement it from the spec and import neither ``drivers`` nor ``kernel``;
- the pure core (``assurance``, ``skills``, ``kernel/core``) does no I/O and starts no
  concurrency, so replay is the same code path as a live run. ``pathlib`` is allowed: the core
  uses ``Path`` only as a type of configuration (assurance/kinematics.py's model path).

A failure lists file:line, the import and the rule it breaks.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT = frozenset({"assurance", "skills", "drivers", "kernel", "stubs", "tools", "tests"})
LAYERS: dict[str, frozenset[str]] = {
    "assurance": frozenset({"assurance"}),
    "skills": frozenset({"skills", "assurance"}),
    "drivers": frozenset({"drivers", "assurance"}),
    "kernel": frozenset({"kernel", "drivers", "skills", "assurance"}),
    "stubs": frozenset({"stubs", "kernel", "drivers", "skills", "assurance"}),
}
"""Layer → the project packages its modules may import."""
STAND_INS = ("stubs/ur_controller", "stubs/dynamixel_bus", "stubs/cia402_drive",
             "stubs/policy_server")
STAND_IN_FORBIDDEN = frozenset({"drivers", "kernel"})
PURE_CORE = ("assurance", "skills", "kernel/core")
IO_AND_CONCURRENCY = frozenset({
    "asyncio", "socket", "selectors", "threading", "multiprocessing", "concurrent",
    "subprocess", "signal", "time", "os", "io", "shutil", "tempfile", "uvloop", "websockets",
    "structlog", "serial", "can", "canopen", "dynamixel_sdk", "rtde_control", "rtde_receive",
    "rtde_io", "mujoco",
})
STATEMENT_SHOWN = 80
"""Longest import statement quoted in a report line."""


@dataclass(frozen=True, slots=True)
class Import:
    path: str
    """Relative to the repository root, with forward slashes."""
    line: int
    module: str
    statement: str
    """The import as written (for the report)."""

    @property
    def top(self) -> str:
        return self.module.split(".")[0]


class Rule(StrEnum):
    LAYERS = "layers"
    STAND_INS = "stand-ins"
    PURE_CORE = "pure core"


@dataclass(frozen=True, slots=True)
class Violation:
    imported: Import
    rule: Rule
    message: str

    def __str__(self) -> str:
        where = f"{self.imported.path}:{self.imported.line}"
        statement = self.imported.statement
        if len(statement) > STATEMENT_SHOWN:
            statement = statement[: STATEMENT_SHOWN - 3] + "..."
        return f"{where}: {statement} ({self.message})"


def imports_in(path: str, source: str) -> Iterator[Import]:
    """Every module ``source`` (the file at ``path``) imports, wherever in the file."""
    package = path.removesuffix(".py").split("/")[:-1]  # the module's package, as a list
    for node in ast.walk(ast.parse(source, filename=path)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(path, node.lineno, alias.name, ast.unparse(node))
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *filter(None, [node.module])])
            if module:
                yield Import(path, node.lineno, module, ast.unparse(node))
            for alias in node.names:  # ``from .. import stubs`` imports stubs
                yield Import(path, node.lineno, ".".join(filter(None, [module, alias.name])),
                             ast.unparse(node))
        elif _is_import_module_call(node):
            yield Import(path, node.lineno, node.args[0].value,  # type: ignore[attr-defined]
                         ast.unparse(node))


def _is_import_module_call(node: ast.AST) -> bool:
    if not isinstance(node, ast.Call) or not node.args:
        return False
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    first = node.args[0]
    return name == "import_module" and isinstance(first, ast.Constant) and isinstance(
        first.value, str)


def violations_in(path: str, source: str) -> list[Violation]:
    """Every rule the imports of one file break (a file outside the layers breaks none)."""
    layer = path.split("/")[0]
    if layer not in LAYERS:
        return []
    found: dict[tuple[int, str], Violation] = {}
    for imported in imports_in(path, source):
        for rule, message in _broken_rules(layer, imported):
            # One report per line and package: ``from stubs import plant`` is one arrow.
            found.setdefault((imported.line, imported.top), Violation(imported, rule, message))
    return sorted(found.values(), key=lambda v: (v.imported.path, v.imported.line))


def _broken_rules(layer: str, imported: Import) -> Iterator[tuple[Rule, str]]:
    path, top = imported.path, imported.top
    if top in PROJECT and top not in LAYERS[layer]:
        allowed = ", ".join(sorted(LAYERS[layer]))
        yield Rule.LAYERS, f"{layer} may not import {top}; it may import only {allowed}"
    if _under(path, STAND_INS) and top in STAND_IN_FORBIDDEN:
        yield Rule.STAND_INS, (f"a stand-in may not import {top}: it re-implements the other "
                               "side of its protocol from the spec")
    if _under(path, PURE_CORE) and top in IO_AND_CONCURRENCY:
        yield Rule.PURE_CORE, f"the pure core may not import {top} (I/O or concurrency)"


def _under(path: str, folders: tuple[str, ...]) -> bool:
    return any(path.startswith(folder + "/") for folder in folders)


def project_violations(root: Path = ROOT) -> list[Violation]:
    found = []
    for layer in LAYERS:
        for file in sorted((root / layer).rglob("*.py")):
            path = file.relative_to(root).as_posix()
            found += violations_in(path, file.read_text(encoding="utf-8"))
    return found


def _fail_on(rule: Rule) -> None:
    broken = [v for v in project_violations() if v.rule is rule]
    if broken:
        pytest.fail(f"{len(broken)} imports break the {rule} rule:\n"
                    + "\n".join(map(str, broken)), pytrace=False)


def test_each_layer_imports_only_the_layers_below_it() -> None:
    _fail_on(Rule.LAYERS)


def test_stand_ins_import_neither_drivers_nor_kernel() -> None:
    _fail_on(Rule.STAND_INS)


def test_the_pure_core_does_no_io_and_starts_no_concurrency() -> None:
    _fail_on(Rule.PURE_CORE)


# -- the checker itself: a rule that can never fail is no rule --------------------------------

def test_the_checker_finds_the_layered_files() -> None:
    files = {Path(p).name for layer in LAYERS for p in (ROOT / layer).rglob("*.py")}
    assert {"gates.py", "driver.py", "runtime.py", "emulator.py"} <= files


def test_an_import_inside_a_function_against_the_direction_is_reported() -> None:
    source = "import numpy\n\n\ndef plant():\n    from stubs.plant import base\n    return base\n"
    [violation] = violations_in("drivers/sim/extra.py", source)
    assert (violation.imported.line, violation.imported.module) == (5, "stubs.plant")
    assert str(violation) == ("drivers/sim/extra.py:5: from stubs.plant import base (drivers "
                              "may not import stubs; it may import only assurance, drivers)")


def test_a_stand_in_importing_the_driver_it_stands_in_for_is_reported() -> None:
    source = "from drivers.canopen402.tables import Index\n"
    [violation] = violations_in("stubs/cia402_drive/extra.py", source)
    assert "a stand-in may not import drivers" in str(violation)
    assert violations_in("stubs/plant/extra.py", source) == []  # other stubs may


def test_io_in_the_pure_core_is_reported_and_pathlib_is_not() -> None:
    source = "from pathlib import Path\nimport time\nfrom concurrent.futures import Future\n"
    violations = violations_in("kernel/core/extra.py", source)
    assert [(v.imported.line, v.imported.top) for v in violations] == [(2, "time"),
                                                                      (3, "concurrent")]
    assert violations_in("kernel/shell/extra.py", source) == []


def test_relative_and_dynamic_imports_are_resolved() -> None:
    [violation] = violations_in("drivers/sim/extra.py", "from ...stubs.plant import base\n")
    assert violation.imported.module == "stubs.plant"
    [violation] = violations_in("drivers/sim/extra.py", "from ... import stubs\n")
    assert violation.imported.module == "stubs"
    dynamic = "import importlib\n\nimportlib.import_module('kernel.wire')\n"
    [violation] = violations_in("stubs/policy_server/extra.py", dynamic)
    assert (violation.imported.line, violation.imported.module) == (3, "kernel.wire")
