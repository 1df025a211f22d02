"""warden's openpi codec against bytes captured from an unmodified openpi server, and against
hostile frames (tests/interop/openpi/capture_frames.py made ``frames/``; its provenance file
names the package versions)."""

from __future__ import annotations

import contextlib
import hashlib
import json
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kernel.openpi_wire import (
    MAX_REPLY_BYTES,
    OpenpiError,
    decode_metadata,
    decode_reply,
    encode_observation,
)

FRAMES = Path(__file__).parent / "frames"


def frame(name: str) -> bytes:
    return (FRAMES / name).read_bytes()


def test_the_captured_frames_are_the_ones_the_provenance_names() -> None:
    provenance = json.loads(frame("provenance.json"))
    assert provenance["packages"]["openpi-server"] == "0.1.0"
    for name, digest in provenance["sha256"].items():
        assert hashlib.sha256(frame(name)).hexdigest() == digest, name


def test_the_metadata_frame_is_read_and_hashed() -> None:
    metadata = decode_metadata(frame("metadata.msgpack"))
    assert metadata.value["reset_pose"][1] == pytest.approx(-1.5708)
    assert metadata.digest == hashlib.sha256(frame("metadata.msgpack")).hexdigest()


def test_a_reply_gives_its_actions_and_the_servers_inference_time() -> None:
    # The scripted policy answers state[:7] + a ramp of 0..0.01 over ten steps (float32).
    first, second = (decode_reply(frame(f"reply{n}.msgpack"), action_dim=7) for n in (1, 2))
    assert first.actions.shape == (10, 7) and first.actions.dtype == np.float64
    np.testing.assert_allclose(first.actions[:, 0], 0.1 + np.linspace(0, 0.01, 10), atol=1e-6)
    np.testing.assert_allclose(second.actions[-1], np.full(7, 0.21), atol=1e-6)
    assert first.infer_ms is not None and 0 <= first.infer_ms < 1000


def test_an_observation_is_packed_byte_for_byte_as_openpis_own_packer_packs_it() -> None:
    rng = np.random.default_rng(1)
    observation = {
        "observation/image": rng.integers(0, 255, (8, 8, 3), dtype=np.uint8),
        "observation/wrist_image": rng.integers(0, 255, (8, 8, 3), dtype=np.uint8),
        "observation/state": np.full(8, 0.1, dtype=np.float32),
        "prompt": "insert the peg",
    }
    assert encode_observation(observation) == frame("observation1.msgpack")


def test_the_traceback_frame_is_text_and_not_a_reply() -> None:
    # openpi sends a server-side exception as a text frame, then closes with 1011: the link
    # sees the frame's type; as bytes it is no MessagePack map.
    assert frame("close_code.txt") == b"1011"
    with pytest.raises(OpenpiError, match="reply frame"):
        decode_reply(frame("reply3.txt"), action_dim=7)


def array(values: np.ndarray, **override: object) -> dict[bytes, object]:
    packed: dict[bytes, object] = {b"__ndarray__": True, b"data": values.tobytes(),
                                   b"dtype": values.dtype.str, b"shape": list(values.shape)}
    packed.update({key.encode(): value for key, value in override.items()})
    return packed


def reply(actions: object) -> bytes:
    return msgspec.msgpack.encode({"actions": actions})


GOOD = np.zeros((5, 7), dtype=np.float32)


@pytest.mark.parametrize(("raw", "message"), [
    (reply(array(GOOD, data=GOOD.tobytes()[:-4])), "holds 136 bytes"),
    (reply(array(GOOD, shape=[5, 7, 3])), "need 420"),
    (reply(array(GOOD, shape=[5, 7, 2**40])), "has shape"),
    (reply(array(GOOD, shape=[-1, 7])), "has shape"),
    (reply(array(GOOD, shape=[5.0, 7])), "has shape"),
    (reply(array(GOOD, dtype="|O")), "has dtype"),
    (reply(array(GOOD.astype(">f4"))), "has dtype"),
    (reply(array(np.zeros((5, 6), np.float32))), "6 dimensions"),
    (reply(array(np.zeros((0, 7), np.float32))), "0 steps"),
    (reply(array(np.zeros((1001, 7), np.float32))), "1001 steps"),
    (reply(array(np.zeros(7, np.float32))), "must be H×D"),
    (reply(array(np.full((5, 7), np.nan, np.float32))), "non-finite"),
    (reply(array(np.full((5, 7), np.inf, np.float64))), "non-finite"),
    (reply([[0.0] * 7] * 5), "not a msgpack_numpy array"),
    (msgspec.msgpack.encode({"action": array(GOOD)}), "no 'actions'"),
    (msgspec.msgpack.encode([1, 2]), "must be a map"),
    (b"\xc1", "not MessagePack"),
    (b"\x91" * 100_000 + b"\x90", "not MessagePack"),
    (b"\x00" * (MAX_REPLY_BYTES + 1), "exceeds"),
])
def test_a_hostile_reply_is_refused_by_name(raw: bytes, message: str) -> None:
    with pytest.raises(OpenpiError, match=message):
        decode_reply(raw, action_dim=7)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=512))
def test_no_bytes_raise_anything_but_a_named_refusal(raw: bytes) -> None:
    with contextlib.suppress(OpenpiError):
        decode_metadata(raw)
    try:
        accepted = decode_reply(raw, action_dim=7)
    except OpenpiError:
        return
    # What is accepted is usable: H×7 finite float64 actions, H within the horizon.
    assert accepted.actions.dtype == np.float64 and accepted.actions.shape[1] == 7
    assert accepted.actions.shape[0] >= 1 and np.isfinite(accepted.actions).all()


def test_arrays_that_cannot_travel_are_refused_before_sending() -> None:
    with pytest.raises(OpenpiError, match="does not travel"):
        encode_observation({"x": np.array([object()])})
