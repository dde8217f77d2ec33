import numpy as np
import pytest

from rtsid.errors import InputDataError
from rtsid.ident.correlation import auto_correlation, cross_correlation, detrend


def brute_cross(u, y, max_lag):
    n = u.size
    return (
        np.array(
            [
                sum(u[t - k] * y[t] for t in range(n) if 0 <= t - k < n)
                for k in range(-max_lag, max_lag + 1)
            ]
        )
        / n
    )


@pytest.mark.parametrize("n,max_lag", [(50, 5), (400, 60), (600, 200)])  # direct and FFT paths
def test_cross_and_auto_correlation_match_the_definition(rng, n, max_lag):
    u, y = rng.standard_normal(n), rng.standard_normal(n)
    np.testing.assert_allclose(
        cross_correlation(u, y, max_lag), brute_cross(u, y, max_lag), atol=1e-12
    )
    np.testing.assert_allclose(
        auto_correlation(u, max_lag), brute_cross(u, u, max_lag)[max_lag:], atol=1e-12
    )


def test_cross_correlation_peaks_at_the_delay(rng):
    u = rng.standard_normal(1000)
    y = np.r_[np.zeros(7), u[:-7]]  # y(t) = u(t-7)
    phi = cross_correlation(u, y, 10)
    assert np.argmax(phi) - 10 == 7


@pytest.mark.parametrize("n", [1, 2, 1_001, 50_000])
def test_detrend_in_its_copy_gives_the_expressions_numbers_bit_for_bit(n):
    x = np.random.default_rng(n).standard_normal(n).cumsum() + 3.0
    t = np.arange(n) - (n - 1) / 2.0
    line = x.sum() / n + ((t @ x) / max(float(t @ t), 1e-300)) * t
    kept = x.copy()
    np.testing.assert_array_equal(detrend(x, "linear"), x - line)
    np.testing.assert_array_equal(detrend(x, "mean"), x - x.sum() / n)
    np.testing.assert_array_equal(x, kept)  # the input is not changed


def test_detrend_kinds():
    t = np.arange(100.0)
    np.testing.assert_allclose(detrend(3 + 0.5 * t), 0, atol=1e-12)
    assert detrend(3 + 0.5 * t, "mean").mean() == pytest.approx(0)
    np.testing.assert_array_equal(detrend(t, "none"), t)
    with pytest.raises(InputDataError, match="detrend kind"):
        detrend(t, "quadratic")


def test_lag_span_longer_than_window_is_refused(rng):
    with pytest.raises(InputDataError, match="lengthen the window"):
        cross_correlation(rng.standard_normal(10), rng.standard_normal(10), 10)


@pytest.mark.parametrize("n", [9, 100, 2001])
@pytest.mark.parametrize("span", ["causal", "two-sided", "all", "one"])
def test_the_compiled_lag_sums_are_the_xcorr_loops_bit_for_bit(rng, n, span):
    from rtsid.ident.levinson import compiled_kernel

    kernel = compiled_kernel()
    if kernel is None:
        pytest.skip("the compiled kernel is not built")
    u, y = rng.standard_normal(n), rng.standard_normal(n)
    first, last = {
        "causal": (0, min(100, n - 1)),
        "two-sided": (-4, 4),
        "all": (-(n - 1), n - 1),
        "one": (3, 3),
    }[span]
    want, got = np.empty(last - first + 1), np.empty(last - first + 1)
    kernel.xcorr(u, y, first, last, 1.0, want)
    kernel.xcorr_lags(u, y, first, last, 1.0, got)
    np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="xcorr_lags: inconsistent sizes"):
        kernel.xcorr_lags(u, y, first, last, 1.0, np.empty(last - first + 2))


@pytest.mark.parametrize("kind", ["linear", "mean", "none"])
def test_detrend_of_a_strided_view_is_that_of_its_copy_bit_for_bit(kind):
    rows = np.random.default_rng(5).standard_normal((50_000, 2)).cumsum(axis=0)
    column = rows[:, 1]  # a strided view: BLAS and numpy's sums would add it in another order
    assert detrend(column, kind).tobytes() == detrend(column.copy(), kind).tobytes()
