"""``python -m stubs.policy_server --host 127.0.0.1 --port N [options]``.

Prints ``READY {"port": N}`` on stdout once listening (for ``stubs/process.py``), then serves
until SIGTERM or SIGINT. ``--fault NAME=VALUE`` (repeatable) injects faults (``faults.py``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys

import uvloop

from peer.access import Access, read_token
from peer.envelope import ReplacementPolicy
from peer.frames import CameraShape
from stubs.policy_server.config import DEFAULT_GOAL, ServerConfig
from stubs.policy_server.faults import FaultConfig
from stubs.policy_server.policy import LatencyModel
from stubs.policy_server.server import PolicyServer


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(","))


def _pair(text: str) -> tuple[int, int]:
    low, high = (int(v) for v in text.split(","))
    return low, high


def parse_args(argv: list[str] | None = None) -> ServerConfig:
    d = ServerConfig()
    p = argparse.ArgumentParser(prog="python -m stubs.policy_server", description=__doc__)
    p.add_argument("--host", default=d.host)
    p.add_argument("--port", type=int, default=d.port, help="0 picks a free port")
    p.add_argument("--server-id", default=d.server_id)
    p.add_argument("--checkpoint", default=d.policy_checkpoint)
    p.add_argument("--config-hash", default=d.config_hash)
    p.add_argument("--observation-keys", default=",".join(d.observation_keys))
    p.add_argument("--action-dim", type=int, default=d.action_dim)
    p.add_argument("--action-units", default=d.action_units)
    p.add_argument("--action-frame", default=d.action_frame)
    p.add_argument("--skill", default=d.skill)
    p.add_argument("--skill-version", default=d.skill_version)
    p.add_argument("--controller-mode", default=d.controller_mode)
    p.add_argument("--calibration-epoch", default=d.calibration_epoch)
    p.add_argument("--protocol", type=_pair, default=d.protocol, help="offered: min,max")
    p.add_argument("--wire-protocol", type=_pair, default=d.wire_protocol, help="min,max")
    p.add_argument("--horizon", type=int, default=d.horizon)
    p.add_argument("--action-dt-ms", type=float, default=d.action_dt_ms)
    p.add_argument("--goal", type=_floats, default=DEFAULT_GOAL, help="q1,...,qD")
    p.add_argument("--max-speed", type=float, default=d.max_speed, help="rad/s")
    p.add_argument("--max-acceleration", type=float, default=None,
                   help="rad/s²; without it the policy jumps to full speed at once")
    p.add_argument("--noise", type=float, default=d.noise_std, help="rad, std")
    p.add_argument("--latency-median-ms", type=float, default=d.latency.median_ms)
    p.add_argument("--latency-p95-ms", type=float, default=d.latency.p95_ms)
    p.add_argument("--lead-ms", type=float, default=None)
    p.add_argument("--replacement-policy", choices=[r.value for r in ReplacementPolicy],
                   default=d.replacement_policy.value)
    p.add_argument("--rtc", action="store_true",
                   help="offer real-time chunking: honour the committed prefix observations carry")
    p.add_argument("--camera", action="append", default=[], metavar="NAME:WxH",
                   help="a camera every observation carries a frame of (protocol 3)")
    p.add_argument("--clock-offset-ms", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--heartbeat-interval", type=float, default=d.heartbeat_interval_s)
    p.add_argument("--heartbeat-timeout", type=float, default=d.heartbeat_timeout_s)
    p.add_argument("--fault", action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--tls-cert", help="PEM certificate: serve wss:// (with --tls-key)")
    p.add_argument("--tls-key", help="PEM private key of --tls-cert")
    p.add_argument("--client-ca", help="PEM bundle: require client certificates it signed")
    p.add_argument("--token-file", help="a file holding the bearer token clients must send")
    a = p.parse_args(argv)
    try:
        return ServerConfig(
            host=a.host, port=a.port, server_id=a.server_id, policy_checkpoint=a.checkpoint,
            config_hash=a.config_hash, observation_keys=tuple(a.observation_keys.split(",")),
            action_dim=a.action_dim, action_units=a.action_units, action_frame=a.action_frame,
            skill=a.skill, skill_version=a.skill_version, controller_mode=a.controller_mode,
            calibration_epoch=a.calibration_epoch, protocol=a.protocol,
            wire_protocol=a.wire_protocol, horizon=a.horizon,
            action_dt_ms=a.action_dt_ms, goal=a.goal, max_speed=a.max_speed,
            max_acceleration=a.max_acceleration,
            noise_std=a.noise, latency=LatencyModel(a.latency_median_ms, a.latency_p95_ms),
            lead_ms=a.lead_ms, replacement_policy=ReplacementPolicy(a.replacement_policy),
            rtc=a.rtc, cameras=tuple(CameraShape.parse(text) for text in a.camera),
            clock_offset_ns=round(a.clock_offset_ms * 1e6), seed=a.seed,
            heartbeat_interval_s=a.heartbeat_interval, heartbeat_timeout_s=a.heartbeat_timeout,
            faults=FaultConfig.parse(a.fault),
            access=Access(cert_file=a.tls_cert, key_file=a.tls_key, client_ca=a.client_ca,
                          token=read_token(a.token_file) if a.token_file else None),
        )
    except (ValueError, OSError) as error:
        p.error(str(error))
        raise  # p.error exits; this keeps the type checker informed


async def _main(config: ServerConfig) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    async with PolicyServer(config) as server:
        print(f"READY {json.dumps({'port': server.port})}", flush=True)
        await stop.wait()


def main(argv: list[str] | None = None) -> int:
    config = parse_args(argv)
    try:
        uvloop.run(_main(config))
    except OSError as error:  # a certificate that does not load, a port that is taken
        print(f"python -m stubs.policy_server: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
