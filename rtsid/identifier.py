"""The Python API: samples in, the daemon's estimates out — the same numbers as
``rtsid identify``, ``rtsid replay`` and a live run.

:class:`Identifier` is the live daemon's window path (:class:`rtsid.runtime.worker.
WindowEvaluator`: one analysis plan, held I and B, the K(t) tracker, the slow lane's reflex
model) fed by the caller instead of a CAN bus: push samples as they arrive and take the
windows they complete. :func:`identify` runs it over a whole record. Both return
:class:`rtsid.io.messages.EstimateMessage` objects, the message the daemon publishes, so a
script reads the same fields (``K_track``, ``K``, ``vaf``, ``ok``, ``reason``, ``I_held`` …)
as the CSV, the MCAP recording and zenoh.

>>> import numpy as np, rtsid
>>> from rtsid.sim.reflex import prbs_ankle_with_reflex
>>> from rtsid.sim import JointParameters
>>> theta, tau = prbs_ankle_with_reflex(6.0, 2500.0, JointParameters(0.015, 0.8, 150.0), None)
>>> windows = rtsid.identify(theta, tau, fs_hz=2500.0)
>>> ok = [w for w in windows if w.ok]
>>> round(float(np.median([w.K for w in ok])) / 10) * 10
150
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rtsid.config import load_toml
from rtsid.errors import InputDataError, TorqueSignError, invalid
from rtsid.io.messages import EstimateMessage
from rtsid.io.schemas import SampleBatch
from rtsid.replay import ReplayedSlowLane, WindowCutter, recorded_evaluator
from rtsid.runtime.daemon import DaemonConfig

__all__ = ["Identifier", "analysis_config", "config_table", "identify", "record_windows"]

#: ``rtsid identify``'s hop (the daemon's is ``[worker] hop_s``, 20 ms).
OFFLINE_HOP_S = 0.1


def analysis_config(
    fs_hz: float,
    config: DaemonConfig | Mapping[str, Any] | str | Path | None = None,
    *,
    window_s: float | None = None,
    hop_s: float | None = None,
    **estimator: Any,
) -> DaemonConfig:
    """The daemon configuration an offline analysis at ``fs_hz`` runs with.

    Parameters
    ----------
    fs_hz : float
        Sampling rate of the samples, Hz.
    config : DaemonConfig, mapping, or path to a TOML file, optional
        Settings as ``rtsid run`` takes them (``[estimator]``, ``[worker]``, ``[slow_lane]``,
        ``[tracker]``); default: the daemon's defaults with a hop of 0.1 s.
    window_s, hop_s : float, optional
        Override ``[worker] window_s`` and ``hop_s``, s.
    **estimator
        Override ``[estimator]`` keys (e.g. ``torque_sign=-1``).
    """
    if isinstance(config, DaemonConfig):
        document = config.as_dict()
    elif isinstance(config, str | Path):
        document = load_toml(config)
    else:
        document = {k: dict(v) if isinstance(v, Mapping) else v for k, v in (config or {}).items()}
    worker = config_table(document, "worker")
    worker.setdefault("hop_s", OFFLINE_HOP_S)
    if window_s is not None:
        worker["window_s"] = window_s
    if hop_s is not None:
        worker["hop_s"] = hop_s
    config_table(document, "estimator").update(estimator)
    link = config_table(document, "link")
    link["fs_hz"] = float(fs_hz)
    config_table(document, "plant")["fs_hz"] = float(fs_hz)
    _ring_for_the_analysis(link, worker, config_table(document, "slow_lane"))
    return DaemonConfig.from_mapping(document)


def _ring_for_the_analysis(
    link: dict[str, Any], worker: dict[str, Any], lane: dict[str, Any]
) -> None:
    """Lengthen ``[link] ring_capacity_s`` to hold a window and the slow lane's horizon with an
    update (an offline analysis has no ring to size; values that are not numbers are left to
    the config's own checks, which name them)."""
    values = (
        lane.get("horizon_s", 20.0),
        lane.get("update_s", 2.0),
        worker.get("window_s", 0.3),
        worker.get("hop_s", OFFLINE_HOP_S),
        link.get("ring_capacity_s", 30.0),
    )
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        horizon, update, window, hop, ring = (float(v) for v in values)
        link["ring_capacity_s"] = max(ring, horizon + update + 1.0, window + hop + 1.0)


def config_table(document: dict[str, Any], name: str) -> dict[str, Any]:
    """Section ``name`` of a config document (created empty), refused unless a table."""
    section = document.setdefault(name, {})
    if not isinstance(section, dict):
        raise invalid(name, section, "a table ([" + name + "] in TOML)")
    return section


class Identifier:
    """Estimate a stream's windows as its samples arrive, exactly as the daemon does.

    Parameters
    ----------
    fs_hz : float
        Sampling rate, Hz.
    config : DaemonConfig, mapping, or path to a TOML file, optional
        See :func:`analysis_config` (which also takes ``window_s``, ``hop_s`` and
        ``[estimator]`` overrides as keywords here).

    Notes
    -----
    Windows end on the daemon's grid (every hop, counted from the first sample pushed), are
    estimated with one analysis plan (planned from the first estimable window), hold I and B
    at the median of the stream's own full fits over ``hold_horizon_s`` once five windows
    have been fitted, and have the slow lane's reflex torque subtracted while it judges a
    reflex present. A window that must not be estimated comes back with ``ok`` false and
    its ``reason``; nothing is dropped.

    Examples
    --------
    >>> ident = Identifier(2500.0, torque_sign=-1)            # doctest: +SKIP
    >>> for chunk_pos, chunk_tau in chunks:                   # doctest: +SKIP
    ...     for window in ident.push(chunk_pos, chunk_tau):
    ...         print(window.t_end_s, window.K_track, window.vaf)
    """

    def __init__(
        self,
        fs_hz: float,
        config: DaemonConfig | Mapping[str, Any] | str | Path | None = None,
        **overrides: Any,
    ) -> None:
        self.config = analysis_config(fs_hz, config, **overrides)
        self.fs_hz = self.config.link.fs_hz
        self._messages: list[dict[str, Any]] = []
        #: The slow lane's fits so far (``/reflex`` messages: the decision and its evidence).
        self.reflex: list[dict[str, Any]] = []
        self.evaluator = recorded_evaluator(self.config, self._messages.append)
        lane = (
            ReplayedSlowLane(self.evaluator, self.reflex.append) if self.evaluator.reflex else None
        )
        self._cutter = WindowCutter(self.evaluator, lane)
        self._next_index = 0
        self._refused: TorqueSignError | None = None

    @property
    def plan(self) -> str | None:
        """The analysis plan, described (None before the first estimable window)."""
        plan = self.evaluator.stream.plan
        return None if plan is None else plan.describe()

    def push(
        self, position_rad: ArrayLike, torque_nm: ArrayLike, valid: ArrayLike | None = None
    ) -> list[EstimateMessage]:
        """Add samples; return the windows they complete, oldest first.

        Parameters
        ----------
        position_rad, torque_nm : array_like, shape (n,)
            The next samples (rad, N·m as the rig reports it: ``torque_sign`` applies).
        valid : array_like of bool, shape (n,), optional
            False for lost samples (their values are ignored; windows bridge a few, as live).

        Raises
        ------
        TorqueSignError
            Most windows read K, B, I < 0: the stream stops there, and every later push
            raises the same error (make a new Identifier with the opposite ``torque_sign``).
        """
        if self._refused is not None:
            raise self._refused  # the stream stopped there; a new Identifier starts afresh
        batch = self._batch(position_rad, torque_nm, valid)
        if len(batch) == 0:
            return []
        try:
            for snap in self._cutter.add(batch):
                self.evaluator.evaluate(snap)
        except TorqueSignError as exc:
            self._refused = exc
            raise
        out = [as_message(m) for m in self._messages]
        self._messages.clear()
        return out

    def _batch(
        self, position: ArrayLike, torque: ArrayLike, valid: ArrayLike | None
    ) -> SampleBatch:
        pos = np.array(position, dtype=np.float64, ndmin=1)
        tor = np.array(torque, dtype=np.float64, ndmin=1)
        if pos.ndim != 1 or pos.shape != tor.shape:
            raise InputDataError(
                f"position and torque must be 1-D and equally long, got {pos.shape} and {tor.shape}"
            )
        ok = np.isfinite(pos) & np.isfinite(tor)
        if valid is not None:
            mask = np.asarray(valid, dtype=bool)
            if mask.shape != pos.shape:
                raise InputDataError(f"valid has shape {mask.shape}, the samples {pos.shape}")
            ok &= mask
        first = self._next_index
        self._next_index += pos.size
        status = np.zeros(pos.size, dtype=np.uint8)
        return SampleBatch(first, self.fs_hz, pos, tor, ok, status)


def identify(
    position_rad: ArrayLike,
    torque_nm: ArrayLike,
    fs_hz: float,
    config: DaemonConfig | Mapping[str, Any] | str | Path | None = None,
    *,
    valid: ArrayLike | None = None,
    **overrides: Any,
) -> list[EstimateMessage]:
    """Every window of a whole record: :class:`Identifier` with all samples pushed at once
    (what ``rtsid identify FILE`` writes). NaN or infinite samples count as lost.

    Raises
    ------
    InputDataError
        The record is shorter than one window (or position and torque differ in shape).
    TorqueSignError
        Most windows read K, B, I < 0: pass the opposite ``torque_sign``.
    """
    return record_windows(Identifier(fs_hz, config, **overrides), position_rad, torque_nm, valid)


def record_windows(
    ident: Identifier,
    position_rad: ArrayLike,
    torque_nm: ArrayLike,
    valid: ArrayLike | None = None,
) -> list[EstimateMessage]:
    """The windows of a whole record pushed into a fresh ``ident`` (see :func:`identify`)."""
    windows = ident.push(position_rad, torque_nm, valid)
    if not windows:
        worker = ident.config.worker
        n = np.size(position_rad)
        raise InputDataError(
            f"the record has {n} samples ({n / ident.fs_hz:g} s), shorter than one "
            f"{worker.window_s:g} s window; use a shorter window (--window)"
        )
    return windows


def as_message(message: Mapping[str, Any]) -> EstimateMessage:
    """An estimate message dict (as published) as the typed :class:`EstimateMessage`."""
    fields = {f.name for f in dataclasses.fields(EstimateMessage)}
    values = {k: v for k, v in message.items() if k in fields}
    values["flags"] = tuple(values.get("flags", ()))
    return EstimateMessage(**values)
