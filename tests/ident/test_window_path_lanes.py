"""The window path's loops two lanes at a time (branch winpath) give the scalar loops' numbers
bit for bit, checked against those loops written out in Python floats (IEEE doubles, one
operation at a time, in the loop's order); and what ``tracker_step`` reads and writes through
an instance's dictionary is what getattr and setattr would (no data descriptor shadows it)."""

import inspect

import numpy as np
import pytest

from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.stream import HeldParameters, StreamTracker
from rtsid.ident.tracker import TrackerOptions
from tests.ident.test_window_kernels import _one_output_at_a_time as _fir

_D1 = [1 / 280, -4 / 105, 1 / 5, -4 / 5, 0.0, 4 / 5, -1 / 5, 4 / 105, -1 / 280]
_D2 = [-1 / 560, 8 / 315, -1 / 5, 8 / 5, -205 / 72, 8 / 5, -1 / 5, 8 / 315, -1 / 560]

compiled = pytest.mark.skipif(compiled_kernel() is None, reason="compiled kernel not built")


def _centred_squares(n: int) -> float:
    nn = float(n)
    return nn * (nn * nn - 1.0) / 12.0


def _without_trend(row: list[float]) -> list[float]:
    """without_trend's loops: the mean, then Σ c·t, then the line's subtraction."""
    n = len(row)
    centre = (n - 1) / 2.0
    mean = 0.0
    for v in row:
        mean += v
    mean /= n
    out, tx, t = [], 0.0, -centre
    for v in row:
        c = v - mean
        out.append(c)
        tx += c * t
        t += 1.0
    coef = tx / _centred_squares(n)
    t = -centre
    for i in range(n):
        out[i] -= coef * t
        t += 1.0
    return out


def _stencil_rows(u: list[float], fs: float) -> list[list[float]]:
    """oe_design's rows d2, d1, u0: each row's nine taps summed in order from 0.0."""
    d1, d2, u0 = [], [], []
    for t in range(len(u) - 8):
        a1 = a2 = 0.0
        for s in range(9):
            a1 += u[t + s] * _D1[s]
            a2 += u[t + s] * _D2[s]
        d1.append(a1 * fs)
        d2.append(a2 * (fs * fs))
        u0.append(u[t + 4])
    return [d2, d1, u0]


@compiled
@pytest.mark.parametrize("samples", [18, 19, 186, 187])  # even and odd rows, both lanes' ends
def test_the_output_error_design_is_the_scalar_loops_bit_for_bit(samples):
    kernel = compiled_kernel()
    rng = np.random.default_rng(samples)
    u, y = rng.standard_normal(samples), rng.standard_normal(samples)
    n = samples - 8
    regressors, projected, gram = np.empty((3, n)), np.empty((4, n)), np.empty((4, 4))
    assert kernel.oe_design(u, y, 625.0, regressors, projected, gram) == kernel.OE_OK
    rows = _stencil_rows(u.tolist(), 625.0)
    assert regressors.tolist() == rows
    want = [_without_trend(row) for row in (*rows, y[4:-4].tolist())]
    assert projected.tolist() == want


def _linear_detrended(x: list[float], sign: float) -> list[float]:
    """detrend_phases(kind = 2) in sample order: sign·x − mean − slope·t."""
    n = len(x)
    centre = (n - 1) / 2.0
    mean = tx = 0.0
    t = -centre
    for v in x:
        mean += sign * v if sign not in (1.0, -1.0) else (v if sign == 1.0 else -v)
        tx += t * sign * v if sign not in (1.0, -1.0) else (t * v if sign == 1.0 else -(t * v))
        t += 1.0
    slope = tx / _centred_squares(n)
    mean /= n
    return [sign * v - mean - slope * (i - centre) for i, v in enumerate(x)]


@compiled
@pytest.mark.parametrize("factor", [1, 2, 3, 4])
@pytest.mark.parametrize("samples", [750, 757])  # phases of either parity, t half-integer or not
def test_the_linear_detrending_phases_are_the_scalar_loop_bit_for_bit(factor, samples):
    kernel = compiled_kernel()
    rng = np.random.default_rng(factor * samples)
    position, torque = rng.standard_normal(samples), rng.standard_normal(samples)
    taps = rng.standard_normal(15)
    lag = 3
    m = (samples - taps.size) // factor + 1
    u, y, h, phi = np.empty(m), np.empty(m), np.empty(2 * lag + 1), np.empty(2 * lag + 1)
    kernel.window_irf(position, torque, taps, factor, -1.0, 2, lag, 0, 0.0, 625.0, u, y, h, phi)
    assert u.tolist() == _fir(_linear_detrended(position.tolist(), 1.0), taps.tolist(), factor)
    assert y.tolist() == _fir(_linear_detrended(torque.tolist(), -1.0), taps.tolist(), factor)


def _data_descriptors(obj: object) -> list[str]:
    """The instance attributes a data descriptor of the class would shadow."""
    shadowed = []
    for name in vars(obj):
        found = inspect.getattr_static(type(obj), name, None)
        if found is not None and hasattr(type(found), "__set__"):
            shadowed.append(name)
    return shadowed


def test_the_trackers_state_is_plain_instance_attributes():
    # tracker_step reads and writes them through the instance dictionary
    tracker = StreamTracker(0.3, 0.02, TrackerOptions()).stiffness
    tracker.step(0.3, 150.0, 5.0)
    for obj in (tracker, *tracker._all):
        assert vars(obj) and _data_descriptors(obj) == []


def test_held_values_are_one_object_until_a_median_changes():
    held = HeldParameters("inertia_damping", horizon_windows=9, min_windows=3)
    assert held.current() is held.current()  # nothing learned: NOT_HELD
    for inertia in (0.010, 0.012, 0.011):
        held.learn(inertia, 1.0, True)
    first = held.current()
    assert (first.inertia, first.damping) == (0.011, 1.0)
    assert held.current() is first  # read again: the same object
    held.learn(0.5, 1.0, False)  # not learned from (explains too little): unchanged
    assert held.current() is first
    held.learn(0.011, 1.0, True)  # the median stays 0.011: the same object
    assert held.current() is first
    held.learn(0.020, 3.0, True)  # (0.010, 0.011, 0.011, 0.012, 0.020): still 0.011
    assert held.current() is first
    held.learn(0.030, 3.0, True)  # six values: the mean of the middle two
    second = held.current()
    assert second is not first
    assert (second.inertia, second.damping) == ((0.011 + 0.012) / 2.0, 1.0)


def test_the_full_fits_vaf_test_is_the_rounded_comparison():
    # the full fit's VAF is rounded only near low_vaf_percent; elsewhere the comparison of
    # the unrounded value must decide the same
    from rtsid.ident.fused import full_fit_explains
    from rtsid.ident.window import EstimatorOptions

    options = EstimatorOptions()
    low = options.low_vaf_percent
    rng = np.random.default_rng(7)
    near = [low + d for d in (-2e-9, -1e-9, -5e-13, -4e-13, 0.0, 4e-13, 5e-13, 1e-9, 2e-9)]
    values = [*near, *np.nextafter(low, [-np.inf, np.inf]), *rng.uniform(-50, 100, 200)]
    for value in [*values, float("nan"), 100.0, 0.0]:
        assert full_fit_explains(float(value), options) == (round(float(value), 12) >= low), value
