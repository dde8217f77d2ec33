"""Benchmarks behind ``rtsid bench NAME``: each prints tables (median, p99, ratios against a
baseline measured in the same run). Tests never time anything; figures come from here.

Each module defines ``add_arguments(parser)`` and ``run(args) -> int``.
"""

# name -> (module, one-line help). Add a benchmark by adding a line here.
BENCHMARKS: dict[str, tuple[str, str]] = {
    "toeplitz": ("rtsid.benchmarks.toeplitz", "EUREKA vs dense inversion vs scipy, n = 100…12800"),
    "window": ("rtsid.benchmarks.window", "IRF + fit + VAF per 300 ms window at 2500 Hz, by stage"),
    "accuracy": ("rtsid.benchmarks.accuracy", "I/B/K error and VAF on the simulated joint"),
    "service": ("rtsid.benchmarks.service", "the daemon end to end: latency, misses, CPU, memory"),
    "replay": ("rtsid.benchmarks.replay", "replay speed of a long recording (× real time)"),
    "real": ("rtsid.benchmarks.real", "windowed estimates over the real ankle recording"),
    "skirt": ("rtsid.benchmarks.skirt", "LTV skirt decomposition study: VAF, resonance RMSE, time"),
    "io": ("rtsid.benchmarks.io", "MCAP logger cost at daemon rates and zenoh one-way latency"),
    "link": ("rtsid.benchmarks.link", "2500 Hz CAN acquisition: loss, latency, CPU, highest rate"),
    "tv": ("rtsid.benchmarks.tv", "K(t) tracker vs windows vs skirt: bias, error, rise, VAF"),
    "calibrate": ("rtsid.benchmarks.calibrate", "robot calibration vs the source's method"),
    "cascade": (
        "rtsid.benchmarks.cascade",
        "intrinsic vs reflex: cascade, slow lane, known reflex",
    ),
    "lab": ("rtsid.benchmarks.lab", "router + 4 daemons + subscriber: e2e, rates, queries, CPU"),
    "inputs": ("rtsid.benchmarks.inputs", "peak memory of rtsid convert on hostile, large inputs"),
    "markers": (
        "rtsid.benchmarks.markers",
        "rtsid mark latency to a daemon, then kill -9: all kept",
    ),
}
