"""``python -m sidecars.lerobot CONFIG.toml``: serve warden's protocol, infer with LeRobot.

Prints ``READY {"port": N, "policy_checkpoint": ..., "config_hash": ...}`` once it listens (the
two values warden's manifest must allow), logs to stderr, and stops on SIGTERM or SIGINT. A
configuration that breaks a rule exits 2 naming the file and the key, before anything listens.
``--identity`` prints the offer's checkpoint and configuration hash and exits.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import signal
import sys

from sidecars.lerobot.bridge import Sidecar
from sidecars.lerobot.config import ConfigError, SidecarConfig, load_config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sidecars.lerobot", description=__doc__)
    parser.add_argument("config", help="the sidecar's TOML file (sidecars/lerobot/example.toml)")
    parser.add_argument("--identity", action="store_true",
                        help="print the offer's policy_checkpoint and config_hash, then exit")
    args = parser.parse_args(argv)
    try:
        config = load_config(args.config)
    except ConfigError as error:
        print(f"python -m sidecars.lerobot: {error}", file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.identity:
        print(json.dumps(_identity(Sidecar(config))))
        return 0
    try:
        asyncio.run(_serve(config))
    except OSError as error:  # a port that is taken, a certificate that does not load
        print(f"python -m sidecars.lerobot: {error}", file=sys.stderr)
        return 2
    return 0


def _identity(sidecar: Sidecar) -> dict[str, str]:
    offer = sidecar.offer(0)
    return {"policy_checkpoint": offer.policy_checkpoint, "config_hash": offer.config_hash}


async def _serve(config: SidecarConfig) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    async with Sidecar(config) as sidecar:
        print(f"READY {json.dumps({'port': sidecar.port, **_identity(sidecar)})}", flush=True)
        await stop.wait()


if __name__ == "__main__":
    sys.exit(main())
