"""Where the arm could go: clearance of every queued action, and of the motion between them.

The cell's solids are a Pinocchio ``GeometryModel`` (coal shapes): the arm's own collision
geoms (the model's primitive geoms, which the kernel loads with the kinematics), the world's
obstacles and keep-out zones, and the held part, fixed to the TCP while the gripper holds it.
Which pairs are checked:

- **self**: two robot geoms whose joints are not adjacent (two or more joints apart), when
  ``self_collision``; they keep the default clearance (``margin``) in every phase;
- **obstacle**: a robot geom (link, tool or part) against an obstacle, at the phase's
  clearance; the tool and the part are not checked against an obstacle in the phases it
  allows contact in (the fixture in CONTACT); the links always are;
- **keep-out**: any robot geom against a keep-out zone, at the phase's clearance, always.

A geom fixed to the base (the base itself) is not checked against the world: no motion
changes that distance.

Between two consecutive configurations ``a`` and ``b`` (the reference the chunk follows, then
each action) no point of a robot geom ``g`` travels farther than
``s_g = Σ_j |Δq_j|·R[g, j]``, where ``R[g, j]`` bounds the distance of any point of ``g`` from
joint ``j``'s origin (the chain's link lengths from ``j`` to ``g``'s joint, plus ``g``'s
offset and its bounding radius: a constant of the model, computed once). On the straight
joint-space segment from ``a`` to ``b`` a pair's distance is therefore at least
``(d(a) + d(b) − s) / 2`` with ``s`` the sum of both geoms' travel: the check asks that bound,
and ``d(b)`` itself, to keep the pair's clearance. It is conservative (it never passes a
segment that comes closer than the clearance), and it tightens as the steps get shorter: a
segment whose bound falls short while both ends keep the clearance is halved at its midpoint
(measured) and each half bounded again, within a fixed budget of distance queries per check.

Pure: no I/O, no clock. One :class:`CellCollision` owns Pinocchio data buffers: one instance
per thread.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import pinocchio as pin

from assurance.kinematics import ArmKinematics
from assurance.reach import CellGeometry, RobotSolid, reach_about_axes, with_part
from assurance.solids import Shape, SolidSpec, arm_geometry


@dataclass(frozen=True, slots=True)
class CollisionSettings:
    margin: float = 0.01
    phase_margins: dict[str, float] = field(default_factory=dict)
    self_collision: bool = True
    part: SolidSpec | None = None
    """The held part, placed in the TCP frame."""
    solids: tuple[SolidSpec, ...] = ()

    def margin_in(self, phase: str) -> float:
        return self.phase_margins.get(phase, self.margin)


class PairKind(StrEnum):
    SELF = "self"
    OBSTACLE = "obstacle"
    KEEP_OUT = "keep_out"


@dataclass(frozen=True, slots=True)
class Clearance:
    """The first place a motion breaks a pair's clearance."""

    action: int
    """Index of the action the motion goes to (0: the first, from the reference)."""
    pair: tuple[str, str]
    distance: float
    """The pair's distance at that action, m (negative: penetration)."""
    bound: float
    """The lower bound on the pair's distance over the motion into that action, m."""
    needed: float
    """The clearance the pair must keep, m."""


SPLIT_BUDGET = 256
"""Distance queries one check may spend halving motions whose bound falls short."""
SPLIT_STEP = 1e-4
"""rad (m for a prismatic joint): a motion no joint of which turns farther is not halved."""


@dataclass(frozen=True, slots=True, eq=False)
class _Pairs:
    """The pairs checked in one phase, with or without the part: their own geometry model
    (holding only those pairs), its data, their clearances and their geoms."""

    model: pin.GeometryModel
    data: pin.GeometryData
    margin: np.ndarray
    mover: np.ndarray
    """Per pair, the geom whose motion changes the pair's distance (the robot's, against a
    world solid; of two robot geoms, the one further along the chain)."""
    mask: np.ndarray
    """(pairs, dof): 1 for the joints that move the mover relative to the other solid (of two
    robot geoms, only the joints between them)."""
    names: tuple[tuple[str, str], ...]


class CellCollision:
    """The clearance checks of one cell (see the module docstring)."""

    def __init__(self, kinematics: ArmKinematics, settings: CollisionSettings) -> None:
        """Raises:
            ValueError: the robot model has no collision geoms."""
        arm = arm_geometry(kinematics)
        self.kinematics = kinematics
        self.settings = settings
        self.model = kinematics.model
        self._data = self.model.createData()
        self._tcp = self.model.getFrameId(kinematics.config.tcp_frame)
        self._held = with_part(self.model, arm, settings.part, settings.solids, self._tcp,
                               held=True)
        self._free = with_part(self.model, arm, settings.part, settings.solids, self._tcp,
                               held=False)
        self._cache: dict[tuple[str, bool], _Pairs] = {}

    @property
    def dof(self) -> int:
        return int(self.model.nq)

    def holds(self, opening: float | None) -> bool:
        """Whether a gripper commanded to ``opening`` (m) holds the part: narrower than the
        part across the pads (its x extent in the TCP frame; a round part's diameter)."""
        part = self.settings.part
        if part is None or opening is None:
            return False
        return opening < 2.0 * part.size[0]

    def distances(self, q: np.ndarray, phase: str, held: bool) -> dict[tuple[str, str], float]:
        """Every checked pair's distance at ``q`` (m; negative: penetration)."""
        pairs = self._pairs(phase, held)
        row = self._distance_row(np.asarray(q, dtype=float), pairs)
        return dict(zip(pairs.names, row.tolist(), strict=True))

    def clear_by_travel(self, start: np.ndarray, rows: np.ndarray, phase: str,
                        held: bool) -> bool:
        """Whether the whole motion, from ``start`` through every row, provably keeps every
        pair's clearance on one distance query (:meth:`_near`): sound like :meth:`check` and
        much cheaper; False only means this bound cannot tell (the motion passes near
        something), never that it collides."""
        pairs = self._pairs(phase, held)
        if rows.shape[0] == 0 or not pairs.names:
            return True
        return not self._near(_path(start, rows), pairs, held).any()

    def check(self, start: np.ndarray, rows: np.ndarray, phase: str,
              held: bool) -> Clearance | None:
        """The first action whose motion from the one before (the first: from ``start``)
        breaks a pair's clearance, or None when every motion keeps them all.

        The pairs :meth:`_near`'s bound proves clear over the whole motion are not looked at
        again; each other pair is measured at every action and bounded over each motion."""
        pairs = self._pairs(phase, held)
        if rows.shape[0] == 0 or not pairs.names:
            return None
        qs = _path(start, rows)
        near = np.flatnonzero(self._near(qs, pairs, held))
        if near.size == 0:
            return None
        geometry = self._held if held else self._free
        movers = np.unique(pairs.mover[near])
        dist = np.empty((qs.shape[0], near.size))
        joints = np.empty((rows.shape[0], self.dof, 4, 4))
        for i, q in enumerate(qs):
            pin.updateGeometryPlacements(self.model, self._data, pairs.model, pairs.data, q)
            dist[i] = [pin.computeDistance(pairs.model, pairs.data, p).min_distance
                       for p in near.tolist()]
            if i < rows.shape[0]:
                joints[i] = self._joint_placements(geometry)
        radius = np.zeros((rows.shape[0], *geometry.radii.shape))
        radius[:, movers] = reach_about_axes(geometry, movers, joints)
        swept = _travel(np.abs(np.diff(qs, axis=0)), radius, geometry.radii, pairs)[:, near]
        bound = np.minimum(dist[1:], 0.5 * (dist[:-1] + dist[1:] - swept))
        splits = _Splits(pairs, geometry)
        for action, column in np.argwhere(bound < pairs.margin[near]).tolist():
            pair = int(near[column])
            lowest = self._split(qs[action], joints[action], qs[action + 1],
                                 (float(dist[action, column]), float(dist[action + 1, column])),
                                 pair, splits)
            if lowest < pairs.margin[pair]:
                return Clearance(action=action, pair=pairs.names[pair],
                                 distance=float(dist[action + 1, column]), bound=lowest,
                                 needed=float(pairs.margin[pair]))
        return None

    def _split(self, a: np.ndarray, placed: np.ndarray, b: np.ndarray,
               ends: tuple[float, float], pair: int, splits: _Splits) -> float:
        """The lowest bound on ``pair``'s distance over the motion from ``a`` to ``b`` that
        halving it can prove: the motion's own bound, or when that falls under the pair's
        clearance, its two halves' (each from the distance at the midpoint, so the bound
        tightens as the halves get shorter), down to steps of ``SPLIT_STEP`` and within
        ``SPLIT_BUDGET`` distance queries per check. A long step (the first one out of a
        hold the queue ran dry into) passes a pair it keeps clear of, which the one bound
        over the whole step could not show; one that comes closer still fails, at the
        midpoint that does. ``placed``: each joint's placement at ``a``; ``ends``: the
        pair's distances at ``a`` and ``b``."""
        lowest = min(ends[1], 0.5 * (sum(ends) - splits.swept(a, placed, b, pair)))
        needed = splits.pairs.margin[pair]
        if lowest >= needed or ends[1] < needed or not splits.take(np.abs(b - a).max()):
            return lowest
        middle = 0.5 * (a + b)
        pin.updateGeometryPlacements(self.model, self._data, splits.pairs.model,
                                     splits.pairs.data, middle)
        at_middle = pin.computeDistance(splits.pairs.model, splits.pairs.data, pair).min_distance
        if at_middle < needed:
            return at_middle
        placed_middle = self._joint_placements(splits.geometry)
        first = self._split(a, placed, middle, (ends[0], at_middle), pair, splits)
        if first < needed:
            return first
        return min(first, self._split(middle, placed_middle, b, (at_middle, ends[1]), pair,
                                      splits))

    def _near(self, qs: np.ndarray, pairs: _Pairs, held: bool) -> np.ndarray:
        """Per pair, whether it may come within its clearance along the path ``qs``, by one
        distance query at its start: its distance there less the farthest its moving solid
        can travel over the whole path must be at least its clearance, or it is near. The
        travel is :func:`_travel`'s bound for one motion whose joint steps are each joint's
        whole travel (the sum of its |Δq| over the path): the argument for one straight
        motion holds for any path, as it uses only how far each joint turns."""
        geometry = self._held if held else self._free
        distance = self._distance_row(qs[0], pairs)
        path = np.abs(np.diff(qs, axis=0)).sum(axis=0)[None, :]  # (1, dof)
        every = np.arange(len(geometry.roles))
        radius = reach_about_axes(geometry, every, self._joint_placements(geometry)[None])
        travel = _travel(path, radius, geometry.radii, pairs)[0]
        return distance - travel < pairs.margin

    def _joint_placements(self, geometry: CellGeometry) -> np.ndarray:
        """(dof, 4, 4): each joint's placement at the configuration just computed."""
        placed = self._data.oMi  # each attribute read builds a proxy: once
        return np.array([placed[joint].homogeneous for joint in geometry.joint_list])

    def _distance_row(self, q: np.ndarray, pairs: _Pairs) -> np.ndarray:
        pin.computeDistances(self.model, self._data, pairs.model, pairs.data, q)
        return np.array([result.min_distance for result in pairs.data.distanceResults])

    def _pairs(self, phase: str, held: bool) -> _Pairs:
        key = (str(phase), held)
        if key not in self._cache:
            self._cache[key] = _select(self._held if held else self._free, self.settings,
                                       str(phase))
        return self._cache[key]


class _Splits:
    """What halving the motions of one check needs: its pairs and geometry, and how many
    distance queries it may still spend."""

    def __init__(self, pairs: _Pairs, geometry: CellGeometry) -> None:
        self.pairs = pairs
        self.geometry = geometry
        self.left = SPLIT_BUDGET

    def take(self, step: float) -> bool:
        """Spend one query on a motion whose largest joint step is ``step``, if any are left
        and the motion is worth halving."""
        if self.left <= 0 or step <= SPLIT_STEP:
            return False
        self.left -= 1
        return True

    def swept(self, a: np.ndarray, placed: np.ndarray, b: np.ndarray, pair: int) -> float:
        """How far ``pair``'s moving solid can travel relative to the other from ``a`` to
        ``b`` (:func:`_travel`); ``placed``: each joint's placement at ``a``."""
        mover = self.pairs.mover[pair : pair + 1]
        radius = np.zeros((1, *self.geometry.radii.shape))
        radius[:, mover] = reach_about_axes(self.geometry, mover, placed[None])
        return float(_travel(np.abs(b - a)[None], radius, self.geometry.radii, self.pairs)[0, pair])


def _path(start: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The configurations of a motion: ``start``, then each row."""
    return np.vstack((np.asarray(start, dtype=float)[None, :], np.asarray(rows, dtype=float)))


def _travel(step: np.ndarray, radius: np.ndarray, bound: np.ndarray,
            pairs: _Pairs) -> np.ndarray:
    """(actions, pairs): how far each pair's moving solid can travel relative to the other
    over each motion. ``step``: |Δq| per action (actions, dof); ``radius``: each geom's reach
    about each joint's axis at the motion's start (actions, geoms, dof); ``bound``: the
    configuration-independent reach from each joint's origin (geoms, dof). While joint j
    turns, the joints after it move the geom by at most Σ_{k>j} |Δq_k|·bound[g, k], so its
    reach about j's axis grows by no more than that during the motion."""
    later = step[:, None, :] * bound[None, :, :]
    after = np.cumsum(later[:, :, ::-1], axis=2)[:, :, ::-1] - later  # Σ over k > j
    reach = np.where(bound[None] > 0.0, radius + after, 0.0)
    moving = reach[:, pairs.mover, :] * pairs.mask[None, :, :]  # (actions, pairs, dof)
    return np.einsum("aj,apj->ap", step, moving)


def _pair_kind(a: RobotSolid | SolidSpec, b: RobotSolid | SolidSpec, joint_a: int, joint_b: int,
               settings: CollisionSettings) -> PairKind | None:
    robot_a, robot_b = isinstance(a, RobotSolid), isinstance(b, RobotSolid)
    if robot_a and robot_b:
        if not settings.self_collision or abs(joint_a - joint_b) < 2:
            return None
        return PairKind.SELF
    if not (robot_a or robot_b):
        return None  # two world solids: neither moves
    robot_joint = joint_a if robot_a else joint_b
    solid = b if robot_a else a
    if robot_joint == 0 or not isinstance(solid, SolidSpec):
        return None  # fixed to the base: no motion changes the distance
    return PairKind.KEEP_OUT if solid.keep_out else PairKind.OBSTACLE


def _select(geometry: CellGeometry, settings: CollisionSettings, phase: str) -> _Pairs:
    model = geometry.model.copy()
    model.removeAllCollisionPairs()
    roles, joints, objects = geometry.roles, geometry.joints, model.geometryObjects
    margin, names, movers, masks = [], [], [], []
    for a in range(len(roles)):
        for b in range(a + 1, len(roles)):
            kind = _pair_kind(roles[a], roles[b], joints[a], joints[b], settings)
            if kind is None or _contact_allowed(kind, roles[a], roles[b], phase):
                continue
            model.addCollisionPair(pin.CollisionPair(a, b))
            margin.append(settings.margin if kind is PairKind.SELF else
                          settings.margin_in(phase))
            names.append((objects[a].name, objects[b].name))
            mover, mask = _mover(geometry, a, b)
            movers.append(mover)
            masks.append(mask)
    dof = geometry.radii.shape[1]
    return _Pairs(model, pin.GeometryData(model), np.array(margin),
                  np.array(movers, dtype=int), np.array(masks).reshape(len(names), dof),
                  tuple(names))


def _mover(geometry: CellGeometry, a: int, b: int) -> tuple[int, np.ndarray]:
    """The geom of pair (a, b) that moves relative to the other, and the joints that move it
    so."""
    joints, every = geometry.joints, np.ones(geometry.radii.shape[1])
    if isinstance(geometry.roles[a], SolidSpec):
        return b, every
    if isinstance(geometry.roles[b], SolidSpec):
        return a, every
    low, high = (a, b) if joints[a] <= joints[b] else (b, a)
    # The joints up to the lower geom's move both rigidly: only those after it count.
    return high, (geometry.joint_of_q > joints[low]).astype(float)


def _contact_allowed(kind: PairKind, a: RobotSolid | SolidSpec, b: RobotSolid | SolidSpec,
                     phase: str) -> bool:
    """The tool and the part may touch an obstacle in the phases it names."""
    if kind is not PairKind.OBSTACLE:
        return False
    robot, solid = (a, b) if isinstance(b, SolidSpec) else (b, a)
    return (robot in (RobotSolid.TOOL, RobotSolid.PART) and isinstance(solid, SolidSpec)
            and phase in solid.allow_contact)


__all__ = ["CellCollision", "Clearance", "CollisionSettings", "PairKind", "Shape", "SolidSpec"]
