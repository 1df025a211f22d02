"""An unmodified openpi ``WebsocketPolicyServer`` serving a scripted policy (openpi venv only).

    python serve_scripted.py --port N [--delay-ms D] [--fail-on N] [--horizon H] [--dim D]
                             [--image KEY:WxH ...]

The server's own ``GET /healthz`` answers once it listens. The policy answers each
observation with ``H`` actions that step from the observed ``observation/state`` towards
``--goal`` along the straight joint-space line (the furthest joint ``--step`` rad per action),
after ``--delay-ms`` of simulated
inference; request ``--fail-on`` raises, so the server sends its traceback frame and closes
with 1011. With ``--image``, every observation must carry that key as a ``uint8`` H×W×3 image
that changed since the last observation's at some point (a camera that sees), or the policy
raises as a real one would on a missing input.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from openpi_client import base_policy
from openpi_server import WebsocketPolicyServer


class Scripted(base_policy.BasePolicy):
    def __init__(self, options: argparse.Namespace) -> None:
        self.options = options
        self.calls = 0
        self.images_seen: dict[str, set[int]] = {}
        self.goal = np.asarray(options.goal, dtype=np.float64) if options.goal else None

    def infer(self, obs: dict) -> dict:
        self.calls += 1
        if self.calls == self.options.fail_on:
            raise RuntimeError(f"scripted failure on request {self.calls}")
        self._check_images(obs)
        time.sleep(self.options.delay_ms / 1000)  # openpi's infer blocks its event loop too
        state = np.asarray(obs["observation/state"], dtype=np.float64)[: self.options.dim]
        goal = state if self.goal is None else self.goal
        # All joints together along the straight joint-space line, the furthest at --step rad
        # per action (a joint-by-joint clip would sweep the part in an arc).
        span = goal - state
        reach = float(np.abs(span).max())
        steps = np.minimum(np.arange(1, self.options.horizon + 1) * self.options.step, reach)
        direction = span / reach if reach > 0 else np.zeros_like(span)
        actions = state + steps[:, None] * direction
        return {"actions": actions.astype(np.float32)}


    def _check_images(self, obs: dict) -> None:
        for spec in self.options.image:
            key, _, size = spec.partition(":")
            width, height = (int(v) for v in size.split("x"))
            image = obs.get(key)
            if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or (
                    image.shape != (height, width, 3)):
                raise ValueError(f"observation key {key!r}: expected a {width}x{height} uint8 "
                                 f"RGB image, got {getattr(image, 'shape', type(image))}")
            self.images_seen.setdefault(key, set()).add(hash(image.tobytes()))
        if self.calls > 20 and any(len(seen) < 2 for seen in self.images_seen.values()):
            raise ValueError("an image has not changed in 20 observations: a frozen camera")


def serve(options: argparse.Namespace) -> None:
    WebsocketPolicyServer(Scripted(options), host="127.0.0.1", port=options.port,
                          metadata={"policy": "scripted", "dim": options.dim}).serve_forever()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--delay-ms", type=float, default=0.0)
    parser.add_argument("--fail-on", type=int, default=0)
    parser.add_argument("--horizon", type=int, default=20)
    parser.add_argument("--dim", type=int, default=6)
    parser.add_argument("--step", type=float, default=0.002)
    parser.add_argument("--goal", type=float, nargs="*")
    parser.add_argument("--image", action="append", default=[], metavar="KEY:WxH")
    serve(parser.parse_args())


if __name__ == "__main__":
    main()
