"""The window path at a full-rate plan (2500 Hz analysis, ±50 lags: the virtual plant's plan).

The compiled kernel computes this plan's sums of products several outputs at a time
(``_eureka.c``, "the window path at a full-rate plan"); every output must still be the sum
its one-at-a-time loop gives, and the whole path must equal the numpy reference to 1e-9.
"""

import numpy as np
import pytest

from rtsid.ident import front, fused, split, stream
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.levinson import compiled_kernel, eureka_unchecked
from rtsid.ident.stream import WindowStream, sliding_estimates
from rtsid.ident.tracker import TrackerOptions
from rtsid.ident.window import EstimatorOptions, analyse_window, resolve_plan
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance

FS = 2500.0
FULL_RATE = EstimatorOptions(analysis_fs_hz=FS, lowpass_hz=190.0, lag_s=0.02)
FIELDS = ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit")

pytestmark = pytest.mark.skipif(compiled_kernel() is None, reason="compiled kernel not built")


def _recording(seconds, seed, profile=None):
    """A wide-band perturbation (120 Hz) of a joint whose stiffness may move."""
    theta = filtered_noise(round(seconds * FS), FS, 120.0, peak=0.03, seed=seed)
    tau = simulate_impedance(
        theta, FS, JointParameters(), profile, noise_percent=5.0, seed=seed + 1
    )
    return theta, tau


def _close(got, want, what):
    if np.isnan(want):
        assert np.isnan(got), what
    else:
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12), what


def test_the_plan_is_full_rate_with_fifty_lags():
    theta, _ = _recording(0.3, 1)
    plan = resolve_plan(theta, FS, FULL_RATE)
    assert (plan.analysis_fs_hz, plan.factor, plan.lag) == (FS, 1, 50)


@pytest.mark.parametrize("samples", [750, 757, 741])  # blocks of 8 with 0, 5 and 3 left over
def test_the_front_ends_correlations_are_the_one_lag_at_a_time_sums(samples):
    # phi_uu comes from the blocked loop; the kernel's xcorr sums one lag at a time
    kernel = compiled_kernel()
    theta, tau = _recording(samples / FS, samples)
    options = EstimatorOptions(analysis_fs_hz=FS, lowpass_hz=190.0, lag_s=0.02, ridge=0.0)
    plan = resolve_plan(theta, FS, options)
    u, _, irf = front.front_end(theta, tau, FS, options, plan)
    one_at_a_time = np.empty(2 * plan.lag + 1)
    kernel.xcorr(u, u, 0, 2 * plan.lag, float(u.size), one_at_a_time)
    np.testing.assert_array_equal(irf.phi_uu, one_at_a_time)


def test_the_front_ends_shared_factorisation_solves_as_eureka_does():
    # without sweeps the IRF is one solve with R's stored filters: the kernel's EUREKA's bits
    kernel = compiled_kernel()
    theta, tau = _recording(0.3, 5)
    options = EstimatorOptions(analysis_fs_hz=FS, lowpass_hz=190.0, lag_s=0.02, refine=0)
    plan = resolve_plan(theta, FS, options)
    u, y, irf = front.front_end(theta, tau, FS, options, plan)
    cross = np.empty(2 * plan.lag + 1)
    kernel.xcorr(u, y, -plan.lag, plan.lag, float(u.size), cross)
    np.testing.assert_array_equal(irf.h, eureka_unchecked(irf.phi_uu, cross) * FS)


@pytest.mark.parametrize("samples", [750, 757, 741])
def test_a_full_rate_window_equals_the_numpy_path(samples, monkeypatch):
    theta, tau = _recording(samples / FS, 40 + samples)
    plan = resolve_plan(theta, FS, FULL_RATE)
    got = analyse_window(theta, tau, FS, FULL_RATE, plan)
    estimate = fused.fused_back_end(*got.signals, FULL_RATE, plan, fused.Held(), got.score)
    monkeypatch.setattr(front, "_eureka", None)
    monkeypatch.setattr(fused, "_eureka", None)
    monkeypatch.setattr(stream, "one_call_possible", lambda _: False)  # nor in one call
    want = analyse_window(theta, tau, FS, FULL_RATE, plan)
    scale = np.abs(want.irf.h).max()
    np.testing.assert_allclose(got.irf.h, want.irf.h, rtol=1e-9, atol=1e-9 * scale)
    from rtsid.ident.window import back_end

    reference = back_end(*want.signals, FULL_RATE, plan, score=want.score)
    for name in FIELDS:
        _close(getattr(estimate.estimate, name), getattr(reference, name), name)


def test_a_full_rate_stream_at_a_4_ms_hop_equals_the_numpy_path(monkeypatch):
    theta, tau = _recording(1.2, 7, StiffnessProfile.sinusoid(150.0, 50.0, 1.0))

    def results():
        stream = WindowStream(FS, FULL_RATE, 0.004, window_s=0.3, tracker=TrackerOptions())
        return list(sliding_estimates(theta, tau, FS, 0.3, 0.004, stream=stream))

    compiled = results()
    monkeypatch.setattr(front, "_eureka", None)
    monkeypatch.setattr(fused, "_eureka", None)
    monkeypatch.setattr(stream, "one_call_possible", lambda _: False)  # nor in one call
    monkeypatch.setattr(split, "_eureka", None)
    reference = results()
    assert len(compiled) == len(reference) > 200
    for got, want in zip(compiled, reference, strict=True):
        assert got.reason == want.reason
        assert want.estimate is not None
        for name in FIELDS:
            _close(getattr(got.estimate, name), getattr(want.estimate, name), name)
        assert got.estimate.flags == want.estimate.flags
        for name in ("K", "K_se", "B", "B_se"):
            _close(getattr(got.track, name), getattr(want.track, name), f"track {name}")


@pytest.mark.parametrize("samples", [750, 741])
def test_the_kernels_gram_sweeps_are_the_residual_sweeps(samples):
    # window_irf's sweeps take the gradient as X'y − X'X·h/fs from the correlation sums; the
    # residual over the rows, correlated with every lag, is what that gradient means
    from numpy.lib.stride_tricks import sliding_window_view

    theta, tau = _recording(samples / FS, 60 + samples)
    options = EstimatorOptions(analysis_fs_hz=FS, lowpass_hz=190.0, lag_s=0.02, refine=0)
    plan = resolve_plan(theta, FS, options)
    u, y, irf = front.front_end(theta, tau, FS, options, plan)
    lag = plan.lag
    lagged = sliding_window_view(u, 2 * lag + 1)[:, ::-1]  # row t: u(t − k), k = −L … L
    loading = irf.phi_uu[0] - u @ u / u.size
    h = irf.h
    for _ in range(3):
        error = y[lag:-lag] - lagged @ (h / FS)
        gradient = error @ lagged / error.size - loading * h / FS
        h = h + eureka_unchecked(irf.phi_uu, gradient) * FS
    _, _, swept = front.front_end(theta, tau, FS, FULL_RATE, plan)
    assert FULL_RATE.refine == 3 and FULL_RATE.ridge == options.ridge
    np.testing.assert_allclose(swept.h, h, rtol=0, atol=1e-9 * np.abs(h).max())
    assert not np.array_equal(swept.h, irf.h)  # the sweeps moved the IRF
