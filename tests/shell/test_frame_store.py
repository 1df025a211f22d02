"""The frame store (kernel/shell/frame_store.py): each frame written once, as a PNG that decodes
to the picture its digest names; a full queue drops and counts, never waits; a failing disk
ends the keeping of pictures with the reason recorded."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from drivers.camera import frame_digest, make_frame
from kernel.shell.frame_store import FrameStore


def _frame(k: int, camera: str = "wrist_rgb"):  # type: ignore[no-untyped-def]
    image = np.zeros((48, 64, 3), dtype=np.uint8)
    image[k % 48, :, k % 3] = 200
    return make_frame(camera, image, k, "cal-12")


def test_each_frame_is_written_once_and_decodes_to_its_digest(tmp_path: Path) -> None:
    store = FrameStore(tmp_path / "frames")
    frames = [_frame(k) for k in range(5)]
    for frame in [*frames, *frames]:  # offered twice: written once
        store.keep(frame)
    store.close()
    assert store.stats.as_dict() == {"written": 5, "dropped": 0, "error": None}
    for frame in frames:
        bgr = cv2.imread(str(store.path_of(frame.camera, frame.digest)))
        assert frame_digest(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)) == frame.digest


def test_a_full_queue_drops_and_counts(tmp_path: Path) -> None:
    store = FrameStore(tmp_path / "frames", capacity=2, start=False)  # a writer that is behind
    for k in range(5):
        store.keep(_frame(k))
    store.start()
    store.close()
    assert store.stats.as_dict() == {"written": 2, "dropped": 3, "error": None}


def test_a_write_that_fails_ends_the_keeping_with_its_reason(tmp_path: Path) -> None:
    blocker = tmp_path / "frames"
    blocker.write_text("a file where the directory should be")
    store = FrameStore(blocker)
    store.keep(_frame(1))
    store.close()
    store.keep(_frame(2))  # after the failure: not even queued
    assert store.stats.written == 0 and store.stats.error is not None
    assert str(blocker) in store.stats.error
