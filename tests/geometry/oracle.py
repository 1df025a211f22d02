"""An independent judge of clearance: MuJoCo's own kinematics and collision distances on the
same scene (the arm's model file plus the manifest's solids), none of the core's code.

The oracle re-derives which pairs count from the table's documented rules: robot geoms at
least two arm joints apart (self), every moving robot geom against each obstacle and keep-out
zone, the tool (the gripper's bodies) and the held part excused from an obstacle in the phases
it allows contact in.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from kernel.model_file import MODELS_DIR

ARM_JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
              "wrist_2_joint", "wrist_3_joint")
TOOL_BODIES = ("gripper", "finger_left", "finger_right")
_SHAPES = {"box": mujoco.mjtGeom.mjGEOM_BOX, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
           "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER, "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE}


@dataclass(frozen=True)
class _Pair:
    a: int
    b: int
    obstacle: dict[str, Any] | None
    """The world solid of the pair (None: two robot geoms)."""
    excusable: bool
    """The robot side is the tool or the part (an obstacle's allow_contact applies)."""


class MujocoOracle:
    def __init__(self, geometry: dict[str, Any], held: bool) -> None:
        spec = mujoco.MjSpec.from_file(str(MODELS_DIR / "ur5e.xml"))
        self.geometry = geometry
        solids = [(o, False) for o in geometry.get("obstacles", [])]
        solids += [(z, True) for z in geometry.get("keep_out", [])]
        for solid, _ in solids:
            body = spec.worldbody.add_body(name=f"oracle_{solid['name']}")
            _add_geom(body, {**solid, "name": f"oracle_{solid['name']}"}, solid["position"])
        part = geometry.get("part")
        if held and part is not None:
            site = spec.site("tcp")
            rotation = np.zeros(9)
            mujoco.mju_quat2Mat(rotation, np.array(site.quat, dtype=float))
            where = np.array(site.pos) + rotation.reshape(3, 3) @ np.array(part["position"])
            _add_geom(spec.body(site.parent.name), {**part, "name": "oracle_part"}, where)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self._qpos = [self.model.joint(name).qposadr[0] for name in ARM_JOINTS]
        self._pairs = list(self._all_pairs(solids))

    def slack(self, q: np.ndarray, phase: str) -> tuple[float, tuple[str, str]]:
        """The smallest (distance − clearance needed) over the checked pairs at ``q``."""
        both = self.slacks(q, phase)
        return min(both.values())

    def slacks(self, q: np.ndarray, phase: str) -> dict[str, tuple[float, tuple[str, str]]]:
        """The smallest slack among the self pairs (``"self"``) and among the pairs with a
        world solid (``"world"``), each with its pair's names."""
        self.data.qpos[:] = 0.0
        self.data.qpos[self._qpos] = q
        mujoco.mj_kinematics(self.model, self.data)
        best = {"self": (np.inf, ("", "")), "world": (np.inf, ("", ""))}
        for pair in self._pairs:
            if pair.obstacle is None:
                kind, needed = "self", self.geometry.get("margin_m", 0.01)
            else:
                if pair.excusable and phase in pair.obstacle.get("allow_contact", ()):
                    continue
                kind = "world"
                needed = self.geometry.get("phase_margin_m", {}).get(
                    phase, self.geometry.get("margin_m", 0.01))
            distance = mujoco.mj_geomDistance(self.model, self.data, pair.a, pair.b, 1.0, None)
            if distance - needed < best[kind][0]:
                best[kind] = (distance - needed,
                              (self.model.geom(pair.a).name, self.model.geom(pair.b).name))
        return best

    def _all_pairs(self, solids: list[tuple[dict[str, Any], bool]]) -> Iterable[_Pair]:
        model = self.model
        depth = [self._depth(model.geom_bodyid[g]) for g in range(model.ngeom)]
        robot = [g for g in range(model.ngeom) if self._on_robot(model.geom_bodyid[g])]
        world = {model.geom(f"oracle_{s['name']}").id: s for s, _ in solids}
        excusable = {g for g in robot
                     if model.body(model.geom_bodyid[g]).name in TOOL_BODIES
                     or model.geom(g).name == "oracle_part"}
        for i, a in enumerate(robot):
            for b in robot[i + 1:]:
                if self.geometry.get("self_collision", True) and abs(depth[a] - depth[b]) >= 2:
                    yield _Pair(a, b, None, False)
            if depth[a] == 0:
                continue  # fixed to the base: no motion changes its distance to the world
            for b, solid in world.items():
                yield _Pair(a, b, solid, a in excusable)

    def _depth(self, body: int) -> int:
        """How many arm joints lie between the world and ``body``."""
        count = 0
        while body > 0:
            count += sum(1 for j in range(self.model.body_jntnum[body])
                         if self.model.joint(self.model.body_jntadr[body] + j).name in ARM_JOINTS)
            body = self.model.body_parentid[body]
        return count

    def _on_robot(self, body: int) -> bool:
        while body > 0:
            if self.model.body(body).name == "base":
                return True
            body = self.model.body_parentid[body]
        return False


def _add_geom(body: Any, solid: dict[str, Any], position: Any) -> None:
    size = list(solid["size"]) + [0.0] * (3 - len(solid["size"]))
    geom = body.add_geom(name=solid["name"], type=_SHAPES[solid["shape"]], size=size,
                         pos=list(map(float, position)), contype=0, conaffinity=0)
    roll, pitch, yaw = solid.get("rotation", (0.0, 0.0, 0.0))
    # About the fixed x, then y, then z axes: R = Rz(yaw) Ry(pitch) Rx(roll).
    cx, sx, cy, sy, cz, sz = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (rz @ ry @ rx).ravel())
    geom.quat = quat
