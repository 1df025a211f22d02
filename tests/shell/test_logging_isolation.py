"""A test's logging configuration ends with it (tests/conftest.py): the second test here runs
after the first in this file's order, and failed before the fixture restored the suite's
configuration (the first's WARNING level hid its INFO line from ``capture_logs``)."""

from __future__ import annotations

import structlog

from kernel.shell.logging import configure_logging


def test_a_command_run_in_process_configures_warning_lines_only() -> None:
    configure_logging("WARNING")  # what `warden check` does, run in-process by its tests
    with structlog.testing.capture_logs() as logs:
        structlog.get_logger("isolation").info("hidden at this level")
    assert logs == []


def test_the_next_test_sees_info_lines_again() -> None:
    with structlog.testing.capture_logs() as logs:
        structlog.get_logger("isolation").info("seen")
    assert [entry["event"] for entry in logs] == ["seen"]
