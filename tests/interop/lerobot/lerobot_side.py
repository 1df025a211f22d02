"""Run inside the LeRobot 0.4.4 venv only (``interop.py`` builds it): never imported by warden.

``python lerobot_side.py make-policy DIR`` saves a randomly initialised ACT (seeded) with its
processors, for a UR5e-sized state and action (6) and two 224×224 cameras, ``wrist`` and
``scene``. ``python lerobot_side.py serve --port N`` runs LeRobot's own, unmodified
``PolicyServer`` (``lerobot.async_inference.policy_server.serve``).

Two facts of this machine are worked around here, not in LeRobot: the only torchvision wheel
for Python 3.11 is a CUDA build whose compiled ops do not load against the CPU torch, and its
meta registrations then fail on the missing ``torchvision::nms`` schema (the schema alone is
registered; ACT never calls the op). ACT's default backbone weights download at construction:
``pretrained_backbone_weights = None`` keeps it offline.
"""

from __future__ import annotations

import sys

import torch

_TORCHVISION = torch.library.Library("torchvision", "DEF")
_TORCHVISION.define("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")

JOINTS = 6
CAMERAS = ("wrist", "scene")
SIDE = 224
SEED = 20261129


def make_policy(directory: str) -> None:
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    inputs = {"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(JOINTS,))}
    for camera in CAMERAS:
        inputs[f"observation.images.{camera}"] = PolicyFeature(
            type=FeatureType.VISUAL, shape=(3, SIDE, SIDE))
    config = ACTConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(JOINTS,))},
        pretrained_backbone_weights=None, device="cpu", chunk_size=50, n_action_steps=50,
    )
    torch.manual_seed(SEED)
    policy = ACTPolicy(config)
    policy.save_pretrained(directory)
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=None)
    preprocessor.save_pretrained(directory)
    postprocessor.save_pretrained(directory)


def serve(arguments: list[str]) -> None:
    from lerobot.async_inference.policy_server import serve as lerobot_serve

    sys.argv = [sys.argv[0], *arguments]
    lerobot_serve()


if __name__ == "__main__":
    torch.set_num_threads(1)  # two threads were 4x slower on this 2-core machine
    if sys.argv[1] == "make-policy":
        make_policy(sys.argv[2])
    elif sys.argv[1] == "serve":
        serve(sys.argv[2:])
    else:
        raise SystemExit(f"unknown command {sys.argv[1]!r}: make-policy DIR | serve ARGS")
