"""Write every catalog scenario to manifests/scenarios/ (``python -m tools.scenarios``)."""

from __future__ import annotations

import sys
from pathlib import Path

from tools.scenarios.catalog import all_documents

TARGET = Path(__file__).resolve().parents[2] / "manifests" / "scenarios"


def main() -> int:
    TARGET.mkdir(parents=True, exist_ok=True)
    for name, text in all_documents().items():
        (TARGET / f"{name}.json").write_text(text, encoding="utf-8")
    print(f"wrote {len(all_documents())} scenarios to {TARGET}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
