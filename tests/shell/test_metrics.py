"""Live metrics: what the run publishes into its shared block, and what the exporter makes of
it (kernel/shell/metrics.py, kernel/shell/metrics_exporter.py), read back with
prometheus_client's own parser."""

from __future__ import annotations

import pytest
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families

from kernel.shell.metrics import AGE_BUCKETS_MS, LAYOUT, MetricsBlock, MetricsPublisher
from kernel.shell.metrics_exporter import BlockCollector
from kernel.summary import RunSummary


@pytest.fixture
def block() -> MetricsBlock:
    block = MetricsBlock()
    yield block
    block.close()


Samples = dict[tuple[str, frozenset[tuple[str, str]]], float]


def scraped(block: MetricsBlock) -> Samples:
    """Every sample of a scrape: (sample name, labels) → value."""
    registry = CollectorRegistry()
    registry.register(BlockCollector(block))
    text = generate_latest(registry).decode()
    return {(sample.name, frozenset(sample.labels.items())): sample.value
            for family in text_string_to_metric_families(text) for sample in family.samples}


def value(samples: Samples, name: str, **labels: str) -> float:
    return samples[(name, frozenset(labels.items()))]


def named(samples: Samples, name: str) -> Samples:
    return {key: v for key, v in samples.items() if key[0] == name}


def summary() -> RunSummary:
    run = RunSummary()
    run.ticks, run.requests = 1200, 14
    run.proposals["PRE_CONTACT"] = 9
    run.decisions["accepted"], run.decisions["rejected"] = 7, 2
    run.refusals["PRE_CONTACT"]["OBSERVATION_STALE"] = 2
    run.refusals["PRE_CONTACT"]["NOT_A_CODE"] = 5  # not a reason code: never a label
    run.queue_depth += [3.0, 11.0]
    run.action_age_ms += [1.0, 7.5, 7.5, 2000.0]
    run.projection += [0.0002]
    run.transitions.append({"t": 1.0, "from": "RUNNING", "to": "SAFE_HOLD", "trigger": "X"})
    return run


def test_what_the_run_counted_is_what_a_scrape_reads(block: MetricsBlock) -> None:
    publisher = MetricsPublisher(block)
    publisher.publish(summary(), {"connects": 2, "frames_in": 40},
                      {"journal_gaps": 1, "deadline_misses": 3})
    metrics = scraped(block)
    assert value(metrics, "warden_ticks_total") == 1200
    assert value(metrics, "warden_deadline_misses_total") == 3
    assert value(metrics, "warden_journal_gaps_total") == 1
    assert value(metrics, "warden_queue_depth_actions") == 11.0
    assert named(metrics, "warden_refusals_total") == {("warden_refusals_total", frozenset(
        {("phase", "PRE_CONTACT"), ("reason", "OBSERVATION_STALE")})): 2.0}
    assert named(metrics, "warden_transitions_total") == {("warden_transitions_total", frozenset(
        {("from_mode", "RUNNING"), ("to_mode", "SAFE_HOLD")})): 1.0}
    assert value(metrics, "warden_link_events_total", counter="connects") == 2
    assert value(metrics, "warden_proposals_total", phase="PRE_CONTACT") == 9
    assert value(metrics, "warden_decisions_total", decision="rejected") == 2
    bucket = "warden_action_age_ms_bucket"
    assert value(metrics, bucket, le="2") == 1  # cumulative: 1.0
    assert value(metrics, bucket, le="10") == 3  # and 7.5 twice
    assert value(metrics, bucket, le="1000") == 3
    assert value(metrics, bucket, le="+Inf") == 4  # and 2000
    assert value(metrics, "warden_action_age_ms_count") == 4
    assert value(metrics, "warden_action_age_ms_sum") == pytest.approx(2016.0)


def test_a_publish_adds_only_what_happened_since_the_last(block: MetricsBlock) -> None:
    publisher, run = MetricsPublisher(block), summary()
    publisher.publish(run, {}, {})
    publisher.publish(run, {}, {})  # nothing new: nothing counted twice
    run.action_age_ms.append(3.0)
    run.transitions.append({"t": 2.0, "from": "SAFE_HOLD", "to": "RUNNING", "trigger": "Y"})
    publisher.publish(run, {}, {})
    metrics = scraped(block)
    assert value(metrics, "warden_action_age_ms_count") == 5
    assert sum(named(metrics, "warden_transitions_total").values()) == 2
    assert value(metrics, "warden_metrics_publishes_total") == 3


def test_fallback_triggers_and_latencies_once_a_tick_commands_the_mode(
        block: MetricsBlock) -> None:
    """A transition's latency is filled in by the summary when a tick commands the new mode:
    it is counted then, once, in the histogram of the mode it went to."""
    publisher, run = MetricsPublisher(block), RunSummary()
    run.transitions += [
        {"t": 1.0, "from": "RUNNING", "to": "SAFE_HOLD", "trigger": "STATE_DIVERGED"},
        {"t": 9.0, "from": "SAFE_HOLD", "to": "RUNNING", "trigger": "RECOVERY_ACCEPTED"}]
    run.transitions[0]["latency_ms"] = 1.5
    publisher.publish(run, {}, {})
    metrics = scraped(block)
    assert value(metrics, "warden_fallback_triggers_total", trigger="RECOVERY_ACCEPTED") == 1
    assert value(metrics, "warden_fallback_latency_ms_count", to_mode="SAFE_HOLD") == 1
    assert value(metrics, "warden_fallback_latency_ms_bucket", to_mode="SAFE_HOLD", le="2") == 1
    assert ("warden_fallback_latency_ms_count", frozenset({("to_mode", "RUNNING")})) not in (
        metrics)  # its latency is not known yet
    run.transitions[1]["latency_ms"] = 0.0
    publisher.publish(run, {}, {})
    publisher.publish(run, {}, {})
    metrics = scraped(block)
    assert value(metrics, "warden_fallback_latency_ms_count", to_mode="RUNNING") == 1
    assert value(metrics, "warden_fallback_latency_ms_count", to_mode="SAFE_HOLD") == 1


def test_the_layout_is_bounded_by_the_enums() -> None:
    last = LAYOUT.latency(LAYOUT.modes[-1])
    assert last is not None and LAYOUT.size == last.at + last.width
    assert LAYOUT.latency("made up") is None and LAYOUT.trigger("made up") is None
    assert LAYOUT.refusal("PRE_CONTACT", "made up") is None
    assert LAYOUT.transition("RUNNING", "made up") is None
    assert LAYOUT.histogram("action_age").buckets == AGE_BUCKETS_MS
