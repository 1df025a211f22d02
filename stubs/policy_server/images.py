"""The reference server's JPEG codec for camera frames: OpenCV's (``peer/frames.py`` checks
every frame, and reads a JPEG's declared size before this decodes it)."""

from __future__ import annotations

import cv2
import numpy as np


def decode_jpeg(data: bytes) -> np.ndarray | None:
    """RGB pixels (H×W×3 uint8) of a JPEG file; None if OpenCV cannot decode it."""
    bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    return None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
