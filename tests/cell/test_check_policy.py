"""``warden check``'s policy server rows (kernel/app/check_policy.py): the server reached as a
run reaches it (TLS, token, subprotocol), without a session; what a refusal says; and for a
whole check of the simulated cell, the rows in the table and the exit code."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from drivers.readiness import CheckVerdict
from kernel.app.check import check_device, load_checked
from kernel.app.check_policy import policy_rows
from kernel.manifest import Manifest, load_manifest
from kernel.signing import generate_keypair, sign
from peer.access import Access
from stubs.cell.sim_world import SimWorld
from stubs.plant.mujoco_plant import MujocoPlant
from stubs.policy_server import PolicyServer
from tests.cell.harness import MANIFESTS
from tests.wire.harness import server_config
from tests.wire.pki import Pki, make_pki

TOKEN = "check-token-31"


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))


def _manifest(tmp_path: Path, port: int, pki: Pki | None, token: str = TOKEN) -> Path:
    text = (MANIFESTS / "sim-ur5e.toml").read_text()
    text = text.replace("launch = true ", "launch = false", 1).replace(
        "port = 0 ", f"port = {port}", 1)
    if pki is not None:
        secret = tmp_path / "token"
        secret.write_text(token + "\n")
        secret.chmod(0o600)
        text += (f'\n[policy.tls]\nca_file = "{pki.ca}"\ncert_file = "{pki.client_cert}"\n'
                 f'key_file = "{pki.client_key}"\n[policy.auth]\ntoken_file = "{secret}"\n')
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path


def _verdicts(rows: list) -> dict[str, str]:  # type: ignore[type-arg]
    return {row.name: row.verdict for row in rows}


def _secured(pki: Pki) -> Access:
    return Access(cert_file=str(pki.server_cert), key_file=str(pki.server_key),
                  client_ca=str(pki.ca), token=TOKEN)


async def test_a_secured_server_is_reached_without_a_session(pki: Pki, tmp_path: Path) -> None:
    async with PolicyServer(server_config(access=_secured(pki))) as server:
        manifest = load_manifest(_manifest(tmp_path, server.port, pki))
        rows = await policy_rows(manifest)
        await asyncio.sleep(0.05)  # let the server see the connection end
        stats = server.stats
    assert _verdicts(rows) == {"policy server": CheckVerdict.READY,
                               "policy configuration": CheckVerdict.NOT_EXERCISED}
    link = rows[0]
    assert "certificate verified" in link.measured and "token accepted" in link.measured
    assert "subprotocol warden.v1" in link.measured
    assert stats.connections == 1 and stats.hellos == [] and stats.observations == 0


async def test_a_wrong_token_is_not_ready_with_what_to_check(pki: Pki, tmp_path: Path) -> None:
    async with PolicyServer(server_config(access=_secured(pki))) as server:
        manifest = load_manifest(_manifest(tmp_path, server.port, pki, token="wrong"))
        (row,) = await policy_rows(manifest)
    assert row.verdict == CheckVerdict.NOT_READY
    assert "refused this robot's credentials (HTTP 401); check [policy.auth]" in row.reason


async def test_nobody_listening_is_not_ready(tmp_path: Path) -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # closed again: nobody listens there
    (row,) = await policy_rows(load_manifest(_manifest(tmp_path, port, None)))
    assert row.verdict == CheckVerdict.NOT_READY and "not reachable" in row.reason


async def test_a_launched_server_is_not_exercised() -> None:
    (row,) = await policy_rows(load_manifest(MANIFESTS / "sim-ur5e.toml"))
    assert row.verdict == CheckVerdict.NOT_EXERCISED and "launch = true" in row.reason


def test_a_whole_check_of_the_cell_includes_the_policy_server(pki: Pki, tmp_path: Path) -> None:
    """The simulated cell, signed, against a reference server over TLS with a token: every
    row READY or NOT EXERCISED."""
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    generate_keypair(tmp_path / "signer.key", trusted / "signer.pub")

    async def checked() -> tuple[Manifest, list]:  # type: ignore[type-arg]
        async with PolicyServer(server_config(access=_secured(pki))) as server:
            path = _manifest(tmp_path, server.port, pki)
            sign(path, tmp_path / "signer.key")
            manifest, signature = load_checked(path, trusted)
            assert signature.verdict == CheckVerdict.READY
            world = SimWorld(manifest.core.control_period_ns, MujocoPlant())
            try:
                return manifest, await check_device(manifest, world, 0.5)
            finally:
                world.close()

    _, findings = asyncio.run(checked())
    verdicts = _verdicts(findings)
    assert verdicts["policy server"] == CheckVerdict.READY, findings
    assert [f.name for f in findings if f.verdict == CheckVerdict.NOT_READY] == []
