"""A chunk's decision: one line, one typed record for the shell, and what it implies.

Admission (:mod:`kernel.core.admit`) decides; this module writes the decision down and carries
out what follows from it: an admitted chunk commits its merge plan to the queue and answers its
observation and the request in flight; a refusal raises the fallback trigger it implies, and a
refused answer to the request in flight answers that request too.
"""

from __future__ import annotations

from assurance.envelope import Chunk, ReplacementPolicy
from assurance.fallback import IRRELEVANT, refusal_trigger
from assurance.merge import MergePlan
from assurance.reasons import ReasonCode as R
from kernel.core.effects import ChunkDecision
from kernel.core.lines import ChunkLine, Decision
from kernel.core.state import CoreState


def commit(
    state: CoreState, chunk: Chunk, plan: MergePlan | None, t_obs: int | None,
    extras: dict[str, object],
) -> None:
    """Admit: the plan goes into the queue in one step, the chunk answers its observation and
    the request in flight, and the timing refusals' count starts again."""
    if plan is None or t_obs is None:  # unreachable: every gate passed, so a plan exists
        refuse(state, chunk.chunk_id, (R.MALFORMED,), detail="no merge plan")
        return
    plan.commit(state.queue)
    state.queue_version += 1
    state.observations.answer(chunk.observation_id)
    state.last_sequence = chunk.sequence
    state.fallback.clear_debounce()
    if state.watermarks is not None:
        state.watermarks.answered()
        state.watermarks.record_round_trip(state.t - t_obs)
    decision = _decision_name(plan)
    log_decision(state, ChunkLine(
        t=state.t_ms, chunk_id=chunk.chunk_id, decision=decision, reasons=(),
        queue_epoch=state.epoch, queue_depth=state.queue.pending_rows(state.t),
        trimmed=plan.trimmed or None,
        merge=plan.merge, displaced=plan.displaced or None, **extras,
    ))


def _decision_name(plan: MergePlan) -> Decision:
    if plan.trimmed:
        return Decision.TRIMMED
    if plan.blended:
        return Decision.BLENDED
    if plan.displaced and plan.merge is not ReplacementPolicy.APPEND:
        return Decision.REPLACED
    return Decision.ACCEPTED


def refuse(
    state: CoreState, chunk_id: str | None, reasons: tuple[R, ...], **extras: object
) -> None:
    """Log a refusal and raise the fallback trigger it implies, if any."""
    log_decision(state, ChunkLine(
        t=state.t_ms, chunk_id=chunk_id, decision=Decision.REJECTED, reasons=reasons,
        queue_epoch=state.epoch, queue_depth=state.queue.pending_rows(state.t), **extras,
    ))
    trigger = refusal_trigger(reasons)
    if trigger is not None:
        state.fire(trigger)


def log_decision(state: CoreState, line: ChunkLine) -> None:
    """Log a chunk's decision, and report it to the shell as a typed record."""
    state.emit(line)
    state.decided(ChunkDecision(chunk_id=line.chunk_id, decision=line.decision,
                                reasons=line.reasons))


def answered_unusably(state: CoreState, chunk: Chunk, reasons: list[R]) -> None:
    """A refused answer to the request in flight (it cites the newest observation, and was
    made for this context) answers that request: the next one may go out at once instead of
    after ``request_retry_ms``, which a queue ran dry waiting out (an answer later than the
    delay it was conditioned on, once in twenty, in the simulated cell)."""
    if state.watermarks is None or chunk.observation_id != state.observations.latest:
        return
    if not IRRELEVANT.intersection(reasons):
        state.watermarks.answered()
