"""`make mutants` prints its counts per module from the results mutmut keeps in ``mutants/``
(tools/mutant_counts.py): each exit code read as mutmut reads it, a mutant not run yet counted
as such, not as a kill."""

from __future__ import annotations

import json
from pathlib import Path

from tools.mutant_counts import counts, main, render


def _meta(root: Path, module: str, codes: dict[str, int | None]) -> None:
    path = root / f"{module}.meta"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"exit_code_by_key": codes, "durations_by_key": {}}))


def test_each_status_is_counted_per_module(tmp_path: Path) -> None:
    _meta(tmp_path, "kernel/signing.py", {"a": 1, "b": 0, "c": None, "d": 33, "e": -24, "f": 3})
    _meta(tmp_path, "assurance/merge.py", {"a": 0, "b": 0})
    table = counts(tmp_path)
    assert dict(table["kernel/signing.py"]) == {
        "killed": 2, "survived": 1, "not run": 1, "no tests": 1, "timeout": 1}
    assert dict(table["assurance/merge.py"]) == {"survived": 2}
    lines = render(table).splitlines()
    assert lines[0].split() == ["module", "total", "killed", "survived", "no", "tests",
                                "timeout", "other", "not", "run"]
    assert lines[1].split() == ["assurance/merge.py", "2", "0", "2", "0", "0", "0", "0"]
    assert lines[2].split() == ["kernel/signing.py", "6", "2", "1", "1", "1", "0", "1"]


def test_no_results_is_a_clear_refusal(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main([str(tmp_path / "mutants")]) == 2
    assert "no such directory (run `make mutants` first)" in capsys.readouterr().err
