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
``[daemon] realtime_priority`` (opt-in too) puts the daemon's threads in the ``SCHED_FIFO``
class (:func:`realtime_process`): they then run as soon as they are woken, ahead of every
normal process. The kernel's real-time throttling
(``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default) still leaves the rest of the
machine a share should one of them spin.
"""

from __future__ import annotations

import os
import struct
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from rtsid.errors import ConfigError

__all__ = ["PM_QOS_DEVICE", "cpu_latency_request", "realtime_process"]

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


def _thread_ids() -> list[int]:
    """Kernel ids of this process's threads (Python's and native ones, zenoh's included)."""
    try:
        return [int(tid) for tid in os.listdir("/proc/self/task")]
    except OSError:
        return [threading.get_native_id()]


def _refusal(priority: int, reason: str) -> ConfigError:
    return ConfigError(
        f"config key 'daemon.realtime_priority' = {priority}: the kernel refused real-time "
        f"scheduling ({reason}); run as root, allow it to the service user (LimitRTPRIO= in "
        "the systemd unit, or rtprio in /etc/security/limits.conf), or set realtime_priority = 0"
    )


@contextmanager
def realtime_process(priority: int) -> Iterator[int]:
    """Run every thread of this process in ``SCHED_FIFO`` at ``priority`` for the ``with``
    block, then give each back its previous scheduling.

    Every thread that exists when the block starts is raised: the daemon's Python threads
    (they share the GIL: one left at normal priority and preempted while holding it would
    hold up the worker) and zenoh's native ones (the estimate's way out). With
    ``SCHED_RESET_ON_FORK``, whatever they start later (the slow lane's process, a thread)
    starts with normal scheduling.

    Parameters
    ----------
    priority : int
        1–99 (higher runs first); 0: nothing changes (yields 0).

    Yields
    ------
    int
        Threads raised.

    Raises
    ------
    ConfigError
        The kernel refused (no ``CAP_SYS_NICE`` / ``RLIMIT_RTPRIO``, or no such scheduling
        class here); the message names the key and the fixes. Nothing stays raised.
    """
    if priority <= 0:
        yield 0
        return
    previous: dict[int, tuple[int, Any]] = {}
    try:
        policy = os.SCHED_FIFO | os.SCHED_RESET_ON_FORK
        for tid in _thread_ids():
            try:
                before = (os.sched_getscheduler(tid), os.sched_getparam(tid))
                os.sched_setscheduler(tid, policy, os.sched_param(priority))
            except ProcessLookupError:
                continue  # ended meanwhile
            previous[tid] = before
    except (OSError, AttributeError) as exc:
        _restore(previous)
        raise _refusal(priority, getattr(exc, "strerror", None) or "not supported here") from None
    try:
        yield len(previous)
    finally:
        _restore(previous)


def _restore(previous: dict[int, tuple[int, Any]]) -> None:
    for tid, (policy, param) in previous.items():
        try:
            os.sched_setscheduler(tid, policy, param)
        except OSError:
            pass  # ended, or not ours to change back
