"""The ``cameras`` section: which cameras observations carry and what losing each means.

A scenario or journal states it as a list of ``{name, on_loss, grace_ms}``; a manifest's
``[[cameras]]`` tables say it with their other keys (kernel/manifest_cameras.py), and the
journal's header repeats this part of them. Each camera must be one of the session's
``observation_keys`` (the handshake promised the policy its frames).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from assurance.clock import ms_to_ns
from kernel.core.config import CameraLoss, LossAction
from kernel.scenario.fields import Where, choice, number, text

CAMERA_KEYS = frozenset({"name", "on_loss", "grace_ms"})
GRACE_MAX_MS = 5_000.0
"""The longest a phase may go on without a camera: a few chunks, never a cycle."""


def cameras_section(doc: Mapping[str, Any], where: Where,
                    observation_keys: tuple[str, ...]) -> tuple[CameraLoss, ...]:
    """Raises:
        ScenarioError: naming the entry and key.
    """
    raw = doc.get("cameras", [])
    here = where.at("cameras")
    if not isinstance(raw, list):
        raise here.error("must be a list of {name, on_loss, grace_ms}")
    cameras: list[CameraLoss] = []
    for index, entry in enumerate(raw):
        at = here.at(index)
        if not isinstance(entry, Mapping):
            raise at.error("must be an object")
        for key in entry:
            if key not in CAMERA_KEYS:
                raise at.at(key).error(f"unknown key (known: {', '.join(sorted(CAMERA_KEYS))})")
        cameras.append(camera_loss(entry, at, observation_keys, [c.name for c in cameras]))
    return tuple(cameras)


def camera_loss(entry: Mapping[str, Any], where: Where, observation_keys: tuple[str, ...],
                named: list[str]) -> CameraLoss:
    name = text(entry, "name", where, numbers_ok=False)
    if name in named:
        raise where.at("name").error(f"{name!r} is named twice")
    if name not in observation_keys:
        raise where.at("name").error(
            f"{name!r} is not one of session.observation_keys ({', '.join(observation_keys)}):"
            " the handshake would not tell the policy it sees through it")
    action = LossAction(choice(entry, "on_loss", where, tuple(LossAction), LossAction.STOP))
    grace = number(entry, "grace_ms", where, 0.0, minimum=0.0, maximum=GRACE_MAX_MS)
    if action is LossAction.CONTINUE and grace <= 0:
        raise where.at("grace_ms").error("on_loss = \"continue\" needs a positive grace_ms "
                                         f"(at most {GRACE_MAX_MS:g})")
    if action is LossAction.STOP and grace > 0:
        raise where.at("grace_ms").error("on_loss = \"stop\" stops at once: no grace_ms")
    return CameraLoss(name=name, on_loss=action, grace_ns=ms_to_ns(grace))
