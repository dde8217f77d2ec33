"""The K(t)/B(t) tracker: its discretisation, calibration on simulated windows, withheld
windows, determinism and its config validation."""

from __future__ import annotations

import copy
import itertools
import math

import numpy as np
import pytest
from scipy import linalg

from rtsid.errors import ConfigError
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.stream import sliding_estimates
from rtsid.ident.tracker import ParameterTracker, TrackerOptions, transition
from rtsid.runtime.daemon import DaemonConfig
from rtsid.sim import JointParameters, simulate_impedance

FS = 2500.0


def test_transition_is_the_exact_integral_of_the_continuous_model():
    dt, tau, ql, qr = 0.02, 0.5, 0.7, 5.0
    a = np.array([[0.0, 1.0], [0.0, -1.0 / tau]])
    qc = np.diag([ql**2, qr**2])
    # Van Loan: expm([[−A, Qc], [0, Aᵀ]]·dt) holds Φ⁻¹·Q and Φᵀ
    m = linalg.expm(np.block([[-a, qc], [np.zeros((2, 2)), a.T]]) * dt)
    phi = m[2:, 2:].T
    q = phi @ m[:2, 2:]
    b, decay, q00, q01, q11 = transition(dt, tau, ql, qr)
    np.testing.assert_allclose([b, decay], [phi[0, 1], phi[1, 1]], rtol=1e-12)
    np.testing.assert_allclose([q00, q01, q11], [q[0, 0], q[0, 1], q[1, 1]], rtol=1e-9)


def _constant_stiffness_track(seed: int, seconds: float = 40.0):
    rng = np.random.default_rng(seed)
    theta = filtered_noise(round(seconds * FS), FS, 40.0, peak=0.03, seed=rng)
    tau = simulate_impedance(
        theta, FS, JointParameters(0.02, 0.8, 150.0), noise_percent=10.0, seed=rng
    )
    return list(sliding_estimates(theta, tau, FS, 0.3, 0.02))


def test_the_95_percent_band_covers_a_constant_stiffness_about_95_percent_of_the_time():
    """Calibration over overlapping windows (w/h = 15): the overlap inflation and the learned
    scale of K_se make the band honest where K_se alone would be too narrow; the track halves
    the window's error."""
    inside, windows, track_err, window_err = 0, 0, [], []
    for seed in (3, 4):
        results = _constant_stiffness_track(seed)[250:]  # after 5 s of settling
        for r in results:
            assert r.track is not None and r.estimate is not None
            inside += abs(r.track.K - 150.0) < 1.96 * r.track.K_se
            windows += 1
            track_err.append(r.track.K - 150.0)
            window_err.append(r.estimate.K - 150.0)
    coverage = inside / windows
    assert 0.9 <= coverage <= 0.995, coverage
    # the floor for a constant stiffness: at most half the window's total error
    assert np.sqrt(np.mean(np.square(track_err))) < 0.5 * np.sqrt(np.mean(np.square(window_err)))


def _windows_of(profile, seconds: float, noise: float, seed: int, hop: float = 0.02):
    """Synthetic 300 ms window estimates of ``profile``: its mean over each window plus noise
    shared between overlapping windows (each hop's own error, averaged over the window)."""
    rng = np.random.default_rng(seed)
    m = round(0.3 / hop)
    t = np.arange(m, round(seconds / hop)) * hop
    fine = np.arange(0, 0.3, 0.002)
    hop_noise = rng.standard_normal(t.size + m) * noise * np.sqrt(m)
    err = np.convolve(hop_noise, np.ones(m) / m, mode="valid")[: t.size]
    z = np.array([profile(tt - 0.3 + fine).mean() for tt in t]) + err
    return t, z


def _track(t, z, se, options=None):
    options = options or TrackerOptions()
    tracker = ParameterTracker(
        0.3, 0.02, options.stiffness_noise, options.stiffness_rate_noise, options
    )
    return [tracker.step(tt, zz, se) for tt, zz in zip(t, z, strict=True)]


def test_a_slow_sinusoid_is_tracked_by_the_trend_filter_without_the_windows_lag():
    def sine(t):
        return 150.0 + 50.0 * np.sin(2 * np.pi * 0.25 * t)

    t, z = _windows_of(sine, 20.0, 0.7, seed=1)
    out = _track(t, z, 0.6)
    keep = t >= 4.0
    value = np.array([o.value for o in out])
    truth = sine(t)
    track_rms = np.sqrt(np.mean((value - truth)[keep] ** 2))
    window_rms = np.sqrt(np.mean((z - truth)[keep] ** 2))  # mostly the half-window lag
    assert track_rms < 0.7 * window_rms, (track_rms, window_rms)
    modes = [o.mode for o, k in zip(out, keep, strict=True) if k]
    assert modes.count("trend") > 0.8 * len(modes)


def test_a_step_is_followed_within_a_few_hops_and_the_filters_restart_after_the_window():
    def step(t):
        return np.where(t < 4.0, 150.0, 300.0)

    t, z = _windows_of(step, 6.0, 0.5, seed=2)
    out = _track(t, z, 0.5)
    first = int(np.searchsorted(t, 4.0 + 1e-9))  # the first window with data after the step
    changes = [i for i, o in enumerate(out) if o.change]
    assert changes == [first], changes  # one change mode, started by the first window after
    assert all(o.mode == "change" for o in out[first : first + 14])
    values = np.array([o.value for o in out])
    # within 3 hops the track is past 2/3 of the step while the windows are at 1/5; past
    # 80 % within 6 hops
    assert values[first + 2] > 250.0 and z[first + 2] < 190.0
    assert values[first + 5] > 270.0
    assert values[first : first + 15].max() < 330.0  # no large overshoot
    # once the windows are past the step, the quiet filter restarts there and averages
    assert out[first + 14].mode == "quiet"
    assert np.all(np.abs(values[first + 14 :] - 300.0) < 2.0)


def test_a_departure_that_reverses_ends_the_change_mode_as_a_false_alarm():
    tracker = ParameterTracker(0.3, 0.02, 0.3, 100.0, TrackerOptions())
    rng = np.random.default_rng(4)
    for i in range(200):
        tracker.step(i * 0.02, 150.0 + 0.3 * rng.standard_normal(), 0.3)
    spike = tracker.step(200 * 0.02, 165.0, 0.3)  # one outlying window
    assert spike.change and spike.mode == "change"
    back = tracker.step(201 * 0.02, 149.0, 0.3)  # the next one is below the old level
    assert back.mode == "quiet" and abs(back.value - 150.0) < 1.0


def test_a_withheld_window_advances_the_prediction_and_widens_the_band():
    options = TrackerOptions()
    tracker = ParameterTracker(0.3, 0.02, 0.3, 100.0, options)
    for i in range(100):
        tracker.step(i * 0.02, 150.0 + (0.5 if i % 2 else -0.5), 0.5)
    before = tracker.step(100 * 0.02, 150.0, 0.5)
    withheld = [tracker.step((101 + i) * 0.02) for i in range(20)]
    assert all(not w.updated for w in withheld)
    assert all(b.se > a.se for a, b in zip([before, *withheld], withheld, strict=False))
    # no measurement invented: the level moves only by the (decaying) rate's prediction
    assert abs(withheld[-1].value - before.value) <= abs(before.rate) * 0.5 + 1e-9
    # NaN / non-positive standard errors are not measurements either
    assert not tracker.step(121 * 0.02, 300.0, float("nan")).updated
    last = tracker.step(122 * 0.02, 300.0, 0.0)
    assert not last.updated and last.se > withheld[-1].se
    predicted_only = copy.deepcopy(tracker).step(123 * 0.02)
    after = tracker.step(123 * 0.02, 150.0, 0.5)
    assert after.updated and after.se < predicted_only.se


def test_a_withheld_window_in_a_change_mode_holds_its_estimate_until_the_window_has_passed():
    tracker = ParameterTracker(0.3, 0.02, 0.3, 100.0, TrackerOptions())
    for i in range(100):
        tracker.step(i * 0.02, 150.0 + (0.2 if i % 2 else -0.2), 0.3)
    start = tracker.step(100 * 0.02, 160.0, 0.3)  # a step of 150 seen by 1/15 of the window
    assert start.change
    held = [tracker.step((101 + i) * 0.02) for i in range(14)]
    assert all(h.mode == "change" and h.value == start.value for h in held[:13])
    assert all(b.se > a.se for a, b in itertools.pairwise(held[:13]))
    assert held[13].mode == "quiet" and held[13].value == pytest.approx(start.value)


def test_the_track_is_deterministic():
    a = [r.track for r in _constant_stiffness_track(5, 4.0)]
    b = [r.track for r in _constant_stiffness_track(5, 4.0)]
    assert a == b


def test_non_overlapping_windows_restart_at_the_window_after_a_change():
    tracker = ParameterTracker(0.3, 0.3, 0.3, 100.0, TrackerOptions())
    for i in range(20):
        tracker.step(i * 0.3, 150.0 + (0.2 if i % 2 else -0.2), 0.3)
    jump = tracker.step(20 * 0.3, 300.0, 0.3)
    assert jump.change and jump.mode == "quiet" and jump.value == pytest.approx(300.0)


def test_before_the_first_estimate_nothing_is_published():
    tracker = ParameterTracker(0.3, 0.02, 0.5, 5.0, TrackerOptions())
    first = tracker.step(0.0)
    assert math.isnan(first.value) and math.isnan(first.se) and not first.updated


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"stiffness_noise": -1.0}, "stiffness_noise"),
        ({"change_gate": 0.5}, "change_gate"),
        ({"split_gate": 0.0}, "split_gate"),
        ({"stiffness_acceleration_noise": -1.0}, "stiffness_acceleration_noise"),
        ({"switch_threshold": -1.0}, "switch_threshold"),
        ({"change_spread": float("inf")}, "change_spread"),
        ({"rate_time_constant_s": 0.0}, "rate_time_constant_s"),
        ({"enabled": "yes"}, "enabled"),
        ({"stiffness_noise": float("nan")}, "stiffness_noise"),
        ({"process_noise": 1.0}, "process_noise"),
    ],
)
def test_tracker_settings_are_validated_like_the_rest_of_the_config(table, message):
    with pytest.raises(ConfigError, match=message):
        DaemonConfig.from_mapping({"tracker": table})


def test_tracker_off_publishes_nothing():
    results = list(
        sliding_estimates(
            *_signals(2.0),
            FS,
            0.3,
            0.02,
            stream=None,
        )
    )
    assert results[-1].track is not None and math.isfinite(results[-1].track.K)
    from rtsid.ident.stream import WindowStream
    from rtsid.ident.window import EstimatorOptions

    stream = WindowStream(
        FS, EstimatorOptions(), 0.02, window_s=0.3, tracker=TrackerOptions(enabled=False)
    )
    off = list(sliding_estimates(*_signals(2.0), FS, 0.3, 0.02, stream=stream))
    assert all(math.isnan(r.track.K) for r in off if r.track is not None)


def _signals(seconds: float):
    rng = np.random.default_rng(9)
    theta = filtered_noise(round(seconds * FS), FS, 40.0, peak=0.03, seed=rng)
    return theta, simulate_impedance(theta, FS, JointParameters(), noise_percent=5.0, seed=rng)
