"""Reason codes: the enum holds every code of CONTRACT.md §3; canonical order and dedup."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from assurance.reasons import CONTRACT_CODES, ReasonCode, canonical, is_known

CONTRACT = Path(__file__).resolve().parents[2] / ".." / "shared" / "CONTRACT.md"


def contract_codes() -> list[str]:
    """Every backticked code in the first column of the §3 table (incl. the trigger row)."""
    if not CONTRACT.is_file():
        pytest.skip(f"public contract not found at {CONTRACT}")
    text = CONTRACT.read_text(encoding="utf-8")
    match = re.search(r"^## 3\. Reason codes\n(.*?)(?=^## )", text, re.S | re.M)
    assert match, "CONTRACT.md has no '## 3. Reason codes' section"
    codes: list[str] = []
    for line in match.group(1).splitlines():
        cells = line.split("|")
        if len(cells) >= 3 and "`" in cells[1]:
            codes += re.findall(r"`([A-Z_]+)`", cells[1])
    return codes


def test_the_contract_table_was_parsed() -> None:
    codes = contract_codes()
    assert {"MALFORMED", "NO_AUTHORITY", "LINK_LOST", "GUARD_FAILED", "E_STOP"} <= set(codes)
    assert len(codes) == len(set(codes)) >= 34


def test_every_contract_code_is_in_the_enum() -> None:
    missing = [code for code in contract_codes() if code not in ReasonCode.__members__]
    assert missing == []


def test_contract_codes_are_exactly_the_contract_table() -> None:
    assert {code.value for code in CONTRACT_CODES} == set(contract_codes())


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
