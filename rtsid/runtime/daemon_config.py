"""The daemon's configuration: one TOML file, one frozen section per part (``rtsid run``'s
``--config``, and the configuration a recording carries in its metadata).

Apart from :mod:`rtsid.runtime.daemon` so that what only reads a configuration — a replay,
above all each spawned process of ``rtsid replay DIR --jobs N`` — does not import the live
machinery (the acquisition thread and python-can, the virtual plant, the zenoh publisher's
session handling): :class:`DaemonConfig` needs each part's settings, not the part.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.config import invalid, load_toml, require_range, section_from_mapping
from rtsid.errors import ConfigError, WindowError
from rtsid.ident.analysis import plan_analysis
from rtsid.ident.reflex_lane import SlowLaneSettings
from rtsid.ident.tracker import TrackerOptions
from rtsid.ident.window import EstimatorOptions
from rtsid.io.calibration import robot_calibration
from rtsid.io.mcap_config import McapConfig
from rtsid.io.session import SessionConfig
from rtsid.io.zenoh_config import ZenohConfig
from rtsid.link.config import LinkConfig, PlantConfig, link_configs_from_mapping
from rtsid.runtime.worker import WorkerConfig

__all__ = ["SECTIONS", "DaemonConfig", "DaemonSettings"]

SECTIONS = (
    "daemon",
    "link",
    "plant",
    "estimator",
    "worker",
    "slow_lane",
    "tracker",
    "mcap",
    "zenoh",
    "session",
)


@dataclass(frozen=True)
class DaemonSettings:
    """The ``[daemon]`` config section.

    Attributes
    ----------
    status_period_s : float
        Period of the status message, s (1–2 Hz is usual).
    sample_batch_s : float
        Samples are forwarded to MCAP (and zenoh) in batches this long, s.
    shutdown_timeout_s : float
        Longest wait for each thread to stop, s.
    gil_switch_interval_s : float
        Python's thread switch interval while the daemon runs, s (CPython's default is
        5 ms, which lets a busy thread delay the window worker by that much; 0.1 ms keeps
        the worker's waits short at a small switching cost).
    cpu_latency_us : int
        Linux PM QoS request held while the daemon runs (``/dev/cpu_dma_latency``): idle
        CPUs only use states that wake within this many µs; 0 keeps them polling, which
        cuts the wake-up tail of every thread on the machine, subscribers included (see
        :mod:`rtsid.runtime.power`). -1: no request (the default; it costs power).
    realtime_priority : int
        0 (the default): normal scheduling. 1–99: the acquisition and window-worker threads
        run in Linux's ``SCHED_FIFO`` class at this priority, ahead of every normal process
        on the machine (needs root, or ``LimitRTPRIO=`` in the systemd unit; see
        :func:`rtsid.runtime.power.set_realtime_priority`).
    """

    status_period_s: float = 0.5
    sample_batch_s: float = 0.1
    shutdown_timeout_s: float = 3.0
    gil_switch_interval_s: float = 0.0001
    cpu_latency_us: int = -1
    realtime_priority: int = 0

    def __post_init__(self) -> None:
        require_range("status_period_s", self.status_period_s, 0.05, 60.0)
        require_range("sample_batch_s", self.sample_batch_s, 0.005, 5.0)
        require_range("shutdown_timeout_s", self.shutdown_timeout_s, 0.1, 60.0)
        require_range("gil_switch_interval_s", self.gil_switch_interval_s, 1e-5, 0.1)
        require_range("cpu_latency_us", self.cpu_latency_us, -1, 1_000_000)
        require_range("realtime_priority", self.realtime_priority, 0, 99)


@dataclass(frozen=True)
class DaemonConfig:
    """The whole configuration of ``rtsid run`` (one TOML file, one section per part)."""

    daemon: DaemonSettings = field(default_factory=DaemonSettings)
    link: LinkConfig = field(default_factory=LinkConfig)
    plant: PlantConfig = field(default_factory=PlantConfig)
    estimator: EstimatorOptions = field(default_factory=EstimatorOptions)
    worker: WorkerConfig = field(default_factory=WorkerConfig)
    slow_lane: SlowLaneSettings = field(default_factory=SlowLaneSettings)
    tracker: TrackerOptions = field(default_factory=TrackerOptions)
    mcap: McapConfig = field(default_factory=McapConfig)
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)
    session: SessionConfig = field(default_factory=SessionConfig)

    def __post_init__(self) -> None:
        """Checks across sections (each section checked its own keys already)."""
        room_s = self.link.ring_capacity_s - self.worker.hop_s
        if self.worker.window_s > room_s:
            raise invalid(
                "worker.window_s",
                self.worker.window_s,
                f"a window that fits the ring with a hop to spare (<= link.ring_capacity_s - "
                f"worker.hop_s = {room_s:g} s); shorten worker.window_s or lengthen "
                "link.ring_capacity_s",
            )
        self._check_analysis_fits_the_window()
        self._check_the_ring_holds_the_slow_lane()
        # a calibration made at another rate is refused when the config loads, before the
        # daemon announces itself and opens the link
        robot_calibration(self.worker.calibration_file, self.link.fs_hz)

    def _check_the_ring_holds_the_slow_lane(self) -> None:
        lane = self.slow_lane
        needed = lane.horizon_s + lane.update_s
        if lane.enabled and self.link.ring_capacity_s < needed:
            raise invalid(
                "link.ring_capacity_s",
                self.link.ring_capacity_s,
                f"a ring that holds the slow lane's horizon and an update (>= slow_lane."
                f"horizon_s + slow_lane.update_s = {needed:g} s); lengthen the ring or shorten "
                "the horizon",
            )

    def _check_analysis_fits_the_window(self) -> None:
        """A window must hold the estimator's lags, filter and stencils, or every window would
        be withheld (as ``too_short``) for a reason the config, not the data, decides."""
        est, fs = self.estimator, self.link.fs_hz
        window = round(self.worker.window_s * fs)
        if est.lag_s >= self.worker.window_s / 4:
            raise invalid(
                "estimator.lag_s",
                est.lag_s,
                f"less than a quarter of worker.window_s = {self.worker.window_s:g} s (the IRF "
                "needs more than 4 lag spans of samples); shorten estimator.lag_s or lengthen "
                "worker.window_s",
            )
        if est.lowpass_hz is None:
            return  # chosen from the data: always below the analysis Nyquist rate
        try:
            plan = plan_analysis(
                np.zeros(window),
                fs,
                lowpass_hz=est.lowpass_hz,
                analysis_fs_hz=est.analysis_fs_hz,
                lag_s=est.lag_s,
                fit_band_hz=est.fit_band_hz,
            )
        except WindowError as exc:
            raise invalid("estimator.lowpass_hz", est.lowpass_hz, str(exc)) from None
        analysed = (window - plan.taps.size) // plan.factor + 1
        if analysed <= max(4 * plan.lag + 1, 16):
            raise invalid(
                "estimator.lowpass_hz",
                est.lowpass_hz,
                f"a cut-off whose {plan.taps.size}-tap filter leaves a {window}-sample window "
                "enough samples for the lags and stencils; raise estimator.lowpass_hz or "
                "lengthen worker.window_s",
            )

    @classmethod
    def from_mapping(
        cls, document: Mapping[str, Any], base_dir: str | Path | None = None
    ) -> DaemonConfig:
        """Validate a parsed TOML document; unknown sections and keys are errors."""
        unknown = sorted(set(document) - set(SECTIONS))
        if unknown:
            raise ConfigError(
                f"unknown config section [{unknown[0]}]; accepted sections: "
                + ", ".join(f"[{s}]" for s in SECTIONS)
            )
        for name in SECTIONS:
            if name in document and not isinstance(document[name], Mapping):
                raise ConfigError(f"config key {name!r} must be a table [{name}]")
        link, plant = link_configs_from_mapping(document, base_dir)
        return cls(
            daemon=section_from_mapping(DaemonSettings, document.get("daemon"), "daemon"),
            link=link,
            plant=plant,
            estimator=section_from_mapping(
                EstimatorOptions, document.get("estimator"), "estimator"
            ),
            worker=WorkerConfig.from_mapping(document.get("worker"), base_dir),
            slow_lane=section_from_mapping(
                SlowLaneSettings, document.get("slow_lane"), "slow_lane"
            ),
            tracker=section_from_mapping(TrackerOptions, document.get("tracker"), "tracker"),
            mcap=McapConfig.from_mapping(document.get("mcap")),
            zenoh=ZenohConfig.from_mapping(document.get("zenoh")),
            session=SessionConfig.from_mapping(document.get("session")),
        )

    @classmethod
    def load(cls, path: str | Path | None) -> DaemonConfig:
        """From a TOML file, or all defaults (embedded virtual plant) when ``path`` is None."""
        if path is None:
            return cls()
        return cls.from_mapping(load_toml(path), Path(path).resolve().parent)

    def as_dict(self) -> dict[str, Any]:
        """Every section as plain data (for MCAP metadata and the ``config`` queryable)."""
        return {name: _plain(getattr(self, name)) for name in SECTIONS}


def _plain(value: Any) -> Any:
    """Dataclasses, mappings and tuples as dicts and lists of plain values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value
