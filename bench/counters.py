"""User-space instruction and cycle counts of this thread, from Linux perf events.

Wall-clock figures on a shared machine move by 2x within an hour; the number of instructions a
piece of code retires does not, so the benchmarks print it beside their times when the kernel
allows (``perf_event_open`` with ``perf_event_paranoid`` <= 2, or root). Where it does not,
:func:`open_counters` returns None and the benchmark says so.
"""

from __future__ import annotations

import ctypes
import os
import platform
import struct
from dataclasses import dataclass

_SYSCALL = {"x86_64": 298, "aarch64": 241}
_HW_CPU_CYCLES, _HW_INSTRUCTIONS = 0, 1
_EXCLUDE_KERNEL, _EXCLUDE_HV = 1 << 5, 1 << 6


class _PerfEventAttr(ctypes.Structure):
    """``struct perf_event_attr`` up to ``config2`` (PERF_ATTR_SIZE_VER1, 72 bytes)."""

    _fields_ = (
        ("type", ctypes.c_uint32), ("size", ctypes.c_uint32), ("config", ctypes.c_uint64),
        ("sample_period", ctypes.c_uint64), ("sample_type", ctypes.c_uint64),
        ("read_format", ctypes.c_uint64), ("flags", ctypes.c_uint64),
        ("wakeup_events", ctypes.c_uint32), ("bp_type", ctypes.c_uint32),
        ("config1", ctypes.c_uint64), ("config2", ctypes.c_uint64),
    )


@dataclass(frozen=True, slots=True)
class Counters:
    instructions_fd: int
    cycles_fd: int

    def read(self) -> tuple[int, int]:
        """(instructions, cycles) retired by this thread in user space so far."""
        return _read(self.instructions_fd), _read(self.cycles_fd)

    def close(self) -> None:
        os.close(self.instructions_fd)
        os.close(self.cycles_fd)


def open_counters() -> Counters | None:
    """Counters for the calling thread, or None where perf events are not available."""
    number = _SYSCALL.get(platform.machine())
    if number is None:
        return None
    libc = ctypes.CDLL(None, use_errno=True)
    instructions = _open(libc, number, _HW_INSTRUCTIONS)
    cycles = _open(libc, number, _HW_CPU_CYCLES)
    if instructions < 0 or cycles < 0:
        for fd in (instructions, cycles):
            if fd >= 0:
                os.close(fd)
        return None
    return Counters(instructions, cycles)


def _open(libc: ctypes.CDLL, number: int, config: int) -> int:
    attr = _PerfEventAttr(type=0, size=ctypes.sizeof(_PerfEventAttr), config=config,
                          flags=_EXCLUDE_KERNEL | _EXCLUDE_HV)
    return int(libc.syscall(number, ctypes.byref(attr), 0, -1, -1, 0))


def _read(fd: int) -> int:
    return int(struct.unpack("q", os.read(fd, 8))[0])
