"""Cameras the policy sees through: what the core does when one is lost or freezes.

The shell watches each camera (kernel/shell/cameras.py) and reports a change as a
:class:`~kernel.core.events.CameraEvent`. While any camera is down, no observation is
requested: the policy would see the cell without it, and the handshake promised it. What else
happens is the manifest's choice per camera (``on_loss``): ``stop`` holds the arm at once
(SAFE_HOLD, ``CAMERA_LOST``); ``continue`` lets the arm finish the actions admitted while the
camera still saw, for at most its ``grace``, then holds the same way. A camera that comes back
lets observations go out again; a hold it caused is left only by the operator, as every hold is.
"""

from __future__ import annotations

from assurance.clock import ns_to_ms
from assurance.reasons import ReasonCode as R
from kernel.core.config import CameraLoss, LossAction
from kernel.core.events import CameraEvent, CameraStatus
from kernel.core.lines import CameraLine
from kernel.core.state import CoreState


def on_camera(state: CoreState, event: CameraEvent) -> None:
    loss = _loss(state, event.camera)
    if loss is None:
        state.emit(CameraLine(t=state.t_ms, camera=event.camera, status=event.status,
                              on_loss="none", detail="not a camera of this configuration"))
        return
    if event.status is CameraStatus.BACK:
        if state.cameras_down.pop(loss.name, None) is None:
            return  # it was never down: nothing changed
    elif loss.name in state.cameras_down:
        return  # already down (lost, then frozen): the first report counts
    else:
        state.cameras_down[loss.name] = state.t
    grace = ns_to_ms(loss.grace_ns) if loss.on_loss is LossAction.CONTINUE else None
    state.emit(CameraLine(t=state.t_ms, camera=loss.name, status=event.status,
                          on_loss=loss.on_loss, grace_ms=grace, detail=event.detail or None))
    check_cameras(state)


def check_cameras(state: CoreState) -> None:
    """Each tick (and at each report): a camera down past what the manifest allows holds the
    arm. Once held, the transition does not apply again until the operator recovers."""
    for name, since in state.cameras_down.items():
        loss = _loss(state, name)
        if loss is None:
            continue
        if loss.on_loss is LossAction.STOP or state.t - since >= loss.grace_ns:
            state.fire(R.CAMERA_LOST, detail=f"camera {name} down since "
                                              f"{ns_to_ms(since)} ms")
            return


def cameras_seeing(state: CoreState) -> bool:
    """Whether an observation may go out: every camera it must carry is up."""
    return not state.cameras_down


def _loss(state: CoreState, name: str) -> CameraLoss | None:
    return next((c for c in state.config.cameras if c.name == name), None)
