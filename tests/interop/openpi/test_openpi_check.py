"""``warden check`` against openpi's own, unmodified server (in its own venv): the metadata
frame's digest is what the allowlist must pin, and check says so, with the entry to add."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

from drivers.readiness import CheckVerdict
from kernel.app.check_policy import policy_rows
from kernel.manifest import load_manifest
from tests.cell.harness import MANIFESTS
from tests.interop.openpi.test_openpi_cell import CHECKPOINT, _metadata_digest
from tests.interop.openpi.test_openpi_live import start


def _manifest(directory: Path, port: int, pinned: str | None) -> Path:
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    text = text.replace("launch = true ", "launch = false", 1).replace(
        "port = 0 ", f"port = {port}", 1)
    text = text.replace("[policy]\n", '[policy]\nprotocol = "openpi"\n', 1)
    text += f'\n[policy.openpi]\npolicy_checkpoint = "{CHECKPOINT}"\n'
    if pinned is not None:
        text += f'\n[[allowlist]]\npolicy_checkpoint = "{CHECKPOINT}"\nconfig_hash = "{pinned}"\n'
    path = directory / "openpi.toml"
    path.write_text(text)
    return path


def test_check_reads_the_openpi_servers_digest_and_says_what_to_pin(tmp_path: Path) -> None:
    for port in start("--dim", "6", "--horizon", "20"):
        digest = asyncio.run(_metadata_digest(port))
        unpinned = asyncio.run(policy_rows(load_manifest(_manifest(tmp_path, port, None))))
        pinned = asyncio.run(policy_rows(load_manifest(_manifest(tmp_path, port, digest))))
    link, configuration = unpinned
    assert link.verdict == CheckVerdict.READY and link.measured == "connected"
    assert configuration.verdict == CheckVerdict.NOT_READY
    assert configuration.measured == f"config_hash {digest}"
    assert re.search(rf"add \[\[allowlist\]\] policy_checkpoint = '{re.escape(CHECKPOINT)}', "
                     rf"config_hash = '{re.escape(digest)}'", configuration.reason)
    assert [row.verdict for row in pinned] == [CheckVerdict.READY, CheckVerdict.READY]
