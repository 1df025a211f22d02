"""All scenario specs, by module."""

from __future__ import annotations

from tools.scenarios import (
    catalog_authority,
    catalog_cameras,
    catalog_cartesian,
    catalog_collision,
    catalog_context,
    catalog_identity,
    catalog_network,
    catalog_queue,
    catalog_recovery,
    catalog_rtc,
    catalog_seed,
    catalog_time,
)
from tools.scenarios.base import dumps

MODULES = (
    catalog_seed, catalog_identity, catalog_context, catalog_time, catalog_queue,
    catalog_authority, catalog_network, catalog_recovery, catalog_cartesian, catalog_collision,
    catalog_rtc, catalog_cameras,
)


def all_documents() -> dict[str, str]:
    documents = {}
    for module in MODULES:
        for build in module.SCENARIOS:
            spec = build()
            if spec.name in documents:
                raise ValueError(f"duplicate scenario name {spec.name}")
            documents[spec.name] = dumps(spec.document())
    return documents
