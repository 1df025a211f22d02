"""The simulated cell driven by an unmodified openpi server (``[policy] protocol = "openpi"``):
warden reads its metadata frame, the core decides the offer made of the manifest's declarations
and the metadata's digest, and the server's replies are admitted as chunks through every gate.

The server is openpi's own ``WebsocketPolicyServer`` in its own venv, serving a scripted policy
that answers the observed state (the arm holds where it is in the learned approach). The cycle
cannot verify (nothing moves the peg into the hole), so it runs out after ``cycle_timeout_s``.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import re
from pathlib import Path

import pytest
import websockets.asyncio.client as ws_client

from kernel.cli import main
from kernel.core.lines import ADMITTED
from kernel.shell.link_openpi import CONFIG_HASH_PREFIX
from tests.cell.harness import MANIFESTS, replays_identically, run_dir
from tests.interop.openpi.test_openpi_live import start

pytestmark = pytest.mark.slow
CHECKPOINT = "scripted-hold@unattested"


async def _metadata_digest(port: int) -> str:
    """What an operator pins in the allowlist: the digest of the server's metadata frame."""
    async with ws_client.connect(f"ws://127.0.0.1:{port}", max_size=None) as link:
        return CONFIG_HASH_PREFIX + hashlib.sha256(await link.recv()).hexdigest()


def _openpi_manifest(directory: Path, port: int, config_hash: str) -> Path:
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    for pattern, new in ((r"(?m)^launch = true( *)#", r"launch = false\1#"),
                         (r"(?m)^port = 0( *)#", rf"port = {port}\1#"),
                         (r"(?m)^cycles = \d+", "cycles = 1"),
                         (r"(?m)^cycle_timeout_s = [0-9.]+", "cycle_timeout_s = 12.0"),
                         (r"(?m)^\[policy\]\n", '[policy]\nprotocol = "openpi"\n')):
        text, count = re.subn(pattern, new, text, count=1)
        assert count == 1, pattern
    path = directory / "openpi.toml"
    path.write_text(text + f'\n[policy.openpi]\npolicy_checkpoint = "{CHECKPOINT}"\n'
                    'prompt = "insert the peg"\n'
                    f'\n[[allowlist]]\npolicy_checkpoint = "{CHECKPOINT}"\n'
                    f'config_hash = "{config_hash}"\n'
                    f'\n[operator]\nsocket = "{directory / "operator.sock"}"\n')
    return path


def test_an_unmodified_openpi_server_drives_the_cell_through_every_gate(tmp_path: Path) -> None:
    for port in start("--dim", "6", "--horizon", "20"):
        digest = asyncio.run(_metadata_digest(port))
        manifest = _openpi_manifest(tmp_path, port, digest)
        code = main(["run", str(manifest), "--journal-dir", str(tmp_path / "runs")])
    assert code == 1  # the held arm never inserts: the cycle runs out, not verified
    directory = run_dir(tmp_path / "runs")
    summary = json.loads((directory / "summary.json").read_text())
    link = summary["link"]
    assert link["handshakes_accepted"] >= 1 and "protocol_violations" not in link, link
    assert link["chunks_admitted"] >= 3 and link["frames_out"] == link["observations_sent"], link
    lines = [json.loads(line) for line in (directory / "decisions.jsonl").read_text().splitlines()]
    handshake = next(line for line in lines if line["kind"] == "handshake")
    assert handshake["decision"] == "ACCEPT"
    admitted = [line for line in lines if line["kind"] == "chunk" and line["decision"] in ADMITTED]
    assert len(admitted) == link["chunks_admitted"]
    assert all(re.fullmatch(r"warden-[0-9a-f]{8}/openpi-\d+", line["chunk_id"])
               for line in admitted), admitted[:2]
    assert replays_identically(directory)
