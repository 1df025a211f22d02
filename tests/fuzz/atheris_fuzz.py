"""Coverage-guided fuzzing of :mod:`tests.fuzz.targets` with atheris (``make fuzz``).

    python -m tests.fuzz.atheris_fuzz TARGET [libFuzzer options]
    python -m tests.fuzz.atheris_fuzz wire_chunk -max_total_time=60

TARGET is one of ``wire_frame``, ``wire_chunk``, ``scenario``, ``manifest``. The corpus lives in
``build/fuzz/TARGET/corpus`` (seeded from the shipped scenarios and manifests, a hand-made
journal and encoded policy-link messages on the first run) and a crashing input is written to
``build/fuzz/TARGET/`` as ``crash-<sha1>``: reproduce it with the same command and the file as
the only argument, then turn it into a regression test (``tests/fuzz/test_regressions.py``).
Only ``kernel`` and ``assurance`` are instrumented: coverage of numpy or msgspec internals would
steer the fuzzer away from our own branches.
"""

from __future__ import annotations

import hashlib
import json
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

import atheris

with atheris.instrument_imports(include=["kernel", "assurance"]):
    from kernel.manifest import load_manifest
    from tests.fuzz import targets

ROOT = Path(__file__).resolve().parents[2]
WORK = ROOT / "build" / "fuzz"


def _seeds(target: str) -> Iterator[bytes]:
    if target == "scenario":
        for path in sorted((ROOT / "manifests" / "scenarios").glob("*.json")):
            yield path.read_bytes()
        yield _journal()
    elif target == "manifest":
        for path in sorted((ROOT / "manifests").glob("*.toml")):
            yield path.read_bytes()
    else:
        yield from _wire_seeds(target)


def _journal() -> bytes:
    sections = load_manifest(ROOT / "manifests" / "sim-ur5e.toml").sections.document()
    lines = [{"format": "warden-journal/1", "name": "seed", **sections},
             {"t": 0, "kind": "state", "q": sections["session"]["state"]},
             *({"t": 2 * k, "kind": "tick"} for k in range(3))]
    return "\n".join(json.dumps(line) for line in lines).encode()


def _wire_seeds(target: str) -> Iterator[bytes]:
    from hypothesis.errors import NonInteractiveExampleWarning

    from peer import envelope as peer_env
    from peer import protocol as peer
    from tests.wire.peer_strategies import CHUNKS, MESSAGES

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NonInteractiveExampleWarning)
        for _ in range(20):
            chunk = CHUNKS.example()
            yield (peer_env.encode_chunk_frame(chunk) if target == "wire_frame"
                   else peer_env.encode_chunk_body(chunk))
            if target == "wire_frame":
                yield peer.encode(MESSAGES.example())


def main(argv: list[str]) -> None:
    if len(argv) < 2 or argv[1] not in targets.TARGETS:
        sys.exit(f"usage: python -m tests.fuzz.atheris_fuzz {{{','.join(targets.TARGETS)}}} "
                 "[libFuzzer options]")
    target = argv[1]
    corpus = WORK / target / "corpus"
    if not corpus.is_dir() or not any(corpus.iterdir()):
        corpus.mkdir(parents=True, exist_ok=True)
        for seed in _seeds(target):
            (corpus / hashlib.sha1(seed).hexdigest()).write_bytes(seed)
    options = [f"-artifact_prefix={WORK / target}/", *argv[2:]]
    if not any(not option.startswith("-") for option in argv[2:]):
        options.append(str(corpus))  # no input file given: fuzz from the corpus
    atheris.Setup([argv[0], *options], targets.TARGETS[target])
    atheris.Fuzz()


if __name__ == "__main__":
    main(sys.argv)
