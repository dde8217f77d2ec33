"""Keep the daemon's threads responsive: a Linux PM QoS CPU latency request, and real-time
scheduling for the threads on the estimate's path.

A thread that sleeps (the window worker between hops, the acquisition thread between frames,
a subscriber waiting for the next estimate) is woken on a core that may have gone into a deep
idle state — or, in a virtual machine, been handed back to the hypervisor. Leaving that state
costs from tens of microseconds to milliseconds, and it lands on every hop's latency tail.
Writing a latency bound to ``/dev/cpu_dma_latency`` and holding the file open asks the kernel
to use only idle states that wake faster than the bound (0: poll); the request ends when the
file is closed, including when the process is killed. This is what ``cyclictest`` and other
real-time Linux tools do; it costs power, so it is opt-in (``[daemon] cpu_latency_us``).

A woken thread also waits for a CPU when other work on the machine holds both: on a shared
2-core machine at a 4 ms hop that wait, not the computation, made most deadline misses.
``[daemon] realtime_priority`` (opt-in too) puts the acquisition and window-worker threads in
the ``SCHED_FIFO`` class (:func:`set_realtime_priority`): they then run as soon as they are
woken, ahead of every normal process. The kernel's real-time throttling
(``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default) still leaves the rest of the
machine a share should one of them spin.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from contextlib import contextmanager

from rtsid.errors import ConfigError

__all__ = ["PM_QOS_DEVICE", "cpu_latency_request", "set_realtime_priority"]

PM_QOS_DEVICE = "/dev/cpu_dma_latency"


@contextmanager
def cpu_latency_request(latency_us: int, device: str | None = None) -> Iterator[bool]:
    """Hold a CPU wake-up latency bound of ``latency_us`` µs for the ``with`` block.

    Parameters
    ----------
    latency_us : int
        The bound, µs (0: idle CPUs poll); negative: no request (yields False).
    device : str, optional
        The PM QoS device (default :data:`PM_QOS_DEVICE`; tests pass a plain file).

    Yields
    ------
    bool
        True while the request is held.

    Raises
    ------
    ConfigError
        The device cannot be opened or written; the message names the key and the fixes.
    """
    if latency_us < 0:
        yield False
        return
    device = device or PM_QOS_DEVICE
    try:
        fd = os.open(device, os.O_WRONLY)
    except OSError as exc:
        raise ConfigError(
            f"config key 'daemon.cpu_latency_us' = {latency_us}: cannot open {device} "
            f"({exc.strerror}); run as root, give the service user write access (udev rule "
            "in hw/README.md), or set cpu_latency_us = -1 to leave CPU power management alone"
        ) from None
    try:
        try:
            os.write(fd, struct.pack("i", latency_us))
        except OSError as exc:
            raise ConfigError(
                f"config key 'daemon.cpu_latency_us' = {latency_us}: {device} refused the "
                f"request ({exc.strerror}); set cpu_latency_us = -1"
            ) from None
        yield True
    finally:
        os.close(fd)


def set_realtime_priority(native_id: int, priority: int, thread_name: str = "") -> None:
    """Run the thread ``native_id`` (of this process) in ``SCHED_FIFO`` at ``priority``.

    Parameters
    ----------
    native_id : int
        The thread's kernel id (``threading.Thread.native_id``).
    priority : int
        1–99 (higher runs first); 0 leaves the thread's scheduling alone.
    thread_name : str
        Named in the error.

    Raises
    ------
    ConfigError
        The kernel refused (no ``CAP_SYS_NICE`` / ``RLIMIT_RTPRIO``, or no such scheduling
        class here); the message names the key and the fixes.
    """
    if priority <= 0:
        return
    try:
        os.sched_setscheduler(native_id, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        reason = getattr(exc, "strerror", None) or "not supported on this system"
        raise ConfigError(
            f"config key 'daemon.realtime_priority' = {priority}: the kernel refused real-time "
            f"scheduling for {thread_name or f'thread {native_id}'} ({reason}); run as root, "
            "allow it to the service user (LimitRTPRIO= in the systemd unit, or rtprio in "
            "/etc/security/limits.conf), or set realtime_priority = 0"
        ) from None
