"""Static friction (stiction) between the gripper's pads and a gripped peg.

Why it is needed: MuJoCo's friction is a velocity-level constraint. Each step it asks the
contact's slip velocity to decay (reference acceleration ``-b*v``), but it has no memory of
where the contact stuck, and the constraint equation leaves out the bias acceleration
``dJ/dt*qvel`` of the contact points. A pad on a moving arm follows curved paths (centripetal
and Coriolis terms of the arm), so a held peg never receives that part of the acceleration
from the contact directly; it lags until the slip velocity ``a_bias/b`` builds up to supply
it, and everything that slips in the meantime is never recovered. The drift over a move is
``integral(a_bias dt) / b``: about 0.4 mm for a 6 rad/s² transport move, whatever the friction
coefficient, grip force, solimp, condim, impratio or noslip iterations, because the contact is
nowhere near its friction limit (under 1 N of a 70 N capacity). ``b`` is capped by the 2 ms
step (solref time constant at least two steps), so only a position-level stick state
removes it.

The model is stick/slip switching (as in Karnopp's friction model):

- Stick: when the gripper squeezes (commanded narrower than it is), both pads touch the peg,
  the grip has stopped closing and the peg moves with the gripper, the weld equality
  ``grasp_stiction`` (``cell.xml``) between the gripper body and the peg is anchored at their
  current relative pose and switched on, and the pads' contacts drop to normal force only
  (condim 1; the pads have contact priority over the peg, so the pad-peg contacts take the
  pads' condim and nothing else changes). The weld carries the grip's tangential and
  torsional load: it plays the pads' shear stiffness, with the same 4 ms time constant as
  every contact in the cell.
- Slip: after every step call the weld's load on the peg is checked against the grip's Coulomb
  capacity, elliptic like MuJoCo's cone: (F_t / mu*N)² + (T_n / mu_spin*N)² <= 1, with F_t the
  force along the pads' faces, T_n the torque about the pads' normal, N both pads' normal force
  (twice the gripper actuator force) and mu, mu_spin the pads' sliding and torsional friction.
  Over it, or when the gripper stops squeezing, the weld lets go and the pad contacts get their
  friction back: the peg slides on MuJoCo's friction until it sticks again (after at least
  ``_REGRIP_HOLD_OFF_S``).

The check runs at the end of each ``step(n)`` call, not inside a multi-step call: a grasp closed
and carried off within one long ``step(n)`` is held by friction alone until the call returns.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from stubs.plant._cell_index import CellIndex

_SQUEEZE_MARGIN_M = 0.0005
"""The gripper squeezes when commanded at least this much narrower than its measured opening."""
_CLOSING_SPEED_MAX = 0.005
"""m/s of opening change below which the grip has stopped closing."""
_STICK_SPEED_MAX = 0.002
"""m/s of peg motion relative to the gripper below which the peg moves with it."""
_STICK_SPIN_MAX = 0.05
"""rad/s of relative rotation, likewise."""
_REGRIP_HOLD_OFF_S = 0.02
"""After a slip, the peg sticks again at the earliest this long after."""
_EQUALITY = int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)  # plain ints compare much faster


class GraspStiction:
    """The stick/slip state of the grip on the peg; inert on a model without the cell."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, ix: CellIndex) -> None:
        self._m, self._d = model, data
        self._weld = ix.grasp_weld
        self.stuck = False
        self._slipped_at = -math.inf
        self._commanded = math.nan
        self._closing = False
        if self._weld is None or ix.peg_body is None or ix.peg_geom is None:
            self._weld = None
            return
        if (model.eq_type[self._weld] != mujoco.mjtEq.mjEQ_WELD
                or model.eq_obj1id[self._weld] != ix.tool_body
                or model.eq_obj2id[self._weld] != ix.peg_body):
            raise ValueError("the grasp stiction equality must weld the tool body to the peg")
        self._pads = list(ix.pad_geoms)
        if any(model.geom_priority[p] <= model.geom_priority[ix.peg_geom] for p in self._pads):
            raise ValueError("the pads need contact priority over the peg")
        self._pad_condim = model.geom_condim[self._pads].copy()
        self._mu = float(model.geom_friction[self._pads[0], 0])
        self._mu_spin = float(model.geom_friction[self._pads[0], 1])
        self._tool, self._peg_body, self._peg_geom = ix.tool_body, ix.peg_body, ix.peg_geom
        self._actuator, self._tendon = ix.gripper_actuator, ix.gripper_tendon
        # Views into MuJoCo's buffers that are allocated once (the efc_* arrays are not).
        self._ctrl, self._opening = data.ctrl, data.ten_length
        self._opening_speed, self._grip_force = data.ten_velocity, data.actuator_force
        self._tool_xmat, self._peg_xmat = data.xmat[self._tool], data.xmat[self._peg_body]
        self._eq_data = model.eq_data[self._weld]
        self._torque_per_row_force = 0.5 * float(self._eq_data[10])  # torquescale
        self._row = -1
        # A gripper commanded fully open cannot squeeze: after_step then has nothing to check.
        self._fully_open = float(model.actuator_ctrlrange[ix.gripper_actuator, 1]
                                 - _SQUEEZE_MARGIN_M)

    def after_step(self) -> None:
        """Stick or slip as the step just taken left things; cheap when nothing is gripped."""
        if self.stuck:
            # Squeezing only stops through a gripper command (gripper_commanded): a stuck peg
            # keeps the opening where it was.
            if self._overloaded():
                self.release(slipped=True)
        elif self._closing and self._squeezing() and self._gripped_and_still():
            self.stick()

    def gripper_commanded(self, opening: float) -> None:
        """The plant set the gripper's command; an opening one lets go of a stuck peg at once.

        Called for every command (drivers repeat it each tick), so a repeat costs nothing.
        """
        if opening == self._commanded:
            return
        self._commanded = opening
        self._closing = self._weld is not None and opening < self._fully_open
        if self.stuck and not self._squeezing():
            self.release()

    def _squeezing(self) -> bool:
        return bool(self._ctrl[self._actuator]
                    < self._opening[self._tendon] - _SQUEEZE_MARGIN_M)

    def stick(self) -> None:
        """Hold the peg at its current pose in the gripper (poses as of the last step)."""
        if self._weld is None:
            return
        d = self._d
        tool_rotation = self._tool_xmat.reshape(3, 3)
        inverse, relative = np.empty(4), np.empty(4)
        mujoco.mju_negQuat(inverse, d.xquat[self._tool])
        mujoco.mju_mulQuat(relative, inverse, d.xquat[self._peg_body])
        self._eq_data[0:3] = 0.0  # anchored at the peg's centre
        self._eq_data[3:6] = tool_rotation.T @ (d.xpos[self._peg_body] - d.xpos[self._tool])
        self._eq_data[6:10] = relative
        self._row = -1  # found in the first step's constraints, then fixed while active
        d.eq_active[self._weld] = 1
        self._m.geom_condim[self._pads] = 1
        self.stuck = True

    def release(self, *, slipped: bool = False) -> None:
        """Back to friction only (also used by resets, with ``slipped`` False)."""
        if self._weld is None:
            return
        self._d.eq_active[self._weld] = 0
        self._m.geom_condim[self._pads] = self._pad_condim
        self.stuck = False
        self._slipped_at = self._d.time if slipped else -math.inf

    def _overloaded(self) -> bool:
        # Plain floats and a cheap bound first: this runs after every step while a peg is held,
        # and numpy's per-call overhead on 3-vectors would cost more than the check itself.
        forces = self._d.efc_force
        row = self._row
        if row < 0 or row + 6 > forces.shape[0]:
            row = self._row = self._search_weld_row()
            if row < 0:
                return False  # the weld was not in the last step's constraints
        fx, fy, fz, rx, ry, rz = forces[row:row + 6].tolist()
        normal = 2.0 * abs(float(self._grip_force[self._actuator]))
        if normal <= 0.0:
            return True
        # With the anchor at the peg's centre, the weld's translational rows act on the peg as
        # a force in world axes and its rotational rows, for the sub-milliradian errors of a
        # stuck grip, as a torque of torquescale/2 times the row forces in the peg's axes
        # (signs do not matter here). Whole force and torque bound the tangential and
        # torsional parts: only a grip near its limit needs the projections.
        sliding, spinning = self._mu * normal, self._mu_spin * normal
        torque_scale = self._torque_per_row_force
        bound = ((fx * fx + fy * fy + fz * fz) / (sliding * sliding)
                 + (rx * rx + ry * ry + rz * rz) * torque_scale * torque_scale
                 / (spinning * spinning))
        if bound <= 1.0:
            return False
        tool = self._tool_xmat.tolist()
        along_y = fx * tool[1] + fy * tool[4] + fz * tool[7]
        along_z = fx * tool[2] + fy * tool[5] + fz * tool[8]
        peg = self._peg_xmat.tolist()
        tx = peg[0] * rx + peg[1] * ry + peg[2] * rz
        ty = peg[3] * rx + peg[4] * ry + peg[5] * rz
        tz = peg[6] * rx + peg[7] * ry + peg[8] * rz
        about_normal = torque_scale * (tx * tool[0] + ty * tool[3] + tz * tool[6])
        return ((along_y * along_y + along_z * along_z) / (sliding * sliding)
                + about_normal * about_normal / (spinning * spinning)) > 1.0

    def _search_weld_row(self) -> int:
        """The weld's first constraint row in the last step, -1 if it was not active.

        MuJoCo lays out the active equality constraints first, in id order, so the row stays
        put while the weld is active (the cell's other equality is always on).
        """
        d = self._d
        rows = np.flatnonzero((d.efc_type[:d.nefc] == _EQUALITY)
                              & (d.efc_id[:d.nefc] == self._weld))
        return int(rows[0]) if rows.size == 6 else -1

    def _gripped_and_still(self) -> bool:
        d = self._d
        if d.time - self._slipped_at < _REGRIP_HOLD_OFF_S:
            return False
        if abs(self._opening_speed[self._tendon]) > _CLOSING_SPEED_MAX or d.ncon == 0:
            return False
        geoms = d.contact.geom
        peg = self._peg_geom
        touching = geoms[(geoms[:, 0] == peg) | (geoms[:, 1] == peg)].ravel()
        if not all(np.any(touching == pad) for pad in self._pads):
            return False
        tool_velocity, peg_velocity = np.empty(6), np.empty(6)
        body = mujoco.mjtObj.mjOBJ_BODY
        mujoco.mj_objectVelocity(self._m, d, body, self._tool, tool_velocity, 0)
        mujoco.mj_objectVelocity(self._m, d, body, self._peg_body, peg_velocity, 0)
        # Both are [angular, linear] in world axes, the linear part at each body's centre of
        # mass: carry the tool's over to the peg's centre.
        lever = d.xipos[self._peg_body] - d.xipos[self._tool]
        spin = tool_velocity[:3]
        tool_at_peg = tool_velocity[3:] + np.array([
            spin[1] * lever[2] - spin[2] * lever[1],
            spin[2] * lever[0] - spin[0] * lever[2],
            spin[0] * lever[1] - spin[1] * lever[0]])
        return (float(np.linalg.norm(peg_velocity[3:] - tool_at_peg)) < _STICK_SPEED_MAX
                and float(np.linalg.norm(peg_velocity[:3] - spin)) < _STICK_SPIN_MAX)
