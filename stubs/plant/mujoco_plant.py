"""The simulated cell as a :class:`~stubs.plant.base.Plant`: a UR5e-class arm in MuJoCo.

Control is torque, computed by MuJoCo inside every 2 ms step from one affine actuator per joint:
``tau = ctrl - kp*q - kd*qd + g(q)``, where ``g`` is gravity compensation (``actuatorgravcomp``)
and the plant writes ``kp``/``kd`` per mode and ``ctrl = kp*q_target + kd*qd_target``. So:

- position: stiff joint PD (+ a velocity feed-forward estimated from the command stream, as a
  servo controller's look-ahead does) tracks setpoints within a few mrad;
- impedance: the caller's per-joint stiffness and damping, so contact forces deflect the arm;
- velocity: ``kd*(qd_target - qd)`` with no position term.

Keeping the law inside MuJoCo's actuators (instead of a Python loop writing motor torques each
step) lets ``step(n)`` run as one native call and lets ``implicitfast`` integrate the damping
term implicitly, which is what keeps stiff gains stable at a 2 ms step.

``state().effort`` is the joint torque the actuators apply, gravity compensation included.
Beyond the protocol: ``reset(q, peg_in_gripper=True)`` starts with the peg already held,
``tcp_pose()``, ``tool_wrench()`` and ``peg_grasped()`` expose what the ground truth uses, and
a physics blow-up raises :class:`PlantDiverged` instead of MuJoCo's silent reset.

A gripped peg is held by static friction: MuJoCo's friction alone only damps slip and lets a
held part drift in the pads as the arm moves, so after each ``step`` call the plant switches the
grip between stick (a weld at the peg's pose in the gripper) and slip (friction), bounded by the
grip's friction capacity; see :mod:`stubs.plant._stiction`.

The wrist wrench is the wrench the environment applies to the tool (gripper, fingers and
anything they hold), in the sensor frame (``ft_site``: z along the tool axis), with the static
weight of the empty gripper removed, like a sensor tared with the empty gripper. A held peg's
weight (0.6 N) and the tool's inertial forces while accelerating are not removed.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import mujoco
import numpy as np

from stubs import robot_model as rm
from stubs.plant._cell_index import CellIndex
from stubs.plant._stiction import GraspStiction
from stubs.plant.base import GroundTruth, PlantState

_TIMESTEP_NS = 2_000_000
_DIVERGENCE_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                        mujoco.mjtWarning.mjWARN_BADQACC)


class PlantDiverged(RuntimeError):
    """The physics blew up (MuJoCo found non-finite or huge state and reset it)."""


class ControlMode(StrEnum):
    POSITION = "position"
    IMPEDANCE = "impedance"
    VELOCITY = "velocity"


@dataclass(frozen=True, slots=True)
class MujocoPlantConfig:
    """Model file and controller gains (N·m/rad, N·m·s/rad), one entry per arm joint."""

    model_path: Path = rm.CELL_MODEL
    position_stiffness: tuple[float, ...] = (20000.0, 20000.0, 10000.0, 3000.0, 3000.0, 3000.0)
    position_damping: tuple[float, ...] = (400.0, 500.0, 200.0, 40.0, 40.0, 40.0)
    velocity_damping: tuple[float, ...] = (400.0, 500.0, 200.0, 40.0, 40.0, 40.0)
    max_impedance_damping: tuple[float, ...] = (800.0, 1000.0, 400.0, 80.0, 80.0, 80.0)
    """Impedance stiffness may go up to ``position_stiffness`` and damping up to this."""
    feedforward_max_interval_ns: int = 20_000_000
    """Position commands further apart than this get no velocity feed-forward."""
    grasp_settle_steps: int = 100
    """Steps the grip is left to settle when ``reset`` places the peg between the pads."""


def _load_model(path: Path) -> mujoco.MjModel:
    """The model at ``path``; the cell's ``<include>`` of the arm gets the arm model's file
    (it lives with the manifests, as data, not beside the cell)."""
    assets = {rm.CELL_ARM_INCLUDE: rm.ARM_MODEL.read_bytes()}
    return mujoco.MjModel.from_xml_string(path.read_text(encoding="utf-8"), assets)


def _vector(values: Sequence[float], n: int, what: str) -> np.ndarray:
    """A float vector of length ``n``; finiteness is checked by the range check that follows."""
    array = np.array(values, dtype=float)
    if array.shape != (n,):
        raise ValueError(f"{what} needs {n} values, got shape {array.shape}")
    return array


def _within(values: np.ndarray, lower: np.ndarray, upper: np.ndarray, what: str) -> None:
    # Python comparisons on six floats: numpy's .all() alone costs a few microseconds here.
    items, low, high = values.tolist(), lower.tolist(), upper.tolist()
    if all(map(operator.le, low, items)) and all(map(operator.le, items, high)):
        return
    j = next(i for i, (lo, v, hi) in enumerate(zip(low, items, high, strict=True))
             if not lo <= v <= hi)  # NaN lands here too
    raise ValueError(f"{what}[{j}] = {items[j]:.6g} is outside [{low[j]:.6g}, {high[j]:.6g}]")


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # np.cross costs ~30 us on a 3-vector; this is ~2 us.
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


class MujocoPlant:
    """The assembly cell (or the bare arm) stepped at 2 ms; see the module docstring."""

    dof = 6
    timestep_ns = _TIMESTEP_NS

    def __init__(
        self, config: MujocoPlantConfig | None = None, q0: Sequence[float] | None = None
    ) -> None:
        self.config = config or MujocoPlantConfig()
        self.model = _load_model(self.config.model_path)
        if round(self.model.opt.timestep * 1e9) != _TIMESTEP_NS:
            raise ValueError(f"{self.config.model_path} has timestep {self.model.opt.timestep} s,"
                             " the plant runs at 0.002 s")
        self.data = mujoco.MjData(self.model)
        self._ix = CellIndex.of(self.model)
        self._stiction = GraspStiction(self.model, self.data, self._ix)
        self._load_gains(self.config)
        self._bind_views()
        self.reset(q0)

    def _load_gains(self, cfg: MujocoPlantConfig) -> None:
        zero, inf = np.zeros(self.dof), np.full(self.dof, np.inf)
        gains = {}
        for name in ("position_stiffness", "position_damping", "velocity_damping",
                     "max_impedance_damping"):
            gains[name] = _vector(getattr(cfg, name), self.dof, name)
            _within(gains[name], zero, inf, name)
        self._kp_position = gains["position_stiffness"]
        self._kd_position = gains["position_damping"]
        self._kd_velocity = gains["velocity_damping"]
        self._kd_impedance_max = gains["max_impedance_damping"]
        self._velocity_limit = np.array(rm.JOINT_VELOCITY_LIMIT)

    def _bind_views(self) -> None:
        """Numpy views into MuJoCo's buffers (they are allocated once, so views stay valid)."""
        ix, m, d = self._ix, self.model, self.data
        self._q, self._qd = d.qpos[ix.arm_qpos], d.qvel[ix.arm_dof]
        self._effort = d.qfrc_actuator[ix.arm_dof]
        self._ctrl = d.ctrl[ix.arm_actuators]
        self._bias_kp = m.actuator_biasprm[ix.arm_actuators, 1]
        self._bias_kd = m.actuator_biasprm[ix.arm_actuators, 2]
        self._force = d.sensordata[ix.force_adr:ix.force_adr + 3]
        self._torque = d.sensordata[ix.torque_adr:ix.torque_adr + 3]
        self._ft_xmat, self._ft_xpos = d.site_xmat[ix.ft_site], d.site_xpos[ix.ft_site]
        self._tool_com = d.subtree_com[ix.tool_body]
        self._tool_weight_support = -m.body_subtreemass[ix.tool_body] * m.opt.gravity

    # -- Plant protocol ---------------------------------------------------------------------

    def reset(self, q: Sequence[float] | None = None, *, peg_in_gripper: bool = False) -> None:
        """Arm at ``q`` (default: home) at rest, gripper open, peg at its start pose.

        With ``peg_in_gripper`` the peg is instead placed between the pads, the gripper closes
        on it and the grip settles for ``grasp_settle_steps`` (arm held) before time restarts
        at zero; the peg is then held by friction only.
        """
        q_arm = _vector(rm.HOME_Q if q is None else q, self.dof, "reset q")
        _within(q_arm, self._ix.lower, self._ix.upper, "reset q")
        mujoco.mj_resetData(self.model, self.data)
        self._stiction.release()
        self._q[:] = q_arm
        self._set_opening(rm.GRIPPER_MAX_OPENING)
        self.data.ctrl[self._ix.gripper_actuator] = rm.GRIPPER_MAX_OPENING
        self._stiction.gripper_commanded(rm.GRIPPER_MAX_OPENING)
        self._t_ns = 0
        self._forget_command_stream()
        self._set_position_target(q_arm, None)
        if peg_in_gripper:
            self._place_peg_in_gripper()
        mujoco.mj_forward(self.model, self.data)

    def command_position(self, q: Sequence[float]) -> None:
        target = _vector(q, self.dof, "position command")
        _within(target, self._ix.lower, self._ix.upper, "position command")
        self._set_position_target(target, self._feedforward_velocity(target))

    def command_impedance(
        self, q: Sequence[float], stiffness: Sequence[float], damping: Sequence[float]
    ) -> None:
        target = _vector(q, self.dof, "impedance target")
        _within(target, self._ix.lower, self._ix.upper, "impedance target")
        kp = _vector(stiffness, self.dof, "stiffness")
        kd = _vector(damping, self.dof, "damping")
        _within(kp, np.zeros(self.dof), self._kp_position, "stiffness")
        _within(kd, np.zeros(self.dof), self._kd_impedance_max, "damping")
        self._forget_command_stream()
        self._apply(ControlMode.IMPEDANCE, kp, kd, kp * target)

    def command_velocity(self, qd: Sequence[float]) -> None:
        target = _vector(qd, self.dof, "velocity command")
        _within(target, -self._velocity_limit, self._velocity_limit, "velocity command")
        self._forget_command_stream()
        kd = self._kd_velocity
        self._apply(ControlMode.VELOCITY, np.zeros(self.dof), kd, kd * target)

    def command_gripper(self, opening: float) -> None:
        value = float(opening)
        if not 0.0 <= value <= rm.GRIPPER_MAX_OPENING:  # also rejects NaN
            raise ValueError(f"gripper opening {opening!r} m is outside "
                             f"[0, {rm.GRIPPER_MAX_OPENING}]")
        self.data.ctrl[self._ix.gripper_actuator] = value
        self._stiction.gripper_commanded(value)

    def hold(self) -> None:
        """Hold the measured joint position, stiffly, from now on."""
        self._forget_command_stream()
        self._set_position_target(self._q.copy(), None)

    def step(self, n: int = 1) -> None:
        if n < 0:
            raise ValueError(f"cannot step a negative number of steps ({n})")
        until = self._feedforward_until_ns
        if until is not None and self._t_ns + n * _TIMESTEP_NS > until:
            # The velocity feed-forward is an estimate of the command stream; it must not
            # outlive the stream, or the arm would drift off the last setpoint.
            first = max(math.ceil((until - self._t_ns) / _TIMESTEP_NS), 0)
            self._advance(first)
            self._feedforward_until_ns = None
            self._set_position_target(self._position_target, None)
            n -= first
        self._advance(n)

    def state(self) -> PlantState:
        return PlantState(
            t_ns=self._t_ns,
            q=tuple(self._q.tolist()),
            qd=tuple(self._qd.tolist()),
            effort=tuple(self._effort.tolist()),
            wrench=tuple(self.tool_wrench().tolist()),
            gripper=float(self.data.ten_length[self._ix.gripper_tendon]),
        )

    def ground_truth(self) -> GroundTruth:
        if self._ix.peg_qpos is None:
            return GroundTruth(t_ns=self._t_ns)
        peg_centre, peg_axis = self._peg_pose()
        hole = self.data.site_xpos[self._ix.hole_site]
        return GroundTruth(
            t_ns=self._t_ns,
            peg_position=(float(peg_centre[0]), float(peg_centre[1]), float(peg_centre[2])),
            hole_position=(float(hole[0]), float(hole[1]), float(hole[2])),
            insertion_depth=self._insertion_depth(peg_centre, peg_axis, hole),
            peg_grasped=self.peg_grasped(),
        )

    # -- extras for tests and evaluators ----------------------------------------------------

    @property
    def mode(self) -> ControlMode:
        return self._mode

    def tcp_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """TCP position and rotation matrix in the base frame (as of the last step)."""
        site = self._ix.tcp_site
        return self.data.site_xpos[site].copy(), self.data.site_xmat[site].reshape(3, 3).copy()

    def tool_wrench(self) -> np.ndarray:
        """(Fx, Fy, Fz, Tx, Ty, Tz) the environment applies to the tool, sensor frame, N and N·m.

        MuJoCo's force/torque sensors report what the parent (sensor body) applies to the
        child (gripper); at rest and out of contact that is exactly the support of the tool's
        weight, which is subtracted, and the sign is flipped so that the result is the
        external wrench.
        """
        rotation_t = self._ft_xmat.reshape(3, 3).T
        support = self._tool_weight_support
        lever = self._tool_com - self._ft_xpos
        force = rotation_t @ support - self._force
        torque = rotation_t @ _cross(lever, support) - self._torque
        return np.concatenate((force, torque))

    def peg_grasped(self) -> bool:
        """Both pads touch the peg (ground truth from the contact list)."""
        if self._ix.peg_geom is None or self.data.ncon == 0:
            return False
        peg = self._ix.peg_geom
        touching = {int(b if a == peg else a) for a, b in self.data.contact.geom if peg in (a, b)}
        return all(pad in touching for pad in self._ix.pad_geoms)

    # -- internals --------------------------------------------------------------------------

    def _advance(self, n: int) -> None:
        if n <= 0:
            return
        mujoco.mj_step(self.model, self.data, nstep=n)
        self._t_ns += n * _TIMESTEP_NS
        # MuJoCo answers a blow-up by silently resetting the state; a test must see it.
        if any(self.data.warning[w].number for w in _DIVERGENCE_WARNINGS):
            raise PlantDiverged(f"MuJoCo reset the simulation at t={self._t_ns} ns: "
                                "non-finite or huge position, velocity or acceleration")
        self._stiction.after_step()

    def _apply(self, mode: ControlMode, kp: np.ndarray, kd: np.ndarray, ctrl: np.ndarray) -> None:
        self._bias_kp[:] = -kp
        self._bias_kd[:] = -kd
        self._ctrl[:] = ctrl
        self._mode = mode

    def _set_position_target(self, q: np.ndarray, qd: np.ndarray | None) -> None:
        self._position_target = q
        kp, kd = self._kp_position, self._kd_position
        self._apply(ControlMode.POSITION, kp, kd, kp * q if qd is None else kp * q + kd * qd)

    def _feedforward_velocity(self, target: np.ndarray) -> np.ndarray | None:
        """Setpoint velocity estimated from the last position command of an earlier step."""
        if self._last_command is not None and self._last_command[0] < self._t_ns:
            self._anchor = self._last_command
        self._last_command = (self._t_ns, target)
        self._feedforward_until_ns = None
        if self._anchor is None or self._mode is not ControlMode.POSITION:
            return None
        interval = self._t_ns - self._anchor[0]
        if interval > self.config.feedforward_max_interval_ns:
            return None
        self._feedforward_until_ns = self._t_ns + interval
        velocity = (target - self._anchor[1]) * (1e9 / interval)
        return velocity.clip(-self._velocity_limit, self._velocity_limit)

    def _forget_command_stream(self) -> None:
        self._last_command: tuple[int, np.ndarray] | None = None
        self._anchor: tuple[int, np.ndarray] | None = None
        self._feedforward_until_ns: int | None = None

    def _set_opening(self, opening: float) -> None:
        for name in rm.GRIPPER_JOINT_NAMES:
            self.data.qpos[self.model.joint(name).qposadr[0]] = opening / 2

    def _place_peg_in_gripper(self) -> None:
        if self._ix.peg_qpos is None:
            raise ValueError(f"{self.config.model_path} has no peg to place in the gripper")
        mujoco.mj_kinematics(self.model, self.data)
        tcp, rotation = self.tcp_pose()
        centre = tcp + rotation[:, 2] * rm.PEG_CENTRE_BELOW_TCP
        # The peg's own +z (its top) points back up the tool axis.
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, (rotation @ np.diag([1.0, -1.0, -1.0])).ravel())
        self._set_opening(2 * rm.PEG_HALF_EXTENTS[0])
        self.data.ctrl[self._ix.gripper_actuator] = 0.0
        self._stiction.gripper_commanded(0.0)
        # Pin the peg at the grasp pose while the pads close and settle: letting it go at the
        # first touch kicks it up to a millimetre along the pads, more than the hole's
        # clearance. Once the grip force has built up, friction alone holds it.
        q_adr, v_adr = self._ix.peg_qpos, self._ix.peg_dof
        for _ in range(self.config.grasp_settle_steps):
            self.data.qpos[q_adr:q_adr + 3] = centre
            self.data.qpos[q_adr + 3:q_adr + 7] = quat
            self.data.qvel[v_adr:v_adr + 6] = 0.0
            mujoco.mj_step(self.model, self.data)
        self._stiction.stick()
        self.data.time = 0.0

    def respawn_peg(self) -> None:
        """The cell's feeder: put a peg back at its start pose, at rest (the arm is untouched).

        Only ever called between cycles, with the gripper open and away from the peg.
        """
        if self._ix.peg_qpos is None:
            raise ValueError(f"{self.config.model_path} has no peg to respawn")
        self._stiction.release()
        q_adr, v_adr = self._ix.peg_qpos, self._ix.peg_dof
        self.data.qpos[q_adr:q_adr + 7] = self.model.qpos0[q_adr:q_adr + 7]
        self.data.qvel[v_adr:v_adr + 6] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def _peg_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Peg centre and long axis (its body z), from the current qpos."""
        adr = self._ix.peg_qpos
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, self.data.qpos[adr + 3:adr + 7])
        return self.data.qpos[adr:adr + 3].copy(), rotation[[2, 5, 8]]

    def _insertion_depth(self, centre: np.ndarray, axis: np.ndarray, hole: np.ndarray) -> float:
        """Metres of the peg's lower end below the fixture's top face, 0 unless in the hole."""
        half_length = rm.PEG_HALF_EXTENTS[2]
        bottom = centre - axis * half_length if axis[2] >= 0 else centre + axis * half_length
        inside = abs(bottom[0] - hole[0]) <= rm.HOLE_HALF_WIDTH and (
            abs(bottom[1] - hole[1]) <= rm.HOLE_HALF_WIDTH)
        return float(max(hole[2] - bottom[2], 0.0)) if inside else 0.0
