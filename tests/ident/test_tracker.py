"""The K(t)/B(t) tracker: its discretisation, calibration on simulated windows, withheld
windows, determinism and its config validation."""

from __future__ import annotations

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
    scale of K_se make the band honest where K_se alone would be too narrow."""
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
    # and the track is better than a window: it averages them
    assert np.sqrt(np.mean(np.square(track_err))) < 0.7 * np.sqrt(np.mean(np.square(window_err)))


def test_a_withheld_window_advances_the_prediction_and_widens_the_band():
    options = TrackerOptions()
    tracker = ParameterTracker(0.3, 0.02, 0.5, 5.0, options)
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
    assert not tracker.step(122 * 0.02, 300.0, 0.0).updated
    after = tracker.step(123 * 0.02, 150.0, 0.5)
    assert after.updated and after.se < withheld[-1].se


def test_a_step_is_followed_within_a_window():
    tracker = ParameterTracker(0.3, 0.02, 0.5, 5.0, TrackerOptions())
    rng = np.random.default_rng(0)
    for i in range(200):
        tracker.step(i * 0.02, 150.0 + 0.5 * rng.standard_normal(), 0.5)
    # the windows ramp over one window length to the new level (a step seen by 300 ms windows)
    values = []
    for j in range(1, 40):
        window_mean = 150.0 + 150.0 * min(1.0, j / 15)
        values.append(tracker.step((200 + j) * 0.02, window_mean, 0.5).value)
    reached = next(j for j, v in enumerate(values, 1) if v > 150.0 + 0.9 * 150.0)
    assert reached <= 15  # within the window length (15 hops)


def test_the_track_is_deterministic():
    a = [r.track for r in _constant_stiffness_track(5, 4.0)]
    b = [r.track for r in _constant_stiffness_track(5, 4.0)]
    assert a == b


def test_before_the_first_estimate_nothing_is_published():
    tracker = ParameterTracker(0.3, 0.02, 0.5, 5.0, TrackerOptions())
    first = tracker.step(0.0)
    assert math.isnan(first.value) and math.isnan(first.se) and not first.updated


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"stiffness_noise": -1.0}, "stiffness_noise"),
        ({"change_gate": 0.5}, "change_gate"),
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
