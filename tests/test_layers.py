"""Imports run one way: stubs → kernel → drivers, skills → assurance; sidecars → peer.

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
import functools
from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT = frozenset({"assurance", "skills", "drivers", "kernel", "stubs", "peer", "sidecars",
                     "tools", "tests"})
LAYERS: dict[str, frozenset[str]] = {
    "assurance": frozenset({"assurance"}),
    "skills": frozenset({"skills", "assurance"}),
    "drivers": frozenset({"drivers", "assurance"}),
    "kernel": frozenset({"kernel", "drivers", "skills", "assurance"}),
    "stubs": frozenset({"stubs", "peer", "kernel", "drivers", "skills", "assurance"}),
    "peer": frozenset({"peer"}),
    "sidecars": frozenset({"sidecars", "peer"}),
}
"""Layer → the project packages its modules may import. ``peer`` (the policy server's side of
warden's wire) and ``sidecars`` run in a sidecar's own small venv: nothing of warden's below."""
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


# -- the safety monitor: independent of warden's core in code, not only in process -------------

MONITOR = "kernel/safety"
MONITOR_FORBIDDEN = ("kernel.core", "assurance", "skills", "pinocchio")
"""What the monitor must not reach, directly or through any module it imports: warden's core
and the robot model (docs/architecture.md, "The safety monitor")."""
MONITOR_REACHES = frozenset({"assurance", "assurance.reasons"})
"""The one exception (the package and its reason codes), reached only through ``drivers``:
their error types carry the public reason codes (CONTRACT.md §3), an enum of names with no
logic of the core. A module of the monitor may not import it itself."""


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the layered packages (package ``__init__`` included) → its file."""
    found = {}
    for package in sorted(LAYERS):
        for file in sorted((root / package).rglob("*.py")):
            parts = file.relative_to(root).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = file
    return found


def _loaded_by(name: str, modules: dict[str, Path]) -> list[str]:
    """The project modules importing ``name`` runs: each enclosing package's ``__init__``, then
    the longest prefix that is a module (``kernel.safety.checks.Sample`` is an attribute)."""
    parts = name.split(".")
    prefixes = [".".join(parts[:n]) for n in range(1, len(parts) + 1)]
    return [p for p in prefixes if p in modules]


def graph_of(root: Path) -> dict[str, set[str]]:
    """The repository's import graph, built once per session; any other tree's, afresh."""
    return _repository_graph() if root == ROOT else import_graph(root)


@functools.cache
def _repository_graph() -> dict[str, set[str]]:
    return import_graph(ROOT)


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module → the modules it imports (third-party ones by their top name), wherever in the
    file the import is (inside a function too: a lazy import is an import)."""
    modules = module_files(root)
    graph: dict[str, set[str]] = {}
    for module, file in modules.items():
        path = file.relative_to(root).as_posix()
        edges = graph.setdefault(module, set())
        for imported in imports_in(path, file.read_text(encoding="utf-8")):
            edges.update(_loaded_by(imported.module, modules) if imported.top in PROJECT
                         else {imported.top})
        edges.discard(module)
    return graph


def reached_from(start: str, graph: dict[str, set[str]]) -> dict[str, str | None]:
    """Every module ``start`` reaches → the module that imports it on one shortest path."""
    parent: dict[str, str | None] = {start: None}
    frontier = [start]
    while frontier:
        following = []
        for module in frontier:
            for imported in sorted(graph.get(module, ())):
                if imported not in parent:
                    parent[imported] = module
                    following.append(imported)
        frontier = following
    return parent


def _chain(module: str, parent: dict[str, str | None]) -> str:
    chain = [module]
    while (step := parent[chain[-1]]) is not None:
        chain.append(step)
    return " → ".join(reversed(chain))


def monitor_reaches_core(root: Path = ROOT) -> list[str]:
    """Each forbidden module a module of the monitor reaches, with the chain that reaches it."""
    graph = graph_of(root)
    found = []
    for start in sorted(m for m in graph if m.replace(".", "/").startswith(MONITOR)):
        parent = reached_from(start, graph)
        for module in sorted(parent):
            forbidden = any(module == f or module.startswith(f + ".") for f in MONITOR_FORBIDDEN)
            importer = parent[module] or ""
            excused = module in MONITOR_REACHES and not importer.startswith("kernel.safety")
            if forbidden and not excused:
                found.append(_chain(module, parent))
    return found


def import_cycles(prefix: str, root: Path = ROOT) -> list[list[str]]:
    """The import circles among the modules under ``prefix`` (strongly connected components
    of more than one module), each sorted."""
    graph = {m: {i for i in edges if i.startswith(prefix)}
             for m, edges in graph_of(root).items() if m.startswith(prefix)}
    return [sorted(c) for c in _components(graph) if len(c) > 1]


def _components(graph: dict[str, set[str]]) -> list[set[str]]:
    """Tarjan's strongly connected components."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[set[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                component.add(member)
                if member == node:
                    break
            found.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_safety_monitor_reaches_nothing_of_wardens_core() -> None:
    reached = monitor_reaches_core()
    if reached:
        pytest.fail(f"the safety monitor reaches warden's core in {len(reached)} ways:\n"
                    + "\n".join(reached), pytrace=False)


def test_the_safety_monitor_has_no_import_circle() -> None:
    cycles = import_cycles("kernel.safety")
    if cycles:
        pytest.fail("import circles in kernel/safety:\n"
                    + "\n".join(" ↔ ".join(c) for c in cycles), pytrace=False)


def _tree(root: Path, files: dict[str, str]) -> Path:
    for name, source in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(source)
    return root


def test_a_core_module_the_monitor_reaches_through_others_is_reported(tmp_path: Path) -> None:
    root = _tree(tmp_path, {
        "kernel/__init__.py": "", "kernel/safety/__init__.py": "",
        "kernel/safety/service.py": "def plan():\n    from kernel.loader import load\n",
        "kernel/loader.py": "from kernel.core.config import CoreConfig\n",
        "kernel/core/__init__.py": "", "kernel/core/config.py": "import numpy\n",
        "kernel/safety/codes.py": "from drivers.base import DriverInitError\n",
        "drivers/__init__.py": "", "drivers/base.py": "from assurance.reasons import R\n",
        "assurance/__init__.py": "", "assurance/reasons.py": "",
    })
    assert monitor_reaches_core(root) == [
        "kernel.safety.service → kernel.loader → kernel.core",
        "kernel.safety.service → kernel.loader → kernel.core.config",
    ]
    (root / "kernel/safety/codes.py").write_text("from assurance.reasons import R\n")
    assert monitor_reaches_core(root)[:2] == ["kernel.safety.codes → assurance",
                                              "kernel.safety.codes → assurance.reasons"]


def test_an_import_circle_through_a_lazy_import_is_reported(tmp_path: Path) -> None:
    root = _tree(tmp_path, {
        "kernel/__init__.py": "", "kernel/safety/__init__.py": "",
        "kernel/safety/devices.py": "def ur():\n    from kernel.safety.ur import URWatch\n",
        "kernel/safety/ur.py": "from kernel.safety.devices import DeviceLost\n",
        "kernel/safety/checks.py": "import math\n",
    })
    assert import_cycles("kernel.safety", root) == [["kernel.safety.devices",
                                                      "kernel.safety.ur"]]


SANS_IO = "kernel.shell.link_protocol"
"""The policy link's protocol objects (kernel/shell/link_protocol*.py): frames and times in,
frames and events out. The shell owns the socket, the tasks and the clock, so a protocol object
reaches none of them, through any module (a lockstep run drives it on the virtual clock)."""


def sans_io_reaches_io(root: Path = ROOT) -> list[str]:
    """Each I/O, clock or concurrency module a protocol object reaches, with the chain."""
    graph = graph_of(root)
    found = []
    for start in sorted(m for m in graph if m.startswith(SANS_IO)):
        parent = reached_from(start, graph)
        found += [_chain(m, parent) for m in sorted(parent) if m in IO_AND_CONCURRENCY]
    return found


def test_the_link_protocol_objects_reach_no_socket_clock_or_task() -> None:
    reached = sans_io_reaches_io()
    if reached:
        pytest.fail("a policy link protocol object reaches I/O, a clock or concurrency:\n"
                    + "\n".join(reached), pytrace=False)


def test_a_clock_a_protocol_object_reaches_through_another_module_is_reported(
        tmp_path: Path) -> None:
    root = _tree(tmp_path, {
        "kernel/__init__.py": "", "kernel/shell/__init__.py": "",
        "kernel/shell/link_protocol_x.py": "from kernel.shell.pacing import wait\n",
        "kernel/shell/pacing.py": "def wait():\n    import asyncio\n",
        "kernel/shell/client.py": "import asyncio\n",
    })
    assert sans_io_reaches_io(root) == [
        "kernel.shell.link_protocol_x → kernel.shell.pacing → asyncio"]
