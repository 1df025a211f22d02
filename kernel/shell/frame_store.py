"""Camera frames kept as pictures beside the journal, when the manifest asks
(``[journal] frames = "pixels"``).

The journal always records each frame an observation carried by its digest
(``ObservationEvent.frames``). With pixels kept, each frame sent is also written once, as a
lossless PNG named by that digest (``<run>/frames/<camera>/<digest>.png``), so a reviewer can see
what the policy saw at any decision, and check that the picture is the one the journal names
(:func:`drivers.camera.frame_digest` of the decoded image is its file name). PNG encoding costs
a few milliseconds: it runs on a thread of its own behind a bounded queue, never on the loop; a
frame that finds the queue full is dropped and counted (the run summary's ``frames``), never
waited for. A write that fails is counted too, and ends the keeping of pictures: the run's own
record (the journal) is the recorder's, and does not depend on this.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass
from pathlib import Path

import cv2

from drivers.camera import CameraFrame

QUEUE_FRAMES = 64
"""Frames waiting to be written (two 224 × 224 cameras: 9.4 MiB at most)."""


@dataclass(slots=True)
class FrameStoreStats:
    written: int = 0
    dropped: int = 0
    """Not written: the writer was behind (the queue was full)."""
    error: str | None = None
    """The first write that failed; no picture is written after it."""

    def as_dict(self) -> dict[str, object]:
        return {"written": self.written, "dropped": self.dropped, "error": self.error}


class FrameStore:
    """Writes each frame offered once, on its own thread (module docstring)."""

    def __init__(self, directory: Path, capacity: int = QUEUE_FRAMES,
                 start: bool = True) -> None:
        self.directory = directory
        self.stats = FrameStoreStats()
        self._queue: queue.Queue[CameraFrame | None] = queue.Queue(capacity)
        self._seen: set[str] = set()
        self._thread = threading.Thread(target=self._write_all, name="frame-store", daemon=True)
        if start:
            self.start()

    def start(self) -> None:
        self._thread.start()

    def keep(self, frame: CameraFrame) -> None:
        """Write ``frame`` unless it was offered before (the loop's call: never blocks)."""
        if frame.digest in self._seen or self.stats.error is not None:
            return
        self._seen.add(frame.digest)
        try:
            self._queue.put_nowait(frame)
        except queue.Full:
            self.stats.dropped += 1

    def close(self, timeout_s: float = 10.0) -> None:
        """Write what is queued, then stop (a run's end)."""
        self._queue.put(None)
        self._thread.join(timeout=timeout_s)

    def path_of(self, camera: str, digest: str) -> Path:
        return self.directory / camera / f"{digest}.png"

    def _write_all(self) -> None:
        while (frame := self._queue.get()) is not None:
            if self.stats.error is None:
                self._write(frame)

    def _write(self, frame: CameraFrame) -> None:
        path = self.path_of(frame.camera, frame.digest)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            ok, data = cv2.imencode(".png", cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR))
            if not ok:
                raise OSError(f"{frame.camera}: the frame does not encode as PNG")
            path.write_bytes(data.tobytes())
        except OSError as error:
            self.stats.error = f"{path}: {error.strerror or error}"
            return
        self.stats.written += 1
