"""Addresses into the compiled cell model, resolved once by name (see ``stubs.robot_model``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from stubs import robot_model as rm

GRASP_WELD = "grasp_stiction"
"""The weld equality in ``cell.xml`` that holds a gripped peg while it sticks (``_stiction``)."""


@dataclass(frozen=True, slots=True, eq=False)
class CellIndex:
    """Addresses into the compiled model; the peg fields are None when the model has no cell.

    The arm's joints, dofs and actuators are contiguous, so they are slices: numpy views
    through slices are what keeps a command + step + state round trip cheap.
    """

    arm_qpos: slice
    arm_dof: slice
    arm_actuators: slice
    lower: np.ndarray
    upper: np.ndarray
    gripper_actuator: int
    gripper_tendon: int
    force_adr: int
    torque_adr: int
    ft_site: int
    tool_body: int
    pad_geoms: tuple[int, int]
    tcp_site: int
    peg_qpos: int | None
    peg_dof: int | None
    peg_geom: int | None
    peg_body: int | None
    hole_site: int | None
    grasp_weld: int | None

    @classmethod
    def of(cls, model: mujoco.MjModel) -> CellIndex:
        joints = [model.joint(name) for name in rm.ARM_JOINT_NAMES]
        has_cell = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, rm.PEG_BODY) >= 0
        peg_body = model.body(rm.PEG_BODY).id if has_cell else -1
        peg_joint = int(model.body_jntadr[peg_body]) if has_cell else -1
        weld = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, GRASP_WELD)
        return cls(
            arm_qpos=contiguous([j.qposadr[0] for j in joints], "arm joint qpos"),
            arm_dof=contiguous([j.dofadr[0] for j in joints], "arm joint dof"),
            arm_actuators=contiguous(
                [model.actuator(n).id for n in rm.ARM_ACTUATOR_NAMES], "arm actuator"),
            lower=np.array([j.range[0] for j in joints]),
            upper=np.array([j.range[1] for j in joints]),
            gripper_actuator=model.actuator(rm.GRIPPER_ACTUATOR_NAME).id,
            gripper_tendon=model.tendon(rm.GRIPPER_TENDON_NAME).id,
            force_adr=int(model.sensor("wrist_force").adr[0]),
            torque_adr=int(model.sensor("wrist_torque").adr[0]),
            ft_site=model.site(rm.FT_SITE).id,
            tool_body=model.body(rm.TOOL_BODY).id,
            pad_geoms=(model.geom(rm.PAD_GEOMS[0]).id, model.geom(rm.PAD_GEOMS[1]).id),
            tcp_site=model.site(rm.TCP_SITE).id,
            peg_qpos=int(model.jnt_qposadr[peg_joint]) if has_cell else None,
            peg_dof=int(model.jnt_dofadr[peg_joint]) if has_cell else None,
            peg_geom=model.geom(rm.PEG_GEOM).id if has_cell else None,
            peg_body=peg_body if has_cell else None,
            hole_site=model.site(rm.HOLE_SITE).id if has_cell else None,
            grasp_weld=weld if has_cell and weld >= 0 else None,
        )


def contiguous(addresses: Sequence[int], what: str) -> slice:
    first = int(addresses[0])
    if list(addresses) != list(range(first, first + len(addresses))):
        raise ValueError(f"{what} addresses {list(addresses)} are not contiguous")
    return slice(first, first + len(addresses))
