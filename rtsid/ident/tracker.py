"""Causal tracking of K(t) (and B(t)) over the window estimates: two Kalman filters and a
change mode per parameter.

The window estimates of a stream arrive every hop ``h``; each is the stiffness of the last
``w`` seconds, with its own standard error. :class:`ParameterTracker` turns them into a
causal track of the parameter *now* (at the window's last sample, the instant the estimate
is published and the instant ``rtsid bench tv`` scores every method at) with a standard
error. Measured against the windowed estimates it filters: ``rtsid bench tv`` and
``docs/identification.md``.

A single random walk cannot serve a steady stiffness (which wants seconds of averaging),
a sinusoid (which wants a trend, extrapolated over the half window the windows lag) and a
step (which no smoothing model follows). So the tracker runs two filters and a change mode.

The two filters
---------------
Both have the state ``x = (p, ṗ)``: the parameter at the newest window's end and its rate.
``p`` is a random walk of density ``level_noise``; ``ṗ`` an Ornstein–Uhlenbeck process with
time constant ``rate_time_constant_s`` driven by ``rate_noise`` (the exact discretisation
over the time since the last window is :func:`transition`, so skipped windows cost nothing
special). A window estimates the parameter averaged over the window — for a linear trend
its value at the window's centre, ``w/2`` before its end: ``z = p − (w/2)·ṗ + e``.

* the **quiet** filter has no rate (``ṗ ≡ 0``): an exponentially forgetting average of the
  windows over a horizon of about ``σ/level_noise`` (seconds, ``σ`` the windows' noise);
* the **trend** filter has the rate: it follows a sinusoid and removes the windows' lag.

Consecutive windows share ``(w − h)/w`` of their samples, so their errors are correlated
(measured autocorrelation: close to the triangle ``1 − k·h/w``, summing to ``n = w/h`` =
14.4–14.6 for 300 ms / 20 ms). The quiet filter takes each window with its variance
inflated by ``n`` (an effective-sample-size correction: over horizons longer than a window
it gathers exactly the information the data hold); the trend filter by ``n/2``, so that its
rate sees the last few windows.

Which filter is published: a Page CUSUM of the two filters' log-likelihood ratio,
``D ← max(0, λ·D + ℓ_trend − ℓ_quiet)`` with ``λ = exp(−h / 1 s)``, both innovations scored
with the same inflated measurement variance (so the trend filter earns the switch by
predicting better, not by claiming a narrower noise). Above ``switch_threshold`` the trend
filter is published and the quiet filter is reset to its level (so on the way back the
quiet filter starts where the trend left, not a lag behind).

The fast filter over each window's newest hop
---------------------------------------------
(K only, with the window's samples.) The windows' filters cannot follow 1–2 Hz: a 300 ms
window sees a 2 Hz sine at half its amplitude, half a window late. Each window's newest hop
(:meth:`rtsid.ident.split.SplitProblem.newest`: K of the last hop's rows, the rest of the
window with its own K) shares no samples with the previous window's, so a third filter —
level and a rate driven by ``stiffness_acceleration_noise`` — takes the hops as independent
measurements, each at its rows' centre, with its relative variance times a scale learned
from the hops' second differences (variance ``6σ²`` for independent hops). It is published
when a CUSUM of its Student-t (:data:`FAST_DF`) log-likelihood ratio against the published
quiet/trend filter, both predicting the same hop and scored with the fast filter's
predictive variance (it must predict better), stays above ``switch_threshold`` for
:data:`FAST_CONFIRM_HOPS` hops, after :data:`FAST_WARM_UP` windows' worth of hops. The split
reads below compare with the quiet/trend level, never the fast one, and restart the fast
filter where they end.

The change mode read from the samples
-------------------------------------
When the stream hands the tracker its window's samples (:mod:`rtsid.ident.split`: every
split of the window's K into a value before and a value after, with its significance), a
step is read from the samples after it instead of from the windows' ramp. A window whose
estimate departs from the trend filter's prediction by more than :data:`SPLIT_PREGATE`
calm standard errors (or whose ``K_se`` swells past 1.25× the calm one) has its splits
scanned; the most significant split beyond ``split_gate`` is a candidate when it is a
plausible step (after a warm-up of two windows' worth, ``K_after`` at least ``split_gate``
calm standard errors from the published value and within a factor :data:`SPLIT_MAX_RATIO`
of it, and ``K_before``, the part before the split, still the published value within
:data:`SPLIT_BEFORE_SHARE` of the step). Two windows at least :data:`SPLIT_CONFIRM_S`
apart must find the same change (instants within a hop, the same side of the published
value): on the shared human recording single windows find "steps" of −60 or +420 N·m/rad
over a few samples (reflex or torque bursts), which a later window does not confirm, and
windows 10 ms apart confirmed a read of 1200 N·m/rad whose part before the split was not
the tracked value either. Until the windows are past the change, the tracker publishes
``K_after`` of the change's split (re-located each window), with its standard error from
the calm windows' scaled by the information after the split; a change whose own split
fades below :data:`SPLIT_FADE` of the gate in a later window was a false alarm. Then both
filters restart from the window.

With the samples available the ramp read below is not used: a window beyond
``change_gate`` that no confirmed split explains is held out once as an outlier (on the
human recording single windows read 20 N·m/rad between 106 and 93); a second one the same
way restarts both filters at the window (so the track is never further out than the
windows; the ramp read multiplies a window's departure by up to ``1/κ²`` and on the human
recording published −317 and +426 N·m/rad where the windows said 25–190).

The change mode read from the windows' ramp
-------------------------------------------
(For estimates without their samples: a recording's estimates fed to
:class:`ParameterTracker` directly, or windows with lost samples.) After a step the
windows do not jump; they ramp over one window length, each reading the old
level on the part of the window before the step and the new one after it. The trend filter's
innovation, in units of the windows' steady spread ``σ_ref`` (an average of calm windows'
``K_se``: the straddling windows' own standard errors balloon with the misfit), crosses
``change_gate`` within one to three hops of a step. The change started ``j`` hops ago,
``j`` counted back over the preceding innovations of the same sign beyond one ``σ_ref``.
From then on, until the windows are past the change (``m − 1`` hops, ``m = round(w/h)``),
the published value is the old level plus the windows' departure from it divided by the
fraction of the window past the change, with a shrinkage::

    F = j/(m − 1),   K = K_old + G·(z − K_old),   G = F / (F² + κ²·F·(1 − F))

``κ = change_spread``: the fraction of the window's information past the change is not
``F`` but varies with the perturbation's energy in each hop (measured on simulated ankles:
standard deviation 0.08–0.17 of ``F``, ≈ ``0.3·√(F(1 − F))``); ``G`` is then the least-
squares gain of ``K_new − K_old`` from that one window (the gains fitted to the true steps
in ``rtsid bench tv`` are within 10–20 % of it). When the windows are past the change both
filters restart from the newest window. A departure that reverses sign ends the change mode
(a false alarm). The band in the change mode adds that multiplicative uncertainty.

Window standard errors and a learned scale
------------------------------------------
``σ`` is the window's own ``K_se`` times a scale ``s`` learned from the estimates' own
scatter (the sandwich standard error of a window can understate it, measured by 10–40 %):
second differences of consecutive windows remove a linear trend, and for triangular-
correlated errors their variance is ``4σ²/n``, so ``n·(Δ²z)²/(4σ²)`` has mean ``s²``. It is
averaged over ``scale_horizon_s`` with each term capped at ``9·s²``, and not at all during a
change mode and one window after it (the ramp's second differences are signal).

A withheld window (no estimate, a low-VAF estimate, a non-finite or missing standard error)
advances the prediction and widens the band; it never invents a measurement (in a change
mode it holds the change's estimate, and the change mode still ends a window after the
change).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

from rtsid.errors import invalid, require_range
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.records import built
from rtsid.ident.split import NewestPart, SplitScan

_eureka: Any = compiled_kernel()

#: Memory of the filters' likelihood-ratio CUSUM, s.
SWITCH_MEMORY_S = 1.0
#: The trend filter counts overlapping windows as this fraction of ``w/h`` independent ones.
TREND_OVERLAP = 0.5
#: Each term of the learned scale is capped at this many times the current scale².
SCALE_CAP = 9.0
#: Preceding innovations beyond this many ``σ_ref`` (same sign) belong to a detected change.
CHANGE_ONSET = 1.0
#: A window's splits are scanned only when it departs from the trend filter's prediction by
#: more than this many ``σ_ref`` (or during a change read from the samples): a step that a
#: split reveals beyond ``split_gate`` moves the window's own estimate too.
SPLIT_PREGATE = 2.0
#: ... or when its own ``K_se`` swells past this many calm ones (a straddling window's does).
SPLIT_SE_SWELL = 1.25
#: A change read from the samples whose own split falls below this fraction of
#: ``split_gate`` in a later window (more samples after it) was a false alarm.
SPLIT_FADE = 0.5

#: A change read from the samples is confirmed by a window at least this much later (the
#: next one at a 20 ms hop; windows 10 ms apart share 97 % of their samples).
SPLIT_CONFIRM_S = 0.02

#: A change read from a part of a window's samples is at most this factor of the published
#: value (a larger one, within a hop, is left for the windows to show).
SPLIT_MAX_RATIO = 4.0
#: ... and the part before the split still reads the published value, to this share of the
#: step (steps in the simulated ankles: within 7 %; the human recording's false reads: 30 %
#: and more).
SPLIT_BEFORE_SHARE = 0.25

#: Splits start no change mode before this many windows' worth of measurements (the calm
#: windows' standard error and its learned scale are not known yet).
SPLIT_WARM_UP = 2

#: A hop's log-likelihood ratio between the fast filter and the published one is clipped to
#: this many nats (one wild hop, a reflex burst on the human recording, does not switch).
FAST_LLR_CAP = 2.0
#: Newest-hop reads are weighed as Student t with this many degrees of freedom (on the
#: human recording their tails are far heavier than a normal's: p1/p99 at ±7 IQR).
FAST_DF = 4.0
#: The fast filter is published once its CUSUM is above ``switch_threshold`` for this many
#: hops in a row (a single hop's false alarm on a constant K cost 25 N·m/rad).
FAST_CONFIRM_HOPS = 2
#: The fast filter is not published before its hops' variance scale was learned from this
#: many windows' worth of hops.
FAST_WARM_UP = 2

#: The window's splits of K, computed on demand (:func:`rtsid.ident.split.split_scan`).
SplitSource = Callable[[], "SplitScan | None"]

__all__ = ["ParameterTracker", "TrackEstimate", "TrackerOptions", "transition"]


@dataclass(frozen=True)
class TrackerOptions:
    """The ``[tracker]`` config section: the K(t)/B(t) tracker over the window estimates.

    Attributes
    ----------
    enabled : bool
        Publish ``K_track``/``B_track`` with every estimate message (false: null).
    stiffness_noise : float
        Random walk of K, N·m/rad per √s (both filters).
    stiffness_rate_noise : float
        Random walk of dK/dt in the trend filter, N·m/rad/s per √s.
    damping_noise : float
        Random walk of B, N·m·s/rad per √s (B is tracked only while it is fitted per window,
        i.e. ``estimator.hold`` is not ``"inertia_damping"``).
    damping_rate_noise : float
        Random walk of dB/dt in the trend filter, N·m·s/rad/s per √s.
    rate_time_constant_s : float
        How long a rate persists without evidence, s (the OU time constant of dK/dt).
    switch_threshold : float
        Log-likelihood ratio (nats, CUSUM over about 1 s) at which the trend filter is
        published instead of the quiet one.
    change_gate : float
        A trend-filter innovation beyond this many of the calm windows' standard deviations:
        with the window's samples, that no confirmed split explains, an outlier held out
        once and a restart of the filters at the second such window; without them, a change
        mode read from the windows' ramp.
    split_gate : float
        A split of a window's K (:mod:`rtsid.ident.split`) whose change is beyond this many
        of its standard errors — a plausible step of at least this many calm windows'
        standard errors from the published value, found by two windows 20 ms apart — starts
        a change mode read from the window's own samples.
    change_spread : float
        κ: the spread of the fraction of a window past a change, relative to
        ``√(F(1 − F))`` (the change mode's shrinkage; 0: the plain inverse of the ramp).
    scale_horizon_s : float
        Horizon of the learned scale of the windows' standard errors, s.
    stiffness_acceleration_noise : float
        Random walk of dK/dt in the fast filter over each window's newest hop, N·m/rad/s²
        per √s (0: no fast filter).
    """

    enabled: bool = True
    stiffness_noise: float = 0.3
    stiffness_rate_noise: float = 100.0
    damping_noise: float = 0.003
    damping_rate_noise: float = 1.0
    rate_time_constant_s: float = 5.0
    switch_threshold: float = 5.0
    change_gate: float = 6.0
    split_gate: float = 8.0
    change_spread: float = 0.3
    scale_horizon_s: float = 10.0
    stiffness_acceleration_noise: float = 1000.0

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise invalid("enabled", self.enabled, "true or false")
        for name in ("stiffness_noise", "stiffness_rate_noise", "damping_noise"):
            require_range(name, getattr(self, name), 0.0, 1e6)
        require_range("damping_rate_noise", self.damping_rate_noise, 0.0, 1e6)
        require_range(
            "rate_time_constant_s", self.rate_time_constant_s, 0.0, 600.0, low_inclusive=False
        )
        require_range("switch_threshold", self.switch_threshold, 0.0, 1000.0)
        require_range("change_gate", self.change_gate, 1.0, 100.0)
        require_range("split_gate", self.split_gate, 1.0, 100.0)
        require_range("change_spread", self.change_spread, 0.0, 10.0)
        require_range("scale_horizon_s", self.scale_horizon_s, 0.0, 3600.0, low_inclusive=False)
        require_range("stiffness_acceleration_noise", self.stiffness_acceleration_noise, 0.0, 1e7)


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
        Its rate, unit per s (0 while the quiet filter or a change mode is published).
    updated : bool
        This window's estimate was used (False: prediction only).
    change : bool
        This window started a change mode.
    mode : str
        What was published: ``"quiet"``, ``"trend"``, ``"fast"`` or ``"change"`` (``""``
        before the first measurement).
    """

    value: float
    se: float
    rate: float
    updated: bool
    change: bool
    mode: str = ""


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


#: How the compiled calm step (``tracker_step``) builds its answer: the record, its fields
#: in order and the modes it publishes (quiet, trend, fast).
_RECORD = (TrackEstimate, tuple(f.name for f in fields(TrackEstimate)), "quiet", "trend", "fast")

#: What :meth:`ParameterTracker.step` returns before the first measurement.
_NOT_STARTED = TrackEstimate(math.nan, math.nan, math.nan, False, False)


class _LevelRateFilter:
    """Kalman filter of ``(p, ṗ)`` with the window-centre measurement (plain floats)."""

    def __init__(self, lag_s: float, level_q: float, rate_q: float, tau: float, overlap: float):
        self.lag, self.level_q, self.rate_q, self.tau = lag_s, level_q, rate_q, tau
        self.overlap = overlap
        self.x0 = self.x1 = self.p00 = self.p01 = self.p11 = math.nan
        self._steps: dict[float, tuple[float, ...]] = {}
        # every interval seen -> its transition (what the rounded key gives it, which never
        # changes once given): a window's end times differ by a hop give or take a few ulps,
        # and round(dt, 9) costs ~3 k instructions
        self._by_dt: dict[float, tuple[float, ...]] = {}
        self._last: tuple[float, tuple[float, ...]] = (math.nan, ())  # (dt, its transition)

    def reset(self, level: float, variance: float) -> None:
        """Start at ``level ± √variance`` with no rate (its stationary spread)."""
        self.x0, self.x1 = level, 0.0
        self.p00, self.p01 = variance, 0.0
        self.p11 = self.rate_q * self.rate_q * self.tau / 2.0

    def predict(self, dt: float) -> None:
        if dt <= 0:
            return
        last_dt, steps = self._last
        if dt != last_dt:  # a stream's hops are all alike: the last interval's, usually
            cached = self._by_dt.get(dt)
            if cached is None:
                cached = self._transition(dt)
            self._last = (dt, cached)
            steps = cached
        b, a, q00, q01, q11 = steps
        p00, p01, p11 = self.p00, self.p01, self.p11
        self.x0 += b * self.x1
        self.x1 *= a
        self.p00 = p00 + 2.0 * b * p01 + b * b * p11 + q00
        self.p01 = a * (p01 + b * p11) + q01
        self.p11 = a * a * p11 + q11

    def _transition(self, dt: float) -> tuple[float, ...]:
        """The transition over ``dt`` s: one per interval rounded to 1 ns (the first such
        interval's; the first 64 kept), remembered for ``dt`` itself."""
        key = round(dt, 9)
        cached = self._steps.get(key)
        if cached is None:
            cached = transition(dt, self.tau, self.level_q, self.rate_q)
            if len(self._steps) < 64:
                self._steps[key] = cached
        if len(self._by_dt) >= 4096:  # bounded (a stream with irregular hops)
            self._by_dt.clear()
        self._by_dt[dt] = cached
        return cached

    def predicted_window(self) -> float:
        """The next window's expected estimate (the parameter at its centre)."""
        return self.predicted_at(self.lag)

    def predicted_at(self, back_s: float) -> float:
        """The parameter ``back_s`` before the newest window's end (a linear trend)."""
        return self.x0 - back_s * self.x1

    def predicted_variance(self) -> float:
        """``H·P·Hᵀ``: the variance of :meth:`predicted_window`."""
        c = self.lag
        return self.p00 - 2.0 * c * self.p01 + c * c * self.p11

    def update(self, z: float, sigma2: float) -> tuple[float, float]:
        """Take window ``z`` of variance ``sigma2`` (inflated by :attr:`overlap`); return its
        innovation and the prediction's variance ``H·P·Hᵀ`` (before the update)."""
        c = self.lag
        ph0 = self.p00 - c * self.p01
        ph1 = self.p01 - c * self.p11
        hph = ph0 - c * ph1
        nu = z - (self.x0 - c * self.x1)
        s = hph + self.overlap * sigma2
        g0, g1 = ph0 / s, ph1 / s
        self.x0 += g0 * nu
        self.x1 += g1 * nu
        self.p00 -= g0 * ph0
        self.p01 -= g0 * ph1
        self.p11 -= g1 * ph1
        return nu, hph


class ParameterTracker:
    """Quiet and trend Kalman filters and a change mode over a stream's window estimates
    (see the module notes).

    Parameters
    ----------
    window_s, hop_s : float
        The stream's window length and hop, s.
    level_noise, rate_noise : float
        Process-noise densities of the level (unit per √s) and of the trend filter's rate
        (unit/s per √s).
    options : TrackerOptions
        Time constant, switch threshold, change gate and spread, scale horizon.
    """

    def __init__(
        self,
        window_s: float,
        hop_s: float,
        level_noise: float,
        rate_noise: float,
        options: TrackerOptions,
        acceleration_noise: float = 0.0,
    ) -> None:
        lag = 0.5 * window_s  # the window's centre behind its end
        self.window_s = window_s
        self.overlap = max(1.0, window_s / hop_s)  # windows per window's worth of information
        self.hop_s = hop_s
        hops = round(window_s / hop_s)
        self.ramp_hops = max(1, hops - 1)  # hops until a window is all past a change
        self.end_hops = max(1, hops)  # hops after which the change mode ends
        tau = options.rate_time_constant_s
        self.quiet = _LevelRateFilter(lag, level_noise, 0.0, tau, self.overlap)
        self.trend = _LevelRateFilter(
            lag, level_noise, rate_noise, tau, max(1.0, TREND_OVERLAP * self.overlap)
        )
        # the fast filter over the windows' newest hops (None: none)
        self.fast = None
        if acceleration_noise > 0:
            self.fast = _LevelRateFilter(0.0, level_noise, acceleration_noise, tau, 1.0)
        both = (self.quiet, self.trend)
        self._all = both if self.fast is None else (*both, self.fast)  # every filter, in order
        self.fast_cusum = 0.0
        self.fast_on = False
        self.fast_scale2 = 1.0  # learned scale of the newest hops' variance
        self.fast_scored = 0  # newest hops it was learned from
        self._fast_hops = 0  # consecutive hops with the fast filter's CUSUM above threshold
        self._hop_recent: tuple[tuple[float, float, float], ...] = ()  # (t, K, var) of the last two
        self.switch_threshold = options.switch_threshold
        self.forget = math.exp(-hop_s / SWITCH_MEMORY_S)
        self.gate = options.change_gate
        self.split_gate = options.split_gate
        self.kappa2 = options.change_spread**2
        self.alpha = min(1.0, hop_s / options.scale_horizon_s)
        self.t_s = math.nan
        self.scale2 = 1.0
        self.se_ref = math.nan  # calm windows' standard error
        self.cusum = 0.0
        self.trending = False
        # change mode: hops since the change (0: none), old level, sign, latest estimate
        self.change_hops = 0
        self.k_old = self.change_sign = 0.0
        self.change_value = self.change_se = math.nan
        # change mode read from the windows' samples: the change's instant (s; NaN: none)
        self.split_at = self.split_value = self.split_se = math.nan
        #: In a change mode read from the windows' samples (``split_at`` not NaN).
        self.splitting = False
        # a change found by one window, to confirm: (instant, K_after, found at), s and N·m/rad
        self._candidate: tuple[float, float, float] | None = None
        self.updates = 0  # windows taken as measurements
        self._outlier = 0.0  # the sign of the last window's departure beyond change_gate
        self.calm_after = 0  # windows until the scale learns again
        self._recent: tuple[tuple[float, float, float], ...] = ()  # (t, z, se) of the last two
        # (trend innovation / σ_ref, level before) of the last ramp_hops + 1 windows
        self._history: deque[tuple[float, float]] = deque(maxlen=self.ramp_hops + 1)

    @property
    def started(self) -> bool:
        """A measurement has been taken."""
        return not math.isnan(self.quiet.x0)

    def step(
        self,
        t_s: float,
        z: float | None = None,
        se: float | None = None,
        split: SplitSource | None = None,
        newest: NewestPart | None = None,
    ) -> TrackEstimate:
        """Advance to ``t_s`` (the window's end, s) and take its estimate ``z ± se`` if usable.

        ``z`` None, or a non-finite ``z`` or ``se``, or ``se <= 0``: prediction only.
        ``split``: computes the window's :func:`~rtsid.ident.split.split_scan` (called only
        when the window departs from the prediction, or during a change read from the
        samples), which detects and reads a change from the window's samples (without it
        the change mode reads the window estimates' ramp). ``newest``: the window's newest
        hop's K, the fast filter's measurement.
        """
        if _eureka is not None:  # a calm window in one compiled call (None: not calm)
            calm = _eureka.tracker_step(self, t_s, z, se, newest, split, _RECORD)
            if calm is not None:
                return calm
        usable = (
            z is not None and se is not None and math.isfinite(z) and se > 0 and math.isfinite(se)
        )
        x0 = self.quiet.x0
        if x0 != x0:  # not started (NaN level), as :attr:`started` without the call
            if not usable:
                return _NOT_STARTED
            return self._start(t_s, float(z), float(se))  # type: ignore[arg-type]
        dt = t_s - self.t_s
        if t_s > self.t_s:
            self.t_s = t_s
        for f in self._all:
            f.predict(dt)
        if not usable:
            self._recent = ()
            self._candidate = None
            return self._withheld(dt)
        if newest is not None and self.fast is not None:
            self._take_newest(newest, float(se))  # type: ignore[arg-type]
        return self._update(float(z), float(se), dt, split)  # type: ignore[arg-type]

    # -- the steps -----------------------------------------------------------------------

    def _start(self, t_s: float, z: float, se: float) -> TrackEstimate:
        self.t_s = t_s
        self.se_ref = se
        for f in self._filters():
            f.reset(z, se * se * self.overlap)
        self._recent = ((t_s, z, se),)
        return self._published(True, False)

    def _hops(self, dt: float) -> int:
        return max(1, round(dt / self.hop_s))

    def _withheld(self, dt: float) -> TrackEstimate:
        if self.splitting:
            self.split_se = math.hypot(self.split_se, self.quiet.level_q * math.sqrt(dt))
            if self.t_s - self.window_s < self.split_at:
                return TrackEstimate(self.split_value, self.split_se, 0.0, False, False, "change")
            self._end_split(self.split_value, self.split_se**2)  # the windows are past it
        if self.change_hops:
            self.change_hops += self._hops(dt)
            self.change_se = math.hypot(self.change_se, self.quiet.level_q * math.sqrt(dt))
            if self.change_hops >= self.end_hops:  # past the change: restart at its estimate
                self._end_change(self.change_value, self.change_se**2)
            else:
                return TrackEstimate(self.change_value, self.change_se, 0.0, False, False, "change")
        return self._published(False, False)

    def _update(self, z: float, se: float, dt: float, split: SplitSource | None) -> TrackEstimate:
        self.updates += 1
        self._learn_scale(z, se)
        sigma2 = self.scale2 * se * se
        if self.splitting and self.t_s - self.window_s >= self.split_at:  # past the change
            self._end_split(z, sigma2 * self.overlap)
            return self._published(True, False)
        worth = self.splitting or self._departs(z) or se > SPLIT_SE_SWELL * self.se_ref
        scan = split() if split is not None and worth else None
        if scan is not None:
            read = self._split_update(scan)
            if read is not None:
                return read
        elif self.splitting:  # no samples to read the change from: hold its read
            return self._withheld(dt)
        else:
            self._candidate = None
        if self.change_hops:
            during = self._continue_change(z, sigma2, dt)
            if during is not None:
                return during
        level_before = self._published_level()
        trend = self.trend  # its predicted window: predicted_window() without the call
        u = (z - (trend.x0 - trend.lag * trend.x1)) / math.sqrt(self.scale2 * self.se_ref**2)
        self._history.append((u, level_before))  # the oldest beyond ramp_hops + 1 drops
        if abs(u) > self.gate:
            if split is None:
                return self._start_change(z, sigma2, u)
            return self._depart(z, sigma2, u)
        self._outlier = 0.0
        self.se_ref += 5.0 * self.alpha * (se - self.se_ref)  # calm windows only
        self._select(z, sigma2)
        return self._published(True, False)

    def _select(self, z: float, sigma2: float) -> None:
        """Update both filters and the CUSUM of their likelihood ratio; reset quiet to trend
        while the trend filter is published."""
        common = self.overlap * sigma2
        nu_q, hph_q = self.quiet.update(z, sigma2)
        nu_t, hph_t = self.trend.update(z, sigma2)
        s_q, s_t = hph_q + common, hph_t + common
        llr = 0.5 * (nu_q * nu_q / s_q - nu_t * nu_t / s_t) + 0.5 * math.log(s_q / s_t)
        self.cusum = max(0.0, self.forget * self.cusum + llr)
        self.trending = self.cusum > self.switch_threshold
        if self.trending:
            self.quiet.reset(self.trend.x0, self.trend.p00)

    def _depart(self, z: float, sigma2: float, u: float) -> TrackEstimate:
        """A window beyond ``change_gate`` that no confirmed split explains: held out as an
        outlier, unless the window before departed the same way, then both filters restart
        at it (the track follows the windows, never further out than they are)."""
        sign = 1.0 if u > 0 else -1.0
        if self._outlier != sign:
            self._outlier = sign
            return self._published(False, False)
        self._outlier = 0.0
        self._end_change(z, sigma2 * self.overlap)
        return self._published(True, False)

    def _departs(self, z: float) -> bool:
        """The window departs from the trend filter's prediction by more than
        :data:`SPLIT_PREGATE` calm windows' standard errors (worth scanning its splits)."""
        ref = math.sqrt(self.scale2) * self.se_ref
        trend = self.trend  # predicted_window() without the call
        return abs(z - (trend.x0 - trend.lag * trend.x1)) > SPLIT_PREGATE * ref

    def _split_update(self, split: SplitScan) -> TrackEstimate | None:
        """The change mode read from the window's samples: ``K_after`` of the most
        significant split beyond ``split_gate`` (in a change mode, of the change's own split
        when none is); None: no change mode (the window is a measurement for the filters)."""
        ref = math.sqrt(self.scale2) * self.se_ref  # calm windows' standard error
        row = split.best()
        if row is not None and abs(split.z_ratio[row]) <= self.split_gate * ref:
            row = None
        if self.splitting:
            return self._follow_split(split, row, ref)
        return self._detect_split(split, row, ref)

    def _follow_split(self, split: SplitScan, row: int | None, ref: float) -> TrackEstimate | None:
        """In a change mode: read the significant split, else the change's own; end as a
        false alarm when the change's own split faded with more samples after it."""
        if row is None:
            row = split.row_at(self.t_s - self.split_at)
            if row is None:
                return TrackEstimate(self.split_value, self.split_se, 0.0, False, False, "change")
            if abs(split.z_ratio[row]) < SPLIT_FADE * self.split_gate * ref:
                self.split_at, self.splitting = math.nan, False
                self.calm_after = self.end_hops
                return None
        return self._read(split, row, ref, started=False)

    def _detect_split(self, split: SplitScan, row: int | None, ref: float) -> TrackEstimate | None:
        """Start a change mode when two windows at least :data:`SPLIT_CONFIRM_S` apart find
        the same plausible step."""
        if row is None or not self._plausible_step(split, row, ref):
            self._candidate = None
            return None
        candidate = (self.t_s - float(split.offsets_s[row]), float(split.k_after[row]), self.t_s)
        earlier = self._candidate
        if earlier is None or not self._same_change(earlier, candidate):
            self._candidate = candidate
            return None
        if self.t_s - earlier[2] < SPLIT_CONFIRM_S - 1e-9:
            return None  # the same change, not yet found over enough new samples
        self._candidate = None
        self.change_hops = 0  # a change mode read from the windows' ramp gives way
        return self._read(split, row, ref, started=True)

    def _plausible_step(self, split: SplitScan, row: int, ref: float) -> bool:
        """``row``'s split is a step worth a change mode: after the warm-up, ``K_after`` at
        least ``split_gate`` calm standard errors from the published value and within a
        factor :data:`SPLIT_MAX_RATIO` of it (K's sign kept), and ``K_before`` still the
        published value (within :data:`SPLIT_BEFORE_SHARE` of the step): a step, not a
        window whose two parts both disagree with the track."""
        level = self._published_level()
        k_after, k_before = float(split.k_after[row]), float(split.k_before[row])
        ratio = k_after / level if level != 0.0 else math.inf
        step = abs(k_after - level)
        return (
            self.updates >= SPLIT_WARM_UP * self.end_hops
            and step > self.split_gate * ref
            and 1.0 / SPLIT_MAX_RATIO <= ratio <= SPLIT_MAX_RATIO
            and abs(k_before - level) <= SPLIT_BEFORE_SHARE * step
        )

    def _same_change(
        self, earlier: tuple[float, float, float], later: tuple[float, float, float]
    ) -> bool:
        """Two windows' splits ``(instant, K_after, found at)`` find the same change:
        instants within a hop (at least :data:`SPLIT_CONFIRM_S`), and both on the same side
        of the published value."""
        level = self._published_level()
        return (
            abs(later[0] - earlier[0]) <= max(self.hop_s, SPLIT_CONFIRM_S)
            and (later[1] - level) * (earlier[1] - level) > 0
        )

    def _read(self, split: SplitScan, row: int, ref: float, started: bool) -> TrackEstimate:
        """Publish ``K_after`` of ``row``'s split (the change mode)."""
        self.split_at = self.t_s - float(split.offsets_s[row])
        self.splitting = not math.isnan(self.split_at)
        self.split_value = float(split.k_after[row])
        self.split_se = ref * math.sqrt(float(split.after_var[row]))
        self._history.clear()
        return TrackEstimate(self.split_value, self.split_se, 0.0, True, started, "change")

    def _start_change(self, z: float, sigma2: float, u: float) -> TrackEstimate:
        sign = 1.0 if u > 0 else -1.0
        hops = 1
        history = self._history
        while hops < len(history) and sign * history[-1 - hops][0] > CHANGE_ONSET:
            hops += 1
        hops = min(hops, self.ramp_hops - 1) if self.ramp_hops > 1 else 1
        self.change_hops, self.change_sign = hops, sign
        self.k_old = history[-hops][1]
        self._history.clear()
        if self.change_hops >= self.end_hops:
            self._end_change(z, sigma2 * self.overlap)
            return self._published(True, True)
        self._change_estimate(z, sigma2)
        return TrackEstimate(self.change_value, self.change_se, 0.0, True, True, "change")

    def _continue_change(self, z: float, sigma2: float, dt: float) -> TrackEstimate | None:
        """The change mode's estimate from this window, None if it ended as a false alarm
        (the window is then a measurement for the filters, which only predicted meanwhile)."""
        self.change_hops += self._hops(dt)
        if (z - self.k_old) * self.change_sign < 0:  # the departure reversed: a false alarm
            self.change_hops = 0
            self.calm_after = self.end_hops
            return None
        if self.change_hops >= self.end_hops:
            self._end_change(z, sigma2 * self.overlap)
            return self._published(True, False)
        self._change_estimate(z, sigma2)
        return TrackEstimate(self.change_value, self.change_se, 0.0, True, False, "change")

    def _change_estimate(self, z: float, sigma2: float) -> None:
        f = min(1.0, self.change_hops / self.ramp_hops)
        spread = self.kappa2 * (1.0 - f)
        step = f * (z - self.k_old) / (f * f + spread * f)
        self.change_value = self.k_old + step
        self.change_se = math.sqrt(sigma2 + step * step * spread / (f + spread))

    def _end_split(self, level: float, variance: float) -> None:
        """The windows are past a change read from the samples: all three filters restart
        at ``level`` (the fast filter followed the step only as far as its Student-t
        weights let the hops move it)."""
        self.split_at, self.splitting = math.nan, False
        self._end_change(level, variance)
        if self.fast is not None:
            self.fast.reset(level, variance)
            self.fast_cusum, self.fast_on, self._fast_hops = 0.0, False, 0

    def _take_newest(self, part: NewestPart, se: float) -> None:
        """The fast filter takes the window's newest hop; outside change modes the CUSUM of
        its log-likelihood ratio against the published filter (both predicting the same
        hop, with its variance) chooses whether it is published."""
        fast = self.fast
        assert fast is not None
        fast.lag = part.centre_s
        r = self._learn_hop_scale(part.k, part.var * se * se) * part.var * se * se
        s_f = fast.predicted_variance() + r
        nu_f = part.k - (fast.x0 - fast.lag * fast.x1)  # predicted_window() without the call
        nis = nu_f * nu_f / s_f
        if not self.change_hops and not self.splitting:
            slow = self.trend if self.trending else self.quiet
            nu_s = part.k - (slow.x0 - part.centre_s * slow.x1)  # slow.predicted_at(centre)
            # both scored with the fast filter's variance: it must predict better, not claim
            # a narrower band (the slow filters' P understates their error on a drift). The
            # log densities of a Student t (FAST_DF degrees of freedom, scale² s_f) at the
            # normalised squared innovations, up to a constant: −½·log s_f − ½(ν+1)·log1p(x/ν)
            spread = -0.5 * math.log(s_f)
            half_df = 0.5 * (FAST_DF + 1.0)
            llr = (spread - half_df * math.log1p(nis / FAST_DF)) - (
                spread - half_df * math.log1p(nu_s * nu_s / s_f / FAST_DF)
            )
            llr = min(FAST_LLR_CAP, max(-FAST_LLR_CAP, llr))
            self.fast_cusum = max(0.0, self.forget * self.fast_cusum + llr)
            above = self.fast_cusum > self.switch_threshold
            self._fast_hops = self._fast_hops + 1 if above else 0
            warm = self.fast_scored >= FAST_WARM_UP * self.end_hops
            self.fast_on = warm and self._fast_hops >= FAST_CONFIRM_HOPS
        fast.update(part.k, r + s_f * max(0.0, nis - 1.0) / (FAST_DF + 1.0))  # the t's weight

    def _learn_hop_scale(self, k: float, var: float) -> float:
        """The newest hops' variance scale, learned like the windows' (:meth:`_learn_scale`)
        from consecutive hops' second differences: the hops share no samples, so for a
        locally linear K their variance is ``6σ²``. A mean over the first hops, then
        forgetting over ``scale_horizon_s``; not during a change mode or a window after."""
        t = self.t_s
        recent = self._hop_recent
        if recent and abs((t - recent[-1][0]) - self.hop_s) >= 1e-9 * max(1.0, t):
            recent = ()
        calm = not self.change_hops and not self.splitting and self.calm_after <= 0
        if len(recent) == 2 and calm:
            (_, k0, v0), (_, k1, v1) = recent
            d2 = k - 2.0 * k1 + k0
            u = d2 * d2 / (2.0 * (v0 + v1 + var))
            self.fast_scored += 1
            weight = max(self.alpha, 1.0 / self.fast_scored)  # a mean, then forgetting
            scale2 = self.fast_scale2
            self.fast_scale2 += weight * (min(u, SCALE_CAP * scale2) - scale2)
        self._hop_recent = (*recent[-1:], (t, k, var))
        return self.fast_scale2

    def _filters(self) -> tuple[_LevelRateFilter, ...]:
        return self._all

    def _end_change(self, level: float, variance: float) -> None:
        """The windows are past the change: both filters restart at ``level``."""
        self.change_hops = 0
        self.quiet.reset(level, variance)
        self.trend.reset(level, variance)
        self.cusum, self.trending = 0.0, False
        self.calm_after = self.end_hops
        self._history.clear()

    def _learn_scale(self, z: float, se: float) -> None:
        """Update the learned scale ``s²`` from consecutive windows' second difference."""
        recent = self._recent
        t = self.t_s
        calm = not self.change_hops and not self.splitting and self.calm_after <= 0
        self.calm_after -= 1
        if len(recent) == 2 and abs((t - recent[1][0]) - self.hop_s) < 1e-9 * max(1.0, t):
            if calm:
                (_, z0, s0), (_, z1, s1) = recent
                d2 = z - 2.0 * z1 + z0
                var = (s0 * s0 + s1 * s1 + se * se) / 3.0
                u = self.overlap * d2 * d2 / (4.0 * var)
                self.scale2 += self.alpha * (min(u, SCALE_CAP * self.scale2) - self.scale2)
        elif recent and abs((t - recent[-1][0]) - self.hop_s) >= 1e-9 * max(1.0, t):
            recent = ()
        self._recent = (*recent[-1:], (t, z, se))

    # -- what is published ---------------------------------------------------------------

    def _published_level(self) -> float:
        if self.splitting:
            return self.split_value
        if self.change_hops:
            return self.change_value
        return self.trend.x0 if self.trending else self.quiet.x0  # not the fast filter's

    def _published_filter(self) -> tuple[_LevelRateFilter, str]:
        if self.fast_on and self.fast is not None:
            return self.fast, "fast"
        return (self.trend, "trend") if self.trending else (self.quiet, "quiet")

    def _published(self, updated: bool, change: bool) -> TrackEstimate:
        f, mode = self._published_filter()
        se = math.sqrt(max(f.p00, 0.0))
        return built(
            TrackEstimate, value=f.x0, se=se, rate=f.x1, updated=updated, change=change, mode=mode
        )
