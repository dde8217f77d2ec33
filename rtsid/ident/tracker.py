"""Causal tracking of K(t) (and B(t)) over the window estimates: a Kalman filter per parameter.

The window estimates of a stream arrive every hop ``h``; each is the stiffness of the last
``w`` seconds, with its own standard error. :class:`ParameterTracker` turns them into a
causal track of the parameter *now* (at the window's last sample) with a standard error.

State model (one filter per parameter, plain floats, no allocation per hop)
-------------------------------------------------------------------------
State ``x = (p, ṗ)``: the parameter at the newest window's end and its rate.

* ``p`` is a random walk with density ``level_noise`` (e.g. N·m/rad per √s);
* ``ṗ`` is an Ornstein–Uhlenbeck process: it decays with ``rate_time_constant_s`` and is
  driven by ``rate_noise`` (N·m/rad/s per √s), so across withheld windows the prediction
  stops extrapolating after about that time while its band keeps widening.

The discrete transition and process noise are the exact integrals of that model over the
time since the last window (``dt``), so skipped windows (an overrun, a gap) cost nothing
special: the prediction advances by the time that passed.

Measurement: a window estimates the parameter averaged over the window, which for a
parameter changing linearly in time is its value at the window's centre, ``w/2`` before its
end: ``z = p − (w/2)·ṗ + e``. The filter thus reports the present value, not the value half
a window ago (the windowed estimate's lag).

Overlapping windows
-------------------
Consecutive windows share ``(w − h)/w`` of their samples, so their errors are correlated:
for noise that is white between the hops the correlation at ``k`` hops is ``1 − k·h/w``
(triangular), and its sum over all lags — the number of windows that carry one window's
worth of independent information — is ``n = w/h`` (measured: 14–15.5 for 300 ms / 20 ms).
The filter treats the windows as independent but with their variance inflated by ``n``
(``R = n·σ²``): over any horizon longer than a window it then accumulates exactly the
information the data hold (an effective-sample-size correction). Over shorter horizons it
is conservative (it cannot average correlated windows below one window's error, and says so).

Window standard errors and a learned scale
------------------------------------------
``σ`` is the window's own ``K_se`` times a scale ``s`` learned from the estimates' own
scatter, because the sandwich standard error of a window can understate it (measured: by
10–40 % on simulated ankles). Second differences of consecutive windows remove a linear
trend of the parameter; for triangular-correlated errors their variance is ``4σ²/n``, so
``n·(Δ²z)²/(4σ²)`` has mean ``s²``. An exponential average over ``scale_horizon_s`` with each
term capped at ``change_gate²·s²`` (a step's kinks do not inflate it) learns ``s²``.

Changes
-------
A Gaussian random walk cannot both average a constant stiffness over seconds and follow a
step within a window. When a window's innovation exceeds ``change_gate`` times its *own*
spread (``√(H·P·Hᵀ + σ²)``, not the inflated one), the parameter has changed: the level's
variance is opened by the innovation (``P_pp += ν²``) and that window is taken with its own
variance (no overlap inflation: its difference from the prediction is signal, not shared
noise), so the filter moves to the new level at once and then averages again. Between
changes the same normalised innovations, averaged over one window (``m``), scale the
process noise by ``max(1, m)²`` and divide the overlap inflation by ``max(1, m)``: while the
windows disagree with the prediction more than their noise explains, the filter is faster.
With a constant parameter ``m ≈ 1`` and the filter is the plain one above.

A withheld window (no estimate, a low-VAF estimate, a non-finite or missing standard error)
advances the prediction and widens the band; it never invents a measurement.

How it compares with the windowed estimates and the skirt decomposition (bias, random
error, total error and rise time, the metrics of van de Ruit et al., Annual Reviews in
Control 52, 2021): ``rtsid bench tv`` and ``docs/identification.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rtsid.errors import invalid, require_range

#: Process noise is multiplied by ``max(1, m)**ADAPT_POWER``, ``m`` the recent mean of the
#: normalised innovations (see the module notes).
ADAPT_POWER = 2.0

__all__ = ["ParameterTracker", "TrackEstimate", "TrackerOptions", "transition"]


@dataclass(frozen=True)
class TrackerOptions:
    """The ``[tracker]`` config section: the K(t)/B(t) tracker over the window estimates.

    Attributes
    ----------
    enabled : bool
        Publish ``K_track``/``B_track`` with every estimate message (false: null).
    stiffness_noise : float
        Random walk of K, N·m/rad per √s.
    stiffness_rate_noise : float
        Random walk of dK/dt, N·m/rad/s per √s.
    damping_noise : float
        Random walk of B, N·m·s/rad per √s (B is tracked only while it is fitted per window,
        i.e. ``estimator.hold`` is not ``"inertia_damping"``).
    damping_rate_noise : float
        Random walk of dB/dt, N·m·s/rad/s per √s.
    rate_time_constant_s : float
        How long a rate persists without evidence, s (the OU time constant of dK/dt).
    change_gate : float
        An innovation beyond this many of the window's own standard deviations is a change:
        the filter's band is opened by it (see the module notes).
    scale_horizon_s : float
        Horizon of the learned scale of the windows' standard errors, s.
    """

    enabled: bool = True
    stiffness_noise: float = 0.5
    stiffness_rate_noise: float = 5.0
    damping_noise: float = 0.005
    damping_rate_noise: float = 0.05
    rate_time_constant_s: float = 0.5
    change_gate: float = 4.0
    scale_horizon_s: float = 10.0

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise invalid("enabled", self.enabled, "true or false")
        for name in ("stiffness_noise", "stiffness_rate_noise", "damping_noise"):
            require_range(name, getattr(self, name), 0.0, 1e6)
        require_range("damping_rate_noise", self.damping_rate_noise, 0.0, 1e6)
        require_range(
            "rate_time_constant_s", self.rate_time_constant_s, 0.0, 600.0, low_inclusive=False
        )
        require_range("change_gate", self.change_gate, 1.0, 100.0)
        require_range("scale_horizon_s", self.scale_horizon_s, 0.0, 3600.0, low_inclusive=False)


@dataclass(frozen=True)
class TrackEstimate:
    """The tracked parameter at one window's end.

    Attributes
    ----------
    value : float
        The parameter now (N·m/rad for K), NaN before the first measurement.
    se : float
        Its standard error, NaN before the first measurement.
    rate : float
        Its rate, unit per s.
    updated : bool
        This window's estimate was used (False: prediction only).
    change : bool
        This window's innovation was a change (the band was opened).
    """

    value: float
    se: float
    rate: float
    updated: bool
    change: bool


def transition(dt: float, tau: float, level_q: float, rate_q: float) -> tuple[float, ...]:
    """Exact discretisation of the level + OU-rate model over ``dt`` seconds.

    Returns
    -------
    tuple of float
        ``(b, a, q00, q01, q11)``: ``p ← p + b·ṗ``, ``ṗ ← a·ṗ``, and the process-noise
        covariance (``level_q²·dt`` on the level plus the rate noise's integral).
    """
    decay = math.expm1(-dt / tau)  # e^{−dt/τ} − 1
    decay2 = math.expm1(-2.0 * dt / tau)
    a = 1.0 + decay
    b = -tau * decay
    i_aa = -0.5 * tau * decay2  # ∫ e^{−2s/τ} ds
    i_ab = tau * (b - i_aa)  # ∫ a·b ds
    i_bb = tau * tau * (dt + 2.0 * tau * decay + i_aa)  # ∫ b² ds
    rq2 = rate_q * rate_q
    return b, a, level_q * level_q * dt + rq2 * max(i_bb, 0.0), rq2 * i_ab, rq2 * i_aa


class ParameterTracker:
    """Kalman filter of one parameter over a stream's window estimates (see module notes).

    Parameters
    ----------
    window_s, hop_s : float
        The stream's window length and hop, s.
    level_noise, rate_noise : float
        Process-noise densities of the level (unit per √s) and of its rate (unit/s per √s).
    options : TrackerOptions
        The time constant, the change gate and the scale horizon.
    """

    def __init__(
        self,
        window_s: float,
        hop_s: float,
        level_noise: float,
        rate_noise: float,
        options: TrackerOptions,
    ) -> None:
        self.lag_s = 0.5 * window_s  # the window's centre behind its end
        self.overlap = max(1.0, window_s / hop_s)  # windows per window's worth of information
        self.hop_s = hop_s
        self.level_q, self.rate_q = level_noise, rate_noise
        self.tau = options.rate_time_constant_s
        self.gate2 = options.change_gate**2
        self.alpha = min(1.0, hop_s / options.scale_horizon_s)
        self.t_s = math.nan
        self.x0 = self.x1 = math.nan
        self.p00 = self.p01 = self.p11 = math.nan
        self.scale2 = 1.0
        self.motion = 1.0  # recent mean of ν²/(H·P·Hᵀ + σ²): ≈ 1 while the model holds
        self.beta = min(1.0, hop_s / window_s)
        self.power = ADAPT_POWER
        self._recent: tuple[tuple[float, float, float], ...] = ()  # (t, z, se) of the last two
        self._steps: dict[float, tuple[float, ...]] = {}

    @property
    def started(self) -> bool:
        """A measurement has been taken."""
        return not math.isnan(self.x0)

    def step(self, t_s: float, z: float | None = None, se: float | None = None) -> TrackEstimate:
        """Advance to ``t_s`` (the window's end, s) and take its estimate ``z ± se`` if usable.

        ``z`` None, or a non-finite ``z`` or ``se``, or ``se <= 0``: prediction only.
        """
        usable = z is not None and se is not None and math.isfinite(z) and se > 0
        usable = usable and math.isfinite(se)  # type: ignore[arg-type]
        if not self.started:
            if not usable:
                return TrackEstimate(math.nan, math.nan, math.nan, False, False)
            return self._start(t_s, float(z), float(se))  # type: ignore[arg-type]
        self._predict(t_s)
        if not usable:
            self._recent = ()
            return self._estimate(False, False)
        return self._update(float(z), float(se))  # type: ignore[arg-type]

    def _start(self, t_s: float, z: float, se: float) -> TrackEstimate:
        self.t_s = t_s
        self.x0, self.x1 = z, 0.0
        self.p00 = se * se
        self.p01 = 0.0
        self.p11 = self.rate_q * self.rate_q * self.tau / 2.0  # the rate's stationary variance
        self._recent = ((t_s, z, se),)
        return self._estimate(True, False)

    def _predict(self, t_s: float) -> None:
        dt = t_s - self.t_s
        if dt <= 0:
            return
        key = round(dt, 9)
        steps = self._steps.get(key)
        if steps is None:
            steps = transition(dt, self.tau, self.level_q, self.rate_q)
            if len(self._steps) < 64:
                self._steps[key] = steps
        b, a, q00, q01, q11 = steps
        boost = max(1.0, self.motion) ** self.power
        q00, q01, q11 = q00 * boost, q01 * boost, q11 * boost
        p00, p01, p11 = self.p00, self.p01, self.p11
        self.x0 += b * self.x1
        self.x1 *= a
        self.p00 = p00 + 2.0 * b * p01 + b * b * p11 + q00
        self.p01 = a * (p01 + b * p11) + q01
        self.p11 = a * a * p11 + q11
        self.t_s = t_s

    def _update(self, z: float, se: float) -> TrackEstimate:
        self._learn_scale(z, se)
        c = self.lag_s
        sigma2 = self.scale2 * se * se
        # H = (1, −c): the window measures the parameter at its centre
        ph0 = self.p00 - c * self.p01
        ph1 = self.p01 - c * self.p11
        hph = ph0 - c * ph1
        nu = z - (self.x0 - c * self.x1)
        nis = nu * nu / (hph + sigma2)
        self.motion += self.beta * (min(nis, self.gate2) - self.motion)
        change = nis > self.gate2
        if change:
            self.p00 += nu * nu
            ph0 = self.p00 - c * self.p01
            ph1 = self.p01 - c * self.p11
            hph = ph0 - c * ph1
        inflation = 1.0 if change else 1.0 + (self.overlap - 1.0) / max(1.0, self.motion)
        s = hph + inflation * sigma2
        g0, g1 = ph0 / s, ph1 / s
        self.x0 += g0 * nu
        self.x1 += g1 * nu
        self.p00 -= g0 * ph0
        self.p01 -= g0 * ph1
        self.p11 -= g1 * ph1
        return self._estimate(True, change)

    def _learn_scale(self, z: float, se: float) -> None:
        """Update the learned scale ``s²`` from consecutive windows' second difference."""
        recent = self._recent
        t = self.t_s
        if len(recent) == 2 and abs((t - recent[1][0]) - self.hop_s) < 1e-9 * max(1.0, t):
            (_, z0, s0), (_, z1, s1) = recent
            d2 = z - 2.0 * z1 + z0
            var = (s0 * s0 + s1 * s1 + se * se) / 3.0
            u = self.overlap * d2 * d2 / (4.0 * var)
            self.scale2 += self.alpha * (min(u, self.gate2 * self.scale2) - self.scale2)
        elif recent and abs((t - recent[-1][0]) - self.hop_s) >= 1e-9 * max(1.0, t):
            recent = ()
        self._recent = (*recent[-1:], (t, z, se))

    def _estimate(self, updated: bool, change: bool) -> TrackEstimate:
        return TrackEstimate(self.x0, math.sqrt(max(self.p00, 0.0)), self.x1, updated, change)
