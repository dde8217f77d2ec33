"""The stream's full per-window path, and how its cost grows (tables of ``rtsid bench window``).

The path a live worker or a replay runs for every hop: the slow lane's reflex prediction
(:func:`rtsid.ident.reflex_lane.predict_reflex_torque`, over the window and the reflex
pathway's history), the window's estimate (:meth:`rtsid.ident.stream.WindowStream.estimate`:
checks, front end, output-error fit, held parameters, VAFs) and the tracker's step with its
split scan (:meth:`~rtsid.ident.stream.WindowStream.track`). The compiled kernel's figures
and the numpy path's (a child process with ``RTSID_NUMPY_ONLY=1``, same windows) are
measured in the same run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rtsid.benchmarks.table import median_p99
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.levinson import HAVE_COMPILED_KERNEL
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.reflex import ReflexPathway, ReflexStream
from rtsid.ident.reflex_lane import (
    ReflexModels,
    SlowLaneSettings,
    fit_reflex_update,
    predict_reflex_torque,
)
from rtsid.ident.stream import WindowStream
from rtsid.ident.tracker import TrackerOptions
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance
from rtsid.sim.reflex import ReflexParameters, prbs_ankle_with_reflex

__all__ = ["PathCase", "PathTimes", "numpy_path_times", "path_times"]

#: Stages of one hop, timed in turn.
STAGES = ("reflex prediction", "estimate", "tracker + split")


@dataclass(frozen=True)
class PathCase:
    """One configuration of the per-window path."""

    fs_hz: float = 2500.0
    window_s: float = 0.3
    hop_s: float = 0.02
    lag_s: float = 0.02
    seconds: float = 20.0
    reflex: bool = True


@dataclass(frozen=True)
class PathTimes:
    """Seconds per hop of each stage and of the whole path (one entry per timed window)."""

    stages: dict[str, list[float]]
    total: list[float]

    def summary_ms(self) -> dict[str, tuple[float, float]]:
        """Median and p99 per stage and ``"total"``, ms."""
        out = {name: median_p99(v) for name, v in self.stages.items()}
        out["total"] = median_p99(self.total)
        return {k: (m * 1e3, p * 1e3) for k, (m, p) in out.items()}


@lru_cache(maxsize=1)
def reflex_pathway() -> ReflexPathway:
    """A rect reflex pathway fitted by the slow lane on a simulated reflex-rich ankle."""
    fs = 2500.0
    joint = JointParameters(0.015, 0.8, 150.0)
    reflex = ReflexParameters(gain=10.0, delay_s=0.04, corner_hz=3.0, damping_ratio=0.7)
    theta, torque = prbs_ankle_with_reflex(8.0, fs, joint, reflex, seed=1)
    settings = SlowLaneSettings(horizon_s=10.0)
    update = fit_reflex_update(0, 0, theta, torque, None, fs, settings)
    if update.pathway is None:  # pragma: no cover - the simulated reflex is strong
        raise RuntimeError(f"the benchmark's reflex fit failed: {update.error}")
    return update.pathway


def _recording(case: PathCase) -> tuple[np.ndarray, np.ndarray]:
    n = round(case.seconds * case.fs_hz)
    rng = np.random.default_rng(3)
    theta = filtered_noise(n, case.fs_hz, 30.0, peak=0.03, seed=rng)
    profile = StiffnessProfile.sinusoid(150.0, 50.0, 0.2)
    tau = simulate_impedance(
        theta, case.fs_hz, JointParameters(), profile, noise_percent=5.0, seed=rng
    )
    return theta, tau


def path_times(case: PathCase, skip_windows: int = 10) -> PathTimes:
    """Time every hop of a simulated recording through the full per-window path.

    The first ``skip_windows`` hops (the stream's plan, caches) are run but not timed.
    """
    theta, tau = _recording(case)
    fs = case.fs_hz
    n_win, n_hop = round(case.window_s * fs), max(1, round(case.hop_s * fs))
    settings = SlowLaneSettings()
    history = ReflexModels(fs, settings).history_samples if case.reflex else 0
    pathway = reflex_pathway() if case.reflex else None
    stream = WindowStream(
        fs,
        EstimatorOptions(lag_s=case.lag_s),
        n_hop / fs,
        window_s=n_win / fs,
        tracker=TrackerOptions(),
    )
    reflex = ReflexStream()  # carried from hop to hop, as the fast lane's
    stages: dict[str, list[float]] = {name: [] for name in STAGES}
    total: list[float] = []
    for k, end in enumerate(range(n_win + history, theta.size + 1, n_hop)):
        t0 = time.perf_counter()
        predicted = None
        if pathway is not None:
            first = end - n_win - history
            segment = theta[first:end]
            predicted = predict_reflex_torque(
                pathway, segment, None, fs, n_win, settings, first_index=first, stream=reflex
            )
        t1 = time.perf_counter()
        position, torque = theta[end - n_win : end], tau[end - n_win : end]
        if predicted is not None:
            torque = torque - predicted
        try:
            estimate = stream.estimate(position, torque, None, predicted)
        except ArithmeticError:  # pragma: no cover - withheld windows still step the tracker
            estimate = None
        t2 = time.perf_counter()
        stream.track((end - 1) / fs, estimate)
        t3 = time.perf_counter()
        if k < skip_windows:
            continue
        for name, seconds in zip(STAGES, (t1 - t0, t2 - t1, t3 - t2), strict=True):
            stages[name].append(seconds)
        total.append(t3 - t0)
    return PathTimes(stages, total)


def numpy_path_times(cases: list[PathCase]) -> list[PathTimes] | None:
    """:func:`path_times` of ``cases`` in a child process running the numpy path
    (``RTSID_NUMPY_ONLY=1``); None when this process already runs it."""
    if not HAVE_COMPILED_KERNEL:
        return None
    request = json.dumps([case.__dict__ for case in cases])
    env = {**os.environ, "RTSID_NUMPY_ONLY": "1"}
    code = "from rtsid.benchmarks.window_path import _child; _child()"
    done = subprocess.run(
        [sys.executable, "-c", code],
        input=request,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=True,
    )
    return [PathTimes(r["stages"], r["total"]) for r in json.loads(done.stdout)]


def _child() -> None:
    """The numpy child's entry point: cases as JSON on stdin, times as JSON on stdout."""
    cases = [PathCase(**c) for c in json.loads(sys.stdin.read())]
    results = [path_times(case) for case in cases]
    json.dump([{"stages": r.stages, "total": r.total} for r in results], sys.stdout)
