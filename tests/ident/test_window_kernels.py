"""The window's kernels at the 625 Hz plan (branch kern625): each faster form gives the numbers
of the loop it replaced bit for bit, checked against that loop written out in Python floats
(IEEE doubles, one operation at a time, in the loop's order)."""

import numpy as np
import pytest

from rtsid.ident import front, fused
from rtsid.ident.analysis import resolve_plan
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.fit import Held
from rtsid.ident.levinson import compiled_kernel
from rtsid.ident.options import EstimatorOptions
from rtsid.ident.window import analyse_window
from rtsid.sim.joint import JointParameters, simulate_impedance

pytestmark = pytest.mark.skipif(compiled_kernel() is None, reason="compiled kernel not built")

FS = 2500.0


def _signal(samples: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    theta = filtered_noise(samples, FS, 30.0, peak=0.03, seed=seed)
    tau = simulate_impedance(theta, FS, JointParameters(), noise_percent=5.0, seed=seed + 1)
    return theta, tau


def _mean_removed(x: list[float], sign: float) -> list[float]:
    """detrend_into(kind = 1): the mean summed in sample order."""
    total = 0.0
    for v in x:
        total += sign * v
    mean = total / len(x)
    return [sign * v - mean for v in x]


def _one_output_at_a_time(x: list[float], taps: list[float], factor: int) -> list[float]:
    """fir_decimate's loop: out[k] = Σ_j taps[j]·x[k·factor + T − 1 − j], j ascending."""
    nt, m = len(taps), (len(x) - len(taps)) // factor + 1
    out = []
    for k in range(m):
        acc = 0.0
        for j in range(nt):
            acc += taps[j] * x[k * factor + nt - 1 - j]
        out.append(acc)
    return out


@pytest.mark.parametrize("factor", [1, 2, 3, 4, 5, 8])
@pytest.mark.parametrize("samples, taps", [(750, 39), (757, 11), (301, 69), (97, 3)])
def test_the_decimating_fir_is_the_one_output_at_a_time_loop(factor, samples, taps):
    # blocks of 8 outputs in pairs of lanes, whatever the remainder and the stride
    kernel = compiled_kernel()
    rng = np.random.default_rng(samples + taps + factor)
    x, coefficients = rng.standard_normal(samples), rng.standard_normal(taps)
    out = np.empty((samples - taps) // factor + 1)
    kernel.band_limit(x, coefficients, factor, -1.0, out)
    want = _one_output_at_a_time(_mean_removed(x.tolist(), -1.0), coefficients.tolist(), factor)
    assert out.tolist() == want


def _line_slope(x: list[float], sign: float) -> float:
    """line_slope: Σ t·sign·x over Σ t², t the sample's distance from the window's centre."""
    centre = (len(x) - 1) / 2.0
    tt = tx = 0.0
    for i, v in enumerate(x):
        t = i - centre
        tt += t * t
        tx += t * sign * v
    return tx / tt


@pytest.mark.parametrize("samples", [750, 757])  # Σt² over half-integers and integers
@pytest.mark.parametrize("detrend", ["linear", "mean", "none"])
def test_the_front_ends_slopes_are_the_line_slopes_of_the_raw_window(detrend, samples):
    # the slopes now come from the detrending's own pass, not a pass of their own
    theta, tau = _signal(samples, 11)
    options = EstimatorOptions(lag_s=0.02, detrend=detrend, torque_sign=-1)
    plan = resolve_plan(theta, FS, options)
    *_, slopes = front._front_end(theta, tau, FS, options, plan)
    assert slopes == (_line_slope(theta.tolist(), 1.0), _line_slope(tau.tolist(), -1.0))


@pytest.mark.parametrize("held", [Held(), Held(0.015), Held(0.015, 0.8)])
@pytest.mark.parametrize("explained", [False, True])
def test_the_fused_vafs_are_the_separate_calls_bit_for_bit(held, explained):
    # oe_window reads the model's torque oe_fit formed instead of forming it again: its VAFs
    # are oe_vafs' (stencils and model torque formed afresh) to the last bit
    kernel = compiled_kernel()
    theta, tau = _signal(757, 21)
    options = EstimatorOptions(lag_s=0.02)
    plan = resolve_plan(theta, FS, options)
    extra = 0.05 * np.sin(np.arange(theta.size) / 40.0) if explained else None
    window = analyse_window(theta, tau, FS, options, plan, explained=extra)
    irf, u, y = window.signals
    buffers = fused.BackEndBuffers()
    got = fused.fused_back_end(
        irf, u, y, options, plan, held, window.score, learn=True, buffers=buffers
    )
    estimate, design = got.estimate, got.design
    params = np.array([estimate.I, estimate.B, estimate.K])
    score = window.score
    vafs = kernel.oe_vafs(
        u,
        y,
        irf.h,
        params,
        np.ascontiguousarray(params @ design.regressors),
        irf.fs_hz,
        score.explained,
        score.torque_slope,
        estimate.K * score.position_slope,
        buffers.kmax,
        buffers.cos,
        buffers.sin,
    )
    at = kernel.OW_VAFS
    assert (buffers.out[at + 1], buffers.out[at + 2]) == (vafs[1], vafs[2])


@pytest.mark.parametrize("band_hz", [0.0, 3.0, 30.0, 55.0, 90.0])  # kmax 0, 1, 4k and others
def test_the_tabled_back_end_is_oe_window_bit_for_bit(band_hz):
    # the published VAF's DFT from the plan's twiddle table sums each bin as the twiddle
    # lookups do; every output of the call is oe_window's
    kernel = compiled_kernel()
    theta, tau = _signal(750, 31)
    options = EstimatorOptions(lag_s=0.02)
    plan = resolve_plan(theta, FS, options)
    extra = 0.05 * np.cos(np.arange(theta.size) / 30.0)
    window = analyse_window(theta, tau, FS, options, plan, explained=extra)
    irf, u, y = window.signals
    outputs = []
    for tabled in (False, True):
        buf = fused.BackEndBuffers().for_window(u.size, irf, plan, max(band_hz, 1e-9))
        args = [u, y, irf.h, irf.fs_hz, 1, np.array([0.015, 0.0]), True, True, buf.lags]
        args += [window.score.explained, 0.01, 0.02, buf.kmax, buf.cos, buf.sin, 12]
        args += [buf.regressors, buf.projected, buf.gram, buf.model, buf.out]
        entry = kernel.oe_window_tabled if tabled else kernel.oe_window
        status = entry(*args, buf.table) if tabled else entry(*args)
        assert status == kernel.OE_OK
        outputs.append(np.concatenate([buf.out, buf.model, buf.projected.ravel()]))
    assert outputs[0].tobytes() == outputs[1].tobytes()


def test_a_band_table_of_the_wrong_size_is_refused():
    kernel = compiled_kernel()
    cos, sin = np.ones(40), np.zeros(40)
    with pytest.raises(ValueError, match="band_table"):
        kernel.band_table(cos, sin, 5, np.empty(40 * 8))
    table = np.empty(2 * 40 * 8)
    kernel.band_table(cos, sin, 5, table)
    assert table[8 * 40 + 1 :: 8].tolist() == [0.0] * 40  # bin 6, past kmax, is zero
