"""The run's cameras: each read on a thread of its own, its newest frame kept for the next
observation, its health watched and reported to the core.

A camera's frames never pass through the control loop. A :class:`CameraReader` thread opens
its source and reads it at the manifest's rate (an OpenCV read blocks until the device has a
frame), or, for a camera that takes pictures on request (the simulated cell's rendered ones),
picks up each new picture as it comes; :meth:`CameraHub.fresh` asks those for a picture just
before an observation is taken, so it is as fresh as the renderer allows. The hub gives the
policy link each camera's newest frame, encoded as the manifest asks, and only when every
camera has one fresh enough and none is reported down: an observation is never sent without a
frame of each ``[[cameras]]`` entry. (An observation key that names a camera the manifest has
no ``[[cameras]]`` entry for is not checked: the shipped joint-only cells still list
``wrist_rgb`` and ``scene_rgb`` among their keys.)
:class:`CameraHealth` judges each camera from what its reader saw (lost: no frame, or none
newer than ``max_frame_age_ms``; frozen: ``freeze_frames`` identical frames in a row) and the
hub's :meth:`~CameraHub.watch` task feeds each change to the core as a
:class:`~kernel.core.events.CameraEvent`; what losing a camera means is the core's decision
(kernel/core/cameras.py).
"""

from __future__ import annotations

import asyncio
import functools
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import cv2

from assurance.clock import ms_to_ns
from assurance.reasons import ReasonCode
from drivers.base import DriverInitError
from drivers.camera import CameraFrame, CameraLost, CameraSource, FreezeWatch, TriggeredSource
from kernel.core.events import CameraEvent, CameraStatus, Event
from kernel.manifest_cameras import CameraSettings
from kernel.shell.link_types import SeenImage
from kernel.shell.realtime import thread_at_ordinary_priority
from kernel.wire import ImageEncoding

FIRST_FRAME_S = 10.0
"""How long a run waits at start for every camera's first frame (a rendered camera's GL
context, a USB camera's exposure settle take a moment)."""
WATCH_PERIOD_S = 0.01
"""How often the hub looks at its cameras' health (a loss is reported within this)."""
POLL_S = 0.002
"""How often a triggered camera's newest frame is picked up (a reference taken under a lock)."""
FRESH_TIMEOUT_S = 0.25
"""How long a request waits for the triggered cameras' pictures before it goes on anyway (the
frames it then takes are judged by their age like any other)."""
STOP_S = 5.0
"""How long a run's end waits for all the camera threads together."""
RETRY_OPEN_S = 0.5
"""A source that would not open, or failed, is opened again after this."""


class CameraUnavailable(DriverInitError):
    """A camera gave no frame at the start of a run: nothing has moved."""

    default_reason = ReasonCode.CAMERA_LOST


class CameraReader:
    """One source read on its own thread, at the ordinary scheduling policy (never the control
    loop's); each new frame is encoded there once, as it will travel (a JPEG of a large frame
    costs milliseconds: never on the loop). :meth:`newest` is the last frame it gave."""

    def __init__(self, source: CameraSource, rate_hz: float, paced: bool,
                 encode: Callable[[CameraFrame], SeenImage]) -> None:
        self.source = source
        self.triggered = isinstance(source, TriggeredSource)
        # A device's read blocks until its next frame: pacing it would let frames queue up in
        # the driver and hand out old ones. A file is paced to the rate; a rendered camera's
        # new pictures are picked up as they come.
        self.period_s = POLL_S if self.triggered else (1.0 / rate_hz if paced else 0.0)
        self._encode = encode
        self._newest: CameraFrame | None = None
        self._seen: SeenImage | None = None
        self._failure: str | None = "not opened yet"
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=f"camera-{self.source.name}",
                                            daemon=True)
            self._thread.start()

    def signal_stop(self) -> None:
        self._stop.set()

    def join(self, deadline: float) -> bool:
        """Wait for the thread until ``deadline`` (monotonic s); False if it is still in a
        read that does not return (an unplugged device): it is a daemon, left to the exit."""
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
            return not thread.is_alive()
        return True

    def newest(self) -> tuple[CameraFrame | None, str | None]:
        """The newest frame, and why there will be no newer one for now (None: reading)."""
        with self._lock:
            return self._newest, self._failure

    def newest_seen(self) -> tuple[SeenImage | None, str | None]:
        """The newest frame as it travels, and why there will be no newer one (None: none)."""
        with self._lock:
            return self._seen, self._failure

    def _run(self) -> None:
        thread_at_ordinary_priority()
        while not self._stop.is_set():
            try:
                self.source.open()
                self._set_failure(None)
                self._read_until_lost()
            except CameraLost as error:
                self._set_failure(str(error))
            finally:
                self.source.close()
            self._stop.wait(RETRY_OPEN_S)

    def _read_until_lost(self) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            frame = self.source.read()
            if frame is not self._newest:
                seen = self._encode(frame)
                with self._lock:
                    self._newest, self._seen = frame, seen
            self._stop.wait(max(0.0, self.period_s - (time.monotonic() - started)))

    def _set_failure(self, failure: str | None) -> None:
        with self._lock:
            self._failure = failure


@dataclass(slots=True)
class CameraHealth:
    """One camera's state as the core was last told it (pure: fed frames and times)."""

    settings: CameraSettings
    down: CameraStatus | None = None
    """Lost or frozen, as last reported (None: up)."""
    _freeze: FreezeWatch | None = None
    _judged: CameraFrame | None = None
    _frozen: bool = False

    def __post_init__(self) -> None:
        repeats = self.settings.freeze_frames
        self._freeze = FreezeWatch(repeats) if repeats else None

    def fresh(self, frame: CameraFrame | None, now_ns: int) -> bool:
        limit = ms_to_ns(self.settings.frame_age_limit_ms)
        return frame is not None and now_ns - frame.t_capture_ns <= limit

    def judge(self, frame: CameraFrame | None, failure: str | None,
              now_ns: int) -> CameraEvent | None:
        """The change to report, if this look at the camera changes what the core knows."""
        if frame is not None and frame is not self._judged:
            self._judged = frame
            self._frozen = self._freeze is not None and self._freeze.frozen(frame)
        if not self.fresh(frame, now_ns):
            age = "no frame" if frame is None else (
                f"newest frame {(now_ns - frame.t_capture_ns) / 1e6:.0f} ms old")
            return self._report(CameraStatus.LOST, now_ns, f"{age}; {failure}" if failure
                                else age)
        if self._frozen:
            return self._report(CameraStatus.FROZEN, now_ns,
                                f"{self.settings.freeze_frames} identical frames")
        return self._report(None, now_ns, "fresh frames again")

    def _report(self, status: CameraStatus | None, now_ns: int,
                detail: str) -> CameraEvent | None:
        if status is self.down or (status is not None and self.down is not None):
            return None  # no change, or down already (the first cause is the one reported)
        self.down = status
        return CameraEvent(t=now_ns, camera=self.settings.name,
                           status=status if status is not None else CameraStatus.BACK,
                           detail=detail[:200])


class CameraHub:
    """The manifest's cameras for one run (module docstring)."""

    def __init__(self, cameras: tuple[CameraSettings, ...],
                 sources: Mapping[str, CameraSource],
                 keep: Callable[[CameraFrame], None] | None = None) -> None:
        self.cameras = cameras
        self._keep = keep
        """Given every frame an observation carries (its pictures kept beside the journal)."""
        self._readers = {c.name: CameraReader(sources[c.name], c.rate_hz,
                                              paced=not c.live_device,
                                              encode=functools.partial(encode, c))
                         for c in cameras}
        self._health = {c.name: CameraHealth(c) for c in cameras}
        self.withheld = 0
        """Observations not sent because a camera had no fresh frame."""

    def start(self) -> None:
        for reader in self._readers.values():
            reader.start()

    def stop(self, timeout_s: float = STOP_S) -> list[str]:
        """Stop every reader within ``timeout_s`` in all; the names of those still blocked in
        a read (left to the process's exit)."""
        for reader in self._readers.values():
            reader.signal_stop()
        deadline = time.monotonic() + timeout_s
        return [name for name, reader in self._readers.items() if not reader.join(deadline)]

    def wait_first_frames(self, timeout_s: float = FIRST_FRAME_S) -> None:
        """Block until every camera has given a frame (a run calls it from a thread).

        Raises:
            CameraUnavailable: naming the first camera without one, and why.
        """
        deadline = time.monotonic() + timeout_s
        for name, reader in self._readers.items():
            while (newest := reader.newest())[0] is None:
                if time.monotonic() > deadline:
                    raise CameraUnavailable(f"camera {name}",
                                            f"no frame in {timeout_s:g} s ({newest[1]})")
                time.sleep(0.01)

    def images(self, now_ns: int) -> tuple[SeenImage, ...] | None:
        """Every camera's newest frame, ready to travel; None when one has none fresh (or is
        reported down): then nothing goes out."""
        images = []
        for camera in self.cameras:
            seen, failure = self._readers[camera.name].newest_seen()
            health = self._health[camera.name]
            if (health.down is not None or failure is not None or seen is None
                    or not health.fresh(seen.frame, now_ns)):
                self.withheld += 1
                return None
            images.append(seen)
        if self._keep is not None:
            for image in images:
                self._keep(image.frame)
        return tuple(images)

    async def fresh(self, since_ns: int, now_ns: Callable[[], int],
                    timeout_s: float = FRESH_TIMEOUT_S) -> None:
        """Have every camera that takes pictures on request take one, and wait (at most
        ``timeout_s``) until each has one taken at ``since_ns`` or later."""
        waiting = [r for r in self._readers.values() if r.triggered]
        for reader in waiting:
            reader.source.trigger()  # type: ignore[attr-defined]
        deadline = now_ns() + round(timeout_s * 1e9)
        while waiting and now_ns() < deadline:
            waiting = [r for r in waiting if not _taken_since(r.newest()[0], since_ns)]
            if waiting:
                await asyncio.sleep(POLL_S)

    def check(self, now_ns: int) -> list[CameraEvent]:
        """What changed since the last look, one event per camera that changed."""
        changes = []
        for name, reader in self._readers.items():
            event = self._health[name].judge(*reader.newest(), now_ns)
            if event is not None:
                changes.append(event)
        return changes

    async def watch(self, now_ns: Callable[[], int], feed: Callable[[Event], object],
                    started: Callable[[], None]) -> None:
        """Report each change to the core until cancelled (a supervised task of the run)."""
        started()
        while True:
            for event in self.check(now_ns()):
                feed(event)
            await asyncio.sleep(WATCH_PERIOD_S)


def _taken_since(frame: CameraFrame | None, since_ns: int) -> bool:
    return frame is not None and frame.t_capture_ns >= since_ns


def encode(camera: CameraSettings, frame: CameraFrame) -> SeenImage:
    """The frame as ``camera`` sends it: its raw RGB bytes, or a JPEG (on its reader's thread).

    Raises:
        CameraLost: the frame does not encode (the reader treats it as a lost camera).
    """
    if camera.encoding is ImageEncoding.JPEG:
        return SeenImage(frame, ImageEncoding.JPEG, encode_jpeg(frame, camera.jpeg_quality))
    return SeenImage(frame, ImageEncoding.RAW, frame.image.tobytes())


def encode_jpeg(frame: CameraFrame, quality: int) -> bytes:
    """The frame as a JPEG file (OpenCV encodes BGR: the RGB image is swapped first)."""
    bgr = cv2.cvtColor(frame.image, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise CameraLost(f"{frame.camera}: the frame does not encode as JPEG")
    return data.tobytes()
