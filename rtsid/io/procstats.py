"""CPU and memory of this process for the status message (no psutil needed on Linux)."""

from __future__ import annotations

import os
import resource
import time
from pathlib import Path

__all__ = ["ProcessMeter", "rss_mb"]

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_mb() -> float:
    """Resident set size now, MiB (peak RSS where /proc is not available)."""
    try:
        fields = Path("/proc/self/statm").read_text().split()
        return int(fields[1]) * _PAGE / 2**20
    except (OSError, IndexError, ValueError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class ProcessMeter:
    """CPU use between calls of :meth:`sample`, RSS and uptime.

    Examples
    --------
    >>> meter = ProcessMeter()
    >>> sorted(meter.sample())
    ['cpu_percent', 'rss_mb', 'uptime_s']
    """

    def __init__(self) -> None:
        self._start = time.monotonic()
        self._last_wall = self._start
        self._last_cpu = self._cpu_s()

    @staticmethod
    def _cpu_s() -> float:
        t = os.times()
        return t.user + t.system

    def sample(self) -> dict[str, float]:
        """``cpu_percent`` (of one core, since the previous call), ``rss_mb``, ``uptime_s``."""
        wall, cpu = time.monotonic(), self._cpu_s()
        elapsed = wall - self._last_wall
        percent = 100.0 * (cpu - self._last_cpu) / elapsed if elapsed > 0 else 0.0
        self._last_wall, self._last_cpu = wall, cpu
        return {"cpu_percent": percent, "rss_mb": rss_mb(), "uptime_s": wall - self._start}
