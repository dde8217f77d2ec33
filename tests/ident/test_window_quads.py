"""The window path's loops four lanes wide (branch glue7): each gives the numbers of the scalar
loop it replaced bit for bit, checked against that loop written out in Python floats (IEEE
doubles, one operation at a time, in the loop's order). The lengths are chosen so that every
block size (32, 16, 8 outputs) and the one-at-a-time remainder run."""

import numpy as np
import pytest

from rtsid.ident import front, onecall
from rtsid.ident.analysis import resolve_plan
from rtsid.ident.fit import Held
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.stream import WindowStream
from tests.ident.test_window_kernels import FS, _one_output_at_a_time, _signal
from tests.ident.test_window_path_lanes import _linear_detrended

pytestmark = pytest.mark.skipif(compiled_kernel() is None, reason="compiled kernel not built")


def _dot_unrolled(u: list[float], v: list[float], n: int) -> float:
    """dot_unrolled: four running sums (s_i over i ≡ 0 … 3 mod 4), the remainder into s0,
    then (s0 + s1) + (s2 + s3)."""
    s = [0.0, 0.0, 0.0, 0.0]
    whole = n - n % 4
    for i in range(whole):
        s[i % 4] += u[i] * v[i]
    for i in range(whole, n):
        s[0] += u[i] * v[i]
    return (s[0] + s[1]) + (s[2] + s[3])


def _levinson(r: list[float], b: list[float]) -> list[float]:
    """eureka_solve in Python floats, step by step."""
    n = len(r)
    rr = r[::-1]
    alpha = r[0]
    a, x = [0.0] * n, [0.0] * n
    a[0], x[0] = 1.0, b[0] / alpha
    for k in range(1, n):
        rk = rr[n - 1 - k :]
        refl = -_dot_unrolled(a, rk, k) / alpha
        a[k] = 0.0
        i, j = 0, k
        while i < j:
            ai, aj = a[i], a[j]
            a[i], a[j] = ai + refl * aj, aj + refl * ai
            i, j = i + 1, j - 1
        if i == j:
            a[i] += refl * a[i]
        alpha *= 1.0 - refl * refl
        mu = (b[k] - _dot_unrolled(x, rk, k)) / alpha
        x[k] = 0.0
        for m in range(k + 1):
            x[m] += mu * a[k - m]
    return x


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 9, 13, 25, 41])
def test_the_toeplitz_solve_is_the_scalar_recursion_bit_for_bit(n):
    # dot_unrolled's four sums in one vector: every reflection and update as the scalar loop's
    kernel = compiled_kernel()
    rng = np.random.default_rng(n)
    r = np.exp(-np.arange(n) / 3.0) * (1.0 + 0.1 * rng.random(n))
    r[0] = 2.0 + rng.random()
    b = rng.standard_normal(n)
    x, work = np.empty(n), np.empty(2 * n)
    status, _ = kernel.solve(r, b, x, work)
    assert status == -1
    assert x.tolist() == _levinson(r.tolist(), b.tolist())


# analysis rows m: 70 (two blocks of 32, 6 left), 79 (two of 32, one of 8, 7 left), 96 (three
# of 32), 112 (three of 32, one of 16), 128 (four of 32) and the whole window's
@pytest.mark.parametrize("rows", [70, 79, 96, 112, 128, None])
def test_the_front_ends_filter_and_correlations_are_the_scalar_loops(rows):
    kernel = compiled_kernel()
    theta, tau = _signal(750, 7)
    options = EstimatorOptions(ridge=0.0)
    plan = resolve_plan(theta, FS, options)
    factor, taps = plan.factor, plan.taps.tolist()
    if rows is not None:
        assert rows > max(4 * plan.lag + 1, 16)  # a window the front end takes
        samples = len(taps) + factor * (rows - 1)
        theta, tau = theta[:samples], tau[:samples]
    u, y, irf = front.front_end(theta, tau, FS, options, plan)
    assert rows is None or u.size == rows
    sign = options.torque_sign
    assert u.tolist() == _one_output_at_a_time(_linear_detrended(theta.tolist(), 1.0), taps, factor)
    assert y.tolist() == _one_output_at_a_time(_linear_detrended(tau.tolist(), sign), taps, factor)
    auto = np.empty(2 * plan.lag + 1)
    kernel.xcorr(u, u, 0, 2 * plan.lag, float(u.size), auto)  # one lag at a time
    np.testing.assert_array_equal(irf.phi_uu, auto)


def test_the_compiled_rounding_is_pythons_round_to_12_decimals():
    # a published VAF is round(x, 12): every value here, ties (odd multiples of 2⁻¹³, exact
    # halves at the 12th decimal) and their neighbours, signed zeros, non-finite values
    # and values past the fast path's range included
    rng = np.random.default_rng(22)
    ties = np.arange(-8192 * 101 + 1, 8192 * 101, 2) / 8192.0
    values = np.concatenate(
        [
            rng.uniform(-200.0, 200.0, 20000),
            rng.uniform(99.99, 100.0, 20000),
            ties,
            np.nextafter(ties, np.inf),
            np.nextafter(ties, -np.inf),
            [0.0, -0.0, 1e-13, -1e-13, 5e-13, -5e-13, 100.0, 4095.9, 4096.0, 1e300],
            [np.nan, np.inf, -np.inf, 99.9999999999995, 0.1 + 0.2],
        ]
    ).tolist()
    rounded = np.array(compiled_kernel().round12(*values))
    want = np.array([round(v, 12) for v in values])
    same = (np.isnan(rounded) & np.isnan(want)) | (
        (rounded == want) & (np.signbit(rounded) == np.signbit(want))
    )
    assert rounded.shape == want.shape and same.all()
    assert compiled_kernel().round12(3, 2.5) == (3, 2.5)  # not a float: Python's round


def test_the_one_calls_arrays_are_views_of_one_buffer_it_checks():
    # the kernel takes one buffer and each array's (offset, length): a window through it is
    # the step-by-step path's, and a layout past the buffer is refused, not read
    theta, tau = _signal(750, 3)
    options = EstimatorOptions()
    plan = resolve_plan(theta, FS, options)
    call = onecall.WindowCall(plan, options, 750, 12)
    for view in (call.u, call.y, call.regressors, call.projected, call.gram, call.out):
        assert view.base is call.work
    done = call(theta, tau, None, Held(), None)
    assert done is not None
    stream = WindowStream(FS, options, 0.02, plan=plan)
    want = stream.estimate(theta, tau, np.ones(750, dtype=bool))  # the step-by-step path
    assert (done[0][2], done[1].tolist()) == (want.K, want.irf.tolist())
    consts = call.consts.copy()
    consts[-2] = call.work.size  # the table starts past the buffer's end
    args = (theta, tau, None, np.empty(call.nh), call.work, consts, call.held)
    with pytest.raises(ValueError, match="within work"):
        compiled_kernel().onecall_window(*args)
    with pytest.raises(ValueError, match="within work"):
        compiled_kernel().onecall_window(*args[:5], call.consts[:-2], call.held)
