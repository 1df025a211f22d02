"""The counts of a mutmut run, per mutated module: how many mutants were killed, survived, had no
test reaching them, timed out or were not run yet (a run stopped early keeps its results).

Reads the ``.meta`` files mutmut 3 writes next to each mutated module under ``mutants/``
(``exit_code_by_key``: mutant name to the exit code of its test run). Usage, from the repository
root after ``make mutants``: ``python -m tools.mutant_counts [mutants]``.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

COLUMNS = ("killed", "survived", "no tests", "timeout", "other", "not run")


def status(exit_code: int | None) -> str:
    """mutmut's reading of a mutant's exit code (mutmut/stats.py, status_by_exit_code)."""
    if exit_code is None:
        return "not run"
    if exit_code in (1, 3):  # a test failed, or pytest's internal error: caught
        return "killed"
    if exit_code == 0:
        return "survived"
    if exit_code in (5, 33):
        return "no tests"
    if exit_code in (24, -24, 36, 152, 255):
        return "timeout"
    return "other"


def counts(mutants: Path) -> dict[str, Counter[str]]:
    """Per module (its path inside the repository): the count of each status."""
    table: dict[str, Counter[str]] = {}
    for meta in sorted(mutants.rglob("*.py.meta")):
        codes = json.loads(meta.read_text())["exit_code_by_key"]
        module = meta.relative_to(mutants).as_posix().removesuffix(".meta")
        table[module] = Counter(status(code) for code in codes.values())
    return table


def render(table: dict[str, Counter[str]]) -> str:
    width = max([len("module"), *map(len, table)])
    lines = [f"{'module':<{width}}  {'total':>5}  " + "  ".join(f"{c:>8}" for c in COLUMNS)]
    for module, seen in table.items():
        cells = "  ".join(f"{seen[c]:>8}" for c in COLUMNS)
        lines.append(f"{module:<{width}}  {sum(seen.values()):>5}  {cells}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    mutants = Path(argv[0] if argv else "mutants")
    if not mutants.is_dir():
        print(f"{mutants}: no such directory (run `make mutants` first)", file=sys.stderr)
        return 2
    print(render(counts(mutants)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
