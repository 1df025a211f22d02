"""The emulated drive's object dictionary (built in code, stubs/cia402_drive/dictionary.py) is
the one the driver's EDS describes, entry by entry, for any node id.

The two are written separately, as a drive's firmware and its EDS file are: this is where a
disagreement between them shows up, instead of as a puzzling SDO abort in a driver test.
"""

from __future__ import annotations

from typing import Any

import pytest
from canopen import ObjectDictionary
from canopen.objectdictionary import ODVariable

from drivers.canopen402.link import load_object_dictionary
from drivers.canopen402.tables import DEFAULT_EDS
from stubs.cia402_drive.dictionary import object_dictionary


def _entries(od: ObjectDictionary) -> dict[tuple[int, int], tuple[Any, ...]]:
    """(index, sub-index) → everything the EDS can say about the variable there."""
    entries = {}
    for obj in od.values():
        variables = [obj] if isinstance(obj, ODVariable) else list(obj.values())
        for v in variables:
            entries[(v.index, v.subindex)] = (
                type(obj).__name__, v.name, v.data_type, v.access_type, v.default,
                v.pdo_mappable, v.relative)
    return entries


@pytest.mark.parametrize("node_id", [1, 7, 127])
def test_the_emulated_dictionary_is_the_one_the_eds_describes(node_id: int) -> None:
    emulated = _entries(object_dictionary(node_id))
    described = _entries(load_object_dictionary(DEFAULT_EDS, node_id))
    assert sorted(emulated) == sorted(described), "objects differ"
    differing = {f"0x{i:04X}sub{s}": (emulated[(i, s)], described[(i, s)])
                 for (i, s) in emulated if emulated[(i, s)] != described[(i, s)]}
    assert not differing, f"emulated vs EDS: {differing}"


def test_each_node_gets_its_own_pdo_cob_ids() -> None:
    assert object_dictionary(3)[0x1800][1].default == 0x183
    assert object_dictionary(3)[0x1400][1].default == 0x203
    assert object_dictionary(3)[0x1802][1].default == 0x8000_0383  # present, not valid
