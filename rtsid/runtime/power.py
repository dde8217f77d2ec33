"""Keep idle CPUs responsive while the daemon runs: a Linux PM QoS CPU latency request.

A thread that sleeps (the window worker between hops, the acquisition thread between frames,
a subscriber waiting for the next estimate) is woken on a core that may have gone into a deep
idle state — or, in a virtual machine, been handed back to the hypervisor. Leaving that state
costs from tens of microseconds to milliseconds, and it lands on every hop's latency tail.
Writing a latency bound to ``/dev/cpu_dma_latency`` and holding the file open asks the kernel
to use only idle states that wake faster than the bound (0: poll); the request ends when the
file is closed, including when the process is killed. This is what ``cyclictest`` and other
real-time Linux tools do; it costs power, so it is opt-in (``[daemon] cpu_latency_us``).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from contextlib import contextmanager

from rtsid.errors import ConfigError

__all__ = ["PM_QOS_DEVICE", "cpu_latency_request"]

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
