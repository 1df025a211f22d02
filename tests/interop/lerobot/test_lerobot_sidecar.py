"""The LeRobot sidecar end to end, in its own venv (tools/venvs.py; built by ``make test``, a
failure to build fails loudly): a robot side made of warden's own codec connects to it, and it
talks gRPC to a stand-in LeRobot server that answers with reply bytes captured from a real
LeRobot 0.4.4 server (``captured/``), or with a hostile pickle, or not at all."""

from __future__ import annotations

import asyncio
import shutil
import ssl
import subprocess
from pathlib import Path

import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

from kernel import wire
from tests.interop.lerobot import harness as h
from tests.sidecars import pickle_assembler as asm
from tests.wire.pki import make_pki
from tools.venvs import ROOT, sidecar_python

pytestmark = pytest.mark.slow


def _observation(index: int) -> tuple[int, tuple[float, ...]]:
    sent = h.PROVENANCE["replies"][index]["observation"]
    return sent["measured_ns"], tuple(sent["state"])


async def test_captured_replies_become_chunks_in_warden_s_clock(tmp_path: Path) -> None:
    with h.stand_in(h.CAPTURED, tmp_path) as (lerobot_port, record), \
            h.sidecar(h.sidecar_toml(lerobot_port), tmp_path) as (port, identity, _):
        async with h.robot(port, identity) as robot:
            offer = await robot.handshake()
            assert offer.offer.policy_checkpoint == h.CHECKPOINT
            assert offer.offer.chunk_horizon == 50
            for index, expected in enumerate(h.PROVENANCE["replies"]):
                t_state, q = _observation(index)
                await robot.observe(index, t_state, q)
                chunk = await robot.next_chunk()
                assert chunk.observation_id == f"o{index}"
                assert chunk.clock_domain == "client"
                assert chunk.times["first_action_time"] == t_state
                assert chunk.times["action_dt"] == round(1e9 / h.FPS)
                assert chunk.config_hash == identity["config_hash"]
                assert np.array_equal(chunk.actions, np.array(expected["actions"], np.float32))
    calls = h.records(record)
    assert [c["call"] for c in calls] == ["Ready", "SendPolicyInstructions", "SendObservations",
                                          "GetActions", "SendObservations", "GetActions"]
    setup = calls[1]["fields"]
    assert setup["lerobot_features"] == h.PROVENANCE["features"]
    sent = calls[2]
    assert sent["type"] == "TimedObservation" and sent["must_go"] is True
    assert sent["timestep"] == 0 and sent["timestamp"] == _observation(0)[0] / 1e9
    assert [sent["values"][name] for name in h.JOINTS] == list(_observation(0)[1])
    assert sent["values"]["wrist"]["shape"] == [h.SIDE, h.SIDE, 3]


async def test_a_hostile_reply_is_refused_and_the_session_goes_on(tmp_path: Path) -> None:
    replies = tmp_path / "replies"
    replies.mkdir()
    canary = tmp_path / "pwned"
    (replies / "reply_0.pickle").write_bytes(
        b"\x80\x02" + asm.call(asm.global_("posix", "system"), asm.text(f"touch {canary}"))
        + b".")
    shutil.copy(h.CAPTURED / "reply_1.pickle", replies / "reply_1.pickle")
    with h.stand_in(replies, tmp_path) as (lerobot_port, record), \
            h.sidecar(h.sidecar_toml(lerobot_port), tmp_path) as (port, identity, log):
        async with h.robot(port, identity) as robot:
            await robot.handshake()
            await robot.observe(0, *_observation(0))
            await _answered(record, 1)
            await robot.observe(1, *_observation(1))
            chunk = await robot.next_chunk()
            assert chunk.observation_id == "o1"
    assert not canary.exists()
    assert "reply refused: the global posix.system is not allowed" in log.read_text()
    assert [c.get("answered") for c in h.records(record) if c["call"] == "GetActions"] == [
        "reply_0.pickle", "reply_1.pickle"]


async def _answered(record: Path, count: int) -> None:
    """Until the stand-in has answered ``count`` GetActions calls."""
    async with asyncio.timeout(10.0):
        while sum(c["call"] == "GetActions" for c in h.records(record)) < count:
            await asyncio.sleep(0.02)


async def test_a_newer_observation_replaces_the_pending_one(tmp_path: Path) -> None:
    """Both observations arrive while the server loads its policy: only the newer is sent,
    as LeRobot's own queue of one keeps only the newest."""
    with h.stand_in(h.CAPTURED, tmp_path) as (lerobot_port, record), \
            h.sidecar(h.sidecar_toml(lerobot_port), tmp_path) as (port, identity, _):
        async with h.robot(port, identity) as robot:
            await robot.handshake()
            await robot.observe(0, *_observation(0))
            await robot.observe(1, *_observation(1))
            chunk = await robot.next_chunk()
            assert chunk.observation_id == "o1"
    sent = [c["timestep"] for c in h.records(record) if c["call"] == "SendObservations"]
    assert sent in ([1], [0, 1])  # [0, 1]: the first went before the second arrived


async def test_an_empty_answer_sends_no_chunk(tmp_path: Path) -> None:
    with h.stand_in(tmp_path / "none", tmp_path) as (lerobot_port, _), \
            h.sidecar(h.sidecar_toml(lerobot_port), tmp_path) as (port, identity, log):
        async with h.robot(port, identity) as robot:
            await robot.handshake()
            await robot.observe(0, *_observation(0))
            with pytest.raises(TimeoutError):
                await robot.next_chunk(timeout_s=1.5)
    assert "LeRobot answered Empty" in log.read_text()


async def test_an_unreachable_lerobot_server_ends_the_session_with_a_reason(
        tmp_path: Path) -> None:
    config = h.sidecar_toml(1, setup_timeout_s=2.0)  # nothing listens on port 1
    with h.sidecar(config, tmp_path) as (port, identity, _):
        async with h.robot(port, identity) as robot:
            await robot.handshake()
            bye = await robot.next_of(wire.Bye, timeout_s=10.0)
    assert bye.reason == wire.ByeReason.SESSION_ENDED
    assert bye.detail.startswith("LeRobot: Ready: ")


async def test_a_second_robot_is_turned_away_while_one_is_served(tmp_path: Path) -> None:
    with h.stand_in(h.CAPTURED, tmp_path) as (lerobot_port, _), \
            h.sidecar(h.sidecar_toml(lerobot_port), tmp_path) as (port, identity, _):
        async with h.robot(port, identity) as first:
            await first.handshake()
            async with h.robot(port, identity) as second:
                with pytest.raises(ConnectionClosed) as closed:
                    await second.ws.recv()
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 1013
            await first.observe(0, *_observation(0))
            assert (await first.next_chunk()).observation_id == "o0"


async def test_a_jpeg_frame_is_a_protocol_violation(tmp_path: Path) -> None:
    with h.stand_in(h.CAPTURED, tmp_path) as (lerobot_port, _), \
            h.sidecar(h.sidecar_toml(lerobot_port), tmp_path) as (port, identity, _):
        async with h.robot(port, identity) as robot:
            await robot.handshake()
            await robot.observe(0, *_observation(0), encoding=wire.ImageEncoding.JPEG)
            bye = await robot.next_of(wire.Bye)
    assert bye.reason == wire.ByeReason.PROTOCOL_VIOLATION
    assert "raw frames only" in bye.detail


async def test_a_sidecar_with_a_token_refuses_a_robot_without_it(tmp_path: Path) -> None:
    token = tmp_path / "token"
    token.write_text("s3cret-robot-token\n")
    listen = f'token_file = "{token}"'
    with h.stand_in(h.CAPTURED, tmp_path) as (lerobot_port, _), \
            h.sidecar(h.sidecar_toml(lerobot_port, listen=listen), tmp_path) as (port, identity, _):
        for wrong in (None, "guess"):
            with pytest.raises(InvalidStatus) as refused:
                async with h.robot(port, identity, token=wrong):
                    pass
            assert refused.value.response.status_code == 401
        async with h.robot(port, identity, token="s3cret-robot-token") as robot:
            await robot.handshake()
            await robot.observe(0, *_observation(0))
            assert (await robot.next_chunk()).observation_id == "o0"


async def test_a_sidecar_behind_tls_with_client_certificates(tmp_path: Path) -> None:
    """``wss://`` with a client certificate required: a robot with the cell's certificate is
    served; one without a certificate, or trusting another authority, never connects."""
    (tmp_path / "pki").mkdir()
    pki = make_pki(tmp_path / "pki")
    listen = (f'cert_file = "{pki.server_cert}"\nkey_file = "{pki.server_key}"\n'
              f'client_ca = "{pki.ca}"')
    good = ssl.create_default_context(cafile=str(pki.ca))
    good.load_cert_chain(pki.client_cert, pki.client_key)
    anonymous = ssl.create_default_context(cafile=str(pki.ca))
    foreign = ssl.create_default_context(cafile=str(pki.other_ca))
    with h.stand_in(h.CAPTURED, tmp_path) as (lerobot_port, _), \
            h.sidecar(h.sidecar_toml(lerobot_port, listen=listen), tmp_path) as (port, identity, _):
        for refused in (anonymous, foreign):
            with pytest.raises((ssl.SSLError, ConnectionClosed, InvalidHandshake, OSError)):
                async with h.robot(port, identity, tls=refused) as robot:
                    await robot.handshake()
        async with h.robot(port, identity, tls=good) as robot:
            await robot.handshake()
            await robot.observe(0, *_observation(0))
            assert (await robot.next_chunk()).observation_id == "o0"


def test_a_bad_configuration_exits_2_naming_the_key(tmp_path: Path) -> None:
    config = tmp_path / "sidecar.toml"
    config.write_text(h.sidecar_toml(8080).replace("fps = 30", "fps = 0"))
    done = subprocess.run([str(sidecar_python()), "-m", "sidecars.lerobot", str(config)],
                          capture_output=True, text=True, cwd=ROOT, timeout=60, check=False)
    assert done.returncode == 2
    assert f"{config}: Expected `float` > 0.0 - at `$.lerobot.fps`" in done.stderr
    assert "Traceback" not in done.stderr


def test_the_sidecar_venv_has_neither_torch_nor_lerobot() -> None:
    done = subprocess.run([str(sidecar_python()), "-c", "import importlib.util as u; print("
                           "[u.find_spec(m) is None for m in ('torch', 'lerobot', 'google')])"],
                          capture_output=True, text=True, timeout=60, check=True)
    assert done.stdout.strip() == "[True, True, True]"
