"""The plausibility rule (assurance/plausibility.py) and what the core does with its verdict.

The rule is judged by motions generated here from the limits alone: any motion a joint can
make inside its velocity and acceleration limits, sampled with jittered stamps and noisy
readings, is plausible; a reading offset that no such motion explains is implausible for as
long as it lasts. In the core, an implausible sample is STATE_IMPLAUSIBLE and never a hold
target: the hold stays where the arm was last plausibly measured.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from assurance.fallback import Mode
from assurance.limits import JointLimits
from assurance.plausibility import Bounds, Breach, Tolerances, judge
from kernel.core.effects import Setpoint
from kernel.core.events import StateEvent, TickEvent
from kernel.core.runtime import Core
from tests.core.test_motion import config

MS = 1_000_000
DOF = 6
V, A = 3.14, 20.0
LIMITS = JointLimits.uniform(DOF, 6.28, V, A)
TOL = Tolerances()


def bounds(period_ms: float = 2.0) -> Bounds:
    return Bounds.of(LIMITS, int(period_ms * MS), TOL)


def motion(accelerations: list[list[float]], period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities of a motion whose acceleration, piecewise constant per
    period, stays inside A and whose speed is clipped (braked) inside V."""
    q, qd = np.zeros(DOF), np.zeros(DOF)
    qs, qds = [q.copy()], [qd.copy()]
    for acc in accelerations:
        a = np.clip(np.array(acc), -A, A)
        new_qd = np.clip(qd + a * period_s, -V, V)
        q = q + 0.5 * (qd + new_qd) * period_s  # exact for a constant acceleration
        qd = new_qd
        qs.append(q.copy())
        qds.append(qd.copy())
    return np.array(qs), np.array(qds)


def feed(samples: list[tuple[int, np.ndarray, np.ndarray | None]], b: Bounds) -> list[bool]:
    track, verdicts = None, []
    for t, q, qd in samples:
        verdict = judge(track, t, q, qd, b)
        track = verdict.track
        verdicts.append(verdict.plausible)
    return verdicts


accelerations = st.lists(
    st.lists(st.floats(-A, A), min_size=DOF, max_size=DOF), min_size=2, max_size=150)


@settings(max_examples=200, deadline=None)
@given(accelerations, st.sampled_from([2.0, 4.0, 8.0]), st.integers(0, 2**32 - 1),
       st.booleans())
def test_every_motion_inside_the_limits_is_plausible(
    acc: list[list[float]], period_ms: float, seed: int, report_velocity: bool
) -> None:
    """With readings noisy by less than the tolerances and each stamp up to a period late
    (a sample read late, or repeated while the device had none newer)."""
    rng = np.random.default_rng(seed)
    period_s = period_ms * 1e-3
    qs, qds = motion(acc, period_s)
    samples = []
    for k, (q, qd) in enumerate(zip(qs, qds, strict=True)):
        late = rng.uniform(0.0, period_ms * MS)
        noisy_q = q + rng.uniform(-0.4, 0.4, DOF) * TOL.position_rad
        noisy_qd = qd + rng.uniform(-0.9, 0.9, DOF) * TOL.velocity_rad_s
        samples.append((int(k * period_ms * MS + late), noisy_q,
                        noisy_qd if report_velocity else None))
    assert all(feed(samples, bounds(period_ms)))


@settings(max_examples=100, deadline=None)
@given(accelerations, st.integers(0, DOF - 1), st.floats(0.2, 2.0), st.booleans(),
       st.integers(1, 100), st.integers(0, 40))
def test_a_reading_offset_is_implausible_while_it_lasts(
    acc: list[list[float]], joint: int, offset: float, negative: bool, samples_off: int,
    start: int,
) -> None:
    """2 ms samples with reported velocities; a glitch of 0.2 rad or more on one joint for
    up to 200 ms: every glitched sample is implausible, and the first one after it is
    plausible again."""
    period_s = 2e-3
    qs, qds = motion(acc + [[0.0] * DOF] * (start + samples_off + 2), period_s)
    glitched = range(start + 1, start + 1 + samples_off)
    samples = []
    for k, (q, qd) in enumerate(zip(qs, qds, strict=True)):
        reading = q.copy()
        if k in glitched:
            reading[joint] += -offset if negative else offset
        samples.append((k * 2 * MS, reading, qd))
    verdicts = feed(samples, bounds())
    assert not any(verdicts[k] for k in glitched)
    assert all(verdicts[:glitched.start]) and verdicts[glitched.stop]


def test_the_issue_glitch_is_implausible_for_its_whole_200_ms() -> None:
    """Joint 0 turning at 0.2 rad/s reads 0.5 rad off for 200 ms: the velocity limit alone
    would accept it after 0.5 rad / (2 × 3.14 rad/s) ≈ 80 ms; its reported velocity does
    not explain it at any point."""
    b = bounds()
    qd = np.array([0.2, 0, 0, 0, 0, 0])
    samples = []
    for k in range(200):
        q = qd * k * 2e-3
        if 10 <= k < 110:
            q = q + np.array([0.5, 0, 0, 0, 0, 0])
        samples.append((k * 2 * MS, q, qd))
    verdicts = feed(samples, b)
    assert verdicts[:10] == [True] * 10
    assert not any(verdicts[10:110])
    assert all(verdicts[110:])


def test_without_reported_velocities_only_the_velocity_limit_judges() -> None:
    b = bounds()
    q0 = np.zeros(DOF)
    track = judge(None, 0, q0, None, b).track
    near = q0 + 0.02  # 0.02 rad in 2 ms: 10 rad/s > 2 × 3.14, but inside the stamp jitter
    far = q0 + np.array([0.1, 0, 0, 0, 0, 0])
    assert judge(track, 2 * MS, near, None, b).plausible
    verdict = judge(track, 2 * MS, far, None, b)
    assert verdict.finding is not None and verdict.finding.breach is Breach.STEP
    assert verdict.finding.joint == 0


def test_a_velocity_past_its_limit_is_implausible_and_the_first_sample_anchors_nothing() -> None:
    b = bounds()
    fast = np.array([0, 0, 0, 7.0, 0, 0])  # 7 rad/s > 2 × 3.14 + 0.05
    verdict = judge(None, 0, np.zeros(DOF), fast, b)
    assert verdict.finding is not None and verdict.finding.breach is Breach.VELOCITY
    assert verdict.finding.joint == 3 and verdict.track is None
    assert judge(None, 0, np.zeros(DOF), np.full(DOF, np.nan), b).finding is not None


def test_a_velocity_glitch_does_not_carry_the_path_away() -> None:
    """After a velocity reading past its limit the integral restarts at the next plausible
    sample, so the true readings after it are plausible again."""
    b = bounds()
    zero = np.zeros(DOF)
    spike = np.array([50.0, 0, 0, 0, 0, 0])
    verdicts = feed([(0, zero, zero), (2 * MS, zero, spike), (4 * MS, zero, zero),
                     (6 * MS, zero, zero)], b)
    assert verdicts == [True, False, True, True]


def test_the_core_holds_where_the_arm_was_last_plausibly_measured() -> None:
    """The issue's case in the core: a hold that starts on a glitched sample holds at the
    last plausible one, and the glitch never becomes the measured state."""
    core = Core(config(executor=None))
    period = core.config.control_period_ns
    home = np.array(core.config.initial_q)
    t = 0
    for _ in range(5):
        core.step(StateEvent(t=t, q=tuple(home), qd=(0.0,) * DOF))
        core.step(TickEvent(t=t))
        t += period
    glitched = home + np.array([0.5, 0, 0, 0, 0, 0])
    holds = []
    for _ in range(100):  # 200 ms of glitched readings
        step = core.step(StateEvent(t=t, q=tuple(glitched), qd=(0.0,) * DOF))
        holds.append(core.step(TickEvent(t=t)).motion)
        t += period
    transitions = [line for line in step.lines if getattr(line, "trigger", None)]
    assert core.status().mode is Mode.SAFE_HOLD
    assert core.status().cause == "STATE_IMPLAUSIBLE"
    assert transitions == []  # one transition, at the first glitched sample only
    assert np.allclose(core.inspect_state().measured_q, home)
    assert all(isinstance(m, Setpoint) and np.allclose(m.q, home) for m in holds)


def test_a_repeated_reading_keeps_its_verdict_and_its_time() -> None:
    """A driver that reads faster than the device sends repeats a frame; at 2 rad/s the
    repeats, stamped later, would look 40 mm... rad behind the path. A repeated glitch stays
    implausible."""
    b = bounds()
    qd = np.array([2.0, 0, 0, 0, 0, 0])
    q0 = np.zeros(DOF)
    stale = [(k * 2 * MS, q0, qd) for k in range(10)]  # one frame, read ten times in 20 ms
    fresh = (20 * MS, qd * 0.02, qd)
    assert all(feed([*stale, fresh], b))
    glitched = q0 + np.array([0.5, 0, 0, 0, 0, 0])
    assert feed([(0, q0, qd), (2 * MS, glitched, qd), (4 * MS, glitched, qd)], b) == [
        True, False, False]


def test_an_arm_at_rest_is_measured_afresh_by_every_identical_reading() -> None:
    """At rest every reading is the same, and each is a measurement: a glitch after a long
    rest is judged against the last one, not against the first (the velocity limit alone
    would allow 0.5 rad after 106 ms)."""
    b = bounds(8.0)
    zero, q0 = np.zeros(DOF), np.zeros(DOF)
    rest = [(k * 8 * MS, q0, zero) for k in range(100)]
    glitched = q0 + np.array([0.5, 0, 0, 0, 0, 0])
    assert feed([*rest, (800 * MS, glitched, zero)], b)[-1] is False
