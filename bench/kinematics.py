"""Per-call cost of kinematics and motion generation (and, for reference, a plant step).

Prints wall-clock p50/p99 (and mean CPU time) in microseconds for: a calibration pair (a numpy
add and a raw Pinocchio FK call, to read the rest against), Pinocchio FK of the TCP, FK + 6x6
Jacobian, one damped least-squares IK iteration, a warm-started IK solve (start 0.05 rad from
the answer), a Cartesian-delta target, a ruckig interpolator tick (target changing every 20 ms,
and every tick), braking to a hold, a joint move plan, and a MuJoCo plant step (arm alone and
the cell).

    .venv/bin/python bench/kinematics.py [--samples N]

A benchmark, not a test: it prints figures and asserts nothing. Hot-loop numbers; expect
several times more inside a busy control loop (bench/loop.py measures it).
"""

from __future__ import annotations

import argparse
import itertools
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from assurance import kinematics as kin_module
from assurance.cartesian import TRANSLATION_UNITS, CartesianMapper
from assurance.kinematics import IKConfig
from assurance.limits import JointLimits
from skills.interpolator import InterpolatorConfig, SetpointInterpolator
from skills.trajectory import MotionLimits, decelerate_to_hold, plan_joint_move
from stubs import robot_model as rm
from stubs.plant.mujoco_plant import MujocoPlant, MujocoPlantConfig
from stubs.robot_model.kinematics import arm_kinematics


def measure(label: str, call: Callable[[int], object], samples: int, warmup: int = 50,
            per: int = 1) -> None:
    """Time ``call(i)`` ``samples`` times; ``per`` divides each time (work items per call).

    Wall-clock p50/p99 per call, plus this thread's mean CPU time per call over the batch: on a
    shared 2-core VM the wall clock also counts time spent descheduled, the CPU time does not.
    (The CPU clock is read once per batch: a read costs ~1 us, too much to take per call.)
    """
    for i in range(warmup):
        call(i)
    wall = np.empty(samples)
    cpu_start = time.thread_time_ns()
    for i in range(samples):
        start = time.perf_counter_ns()
        call(i)
        wall[i] = time.perf_counter_ns() - start
    cpu_mean = (time.thread_time_ns() - cpu_start) / (1000.0 * per * samples)
    p50, p99 = np.percentile(wall / (1000.0 * per), [50, 99])
    print(f"{label:58s} p50 {p50:8.2f}  p99 {p99:8.2f}  cpu mean {cpu_mean:8.2f}  (us)")


def calibration(samples: int) -> None:
    """Machine speed right now: on a shared VM every figure below scales with these two."""
    a, b = np.ones(6), np.arange(6.0)
    measure("reference: numpy a + b on 6-vectors", lambda _i: a + b, samples)
    kin = arm_kinematics()
    q = np.array(rm.HOME_Q)

    def raw_fk(_i: int) -> None:
        pin.forwardKinematics(kin.model, kin._data, q)
        pin.updateFramePlacement(kin.model, kin._data, kin._frame)

    measure("reference: raw pin FK call (no wrapper)", raw_fk, samples)


def kinematics_benchmarks(samples: int) -> None:
    kin = arm_kinematics()
    rng = np.random.default_rng(7)
    goals = rng.uniform(kin.lower, kin.upper, size=(samples + 100, 6))
    starts = np.clip(goals + rng.normal(0.0, 0.05, goals.shape), kin.lower, kin.upper)
    targets = [kin.forward(q) for q in goals]
    measure("pinocchio FK (tcp pose)", lambda i: kin.forward(goals[i]), samples)
    measure("pinocchio FK + 6x6 Jacobian", lambda i: kin.forward_with_jacobian(goals[i]),
            samples)

    def one_iteration(i: int) -> None:  # the body of ArmKinematics.solve's loop, once
        pose, jac = kin._pose_and_jacobian(starts[i])
        error = kin_module._pose_error(targets[i], pose.translation, pose.rotation)
        position_sq, rotation_sq = float(error[:3] @ error[:3]), float(error[3:] @ error[3:])
        step = kin_module._dls_step(jac, error, 1e-6 + position_sq + rotation_sq, 0.5)
        (starts[i] + step).clip(kin.lower, kin.upper)

    measure("DLS IK iteration", one_iteration, samples)
    results = []
    measure("IK solve, warm start 0.05 rad away",
            lambda i: results.append(kin.solve(targets[i], starts[i])), samples)
    converged = [r for r in results if r.converged]
    print(f"{'':58s} converged {len(converged)}/{len(results)}, iterations "
          f"mean {np.mean([r.iterations for r in converged]):.1f} "
          f"max {max(r.iterations for r in converged)}")
    home = np.array(rm.HOME_Q)
    deltas = rng.normal(0.0, 0.01, size=(samples + 100, 3))
    measure("Cartesian delta (<= ~3 cm) -> joint target",
            lambda i: kin.cartesian_delta_target(home, deltas[i], config=IKConfig()), samples)
    limits = JointLimits(kin.lower, kin.upper, np.full(6, np.pi), np.full(6, 20.0))
    mapper = CartesianMapper(kin, limits, TRANSLATION_UNITS)
    ramps = [np.outer(np.arange(1, 21), rng.normal(0.0, 0.001, 3)) for _ in range(samples + 100)]
    measure("Cartesian chunk 20x3 (1 mm steps) -> joints, admission's mapping",
            lambda i: mapper.to_joints(ramps[i], home), max(samples // 10, 50))


def trajectory_benchmarks(samples: int) -> None:
    kin = arm_kinematics()
    limits = MotionLimits(kin.lower, kin.upper, np.full(6, np.pi), np.full(6, 8.0),
                          np.full(6, 80.0))
    home = np.array(rm.HOME_Q)
    for every, label in ((10, "interpolator tick, new target every 20 ms"),
                         (1, "interpolator tick, new target every tick")):
        interpolator = SetpointInterpolator(limits, home,
                                            InterpolatorConfig(control_period_ns=2_000_000))
        ticks = itertools.count()  # warm-up and measured calls share one clock

        def tick(_i: int, it: SetpointInterpolator = interpolator, e: int = every,
                 clock: itertools.count = ticks) -> None:
            k = next(clock)
            it.update(home + 0.05 * np.sin(0.1 * (k // e)), k * 2_000_000)

        measure(label, tick, samples)
    rng = np.random.default_rng(3)
    velocities = rng.uniform(-np.pi, np.pi, size=(samples + 100, 6))
    measure("decelerate_to_hold plan", lambda i: decelerate_to_hold(home, velocities[i], limits),
            samples)
    goals = np.clip(home + rng.normal(0.0, 0.5, size=(samples + 100, 6)), kin.lower, kin.upper)
    measure("plan_joint_move plan", lambda i: plan_joint_move(home, goals[i], limits), samples)


def plant_benchmarks(samples: int) -> None:
    home = np.array(rm.HOME_Q)
    for name, path in (("arm alone", rm.ARM_MODEL), ("cell, peg on table", rm.CELL_MODEL)):
        plant = MujocoPlant(MujocoPlantConfig(model_path=path))
        measure(f"plant step(1), {name}", lambda _i, p=plant: p.step(1), samples)
        measure(f"plant step(100), per step, {name}", lambda _i, p=plant: p.step(100),
                max(samples // 20, 20), warmup=5, per=100)
        measure(f"command_position+step(1)+state(), {name}",
                lambda _i, p=plant: (p.command_position(home), p.step(1), p.state()), samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    args = parser.parse_args()
    print("== calibration ==")
    calibration(args.samples)
    print("== kinematics (Pinocchio) ==")
    kinematics_benchmarks(args.samples)
    print("== trajectories (ruckig) ==")
    trajectory_benchmarks(args.samples)
    print("== plant (MuJoCo, 2 ms step) ==")
    plant_benchmarks(args.samples)


if __name__ == "__main__":
    main()
