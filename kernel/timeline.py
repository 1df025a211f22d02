"""A readable timeline of a decision log (``warden replay --pretty`` and ``make run``).

Ticks are folded: consecutive ticks with the same command, owner, phase, mode and reason are
shown as one line with their time span and how many actions ran, so a 300 ms trace fits a
screen while every decision stays visible.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

from assurance.handshake import HandshakeVerdict

_KEYS = ("command", "owner", "phase", "mode", "reason")


def render(lines: Iterable[dict[str, Any]]) -> Iterator[str]:
    run: list[dict[str, Any]] = []
    for line in lines:
        if line["kind"] == "tick":
            if run and any(run[-1].get(k) != line.get(k) for k in _KEYS):
                yield _ticks(run)
                run = []
            run.append(line)
            continue
        if run:
            yield _ticks(run)
            run = []
        yield _event(line)
    if run:
        yield _ticks(run)


def _t(value: float) -> str:
    return f"{value:>9.3f} ms" if isinstance(value, float) else f"{value:>5} ms    "


def _ticks(run: list[dict[str, Any]]) -> str:
    first, last = run[0], run[-1]
    span = f"{_t(first['t'])}" if len(run) == 1 else f"{_t(first['t'])} – {last['t']} ms"
    sent = [line["sent"] for line in run if line.get("sent")]
    actions = sorted({(s["chunk_id"], s["index"]) for s in sent})
    what = f"{first['command']:<8} by {first['owner']:<8}"
    detail = f"[{first['phase']}/{first['mode']}]"
    if actions:
        chunks = sorted({c for c, _ in actions})
        detail += f" ran {len(actions)} action(s) of {', '.join(chunks)}"
    if first.get("reason"):
        detail += f" ({first['reason']})"
    return f"{span}  · {what} {detail}  ×{len(run)} ticks"


def _event(line: dict[str, Any]) -> str:
    kind = line["kind"]
    head = f"{_t(line['t'])}  ▶ "
    if kind == "chunk":
        reasons = " + ".join(line["reasons"]) or "-"
        extra = ""
        if line.get("trimmed"):
            extra += f", trimmed {line['trimmed']}"
        if line.get("projection_distance") is not None:
            extra += f", projection {line['projection_distance']:.4f}"
        return (f"{head}chunk {line['chunk_id']}: {line['decision'].upper()} ({reasons}), "
                f"epoch {line['queue_epoch']}, queue {line['queue_depth']}{extra}")
    if kind == "transition":
        verb = "→" if line.get("accepted", True) else "✗ refused →"
        target = line.get("requested") or line["to"]
        return f"{head}{line['machine']}: {line['from']} {verb} {target} ({line['trigger']})"
    if kind == "handshake":
        if line["decision"] == HandshakeVerdict.ACCEPT:
            return f"{head}handshake ACCEPT, fingerprint {line['fingerprint'][:12]}…"
        return f"{head}handshake REJECT ({' + '.join(line['reasons'])})"
    if kind == "queue":
        what = f"{line['action']} (epoch {line['queue_epoch']}, dropped {line.get('dropped', 0)})"
        return f"{head}queue {what}"
    if kind == "request":
        return f"{head}request inference (observation {line.get('observation_id')})"
    if kind == "motion":
        return f"{head}{_motion(line)}"
    return f"{head}{line}"


def _motion(line: dict[str, Any]) -> str:
    """``move #3 PLANNED, 1840.0 ms``, ``gripper SET, opening 0.085 m``, ``insert REFUSED
    (why)``: the request, what the core decided, and what it carried."""
    what = line["request"] + (f" #{line['move_id']}" if line.get("move_id") is not None else "")
    extra = ""
    if line.get("duration_ms") is not None:
        extra += f", {line['duration_ms']} ms"
    if line.get("opening") is not None:
        extra += f", opening {line['opening']:.4f} m"
    if line.get("detail"):
        extra += f" ({line['detail']})"
    return f"motion {what} {line['decision'].upper()}{extra}"
