"""Reason codes: the enum holds every code of docs/contract.md §3 and the names §8 added;
canonical order and dedup."""

from __future__ import annotations

import re
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from assurance.reasons import CONTRACT_CODES, ReasonCode, canonical, is_known

CONTRACT = Path(__file__).resolve().parents[2] / "docs" / "contract.md"


def _section(heading: str) -> str:
    """The body of the section whose heading line matches ``heading`` (a regex), up to the next
    heading of any level. A missing file or section fails: the contract is part of the repo."""
    text = CONTRACT.read_text(encoding="utf-8")
    match = re.search(rf"^{heading}\n(.*?)(?=^#+ |\Z)", text, re.S | re.M)
    assert match, f"{CONTRACT} has no section matching {heading!r}"
    return match.group(1)


def _first_column_codes(section: str) -> list[str]:
    """Every backticked code in the first column of the section's tables."""
    codes: list[str] = []
    for line in section.splitlines():
        cells = line.split("|")
        if len(cells) >= 3 and "`" in cells[1]:
            codes += re.findall(r"`([A-Z_]+)`", cells[1])
    return codes


def contract_codes() -> list[str]:
    """Every code of the §3 table (incl. the trigger row)."""
    return _first_column_codes(_section(r"## 3\. Reason codes"))


def added_codes() -> list[str]:
    """Every code warden added (§8, "Added names")."""
    return _first_column_codes(_section(r"### Added names"))


def test_the_contract_table_was_parsed() -> None:
    codes = contract_codes()
    assert {"MALFORMED", "NO_AUTHORITY", "LINK_LOST", "GUARD_FAILED", "E_STOP"} <= set(codes)
    assert len(codes) == len(set(codes)) >= 34


def test_every_contract_code_is_in_the_enum() -> None:
    missing = [code for code in contract_codes() if code not in ReasonCode.__members__]
    assert missing == []


def test_contract_codes_are_exactly_the_contract_table() -> None:
    assert {code.value for code in CONTRACT_CODES} == set(contract_codes())


def test_every_added_code_is_documented_and_no_more() -> None:
    added = added_codes()
    assert len(added) == len(set(added))
    assert set(added) == {code.value for code in ReasonCode if code not in CONTRACT_CODES}


def test_values_equal_names() -> None:
    assert all(code.name == code.value for code in ReasonCode)


def test_canonical_orders_by_definition_and_deduplicates() -> None:
    codes = [ReasonCode.STATE_DIVERGED, ReasonCode.PHASE_MISMATCH, ReasonCode.MALFORMED,
             ReasonCode.PHASE_MISMATCH]
    assert canonical(codes) == (ReasonCode.MALFORMED, ReasonCode.PHASE_MISMATCH,
                                ReasonCode.STATE_DIVERGED)
    assert canonical([]) == ()


@given(st.lists(st.sampled_from(list(ReasonCode)), max_size=20))
def test_canonical_is_a_sorted_set(codes: list[ReasonCode]) -> None:
    result = canonical(codes)
    order = list(ReasonCode)
    assert set(result) == set(codes) and len(result) == len(set(codes))
    assert [order.index(c) for c in result] == sorted(order.index(c) for c in result)
    assert canonical(reversed(codes)) == result


def test_is_known() -> None:
    assert is_known("EXPIRED") and is_known(ReasonCode.OOD)
    for bad in ("expired", "NOT_A_CODE", "", None, 3):
        assert not is_known(bad)
