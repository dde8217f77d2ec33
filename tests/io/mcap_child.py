"""Child process for the SIGKILL test: logs 100 ms sample batches in real time and prints the
end index of each batch once ``log_samples`` returned (i.e. what the caller handed over).

Usage: python mcap_child.py DIRECTORY FLUSH_INTERVAL_S
"""

from __future__ import annotations

import sys
import time

import numpy as np

from rtsid.io.mcap_log import McapConfig, McapLogger

FS_HZ = 2500.0
BATCH = 250


def main(directory: str, flush_interval_s: float) -> None:
    cfg = McapConfig(directory=directory, flush_interval_s=flush_interval_s)
    with McapLogger(cfg, robot="kill", joint="ankle", fs_hz=FS_HZ) as logger:
        print("file", flush=True)
        deadline = time.monotonic()
        for k in range(10_000):  # bounded: the parent kills us long before
            idx = np.arange(k * BATCH, (k + 1) * BATCH)
            logger.log_samples(k * BATCH, np.sin(idx / 100.0), np.cos(idx / 100.0))
            print("end", (k + 1) * BATCH, flush=True)
            deadline += BATCH / FS_HZ
            time.sleep(max(0.0, deadline - time.monotonic()))


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
