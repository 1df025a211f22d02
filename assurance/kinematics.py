"""Arm kinematics on Pinocchio, built from the same MJCF file that MuJoCo simulates.

Forward kinematics and the frame Jacobian of the TCP, a damped-least-squares IK that never
leaves the joint limits, a Cartesian-delta helper for pre-contact proposals expressed as
"move the TCP by this much in the base frame", and an axis-aligned workspace box.

Pure: no I/O, threads or clocks. An :class:`ArmKinematics` owns one Pinocchio ``Data``
scratch buffer, so use one instance per thread.

The model is handed in: the kernel reads the robot model file the manifest names (MJCF or
URDF) into a ``pin.Model``; here every joint that is not an arm joint (a gripper's fingers) is
locked at its neutral value with ``pin.buildReducedModel``, so the kinematic state is exactly
the arm's angles.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import pinocchio as pin


class JacobianFrame(StrEnum):
    """Which axes the 6×6 Jacobian's rows are expressed in (linear rows first)."""

    BASE = "base"
    """TCP point velocity and angular velocity in base-frame axes (LOCAL_WORLD_ALIGNED)."""
    TOOL = "tool"
    """The same twist in the TCP frame's own axes (LOCAL)."""


_IDENTITY3 = np.eye(3)
_PIN_FRAME = {
    JacobianFrame.BASE: pin.ReferenceFrame.LOCAL_WORLD_ALIGNED,
    JacobianFrame.TOOL: pin.ReferenceFrame.LOCAL,
}


@dataclass(frozen=True, slots=True, eq=False)
class KinematicsConfig:
    model: pin.Model
    """The robot's full kinematic model, as read from its model file."""
    tcp_frame: str
    arm_joints: tuple[str, ...]
    """The arm's joints, base to tool; every other joint is locked at its neutral value."""
    source: str = "robot model"
    """Where the model came from (named in errors)."""
    sha256: str = ""
    """SHA-256 of the very bytes ``model`` was parsed from (empty: built in memory)."""
    collision: pin.GeometryModel | None = None
    """The model's collision geoms on ``model`` (from the same bytes), where the file has
    them (MJCF primitive geoms); :mod:`assurance.collision` checks clearances with them."""


@dataclass(frozen=True, slots=True)
class IKConfig:
    """Damped least squares, ``dq = Jᵀ (J Jᵀ + λ·I)⁻¹ e``, each iterate clamped into the limits.

    ``λ = damping + ‖e‖²`` (Levenberg–Marquardt style, as in Sugihara 2011): heavy damping far
    from the target keeps steps sane near singularities, and vanishing damping close to it
    gives Gauss–Newton convergence even where the Jacobian is nearly singular.
    """

    max_iterations: int = 100
    position_tolerance: float = 1e-6
    """Metres."""
    rotation_tolerance: float = 1e-5
    """Radians."""
    damping: float = 1e-6
    """Floor of λ, so the system stays solvable at an exact singularity."""
    max_step: float = 0.5
    """Largest joint change per iteration (rad): a trust region for far-away targets."""

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be at least 1, got {self.max_iterations}")
        for name in ("position_tolerance", "rotation_tolerance", "damping", "max_step"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")


_DEFAULT_IK = IKConfig()


@dataclass(frozen=True, slots=True, eq=False)
class Pose:
    """A TCP pose in the base frame: position (m) and rotation matrix."""

    position: np.ndarray
    rotation: np.ndarray

    def __post_init__(self) -> None:
        if np.shape(self.position) != (3,) or np.shape(self.rotation) != (3, 3):
            raise ValueError("a Pose needs a 3-vector position and a 3x3 rotation")


@dataclass(frozen=True, slots=True, eq=False)
class IKResult:
    q: np.ndarray
    converged: bool
    iterations: int
    position_error: float
    """Metres between the reached and the requested TCP position."""
    rotation_error: float
    """Radians between the reached and the requested TCP orientation."""

    @property
    def residual(self) -> float:
        return float(np.hypot(self.position_error, self.rotation_error))


@dataclass(frozen=True, slots=True, eq=False)
class WorkspaceBox:
    """An axis-aligned box in the base frame that the TCP must stay in."""

    lower: np.ndarray
    upper: np.ndarray
    _bounds: tuple[list[float], list[float]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        lower = np.array(self.lower, dtype=float)
        upper = np.array(self.upper, dtype=float)
        if lower.shape != (3,) or upper.shape != (3,):
            raise ValueError("WorkspaceBox bounds must be 3-vectors")
        if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
            raise ValueError("WorkspaceBox bounds must be finite")
        if np.any(lower > upper):
            raise ValueError(f"WorkspaceBox lower {lower} exceeds upper {upper}")
        lower.setflags(write=False)
        upper.setflags(write=False)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "_bounds", (lower.tolist(), upper.tolist()))

    def contains(self, position: np.ndarray) -> bool:
        """True when ``position`` is inside the box or on its boundary (NaN is outside)."""
        values = np.asarray(position, dtype=float).tolist()
        if not isinstance(values, list) or len(values) != 3:
            raise ValueError(f"a workspace position needs 3 values, got {values!r}")
        low, high = self._bounds
        return all(map(operator.le, low, values)) and all(map(operator.le, values, high))


class ArmKinematics:
    """FK, Jacobian and IK of the TCP frame of the arm model (see the module docstring)."""

    def __init__(self, config: KinematicsConfig) -> None:
        self.config = config
        self.model = _arm_model(config)
        self._data = self.model.createData()
        if not self.model.existFrame(config.tcp_frame):
            raise ValueError(f"{config.source} has no frame {config.tcp_frame!r}")
        self._frame = self.model.getFrameId(self.config.tcp_frame)
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()
        self.lower.setflags(write=False)
        self.upper.setflags(write=False)
        # Plain-float copies: on six values, Python comparisons beat numpy reductions (.all(),
        # .max() cost a few microseconds each here).
        self._lower_list, self._upper_list = self.lower.tolist(), self.upper.tolist()

    @property
    def dof(self) -> int:
        return int(self.model.nq)

    def forward(self, q: np.ndarray) -> Pose:
        """TCP pose at joint angles ``q``."""
        q = self._joint_vector(q)
        pin.forwardKinematics(self.model, self._data, q)
        placement = pin.updateFramePlacement(self.model, self._data, self._frame)
        return Pose(placement.translation.copy(), placement.rotation.copy())

    def jacobian(self, q: np.ndarray, frame: JacobianFrame = JacobianFrame.BASE) -> np.ndarray:
        """6×6 TCP Jacobian at ``q``: rows (vx, vy, vz, wx, wy, wz), columns the joints."""
        q = self._joint_vector(q)
        return pin.computeFrameJacobian(self.model, self._data, q, self._frame,
                                        _PIN_FRAME[JacobianFrame(frame)]).copy()

    def forward_with_jacobian(self, q: np.ndarray) -> tuple[Pose, np.ndarray]:
        """Pose and base-axes Jacobian from one kinematics pass."""
        pose, jac = self._pose_and_jacobian(self._joint_vector(q))
        return Pose(pose.translation.copy(), pose.rotation.copy()), jac.copy()

    def within_limits(self, q: np.ndarray) -> bool:
        """True when every joint is inside its limits (False for NaN)."""
        values = np.asarray(q, dtype=float).tolist()
        return all(map(operator.le, self._lower_list, values)) and all(
            map(operator.le, values, self._upper_list))

    def solve(self, target: Pose, q_start: np.ndarray, config: IKConfig | None = None) -> IKResult:
        """Joint angles that put the TCP at ``target``, warm-started from ``q_start``.

        Every iterate is clamped into the joint limits, so the returned ``q`` is always inside
        them even when the solve does not converge (``converged`` is then False and the
        errors say how far off it is).

        Raises:
            ValueError: ``q_start`` has the wrong length, is not finite or is outside the
                limits, or ``target`` is not finite or its rotation is not a rotation.
        """
        q = self._checked_start(q_start)
        _check_target(target)
        return self._iterate(target, q, config or _DEFAULT_IK)

    def follow(self, targets: Sequence[Pose], q_start: np.ndarray,
               config: IKConfig | None = None) -> tuple[np.ndarray, IKResult | None]:
        """Joint angles for a sequence of nearby TCP targets (a path), each solve warm-started
        from the previous solutions extrapolated one step, so a smooth path typically costs
        one pose evaluation per target and stays on one IK branch.

        Returns the solutions (one row per target) and None, or the solutions up to the first
        target that did not converge and that target's result.

        Raises:
            ValueError: as :meth:`solve`, for the start or for any target.
        """
        cfg = config or _DEFAULT_IK
        q = self._checked_start(q_start)
        checked: set[int] = set()  # a path often holds one orientation: check each once
        for target in targets:
            _check_target(target, check_rotation=id(target.rotation) not in checked)
            checked.add(id(target.rotation))
        solutions = np.empty((len(targets), self.dof))
        previous: np.ndarray | None = None
        for row, target in enumerate(targets):
            seed = q if previous is None else (2.0 * q - previous).clip(self.lower, self.upper)
            result = self._iterate(target, seed, cfg)
            if not result.converged:
                return solutions[:row], result
            previous, q = q, result.q
            solutions[row] = q
        return solutions, None

    def _iterate(self, target: Pose, q: np.ndarray, cfg: IKConfig) -> IKResult:
        tolerance_sq = (cfg.position_tolerance**2, cfg.rotation_tolerance**2)
        for iteration in range(cfg.max_iterations + 1):
            pose, jac = self._pose_and_jacobian(q)
            error = _pose_error(target, pose.translation, pose.rotation)
            position_sq, rotation_sq = _squared_norms(error)
            converged = position_sq <= tolerance_sq[0] and rotation_sq <= tolerance_sq[1]
            if converged or iteration == cfg.max_iterations:
                break
            step = _dls_step(jac, error, cfg.damping + position_sq + rotation_sq, cfg.max_step)
            q = (q + step).clip(self.lower, self.upper)
        position_error, rotation_error = math.sqrt(position_sq), math.sqrt(rotation_sq)
        return IKResult(q, converged, iteration, position_error, rotation_error)

    def cartesian_delta_target(
        self,
        q: np.ndarray,
        delta_position: np.ndarray,
        delta_rotation: np.ndarray | None = None,
        config: IKConfig | None = None,
    ) -> IKResult:
        """Joint target for moving the TCP by a delta expressed in the base frame.

        Args:
            q: current joint angles (also the IK warm start).
            delta_position: TCP translation in base axes (m).
            delta_rotation: rotation vector (axis·angle, rad) in base axes, applied on the
                left of the current orientation; None for no rotation.
            config: IK settings.
        """
        current = self.forward(q)
        d_position = np.asarray(delta_position, dtype=float)
        d_rotation = np.zeros(3) if delta_rotation is None else np.asarray(delta_rotation, float)
        if d_position.shape != (3,) or d_rotation.shape != (3,):
            raise ValueError("Cartesian deltas must be 3-vectors")
        target = Pose(current.position + d_position, pin.exp3(d_rotation) @ current.rotation)
        return self.solve(target, q, config)

    def _pose_and_jacobian(self, q: np.ndarray) -> tuple[pin.SE3, np.ndarray]:
        # computeFrameJacobian runs the joint placements itself; the frame placement is then
        # one more cheap update, so pose and Jacobian come from a single kinematics pass.
        jac = pin.computeFrameJacobian(self.model, self._data, q, self._frame,
                                       pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return pin.updateFramePlacement(self.model, self._data, self._frame), jac

    def _checked_start(self, q_start: np.ndarray) -> np.ndarray:
        q = np.array(q_start, dtype=float)
        if q.shape != (self.dof,):
            raise ValueError(f"expected {self.dof} joint values, got shape {q.shape}")
        if not self.within_limits(q):  # NaN fails this too
            raise ValueError(f"IK start {q.tolist()} is not finite or outside the joint limits")
        return q

    def _joint_vector(self, q: np.ndarray) -> np.ndarray:
        array = np.array(q, dtype=float)
        if array.shape != (self.dof,):
            raise ValueError(f"expected {self.dof} joint values, got shape {array.shape}")
        if not all(map(math.isfinite, array.tolist())):
            raise ValueError(f"joint vector is not finite: {array.tolist()}")
        return array


def _arm_model(config: KinematicsConfig) -> pin.Model:
    full = config.model
    names = [full.names[j] for j in range(1, full.njoints)]
    missing = [name for name in config.arm_joints if name not in names]
    if missing:
        raise ValueError(f"{config.source} has no joints {missing}")
    locked = [full.getJointId(name) for name in names if name not in config.arm_joints]
    model = pin.buildReducedModel(full, locked, pin.neutral(full)) if locked else full
    if tuple(model.names[1:]) != tuple(config.arm_joints):
        raise ValueError(f"arm joints {config.arm_joints} are not the model's kinematic chain "
                         f"{tuple(model.names[1:])} in order")
    if model.nq != len(config.arm_joints) or model.nv != model.nq:
        raise ValueError(f"arm joints must be 1-DoF; got nq={model.nq} nv={model.nv}")
    return model


def _check_target(target: Pose, check_rotation: bool = True) -> None:
    if not all(map(math.isfinite, target.position.tolist())):
        raise ValueError(f"IK target position is not finite: {target.position.tolist()}")
    if not check_rotation:
        return
    deviation = (target.rotation @ target.rotation.T - _IDENTITY3).ravel().tolist()
    if not all(abs(value) <= 1e-6 for value in deviation):  # also false for NaN
        raise ValueError("IK target rotation is not orthonormal (or not finite)")


def _squared_norms(error: np.ndarray) -> tuple[float, float]:
    """Squared position and rotation errors (plain floats: cheaper than two dot products)."""
    px, py, pz, rx, ry, rz = error.tolist()
    return px * px + py * py + pz * pz, rx * rx + ry * ry + rz * rz


def _pose_error(target: Pose, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(position error, rotation-vector error), both in base axes, target minus current."""
    return np.concatenate((target.position - position, pin.log3(target.rotation @ rotation.T)))


def _dls_step(jac: np.ndarray, error: np.ndarray, damping: float, max_step: float) -> np.ndarray:
    gram = jac @ jac.T
    gram.flat[::7] += damping  # the diagonal of the 6x6
    # A 2-D right-hand side takes numpy's faster solve path (~9 us instead of ~17 us here).
    step = jac.T @ np.linalg.solve(gram, error[:, None])[:, 0]
    largest = max(map(abs, step.tolist()))
    return step * (max_step / largest) if largest > max_step else step
