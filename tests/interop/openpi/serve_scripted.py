"""An unmodified openpi ``WebsocketPolicyServer`` serving a scripted policy (openpi venv only).

    python serve_scripted.py --port N [--delay-ms D] [--fail-on N] [--horizon H] [--dim D]

The server's own ``GET /healthz`` answers once it listens. The policy answers each
observation with ``H`` actions that step from the observed ``observation/state`` towards
``--goal`` (at most ``--step`` rad per action and joint), after ``--delay-ms`` of simulated
inference; request ``--fail-on`` raises, so the server sends its traceback frame and closes
with 1011.
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
        self.goal = np.asarray(options.goal, dtype=np.float64) if options.goal else None

    def infer(self, obs: dict) -> dict:
        self.calls += 1
        if self.calls == self.options.fail_on:
            raise RuntimeError(f"scripted failure on request {self.calls}")
        time.sleep(self.options.delay_ms / 1000)  # openpi's infer blocks its event loop too
        state = np.asarray(obs["observation/state"], dtype=np.float64)[: self.options.dim]
        goal = state if self.goal is None else self.goal
        steps = np.arange(1, self.options.horizon + 1)[:, None] * self.options.step
        actions = state + np.clip(goal - state, -steps, steps)
        return {"actions": actions.astype(np.float32)}


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
    serve(parser.parse_args())


if __name__ == "__main__":
    main()
