"""Long admission work, as jobs the shell runs where they cannot delay a control tick.

Two steps of admission can take a millisecond or more in Python: mapping a Cartesian chunk to
joint targets (an IK solve per action) and the exact, sequential feasibility projection of a
proposal that fails the fast check. The core does not run them inline on a live run: it parks
the chunk and emits a :class:`~kernel.core.effects.Compute` effect with a job; the shell runs
the job (in a worker process) and feeds the result back as a
:class:`~kernel.core.events.ComputedEvent`, which the journal records. The core then finishes
the admission at that instant, with every time gate evaluated again. A replay feeds the
recorded result, so the decisions are the run's bit for bit; a scenario replay runs each job
at once, at the instant it was asked for.

Jobs and results are frozen msgspec Structs of plain floats, so they cross a process boundary
and a journal exactly. :func:`run_job` is the one implementation both sides call.
"""

from __future__ import annotations

import msgspec
import numpy as np

from assurance.cartesian import CartesianMapper
from assurance.collision import CellCollision
from assurance.limits import JointLimits
from assurance.projection import Reference, project

Rows = tuple[tuple[float, ...], ...]


class MapJob(msgspec.Struct, frozen=True, kw_only=True, tag_field="job", tag="map"):
    """Map a Cartesian chunk's actions to joint targets, from the joint state ``anchor``."""

    job_id: int
    actions: Rows
    anchor: tuple[float, ...]


class ProjectJob(msgspec.Struct, frozen=True, kw_only=True, tag_field="job", tag="project"):
    """Project ``rows`` into the limits exactly, following the reference setpoint."""

    job_id: int
    rows: Rows
    ref_q: tuple[float, ...]
    ref_step: tuple[float, ...]
    dt_ns: int


class ClearanceJob(msgspec.Struct, frozen=True, kw_only=True, tag_field="job",
                   tag="clearance"):
    """Check the clearance of the arm at every row of ``rows`` (arm joints) and of the motion
    into it from the one before (the first: from ``start``), in ``phase``, with the part
    held or not (:mod:`assurance.collision`)."""

    job_id: int
    rows: Rows
    start: tuple[float, ...]
    phase: str
    held: bool


Job = MapJob | ProjectJob | ClearanceJob


class MapResult(msgspec.Struct, frozen=True, kw_only=True, tag_field="job", tag="map"):
    job_id: int
    joints: Rows | None
    """Joint targets for every action, or None when the chunk cannot be mapped (``detail``)."""
    detail: str = ""


class ProjectResult(msgspec.Struct, frozen=True, kw_only=True, tag_field="job", tag="project"):
    job_id: int
    actions: Rows
    distances: tuple[float, ...]
    recoverable: bool
    max_distance: float


class ClearanceResult(msgspec.Struct, frozen=True, kw_only=True, tag_field="job",
                      tag="clearance"):
    """``clear``, or the first action whose motion breaks a pair's clearance (m)."""

    job_id: int
    clear: bool
    action: int = 0
    pair: tuple[str, str] = ("", "")
    distance: float = 0.0
    bound: float = 0.0
    needed: float = 0.0


class JobFailed(msgspec.Struct, frozen=True, kw_only=True, tag_field="job", tag="failed"):
    """The job could not be run (the worker died, or refused its input): the chunk it was
    for is refused, never admitted without its check."""

    job_id: int
    detail: str


JobResult = MapResult | ProjectResult | ClearanceResult | JobFailed


def rows_of(array: np.ndarray) -> Rows:
    return tuple(tuple(row) for row in array.tolist())


def array_of(rows: Rows, width: int) -> np.ndarray:
    array = np.array(rows, dtype=float).reshape(len(rows), width)
    array.setflags(write=False)
    return array


def run_job(job: Job, limits: JointLimits, mapper: CartesianMapper | None,
            collision: CellCollision | None = None) -> JobResult:
    """The job's result: pure, deterministic for the same job, limits and model."""
    if isinstance(job, MapJob):
        return _map(job, mapper)
    if isinstance(job, ClearanceJob):
        return _clearance(job, collision)
    return _project(job, limits)


def _clearance(job: ClearanceJob, collision: CellCollision | None) -> JobResult:
    if collision is None:
        return JobFailed(job_id=job.job_id, detail="no [geometry] for this core")
    found = collision.check(np.array(job.start), array_of(job.rows, collision.dof), job.phase,
                            job.held)
    if found is None:
        return ClearanceResult(job_id=job.job_id, clear=True)
    return ClearanceResult(job_id=job.job_id, clear=False, action=found.action,
                           pair=found.pair, distance=found.distance, bound=found.bound,
                           needed=found.needed)


def _map(job: MapJob, mapper: CartesianMapper | None) -> JobResult:
    if mapper is None:
        return JobFailed(job_id=job.job_id, detail="no Cartesian mapper for this session")
    width = len(job.actions[0]) if job.actions else 0
    mapped = mapper.to_joints(array_of(job.actions, width), np.array(job.anchor))
    joints = None if mapped.joints is None else rows_of(mapped.joints)
    return MapResult(job_id=job.job_id, joints=joints, detail=mapped.detail)


def _project(job: ProjectJob, limits: JointLimits) -> JobResult:
    rows = array_of(job.rows, limits.dim)
    reference = Reference(np.array(job.ref_q), np.array(job.ref_step))
    projection = project(rows, reference, job.dt_ns * 1e-9, limits)
    return ProjectResult(
        job_id=job.job_id, actions=rows_of(projection.actions),
        distances=tuple(projection.distances.tolist()), recoverable=projection.recoverable,
        max_distance=projection.max_distance,
    )
