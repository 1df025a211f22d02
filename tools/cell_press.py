"""Policies that press into the cell, run through a simulated cell, judged by MuJoCo.

Each press is the reference policy server (``python -m stubs.policy_server``, the arguments
``warden run`` gives it for the cell, ``stubs/cell/reference.py``) with another ``--goal``: a
smooth joint-space approach, inside every joint, velocity and acceleration limit, from wherever
the pre-contact phase starts (the staging pose above the fixture) towards

- ``table``: a tool-down pose whose TCP is 2 cm below the table top, 15 cm from the fixture;
- ``fixture``: the held peg's bottom 2 cm into the fixture's top, over the wall beside the hole;
- ``elbow``: the upper arm pointing down into the table while the tool turns up (the TCP is
  0.16 m above the table where the upper arm first comes within 5 mm of it);
- ``wrist``: the elbow folded until the wrist and the tool lie in the upper arm (the tool's
  fingers first come within 3 cm of the upper arm, the table never within 5 cm but for the
  shoulder's fixed 3 cm).

The elbow and the wrist presses move at 0.7 rad/s (the reference server's 0.3 would not reach
a goal 2-3.4 rad away before the approach's 8 s timeout; faster chunks are refused by the
projection gate), with the pre-contact divergence and projection gates scaled to that pace
(:func:`pressing_manifest`).

warden runs the cell with ``[policy] launch = false`` against that server, one cycle.
:func:`judge` reads the run's journal: every joint setpoint warden commanded, put through
MuJoCo's forward kinematics and collision distances of the cell's own scene (the arm model,
the table and the fixture's walls of ``stubs/robot_model/cell.xml``, the held peg as a box at
the TCP), never warden's Pinocchio or coal code. ``python tools/cell_press.py [PRESS]
[--manifest sim-ur5e.toml]`` runs one press and prints the judgement (the figures the issue's
note asks for, measurable on any version of warden).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MANIFESTS = ROOT / "manifests"
HOST = "127.0.0.1"
TABLE_TOP_Z = 0.0
PEG_CENTRE_BELOW_TCP, PEG_HALF = 0.0175, (0.01, 0.01, 0.03)
PEG_BOTTOM_BELOW_TCP = PEG_CENTRE_BELOW_TCP + PEG_HALF[2]
FIXED_BODIES = frozenset({"base", "shoulder_link"})
"""Bodies whose distance to the table no joint changes (the shoulder only turns about the
base's vertical axis, its lowest point 3 cm above the table)."""
UPPER = frozenset({"shoulder_link", "upper_arm_link"})
WRIST = frozenset({"wrist_2_link", "wrist_3_link", "gripper", "finger_left", "finger_right"})
"""Non-adjacent to the upper arm and the shoulder: a wrist folded into them is a collision."""


@dataclass(frozen=True, slots=True)
class Press:
    name: str
    goal: Callable[[object, np.ndarray], np.ndarray]
    """(the cell's context, the pre-contact staging configuration) → the policy's goal."""
    max_speed: float | None = None
    """rad/s, the policy's speed if not the reference server's (0.3)."""


def _tool_down(position: tuple[float, float, float]) -> Callable[[object, np.ndarray],
                                                                 np.ndarray]:
    def goal(context, staging: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
        from stubs.cell.reference import policy_goal

        return np.asarray(context.planner.solve(policy_goal(context), np.array(position)))
    return goal


def _joints(lift: float, elbow: float, wrist_1: float) -> Callable[[object, np.ndarray],
                                                                   np.ndarray]:
    def goal(context, staging: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
        return np.array([staging[0], lift, elbow, wrist_1, staging[4], staging[5]])
    return goal


PRESSES: dict[str, Press] = {press.name: press for press in (
    Press("table", _tool_down((-0.40, -0.15, TABLE_TOP_Z - 0.02))),
    Press("fixture", _tool_down((-0.53, -0.15, 0.03 - 0.02 + PEG_BOTTOM_BELOW_TCP))),
    Press("elbow", _joints(0.5, -0.7, -3.0), max_speed=0.7),
    Press("wrist", _joints(-1.9, 2.9, 1.5), max_speed=0.7),
)}


def press_goal(press: Press, manifest_path: Path) -> np.ndarray:
    """The goal of ``press`` for the cell of ``manifest_path``, solved on its arm model."""
    from kernel.app.compose import cell_context
    from kernel.manifest import load_manifest

    context = cell_context(load_manifest(manifest_path))
    layout = context.layout
    staging = context.planner.solve(layout.home_q, layout.staging_tcp)
    return press.goal(context, np.asarray(staging))


REFERENCE_SPEED = 0.3
"""rad/s: the reference server's pace, the one the cells' pre-contact gates are set for."""
PACED_GATES = ("max_divergence", "max_projection")
"""The pre-contact gates that measure how far the arm moved while a chunk was on its way."""


def pressing_manifest(base: Path, port: int, directory: Path,
                      max_speed: float | None = None,
                      cycle_timeout_s: float | None = None) -> Path:
    """``base`` for one cycle against a policy server on ``port``, with its own operator
    socket (the default one may be another warden's).

    A press faster than the reference server's pace gets the pre-contact divergence and
    projection gates scaled by its speed over that pace: what those gates measure is the
    arm's motion during a chunk's round trip, so at 0.7 rad/s the cell's own 0.03 rad would
    refuse every chunk more than 43 ms late (a loaded test machine), and the press would
    never reach what it presses on. Nothing else of the cell changes: not a limit, not the
    geometry, not a clearance."""
    text = base.read_text()
    changes = [(r"(?m)^launch = true( *)#", r"launch = false\1#"),
               (r"(?m)^port = 0( *)#", rf"port = {port}\1#"),
               (r"(?m)^cycles = \d+", "cycles = 1")]
    for pattern, new in changes:
        text, count = re.subn(pattern, new, text, count=1)
        if count != 1:
            raise ValueError(f"{base}: no line matches {pattern!r}")
    if max_speed is not None and max_speed > REFERENCE_SPEED:
        text = _paced(text, base, max_speed / REFERENCE_SPEED)
    if cycle_timeout_s is not None:
        text, count = re.subn(r"(?m)^cycle_timeout_s = [0-9.]+",
                              f"cycle_timeout_s = {cycle_timeout_s}", text, count=1)
        if count != 1:
            raise ValueError(f"{base}: no cycle_timeout_s line")
    path = directory / f"pressing-{base.name}"
    path.write_text(text + f'\n[operator]\nsocket = "{directory / "operator.sock"}"\n')
    return path


def _paced(text: str, base: Path, factor: float) -> str:
    for gate in PACED_GATES:
        pattern = rf"(\[phases\.PRE_CONTACT\][^\[]*?^{gate} = )([0-9.]+)"
        text, count = re.subn(pattern, lambda m: f"{m[1]}{float(m[2]) * factor:.4f}", text,
                              count=1, flags=re.MULTILINE | re.DOTALL)
        if count != 1:
            raise ValueError(f"{base}: no {gate} in [phases.PRE_CONTACT]")
    return text


@contextmanager
def serving(manifest_path: Path, goal: np.ndarray, max_speed: float | None = None,
            ) -> Iterator[int]:
    """The reference policy server ``warden run`` would start for the cell, heading for
    ``goal``; yields its port."""
    from kernel.manifest import load_manifest
    from stubs.cell.reference import server_args
    from stubs.process import EmulatorProcess

    args = server_args(load_manifest(manifest_path), goal, HOST, 0)
    if max_speed is not None:
        args[args.index("--max-speed") + 1] = str(max_speed)
    process = EmulatorProcess("stubs.policy_server", *args).start()
    try:
        yield int(process.info["port"])
    finally:
        process.stop()


def run_press(press: Press, manifest_name: str, directory: Path,
              cycle_timeout_s: float | None = None) -> Path:
    """Run ``press`` through the cell of ``manifest_name`` (its cycle ended after
    ``cycle_timeout_s`` when given); the run's journal directory."""
    base = MANIFESTS / manifest_name
    goal = press_goal(press, base)
    with serving(base, goal, press.max_speed) as port:
        manifest = pressing_manifest(base, port, directory, press.max_speed, cycle_timeout_s)
        journals = directory / "runs"
        subprocess.run([sys.executable, "-m", "kernel.cli", "run", str(manifest),
                        "--journal-dir", str(journals)], cwd=ROOT, check=False,
                       stdout=subprocess.DEVNULL, stderr=(directory / "warden.log").open("w"))
    (run,) = [p for p in journals.iterdir() if p.is_dir()]
    return run


# -- the judge -------------------------------------------------------------------------------

class Scene:
    """The cell as MuJoCo sees it: the arm, the table, the fixture's walls, a held peg."""

    def __init__(self) -> None:
        from stubs import robot_model as rm

        spec = mujoco.MjSpec.from_string(rm.CELL_MODEL.read_text(encoding="utf-8"),
                                         {rm.CELL_ARM_INCLUDE: rm.ARM_MODEL.read_bytes()})
        spec.delete(spec.body(rm.PEG_BODY))  # the free peg on the table: the held one below
        tcp = spec.site(rm.TCP_SITE)
        spec.body(rm.TOOL_BODY).add_geom(
            name="held_peg", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(PEG_HALF),
            pos=[tcp.pos[0], tcp.pos[1], tcp.pos[2] + PEG_CENTRE_BELOW_TCP])
        for equality in list(spec.equalities):
            spec.delete(equality)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.table = m.geom("table_top").id
        self.walls = [m.geom(name).id for name in rm.FIXTURE_WALL_GEOMS]
        self.peg = m.geom("held_peg").id
        body = {g: m.body(m.geom_bodyid[g]).name for g in range(m.ngeom)}
        moving = [g for g in range(m.ngeom) if m.body_weldid[m.geom_bodyid[g]] != 0]
        self.arm = [g for g in moving if g != self.peg and body[g] not in FIXED_BODIES]
        self.upper = [g for g in moving if body[g] in UPPER]
        self.wrist = [g for g in moving if body[g] in WRIST]
        self.arm_joints = [m.joint(name).qposadr[0] for name in rm.ARM_JOINT_NAMES]
        self.tcp = m.site(rm.TCP_SITE).id

    def measure(self, q: list[float]) -> dict[str, float]:
        """Distances (m, negative: into) of the configuration ``q``: the arm and the peg to
        the table and to the fixture, the wrist to the upper arm; the TCP's and the peg's
        bottom's height."""
        m, d = self.model, self.data
        d.qpos[self.arm_joints] = q
        mujoco.mj_kinematics(m, d)
        far = 1.0
        rotation = d.site_xmat[self.tcp].reshape(3, 3)
        bottom = d.site_xpos[self.tcp] + rotation[:, 2] * PEG_BOTTOM_BELOW_TCP
        return {
            "tcp_z": float(d.site_xpos[self.tcp][2]),
            "peg_bottom_z": float(bottom[2]),
            "arm_table": min(mujoco.mj_geomDistance(m, d, g, self.table, far, None)
                             for g in self.arm),
            "peg_table": mujoco.mj_geomDistance(m, d, self.peg, self.table, far, None),
            "peg_fixture": min(mujoco.mj_geomDistance(m, d, self.peg, w, far, None)
                               for w in self.walls),
            "arm_fixture": min(mujoco.mj_geomDistance(m, d, g, w, far, None)
                               for g in self.arm for w in self.walls),
            "wrist_upper": min(mujoco.mj_geomDistance(m, d, a, b, far, None)
                               for a in self.wrist for b in self.upper),
        }


@dataclass(frozen=True, slots=True)
class Judgement:
    setpoints: int
    """Commanded joint setpoints while the policy drove (PRE_CONTACT)."""
    lowest: dict[str, float]
    """Each measure's smallest value over those setpoints."""
    below_peg_touch: int
    """Setpoints whose peg bottom is below the table top."""
    refusals: dict[str, int]
    """Chunk refusals by reason code."""
    collision_details: list[str]


def _phases(decisions: list[dict]) -> list[tuple[float, str]]:
    return [(line["t"], line["phase"]) for line in decisions if line["kind"] == "tick"]


def judge(run: Path, scene: Scene | None = None) -> Judgement:
    """The run's commanded setpoints while the policy drove, through MuJoCo."""
    scene = scene or Scene()
    decisions = [json.loads(line) for line in (run / "decisions.jsonl").open()]
    phase_at = dict(_phases(decisions))
    journal = [json.loads(line) for line in (run / "journal.jsonl").open()]
    measured = []
    for record in journal:
        if record.get("kind") != "command" or phase_at.get(record["t"]) != "PRE_CONTACT":
            continue
        q = record["effect"].get("q")
        if q is not None:
            measured.append(scene.measure(q[:6]))
    refusals: dict[str, int] = {}
    details = []
    for line in decisions:
        if line["kind"] == "chunk" and line["decision"] not in ("ADMITTED", "TRIMMED"):
            for reason in line["reasons"]:
                refusals[reason] = refusals.get(reason, 0) + 1
            if "COLLISION" in line["reasons"]:
                details.append(json.dumps(line.get("collision") or line.get("detail")))
    lowest = {key: min(m[key] for m in measured) for key in measured[0]} if measured else {}
    return Judgement(len(measured), lowest,
                     sum(m["peg_bottom_z"] < TABLE_TOP_Z for m in measured), refusals, details)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("press", nargs="?", default="table", choices=sorted(PRESSES))
    parser.add_argument("--manifest", default="sim-ur5e.toml")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="cell-press-") as directory:
        run = run_press(PRESSES[args.press], args.manifest, Path(directory))
        verdict = judge(run)
    print(f"{args.press} press through {args.manifest}: {verdict.setpoints} policy setpoints")
    for key, value in verdict.lowest.items():
        print(f"  lowest {key:<13} {value:+.4f} m")
    print(f"  setpoints with the peg's bottom below the table top: {verdict.below_peg_touch}")
    print(f"  refusals: {verdict.refusals or 'none'}")
    for detail in verdict.collision_details[:3]:
        print(f"  COLLISION: {detail}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
