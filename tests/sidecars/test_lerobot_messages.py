"""What the sidecar sends LeRobot is what LeRobot's own code sends: the protobuf messages byte for
byte as protobuf's generated code serialized them, and the policy instructions read back (the
way LeRobot's server reads them) to the same fields as the ones LeRobot's own client pickled,
all captured from LeRobot 0.4.4 (tests/interop/lerobot/capture_replies.py). Then the sidecar's
configuration and its reading of a reply against the observation it answers."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from sidecars.lerobot import pickles, protobuf
from sidecars.lerobot.config import ConfigError, load_config
from sidecars.lerobot.mapping import ReplyMismatch, Sent, reply_actions
from sidecars.lerobot.protobuf import PIECE_BYTES, MalformedMessage, TransferState
from sidecars.lerobot.replies import read_reply
from tests.interop.lerobot import harness
from tests.interop.lerobot.lerobot_pickles import unpickle
from tests.sidecars import pickle_assembler as asm

CAPTURED = harness.CAPTURED
PROVENANCE = harness.PROVENANCE
REAL = {name: bytes.fromhex(value) for name, value in PROVENANCE["protobuf"].items()}


def test_messages_are_protobufs_own_bytes() -> None:
    assert REAL["empty"] == protobuf.EMPTY
    assert protobuf.policy_setup(b"setup") == REAL["policy_setup"]
    assert protobuf.observation_message(TransferState.BEGIN, b"\x00" * 300) == REAL[
        "observation_begin"]
    assert protobuf.observation_message(TransferState.MIDDLE, b"m") == REAL["observation_middle"]
    assert protobuf.observation_message(TransferState.END, b"end") == REAL["observation_end"]
    reply = (CAPTURED / "reply_0.pickle").read_bytes()
    assert protobuf.actions_data(REAL["actions_reply_0_before_data"] + reply) == reply


@pytest.mark.parametrize(("size", "states"), [
    (10, [TransferState.END]), (PIECE_BYTES, [TransferState.END]),
    (PIECE_BYTES + 1, [TransferState.BEGIN, TransferState.END]),
    (2 * PIECE_BYTES + 5, [TransferState.BEGIN, TransferState.MIDDLE, TransferState.END]),
])
def test_a_pickle_goes_in_pieces_as_lerobots_sender_cuts_it(
        size: int, states: list[TransferState]) -> None:
    data = bytes(range(256)) * (size // 256) + b"x" * (size % 256)
    pieces = list(protobuf.observation_pieces(data))
    expected = [protobuf.observation_message(state, data[i * PIECE_BYTES:(i + 1) * PIECE_BYTES])
                for i, state in enumerate(states)]
    assert pieces == expected


def test_an_actions_message_is_read_strictly() -> None:
    assert protobuf.actions_data(b"") == b""  # the server's Empty
    assert protobuf.actions_data(b"\x10\x05\x0a\x02ok") == b"ok"  # an unknown varint skipped
    for broken in (b"\x0a\x05ab", b"\x0a", b"\x0a\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\x01",
                   b"\x08\x01", b"\x0b", b"\x0d\x00\x00\x00\x00",  # field 1 as fixed32
                   b"\x09" + b"\x00" * 8, b"\x02\x00",  # as fixed64; field number 0
                   b"\x10\x00" * 65):  # more fields than a message of one has
        with pytest.raises(MalformedMessage):
            protobuf.actions_data(broken)


def test_the_policy_instructions_read_as_lerobots_own_client_wrote_them() -> None:
    features = PROVENANCE["features"]
    for feature in features.values():
        feature["shape"] = tuple(feature["shape"])
    ours = unpickle(pickles.dumps(pickles.RemotePolicyConfig(
        "act", "build/lerobot-act", features, 50, "cpu", {})))
    theirs = unpickle((CAPTURED / "policy_setup.pickle").read_bytes())
    assert (ours.name, ours.fields) == (theirs.name, theirs.fields) == (
        "RemotePolicyConfig", theirs.fields)
    assert list(ours.fields) == list(theirs.fields)  # the dataclass's own field order


def test_an_observation_pickles_as_lerobots_dataclass() -> None:
    rgb = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
    record = unpickle(pickles.dumps(pickles.TimedObservation(
        12.5, 3, {"joint_0.pos": 0.25, "wrist": rgb, "task": "insert"}, must_go=True)))
    assert record.name == "TimedObservation"
    assert list(record.fields) == ["timestamp", "timestep", "observation", "must_go"]
    assert record.fields["observation"]["joint_0.pos"] == 0.25
    assert np.array_equal(record.fields["observation"]["wrist"], rgb)
    with pytest.raises(TypeError, match="is a int"):
        pickles.dumps(pickles.TimedObservation(1.0, 0, {"joint_0.pos": 1}, must_go=True))


# -- the configuration and the reading of a reply ----------------------------------------------

def _config(tmp_path: Path, text: str | None = None):  # type: ignore[no-untyped-def]
    path = tmp_path / "sidecar.toml"
    path.write_text(harness.sidecar_toml(8080) if text is None else text)
    return load_config(str(path))


def _sent(timestep: int = 0, t_first: int = 12_345_678_901_234) -> Sent:
    return Sent(observation=None, q=np.zeros(6), timestep=timestep,  # type: ignore[arg-type]
                t_first=t_first, t_arrival=0)


def test_a_reply_is_read_against_the_observation_it_answers(tmp_path: Path) -> None:
    config = _config(tmp_path)
    expected = PROVENANCE["replies"][0]
    records = read_reply((CAPTURED / expected["file"]).read_bytes())
    sent = _sent(0, expected["observation"]["measured_ns"])
    assert np.array_equal(reply_actions(config, sent, records),
                          np.array(expected["actions"], dtype=np.float32))
    with pytest.raises(ReplyMismatch, match="answers timesteps from 0, the observation sent was 1"):
        reply_actions(config, _sent(1, sent.t_first), records)
    with pytest.raises(ReplyMismatch, match="first action's time is not the observation's"):
        reply_actions(config, _sent(0, sent.t_first + 1), records)


@pytest.mark.parametrize(("change", "message"), [
    ({"fps": 29.0}, "server's --fps is not lerobot.fps"),
    ({"width": 7}, "actions of width \\[7\\], the robot has 6"),
    ({"rows": 51}, "51 actions, asked for at most 50"),
])
def test_a_reply_of_another_shape_or_pace_is_refused(
        tmp_path: Path, change: dict[str, float], message: str) -> None:
    config = _config(tmp_path)
    rows, width = int(change.get("rows", 10)), int(change.get("width", 6))
    data = asm.reply(np.zeros((rows, width), np.float32), t0=12.5, step0=4,
                     fps=change.get("fps", harness.FPS))
    with pytest.raises(ReplyMismatch, match=message):
        reply_actions(config, _sent(4, 12_500_000_000), read_reply(data))


def test_the_example_configuration_loads_and_names_its_offer() -> None:
    example = Path(__file__).parents[2] / "sidecars" / "lerobot" / "example.toml"
    config = load_config(str(example))
    assert config.offer.observation_keys[:2] == ("wrist_rgb", "scene_rgb")
    assert config.config_hash(b"x").startswith("lerobot-sha256:")


@pytest.mark.parametrize(("edit", "message"), [
    (("fps = 30", "fps = -1"), "lerobot.fps"),
    (("fps = 30", "fps = 30\nspeed = 2"), "unknown field `speed`"),
    (('policy_type = "act"\n', ""), "missing required field `policy_type`"),
    (('warden = "scene_rgb"', 'warden = "wrist_rgb"'), "cameras: a camera is named twice"),
    (('"127.0.0.1:8080"', '"localhost"'), "lerobot.server: host:port"),
    (('observation_keys = ["wrist_rgb", ', 'observation_keys = ['),
     "offer.observation_keys: lacks the cameras ['wrist_rgb']"),
    (("[lerobot]", "[lerobot"), "not TOML"),
])
def test_a_bad_configuration_names_the_file_and_key(
        tmp_path: Path, edit: tuple[str, str], message: str) -> None:
    text = harness.sidecar_toml(8080)
    assert edit[0] in text
    with pytest.raises(ConfigError, match=r"sidecar\.toml: .*" + re.escape(message)):
        _config(tmp_path, text.replace(edit[0], edit[1], 1))


def test_a_missing_configuration_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nothing\.toml: cannot read"):
        load_config(str(tmp_path / "nothing.toml"))


def test_the_identity_changes_with_what_is_asked(tmp_path: Path) -> None:
    base = _config(tmp_path)
    other = _config(tmp_path, harness.sidecar_toml(8080, task="pick"))
    assert base.config_hash(b"setup") != other.config_hash(b"setup")
    assert base.config_hash(b"setup") != base.config_hash(b"other setup")
    assert json.dumps(base.features()["observation.images.wrist"]["shape"]) == "[224, 224, 3]"


def test_the_shipped_manifest_allows_the_example_sidecar() -> None:
    """manifests/sim-lerobot.toml pins what sidecars/lerobot/example.toml offers: a change to
    either that the other does not follow would have warden refuse the sidecar."""
    root = Path(__file__).parents[2]
    config = load_config(str(root / "sidecars" / "lerobot" / "example.toml"))
    manifest = tomllib.loads((root / "manifests" / "sim-lerobot.toml").read_text())
    offered = (config.offer.policy_checkpoint, config.config_hash(config.policy_setup()))
    assert offered in {(entry["policy_checkpoint"], entry["config_hash"])
                       for entry in manifest["allowlist"]}
    assert list(config.offer.observation_keys) == manifest["session"]["observation_keys"]
    assert {c.warden for c in config.cameras} == {c["name"] for c in manifest["cameras"]}
    assert manifest["policy"]["port"] == config.listen.port
