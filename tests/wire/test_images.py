"""Camera frames over warden's protocol 3: a real core behind a real client, its frames read by
a camera hub from real sources on threads, sent to the reference server, which checks every
frame with its own codec (stubs/policy_server/images.py). The journal keeps the digests, and
the observation is as old as its oldest frame."""

from __future__ import annotations

import hashlib

import cv2
import msgspec
import numpy as np
import pytest

from drivers.camera import frame_digest
from kernel import wire
from kernel.core.events import ObservationEvent
from kernel.shell.cameras import CameraHub, encode_jpeg
from kernel.shell.link_types import SeenImage
from peer.frames import CameraShape, ImageProblem, check_images, jpeg_size
from peer.protocol import Observation as PeerObservation
from stubs.policy_server.images import decode_jpeg
from tests.wire.cameras import HEIGHT, WIDTH, PatternCamera, settings
from tests.wire.harness import (
    LoopbackGateway,
    journal_round_trip,
    running,
    server_config,
    wait_for,
)

NAMES = ("wrist_rgb", "scene_rgb")
SHAPES = tuple(CameraShape(name, WIDTH, HEIGHT) for name in NAMES)
FRAME_AGE_NS = 15_000_000
CAMERAS_SECTION = [{"name": "wrist_rgb", "on_loss": "stop"},
                   {"name": "scene_rgb", "on_loss": "stop"}]


def _hub(gateway: LoopbackGateway,
         encoding: wire.ImageEncoding = wire.ImageEncoding.RAW) -> CameraHub:
    sources = {name: PatternCamera(name, gateway.now_ns, age_ns=FRAME_AGE_NS) for name in NAMES}
    hub = CameraHub(tuple(settings(name, encoding) for name in NAMES), sources)
    hub.start()
    hub.wait_first_frames(5.0)
    return hub


def _observations(gateway: LoopbackGateway) -> list[ObservationEvent]:
    return [e for e in gateway.events if isinstance(e, ObservationEvent)]


def _digests(gateway: LoopbackGateway) -> set[str]:
    return {frame.digest for o in _observations(gateway) for frame in o.frames}


async def test_frames_travel_checked_and_the_journal_keeps_their_digests() -> None:
    gateway = LoopbackGateway(protocol=(3, 3), cameras=CAMERAS_SECTION)
    hub = _hub(gateway)
    try:
        async with running(server_config(cameras=SHAPES), gateway, cameras=hub) as link:
            await wait_for(lambda: len(gateway.admitted()) >= 3 and len(_digests(gateway)) > 2,
                           "three admitted chunks, and a camera's frame that changed")
            stats = link.server.stats
    finally:
        hub.stop()
    assert stats.violations == 0 and stats.frames_seen >= 2 * stats.observations - 2
    observations = _observations(gateway)
    assert observations and all(len(o.frames) == 2 for o in observations)
    assert set(stats.frame_digests) <= _digests(gateway)
    # The observation is as old as its oldest frame: every answer's age counts from it.
    for line in gateway.admitted():
        assert line.observation_age_ms is not None and line.observation_age_ms >= 15
    journal_round_trip(gateway)


async def test_jpeg_frames_are_decoded_by_the_server() -> None:
    gateway = LoopbackGateway(protocol=(3, 3), cameras=CAMERAS_SECTION)
    hub = _hub(gateway, wire.ImageEncoding.JPEG)
    try:
        async with running(server_config(cameras=SHAPES), gateway, cameras=hub) as link:
            await wait_for(lambda: link.server.stats.frames_seen >= 4, "four frames")
            assert link.server.stats.violations == 0
    finally:
        hub.stop()


async def test_an_observation_without_the_promised_frames_is_a_violation() -> None:
    gateway = LoopbackGateway(protocol=(3, 3))
    async with running(server_config(cameras=SHAPES), gateway) as link:
        await wait_for(lambda: "protocol_violation" in link.server.stats.byes_sent,
                       "the server's goodbye")  # counted as a violation first, then said
        assert link.server.stats.frames_seen == 0 and link.server.stats.violations >= 1
    assert not gateway.admitted()


def _peer_decoded(images: tuple[SeenImage, ...], t_event: int) -> PeerObservation:
    observation = wire.Observation(
        observation_id="o1", t_event=t_event, queue_epoch=0, task_phase="PRE_CONTACT",
        q=wire.vector_payload(np.zeros(6)), images=tuple(i.payload() for i in images))
    frame = wire.decode_frame(wire.encode(observation))
    return msgspec.msgpack.decode(frame.body, type=PeerObservation)


def _seen(encoding: wire.ImageEncoding, t_capture: int = 100) -> tuple[SeenImage, ...]:
    seen = []
    for name in NAMES:
        frame = PatternCamera(name, lambda: t_capture).read()
        data = encode_jpeg(frame, 95) if encoding is wire.ImageEncoding.JPEG else (
            frame.image.tobytes())
        seen.append(SeenImage(frame, encoding, data))
    return tuple(seen)


def test_the_peer_codec_reads_raw_frames_to_the_pixel() -> None:
    images = _seen(wire.ImageEncoding.RAW)
    pixels = check_images(_peer_decoded(images, 100), SHAPES, 3)
    for image, rgb in zip(images, pixels, strict=True):
        assert np.array_equal(rgb, image.frame.image)
        assert frame_digest(rgb) == image.frame.digest
    shape_then_bytes = hashlib.sha256(repr(rgb.shape).encode() + rgb.tobytes()).hexdigest()
    assert images[-1].frame.digest == shape_then_bytes[:32]  # docs/protocol.md's definition


def test_the_peer_codec_decodes_jpeg_frames_near_enough() -> None:
    images = _seen(wire.ImageEncoding.JPEG)
    pixels = check_images(_peer_decoded(images, 100), SHAPES, 3, decode_jpeg)
    for image, rgb in zip(images, pixels, strict=True):
        error = np.abs(rgb.astype(int) - image.frame.image.astype(int)).mean()
        other = np.abs(rgb.astype(int) - np.roll(image.frame.image, 7, axis=1).astype(int))
        assert error < 8.0 < other.mean(), (error, other.mean())  # this picture, not another


@pytest.mark.parametrize(("change", "problem"), [
    ({"data": b"\x00" * 10}, "bytes for a raw"),
    ({"width": WIDTH + 1}, "expected 64x48"),
    ({"digest": "0" * 32}, "do not give the frame's digest"),
    ({"camera": "thermal"}, "not in the session"),
    ({"t_capture": 99}, "taken before the observation's time"),
])
def test_the_server_refuses_frames_that_are_not_what_they_claim(
        change: dict[str, object], problem: str) -> None:
    observation = _peer_decoded(_seen(wire.ImageEncoding.RAW), 100)
    first = msgspec.structs.replace(observation.images[0], **change)
    hostile = msgspec.structs.replace(observation, images=(first, *observation.images[1:]))
    with pytest.raises(ImageProblem, match=problem):
        check_images(hostile, SHAPES, 3)


def test_frames_before_protocol_3_or_missing_are_refused() -> None:
    observation = _peer_decoded(_seen(wire.ImageEncoding.RAW), 100)
    with pytest.raises(ImageProblem, match="need protocol 3"):
        check_images(observation, SHAPES, 2)
    with pytest.raises(ImageProblem, match="no frame of camera scene_rgb"):
        check_images(msgspec.structs.replace(observation, images=observation.images[:1]),
                     SHAPES, 3)


def test_an_oversized_image_field_is_refused_by_the_decoder() -> None:
    big = wire.WireImage(camera="wrist_rgb", encoding=wire.ImageEncoding.RAW, height=1,
                         width=1, data=b"123", t_capture=0, digest="d", calibration_epoch="c")
    body = msgspec.msgpack.encode(msgspec.structs.replace(big, height=5000))
    with pytest.raises(msgspec.ValidationError):
        msgspec.msgpack.decode(body, type=wire.WireImage)


def test_a_hostile_picture_is_refused_before_it_is_decoded() -> None:
    """A PNG (not what it claims), a JPEG that declares another size, one larger than the raw
    pixels, and bytes that only start like a JPEG are each refused without decoding them."""
    observation = _peer_decoded(_seen(wire.ImageEncoding.JPEG), 100)
    first = observation.images[0]
    rgb = PatternCamera("x", lambda: 0).read().image
    png = cv2.imencode(".png", rgb)[1].tobytes()
    big = cv2.imencode(".jpg", np.zeros((HEIGHT * 4, WIDTH * 4, 3), np.uint8))[1].tobytes()
    for data in (png, big, first.data + b"\x00" * (WIDTH * HEIGHT * 3), b"\xff\xd8\xff\xe0"):
        hostile = msgspec.structs.replace(observation, images=(
            msgspec.structs.replace(first, data=data), *observation.images[1:]))
        with pytest.raises(ImageProblem, match="not a 64x48 JPEG"):
            check_images(hostile, SHAPES, 3, decode_jpeg)
    assert jpeg_size(first.data) == (WIDTH, HEIGHT) and jpeg_size(big) == (WIDTH * 4, HEIGHT * 4)


def test_a_server_without_a_jpeg_codec_refuses_jpeg_frames() -> None:
    observation = _peer_decoded(_seen(wire.ImageEncoding.JPEG), 100)
    with pytest.raises(ImageProblem, match="raw frames only"):
        check_images(observation, SHAPES, 3)
