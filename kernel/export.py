"""``warden export RUN --mcap``: a run's record as an MCAP file that Foxglove opens.

Written with Foxglove's own SDK (``foxglove-sdk``), in typed channels where Foxglove has a
schema for the thing and JSON where warden's own records are the schema:

- ``/joint_states``: ``foxglove.JointStates`` of every state sample (positions, velocities);
- ``/joint_commands``: ``foxglove.JointStates`` of every command with a joint target (setpoints,
  retreats);
- ``/tcp``, ``/tcp_target``: ``foxglove.PoseInFrame`` (frame ``base``) of the arm's model at those
  joints;
- ``/camera/<name>``: ``foxglove.CompressedImage`` (PNG) of the frames a run kept
  (``[journal] frames = "pixels"``);
- ``/commands`` (JSON ``warden.command``): every command, its kind, owner and gripper, and what the
  device answered;
- ``/decisions``, ``/transitions``, ``/motions``, ``/queue``, ``/ticks`` (JSON ``warden.<kind>``):
  the decision log's lines of each kind (a tick line: owner, command, phase, mode);
- ``/observations``, ``/chunks_in`` (JSON): what was sent to the policy, and what came back;
- ``/summary`` (JSON ``warden.summary``): the run's summary, once, at its last time.

Times are the run's own (its monotonic clock, as the journal has them), as nanoseconds: the
record says nothing of wall time. Bad input (not a run directory, a journal that does not parse,
an output that exists) is a :class:`~kernel.scenario.fields.ScenarioError`: exit 2, named.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import foxglove
import msgspec
import numpy as np
import pinocchio as pin
from foxglove import channels, messages

from assurance.kinematics import ArmKinematics
from kernel.core.effects import Retreat, Setpoint
from kernel.core.events import ChunkEvent, ObservationEvent, StateEvent
from kernel.journal import CommandRecord
from kernel.scenario.fields import ScenarioError
from kernel.scenario.load import Scenario, load_scenario

JSON_OBJECT = b'{"type": "object"}'
"""The JSON channels' schema: warden's own records (docs/contract.md) say what each holds."""
DECISION_TOPICS = {"chunk": "/decisions", "transition": "/transitions", "motion": "/motions",
                   "queue": "/queue", "tick": "/ticks"}


def export_mcap(run: Path, out: Path) -> Counter[str]:
    """Write ``out`` from the run directory ``run``; the messages written, per topic.

    Raises:
        ScenarioError: ``run`` is not a run directory, its journal does not parse, its decision
            log is broken, or ``out`` exists or cannot be written.
    """
    journal = run / "journal.jsonl"
    if not journal.is_file():
        raise ScenarioError(f"{run}: not a run directory (no journal.jsonl)")
    if out.exists():
        raise ScenarioError(f"{out}: exists already: export to another file")
    scenario = load_scenario(journal)
    writer = _Writer(scenario, _joint_names(journal, scenario), run)
    try:
        with foxglove.open_mcap(out, context=writer.context):
            writer.record(scenario.events)
            writer.decisions(_decision_lines(run / "decisions.jsonl"))
            writer.summary(run / "summary.json")
    except OSError as error:
        raise ScenarioError(f"{out}: cannot write: {error.strerror or error}") from None
    return writer.counts


class _Writer:
    def __init__(self, scenario: Scenario, names: list[str], run: Path) -> None:
        self.context = foxglove.Context()
        self.names, self.run = names, run
        self.kinematics: ArmKinematics | None = scenario.config.kinematics
        self.arm = scenario.config.limits.arm_mask
        self.counts: Counter[str] = Counter()
        self.last_t = 0
        self._typed: dict[str, Any] = {}
        self._json: dict[str, foxglove.Channel] = {}

    # -- the journal ---------------------------------------------------------------------------

    def record(self, events: Iterable[Any]) -> None:
        for event in events:
            t = int(event.t)
            self.last_t = max(self.last_t, t)
            if isinstance(event, StateEvent):
                self._joints("/joint_states", t, event.q, event.qd)
                self._pose("/tcp", t, event.q)
            elif isinstance(event, CommandRecord):
                self._command(t, event)
            elif isinstance(event, ObservationEvent):
                self._observation(t, event)
            elif isinstance(event, ChunkEvent):
                self._log_json("/chunks_in", t, {"chunk_id": event.chunk.chunk_id})

    def _command(self, t: int, record: CommandRecord) -> None:
        effect = record.effect
        body = {"effect": msgspec.to_builtins(effect),
                "applied": msgspec.to_builtins(record.applied), "origin": str(record.origin)}
        self._log_json("/commands", t, body)
        if isinstance(effect, Setpoint | Retreat):
            self._joints("/joint_commands", t, effect.q, None)
            self._pose("/tcp_target", t, effect.q)

    def _observation(self, t: int, event: ObservationEvent) -> None:
        frames = [msgspec.to_builtins(frame) for frame in event.frames]
        self._log_json("/observations", t, {"observation_id": event.observation_id,
                                            "frames": frames})
        for frame in event.frames:
            picture = self.run / "frames" / frame.camera / f"{frame.digest}.png"
            if picture.is_file():
                channel = self._channel(f"/camera/{frame.camera}", channels.CompressedImageChannel)
                channel.log(messages.CompressedImage(
                    timestamp=_stamp(frame.t_capture), frame_id=frame.camera,
                    data=picture.read_bytes(), format="png"), log_time=t)
                self.counts[f"/camera/{frame.camera}"] += 1

    def _joints(self, topic: str, t: int, q: tuple[float, ...],
                qd: tuple[float, ...] | None) -> None:
        velocity = qd if qd is not None else (None,) * len(q)
        joints = [messages.JointState(name=name, position=float(p),
                                      **({} if v is None else {"velocity": float(v)}))
                  for name, p, v in zip(self.names, q, velocity, strict=False)]
        channel = self._channel(topic, channels.JointStatesChannel)
        channel.log(messages.JointStates(timestamp=_stamp(t), joints=joints), log_time=t)
        self.counts[topic] += 1

    def _pose(self, topic: str, t: int, q: tuple[float, ...]) -> None:
        if self.kinematics is None:
            return
        pose = self.kinematics.forward(np.asarray(q, dtype=float)[self.arm])
        x, y, z, w = pin.Quaternion(np.asarray(pose.rotation)).coeffs().tolist()
        position = [float(v) for v in pose.position]
        channel = self._channel(topic, channels.PoseInFrameChannel)
        channel.log(messages.PoseInFrame(
            timestamp=_stamp(t), frame_id="base", pose=messages.Pose(
                position=messages.Vector3(x=position[0], y=position[1], z=position[2]),
                orientation=messages.Quaternion(x=x, y=y, z=z, w=w))), log_time=t)
        self.counts[topic] += 1

    # -- the decision log and the summary ------------------------------------------------------

    def decisions(self, lines: Iterable[dict[str, Any]]) -> None:
        for line in lines:
            topic = DECISION_TOPICS.get(str(line.get("kind")))
            if topic is not None:
                self._log_json(topic, round(float(line["t"]) * 1e6), line)

    def summary(self, path: Path) -> None:
        if path.is_file():
            self._log_json("/summary", self.last_t, json.loads(path.read_text()))

    # -- channels ------------------------------------------------------------------------------

    def _channel(self, topic: str, kind: Any) -> Any:
        channel = self._typed.get(topic)
        if channel is None:
            channel = self._typed[topic] = kind(topic, context=self.context)
        return channel

    def _log_json(self, topic: str, t: int, body: dict[str, Any]) -> None:
        channel = self._json.get(topic)
        if channel is None:
            schema = foxglove.Schema(name=f"warden.{topic.strip('/')}", encoding="jsonschema",
                                     data=JSON_OBJECT)
            channel = self._json[topic] = foxglove.Channel(
                topic, schema=schema, message_encoding="json", context=self.context)
        channel.log(json.dumps(body, default=str), log_time=t)
        self.counts[topic] += 1


def _stamp(t_ns: int) -> messages.Timestamp:
    seconds, nanoseconds = divmod(int(t_ns), 1_000_000_000)
    return messages.Timestamp(sec=seconds, nsec=nanoseconds)


def _joint_names(journal: Path, scenario: Scenario) -> list[str]:
    with open(journal, encoding="utf-8") as file:
        header = json.loads(file.readline())
    names = header.get("robot", {}).get("joints") if isinstance(header, dict) else None
    count = int(scenario.config.limits.dim)
    if isinstance(names, list) and len(names) == count and all(isinstance(n, str) for n in names):
        return names
    return [f"joint_{index}" for index in range(count)]


def _decision_lines(path: Path) -> list[dict[str, Any]]:
    """The decision log beside the journal, if the run kept one (a last line cut off is
    left out, as a replay leaves it out)."""
    if not path.is_file():
        return []
    lines: list[dict[str, Any]] = []
    with open(path, encoding="utf-8") as file:
        for number, text in enumerate(file, start=1):
            try:
                line = json.loads(text)
            except json.JSONDecodeError:
                if text.endswith("\n"):
                    raise ScenarioError(f"{path}: line {number}: not JSON") from None
                break  # the last line, cut off while it was written
            if isinstance(line, dict) and "t" in line:
                lines.append(line)
    return lines
