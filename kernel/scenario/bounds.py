"""The sane physical and practical range of every limit and threshold a file may set.

A value outside these ranges is never a configuration anyone means: it is a typo (a missing
decimal point), a unit mistake (degrees for radians, seconds for milliseconds, microseconds for
milliseconds) or garbage, and taken at its word it either switches a gate off (a divergence
bound of 1e9 rad admits anything), never finishes (a billion joints, a scenario a million years
long) or fails later with the device already running. Every bound is generous enough for any
real manipulator, so it never refuses a real cell; the rationale of each is in
``docs/manifest.md`` ("Bounds"). The loaders check them while reading, before anything starts.
"""

from __future__ import annotations

import math

MAX_DEPTH = 32
"""Nesting of objects and arrays in a file: the deepest legitimate value (a journal's command
record) is 5 levels deep; deeper input only exhausts the parser's stack."""
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
"""Integers are 64-bit, as TOML specifies and MessagePack carries: anything wider is refused
where it is read, with its key, before it can overflow a float or a clock."""

DOF_MAX = 64
"""Arm joints: a humanoid with two hands has about 50; a single manipulator has 6 or 7."""
POSITION_LIMIT_MAX = 8 * math.pi
"""rad (or m for a linear axis): four turns either way. No revolute joint of a manipulator is
allowed more (UR joints: one turn either way; continuous wrists are cable-limited), and as
metres it covers a 25 m linear rail."""
VELOCITY_LIMIT_MAX = 100.0
"""rad/s (about 5700 deg/s): twice the fastest joint of any manipulator (a SCARA's spinning
fourth axis, about 2600 deg/s; a UR5e joint makes 180 deg/s)."""
ACCELERATION_LIMIT_MAX = 10_000.0
"""rad/s²: from standstill to the velocity bound in 10 ms; direct-drive and delta robots stay
well below (a UR5e joint: about 40 rad/s²)."""
JERK_MAX = 1_000_000.0
"""rad/s³: the interpolator's and planner's jerk (the defaults are 50 and 60)."""
WORKSPACE_MAX_M = 100.0
"""m, base frame: every Cartesian coordinate (workspace box, task poses). The longest-reach
manipulators reach under 5 m."""
LENGTH_MAX_M = 1.0
"""m: a part's size, a hole's depth, a gripper's stroke, a tolerance or a clearance."""
FORCE_MAX_N = 100_000.0
"""N: a contact force band. About ten tonnes-force: beyond any manipulator's payload."""

PERIOD_MIN_MS = 0.05
"""ms: 20 kHz. The fastest arm control loops run at 1 to 8 kHz (UR: 500 Hz, Franka: 1 kHz)."""
PERIOD_MAX_MS = 1000.0
"""ms: a control period (or an action spacing) longer than a second is not control."""
DURATION_MAX_MS = 60_000.0
"""ms: ages, watermarks, retries, underruns, watchdogs, latencies. A freshness bound of more
than a minute is a gate switched off; a latency of more than a minute is a dead server."""
UNCERTAINTY_MAX_MS = 1000.0
"""ms: clock uncertainty. More than a second and every age check fails; synchronise instead."""
CLOCK_OFFSET_MAX_MS = 4e12
"""ms (about 127 years): a foreign clock's offset, large enough for a server on the Unix epoch
clock (today about 1.8e12 ms) while every time, in integer nanoseconds, stays within 64 bits."""
EVENT_TIME_MAX_MS = 4e12
"""ms: an event's time since the start of the run (the same 64-bit headroom)."""
UNTIL_MAX_MS = 3_600_000.0
"""ms: one hour. A scenario is a test case: its ticks are generated, and a replay keeps every
decision line in memory."""
TICKS_MAX = 2_000_000
"""Generated ticks of one scenario (``until`` / ``control_period_ms``): an hour at 500 Hz is
1.8 million."""

DEGRADE_AFTER_MAX = 10_000
"""Timing refusals counted before RUNNING degrades: a debounce, not a switch-off."""
QUEUE_EPOCH_MAX = 2**31 - 1
PROTOCOL_MAX = 65_535
CHUNK_HORIZON_MAX = 1000
"""Actions per chunk: ten times the longest chunk of published chunking policies (ACT: 100)."""
NOISE_MAX_RAD = 1.0
"""rad: the reference policy's action noise (standard deviation)."""
PORT_MAX = 65_535
CYCLES_MAX = 1_000_000
"""Assembly cycles of one run: about four months of ten-second cycles."""
CYCLE_TIMEOUT_MIN_S, CYCLE_TIMEOUT_MAX_S = 0.1, 3600.0
SEED_MAX = 2**63 - 1

NAME_PATTERN = r"[A-Za-z0-9_][A-Za-z0-9._-]{0,63}"
"""A run's name becomes a directory name: ASCII letters, digits, ``.``, ``_`` and ``-``, at
most 64 characters, not starting with a dot or a dash (no path separator, never ``..``, never
hidden, never read as an option)."""
