"""A run's live metrics (``[metrics]``): scraped while the cell runs, with prometheus_client's
own parser; a port that is taken, or an address other hosts could reach, is refused before
anything starts; the exporter never runs at the control loop's priority."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from kernel.cli import main
from kernel.shell.metrics import MetricsEndpoint
from tests.cell.harness import MANIFESTS

pytestmark = pytest.mark.slow
BASE = (MANIFESTS / "sim-ur5e.toml").read_text()
WARDEN = Path(sys.executable).with_name("warden")


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _manifest(tmp_path: Path, metrics: str) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(f"{BASE}\n[metrics]\n{metrics}\n")
    return path


def _scrape(port: int) -> dict[str, float]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as reply:
        text = reply.read().decode()
    return {sample.name + "".join(f"|{k}={v}" for k, v in sorted(sample.labels.items())):
            sample.value for family in text_string_to_metric_families(text)
            for sample in family.samples}


def test_a_run_is_scraped_while_it_runs(tmp_path: Path) -> None:
    port = _free_port()
    path = _manifest(tmp_path, f"port = {port}\npublish_interval_ms = 100")
    run = subprocess.Popen([str(WARDEN), "run", str(path), "--cycles", "1", "--no-journal",
                            "--json", str(tmp_path / "summary.json")],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    scrapes: list[dict[str, float]] = []
    try:
        deadline = time.monotonic() + 120
        while run.poll() is None and time.monotonic() < deadline:
            with contextlib.suppress(OSError):  # not listening yet, or the run just ended
                scrapes.append(_scrape(port))
            time.sleep(0.5)
    finally:
        _, stderr = run.communicate(timeout=60)
    assert run.returncode == 0, stderr[-2000:]
    ticks = [s["warden_ticks_total"] for s in scrapes if "warden_ticks_total" in s]
    assert len(ticks) >= 3 and ticks == sorted(ticks) and ticks[-1] > ticks[0] > 0
    last = scrapes[-1]
    assert last["warden_link_events_total|counter=handshakes_accepted"] >= 1
    assert last["warden_proposals_total|phase=PRE_CONTACT"] > 0
    assert last["warden_action_age_ms_count"] > 0
    with pytest.raises(OSError):
        _scrape(port)  # the exporter ended with the run


def test_a_taken_port_exits_2_before_anything_starts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        path = _manifest(tmp_path, f"port = {taken.getsockname()[1]}")
        code = main(["run", str(path), "--journal-dir", str(tmp_path / "runs")])
    assert code == 2
    assert "metrics.port: cannot listen on 127.0.0.1:" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


@pytest.mark.parametrize(("metrics", "arguments", "needle"), [
    ('port = 9464\nhost = "0.0.0.0"', [], "metrics.host: '0.0.0.0' is not a loopback"),
    ("port = 0", [], "metrics.port"),
    ("port = 9464\nscrape = 1", [], "metrics.scrape: unknown key"),
    ("port = 9464", ["--clock", "virtual"], "has [metrics], which a virtual-clock run"),
])
def test_a_bad_metrics_table_exits_2_naming_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], metrics: str,
        arguments: list[str], needle: str) -> None:
    code = main(["run", str(_manifest(tmp_path, metrics)), "--no-journal", *arguments])
    assert code == 2
    assert needle in capsys.readouterr().err


def test_the_exporter_runs_at_the_ordinary_priority_whatever_starts_it() -> None:
    """Started from a SCHED_FIFO thread (the control loop's), the exporter's imports would take
    the loop's CPU (a 105 ms gap and a watchdog stop were measured before this)."""
    probe = (
        "import os\n"
        "from kernel.shell.metrics import MetricsEndpoint\n"
        "try:\n"
        "    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))\n"
        "    fifo = True\n"
        "except PermissionError:\n"
        "    fifo = False\n"
        "endpoint = MetricsEndpoint('127.0.0.1', 0)\n"
        "endpoint.start()\n"
        "print(fifo, os.sched_getscheduler(endpoint.pid) == os.SCHED_OTHER)\n"
        "endpoint.close()\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=60, check=True, cwd=Path(__file__).parents[2])
    fifo, ordinary = done.stdout.split()
    assert ordinary == "True", (fifo, done.stderr)
    if fifo != "True":  # without the privilege the test proves less: say so in its output
        print("SCHED_FIFO not permitted here: the exporter's parent ran at SCHED_OTHER")
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # this test process never went FIFO


def test_an_idle_client_holds_no_scrape_and_a_dead_exporter_refuses_them() -> None:
    """A client that connects and sends nothing keeps only its own thread; an exporter that
    died leaves the port refusing scrapes (warden keeps no copy of its socket) and its exit
    status in the endpoint."""
    endpoint = MetricsEndpoint("127.0.0.1", 0)
    endpoint.start()
    try:
        with socket.create_connection(("127.0.0.1", endpoint.port)):  # idle: sends nothing
            for _ in range(50):  # the child is importing its modules at first
                with contextlib.suppress(OSError):
                    assert "warden_ticks_total" in _scrape(endpoint.port)
                    break
                time.sleep(0.2)
            else:
                raise AssertionError("no scrape answered beside an idle client")
        assert endpoint.pid is not None
        os.kill(endpoint.pid, signal.SIGKILL)
        time.sleep(0.5)
        with pytest.raises(urllib.error.URLError) as refused:
            _scrape(endpoint.port)
        assert isinstance(refused.value.reason, ConnectionRefusedError)
    finally:
        endpoint.close()
    assert endpoint.exit_code == -signal.SIGKILL
