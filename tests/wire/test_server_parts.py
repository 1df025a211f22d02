"""The reference server's parts: the scripted policy, the latency model, faults, the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from peer.envelope import ReplacementPolicy
from stubs.policy_server import FaultConfig, InsertionPolicy, LatencyModel
from stubs.policy_server.__main__ import parse_args
from stubs.policy_server.faults import FaultPlan

GOAL = np.array([0.5, -0.2, 0.0])


def test_policy_moves_toward_the_goal_at_bounded_speed() -> None:
    policy = InsertionPolicy(goal=GOAL, max_speed=0.5, noise_std=0.0, horizon=60,
                             action_dt_s=0.02)
    q = np.zeros(3)
    actions = policy.actions(q, lead_s=0.01, rng=np.random.default_rng(0))
    assert actions.shape == (60, 3)
    steps = np.abs(np.diff(np.vstack([q, actions]), axis=0))
    assert steps[0].max() <= 0.5 * 0.01 + 1e-12  # the lead before the first action
    assert steps[1:].max() <= 0.5 * 0.02 + 1e-12
    np.testing.assert_allclose(actions[-1], GOAL)  # reached, and held there
    assert np.all(np.abs(actions - q) <= np.abs(GOAL - q) + 1e-12)  # never overshoots


def test_policy_noise_is_seeded() -> None:
    policy = InsertionPolicy(goal=GOAL, max_speed=0.5, noise_std=1e-3, horizon=5,
                             action_dt_s=0.02)
    first = policy.actions(np.zeros(3), 0.0, np.random.default_rng(7))
    again = policy.actions(np.zeros(3), 0.0, np.random.default_rng(7))
    np.testing.assert_array_equal(first, again)
    with pytest.raises(ValueError, match="joints"):
        policy.actions(np.zeros(4), 0.0, np.random.default_rng(7))


def test_latency_model_has_the_configured_median_and_p95() -> None:
    model, rng = LatencyModel(median_ms=5.0, p95_ms=12.0), np.random.default_rng(1)
    samples = np.array([model.sample_s(rng) for _ in range(20_000)]) * 1e3
    assert np.median(samples) == pytest.approx(5.0, rel=0.05)
    assert np.percentile(samples, 95) == pytest.approx(12.0, rel=0.05)
    assert LatencyModel(0.0, 0.0).sample_s(rng) == 0.0
    with pytest.raises(ValueError):
        LatencyModel(5.0, 1.0)


def test_fault_fractions_follow_a_fixed_pattern() -> None:
    plan = FaultPlan(FaultConfig(drop=0.5, duplicate=1 / 3, spike=1.0, spike_ms=40.0))
    chunks = [plan.next_chunk() for _ in range(6)]
    assert [c.drop for c in chunks] == [False, True] * 3
    assert [c.duplicate for c in chunks] == [False, False, True] * 2
    assert all(c.spike_s == pytest.approx(0.04) for c in chunks)
    with pytest.raises(ValueError, match="fraction"):
        FaultConfig(drop=1.5)


def test_command_line() -> None:
    config = parse_args([
        "--port", "0", "--goal", "0.1,0.2,0.3,0.4,0.5,0.6", "--protocol", "1,1",
        "--clock-offset-ms", "2.5", "--replacement-policy", "blend",
        "--fault", "drop=0.25", "--fault", "checkpoint=other", "--fault", "close_after=3",
    ])
    assert config.goal == (0.1, 0.2, 0.3, 0.4, 0.5, 0.6) and config.protocol == (1, 1)
    assert config.clock_offset_ns == 2_500_000
    assert config.replacement_policy is ReplacementPolicy.BLEND
    assert config.faults == FaultConfig(drop=0.25, checkpoint="other", close_after=3)
    with pytest.raises(SystemExit):
        parse_args(["--fault", "explode=1"])
