import numpy as np
import pytest

from rtsid.errors import InputDataError, NotPositiveDefiniteError
from rtsid.ident.irf import estimate_irf


def test_recovers_a_two_sided_fir_exactly_with_refinement(rng):
    fs, max_lag = 500.0, 6
    h_true = rng.standard_normal(2 * max_lag + 1) * fs  # N·m/rad/s on the lag grid
    u = rng.standard_normal(300)
    y = np.convolve(u, h_true / fs, mode="full")[max_lag : max_lag + u.size]
    plain = estimate_irf(u, y, fs, max_lag)
    refined = estimate_irf(u, y, fs, max_lag, refine=8)
    err_plain = np.max(np.abs(plain.h - h_true)) / np.max(np.abs(h_true))
    err_refined = np.max(np.abs(refined.h - h_true)) / np.max(np.abs(h_true))
    assert err_refined < 1e-6 < err_plain  # the Toeplitz edge bias is removed
    np.testing.assert_allclose(refined.lags_s, np.arange(-6, 7) / fs)
    np.testing.assert_allclose(refined.predict(u)[max_lag:-max_lag], y[max_lag:-max_lag], atol=1e-8)


def test_frequency_response_of_a_pure_delay_and_gain():
    fs = 1000.0
    h = np.zeros(11)
    h[5 + 2] = 3.0 * fs  # gain 3 at lag +2 samples
    u = np.random.default_rng(1).standard_normal(500)
    y = 3.0 * np.r_[0, 0, u[:-2]]
    irf = estimate_irf(u, y, fs, 5, refine=5)
    f = np.array([10.0, 100.0])
    np.testing.assert_allclose(
        irf.frequency_response(f), 3.0 * np.exp(-2j * np.pi * f * 0.002), atol=1e-6
    )


def test_constant_input_is_not_positive_definite():
    with pytest.raises(NotPositiveDefiniteError):
        estimate_irf(np.zeros(100), np.ones(100), 100.0, 3)


def test_lag_span_must_fit(rng):
    with pytest.raises(InputDataError, match="cannot support"):
        estimate_irf(rng.standard_normal(20), rng.standard_normal(20), 100.0, 5)
    with pytest.raises(InputDataError, match="NaN"):
        estimate_irf(np.r_[np.nan, np.ones(99)], np.ones(100), 100.0, 3)
