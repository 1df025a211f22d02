"""The metrics exporter: a child process of a run that serves its shared block
(``kernel/shell/metrics.py``) in Prometheus' text format at ``/metrics``.

``python -m kernel.shell.metrics_exporter --block NAME --fd N`` serves on the listening socket
``N`` it inherited (warden bound it before the run opened anything) and exits when its stdin
closes, which the run's end, or the run's process dying, does. Reading the block is a copy of
a few hundred float64 slots: a scrape runs here, on this process's interpreter, never on the
run's. It uses prometheus_client's own collectors and exposition.
"""

from __future__ import annotations

import argparse
import socket
import sys
import threading
from collections.abc import Iterator
from socketserver import ThreadingMixIn
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer

import numpy as np
from prometheus_client import CollectorRegistry, make_wsgi_app
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.registry import Collector

from kernel.shell.metrics import LAYOUT, MetricsBlock

PREFIX = "warden_"


class BlockCollector(Collector):
    def __init__(self, block: MetricsBlock) -> None:
        self.block = block

    def collect(self) -> Iterator[CounterMetricFamily | GaugeMetricFamily | HistogramMetricFamily]:
        return iter(families(self.block.values.copy()))


def families(values: np.ndarray) -> list[CounterMetricFamily | GaugeMetricFamily |
                                          HistogramMetricFamily]:
    """The metric families of one snapshot of the block."""
    slots = LAYOUT.slots
    out: list[CounterMetricFamily | GaugeMetricFamily | HistogramMetricFamily] = [
        CounterMetricFamily(PREFIX + "ticks", "control ticks run", value=values[slots["ticks"]]),
        CounterMetricFamily(PREFIX + "inference_requests", "observations sent for a chunk",
                            value=values[slots["requests"]]),
        GaugeMetricFamily(PREFIX + "queue_depth_actions",
                          "queued actions when the last chunk was decided",
                          value=values[slots["queue_depth"]]),
        CounterMetricFamily(PREFIX + "journal_gaps", "journal records lost",
                            value=values[slots["journal_gaps"]]),
        CounterMetricFamily(PREFIX + "deadline_misses", "control ticks past their deadline",
                            value=values[slots["deadline_misses"]]),
        CounterMetricFamily(PREFIX + "metrics_publishes", "times the run wrote these numbers",
                            value=values[slots["published"]]),
    ]
    out.append(_labelled(values, "proposals", "chunks proposed, by task phase", ["phase"],
                         [(p,) for p in LAYOUT.phases]))
    out.append(_labelled(values, "decisions", "chunk decisions, by decision", ["decision"],
                         [(d,) for d in LAYOUT.decisions]))
    out.append(_labelled(values, "refusals", "refusal reasons, by task phase", ["phase", "reason"],
                         [(p, r) for p in LAYOUT.phases for r in LAYOUT.reasons], sparse=True))
    out.append(_labelled(values, "transitions", "fallback transitions", ["from_mode", "to_mode"],
                         [(a, b) for a in LAYOUT.modes for b in LAYOUT.modes], sparse=True))
    out.append(_labelled(values, "triggers", "fallback transitions, by trigger (reason code)",
                         ["trigger"], [(r,) for r in LAYOUT.reasons], sparse=True,
                         name="fallback_triggers"))
    out.append(_latencies(values))
    out.append(_labelled(values, "links", "policy link counters", ["counter"],
                         [(n,) for n in LAYOUT.links], name="link_events"))
    out.append(_histogram(values, "action_age", "age of the action sent at a tick, ms",
                          "action_age_ms"))
    out.append(_histogram(values, "projection", "projection distance of admitted chunks, rad",
                          "projection_distance_rad"))
    return out


def _labelled(values: np.ndarray, slot: str, documentation: str, labels: list[str],
              keys: list[tuple[str, ...]], sparse: bool = False,
              name: str | None = None) -> CounterMetricFamily:
    family = CounterMetricFamily(PREFIX + (name or slot), documentation, labels=labels)
    at = LAYOUT.slots[slot]
    for index, key in enumerate(keys):
        value = float(values[at + index])
        if value or not sparse:  # thousands of reason × phase pairs: only those that happened
            family.add_metric(list(key), value)
    return family


def _histogram(values: np.ndarray, slot: str, documentation: str,
               name: str) -> HistogramMetricFamily:
    histogram = LAYOUT.histogram(slot)
    counts = values[histogram.at:histogram.at + len(histogram.buckets) + 1]
    buckets = _cumulative(histogram.buckets, counts)
    return HistogramMetricFamily(PREFIX + name, documentation, buckets=buckets,
                                 sum_value=float(values[histogram.at + histogram.width - 1]))


def _latencies(values: np.ndarray) -> HistogramMetricFamily:
    family = HistogramMetricFamily(
        PREFIX + "fallback_latency_ms", "a fallback transition's trigger to the first tick "
        "commanding its mode, ms, by the mode it went to", labels=["to_mode"])
    for mode in LAYOUT.modes:
        histogram = LAYOUT.latency(mode)
        if histogram is None:
            continue
        counts = values[histogram.at:histogram.at + len(histogram.buckets) + 1]
        if not counts.any():
            continue  # a mode never entered: no series
        family.add_metric([mode], _cumulative(histogram.buckets, counts),
                          sum_value=float(values[histogram.at + histogram.width - 1]))
    return family


def _cumulative(bounds: tuple[float, ...], counts: np.ndarray) -> list[tuple[str, float]]:
    cumulative = np.cumsum(counts)
    buckets = [(f"{bound:g}", float(total)) for bound, total in
               zip(bounds, cumulative[:-1], strict=True)]
    buckets.append(("+Inf", float(cumulative[-1])))
    return buckets


class _Server(ThreadingMixIn, WSGIServer):
    """A thread per connection: an idle client holds only its own thread."""

    daemon_threads = True


class _Quiet(WSGIRequestHandler):
    timeout = 5.0  # a client that sends nothing is dropped, not waited on

    def log_message(self, format: str, *args: object) -> None:
        pass  # a scrape every few seconds is not news


def serve(block: MetricsBlock, listener: socket.socket) -> _Server:
    registry = CollectorRegistry(auto_describe=True)
    registry.register(BlockCollector(block))
    server = _Server(listener.getsockname()[:2], _Quiet, bind_and_activate=False)
    server.socket.close()
    server.socket = listener
    server.server_address = listener.getsockname()[:2]
    server.server_name, server.server_port = server.server_address  # what bind() would set
    server.setup_environ()
    server.set_app(make_wsgi_app(registry))
    return server


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--block", required=True)
    parser.add_argument("--fd", type=int, required=True)
    args = parser.parse_args(argv)
    block = MetricsBlock(args.block)
    listener = socket.socket(fileno=args.fd)
    server = serve(block, listener)
    thread = threading.Thread(target=server.serve_forever, name="metrics-http")
    thread.start()
    try:
        sys.stdin.buffer.read()  # until the run closes our stdin, or its process is gone
    finally:
        server.shutdown()
        thread.join()
    return 0


if __name__ == "__main__":
    sys.exit(main())
