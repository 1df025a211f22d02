"""The sidecar's configuration file: one TOML, typed, every key checked before anything starts.

An unknown or missing key, or a value outside its range, exits 2 naming the file and the key
(``__main__.py``). What the file says and why is in ``docs/protocol.md`` ("LeRobot through the
sidecar"); ``sidecars/lerobot/example.toml`` is a complete one.
"""

from __future__ import annotations

import hashlib
from typing import Annotated

import msgspec

from peer.access import Access, read_token
from peer.handshake import HandshakeOffer
from peer.protocol import PROTOCOL_RANGE
from sidecars.lerobot import pickles

Name = Annotated[str, msgspec.Meta(min_length=1, max_length=128)]
Port = Annotated[int, msgspec.Meta(ge=0, le=65535)]
Seconds = Annotated[float, msgspec.Meta(gt=0, le=3600)]
Side = Annotated[int, msgspec.Meta(ge=1, le=4096)]


class Listen(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Where warden connects: ``ws://`` or, with a certificate, ``wss://``."""

    host: str = "127.0.0.1"
    port: Port = 8765
    cert_file: str | None = None
    key_file: str | None = None
    client_ca: str | None = None
    token_file: str | None = None
    """The bearer token warden must present, read from this file (never written here)."""

    def access(self) -> Access:
        token = None if self.token_file is None else read_token(self.token_file)
        return Access(cert_file=self.cert_file, key_file=self.key_file,
                      client_ca=self.client_ca, token=token)


class LeRobot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The PolicyServer and what to ask it for (LeRobot's ``RemotePolicyConfig``)."""

    server: Name
    """``host:port`` of an unmodified ``lerobot.async_inference.policy_server``."""
    policy_type: Name
    pretrained_name_or_path: Name
    actions_per_chunk: Annotated[int, msgspec.Meta(ge=1, le=1024)]
    fps: Annotated[float, msgspec.Meta(gt=0, le=1000)]
    """The server's ``--fps``: its actions are ``1/fps`` apart; a reply spaced otherwise is
    refused."""
    device: Name = "cpu"
    task: str | None = None
    """The instruction a language-conditioned policy reads (``observation["task"]``)."""
    rename_map: dict[str, str] = {}
    setup_timeout_s: Seconds = 120.0
    """``Ready`` and ``SendPolicyInstructions`` (the server loads the policy meanwhile)."""
    reply_timeout_s: Seconds = 10.0
    """One observation's ``SendObservations`` and ``GetActions`` together."""


class Camera(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    warden: Name
    """warden's camera name (the manifest's ``[[cameras]] name``)."""
    lerobot: Name
    """The robot-side key LeRobot's features name (``observation.images.<lerobot>``)."""
    width: Side
    height: Side


class Offer(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What the sidecar offers in warden's handshake."""

    policy_checkpoint: Name
    """Declared by whoever runs the sidecar: LeRobot cannot attest what it loaded."""
    observation_keys: tuple[Name, ...]
    action_units: Name = "rad"
    action_frame: Name = "joint"
    server_id: Name = "lerobot-sidecar"


class SidecarConfig(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    lerobot: LeRobot
    joints: tuple[Name, ...]
    """LeRobot's names of the state's entries, in warden's joint order (``observation.state``
    lists them; the actions come back in the policy's action order, which must be the same)."""
    offer: Offer
    listen: Listen = Listen()
    cameras: tuple[Camera, ...] = ()

    @property
    def action_dim(self) -> int:
        return len(self.joints)

    def features(self) -> dict[str, dict]:
        """LeRobot's ``lerobot_features``: what ``hw_to_dataset_features`` makes of the robot."""
        found: dict[str, dict] = {"observation.state": {
            "dtype": "float32", "shape": (len(self.joints),), "names": list(self.joints)}}
        for camera in self.cameras:
            found[f"observation.images.{camera.lerobot}"] = {
                "dtype": "image", "shape": (camera.height, camera.width, 3),
                "names": ["height", "width", "channels"]}
        return found

    def policy_setup(self) -> bytes:
        """The pickled ``RemotePolicyConfig`` sent with ``SendPolicyInstructions``."""
        settings = self.lerobot
        return pickles.dumps(pickles.RemotePolicyConfig(
            settings.policy_type, settings.pretrained_name_or_path, self.features(),
            settings.actions_per_chunk, settings.device, dict(settings.rename_map)))

    def config_hash(self, setup: bytes) -> str:
        """The offer's ``config_hash``: the policy instructions sent and the sidecar's mapping,
        so a changed request, camera or joint order is a changed configuration."""
        digest = hashlib.sha256(setup)
        digest.update(msgspec.json.encode([self.joints, self.cameras, self.lerobot.fps,
                                           self.lerobot.task, self.offer]))
        return f"lerobot-sha256:{digest.hexdigest()[:16]}"

    def offer_for(self, setup: bytes, queue_epoch: int) -> HandshakeOffer:
        offer = self.offer
        return HandshakeOffer(
            policy_checkpoint=offer.policy_checkpoint, config_hash=self.config_hash(setup),
            observation_keys=offer.observation_keys, action_dim=self.action_dim,
            action_units=offer.action_units, action_frame=offer.action_frame,
            chunk_horizon=self.lerobot.actions_per_chunk, protocol=PROTOCOL_RANGE,
            queue_epoch=queue_epoch,
        )


class ConfigError(ValueError):
    """The file cannot be read or breaks a rule; the message names the file and the key."""


def load_config(path: str) -> SidecarConfig:
    """Raises:
        ConfigError: naming ``path`` and the key."""
    try:
        with open(path, "rb") as file:
            text = file.read()
    except OSError as error:
        raise ConfigError(f"{path}: cannot read: {error.strerror}") from None
    try:
        config = msgspec.toml.decode(text, type=SidecarConfig)
    except msgspec.ValidationError as error:
        raise ConfigError(f"{path}: {error}") from None
    except msgspec.DecodeError as error:
        raise ConfigError(f"{path}: not TOML: {error}") from None
    return _checked(path, config)


def _checked(path: str, config: SidecarConfig) -> SidecarConfig:
    names = [camera.warden for camera in config.cameras]
    if len(set(names)) != len(names) or len({c.lerobot for c in config.cameras}) != len(names):
        raise ConfigError(f"{path}: cameras: a camera is named twice")
    missing = set(names) - set(config.offer.observation_keys)
    if missing:
        raise ConfigError(f"{path}: offer.observation_keys: lacks the cameras {sorted(missing)}")
    if len(set(config.joints)) != len(config.joints) or not config.joints:
        raise ConfigError(f"{path}: joints: one name per joint, none twice")
    host, _, port = config.lerobot.server.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"{path}: lerobot.server: host:port, got {config.lerobot.server!r}")
    if (config.listen.cert_file is None) != (config.listen.key_file is None):
        raise ConfigError(f"{path}: listen.cert_file and listen.key_file go together")
    return config
