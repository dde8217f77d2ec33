from dataclasses import replace

import numpy as np
import pytest

from rtsid.errors import ConfigError, InputDataError
from rtsid.ident.reflex import ReflexStream
from rtsid.ident.reflex_lane import (
    ReflexModels,
    ReflexUpdate,
    SlowLaneSettings,
    bridged,
    fit_reflex_update,
    predict_reflex_torque,
    warm_up,
)
from tests.ident.test_cascade import FS as FS_SIM
from tests.ident.test_cascade import joint_with_reflex

FS = 1000.0
SETTINGS = SlowLaneSettings(enabled=True, horizon_s=10.0, update_s=2.0, apply_after_s=1.0)


@pytest.fixture(scope="module")
def pathway():
    theta, torque = joint_with_reflex(seconds=8.0)
    update = fit_reflex_update(0, 0, theta, torque, None, FS_SIM, SETTINGS)
    assert update.error is None
    return update.pathway


def fitted(pathway, seq, start, end):
    return ReflexUpdate(seq, start, end, pathway, True, 99.0, 80.0, 80.0, 20.0, 2)


def test_the_schedule_is_a_function_of_sample_indices_only():
    models = ReflexModels(FS, SETTINGS)
    assert (models.update, models.horizon, models.apply_after) == (2000, 10000, 1000)
    # data from sample 500: the first fit with 3 s (three reflex-IRF lengths) ends at 4000
    assert models.first_seq(500) == 2
    assert models.fit_span(2, 500) == (500, 4000)
    assert models.fit_span(1, 500) is None
    assert models.fit_span(9, 500) == (8000, 18000)  # the last horizon_s only
    # fit 2 ends at 4000 and applies to windows ending at 4999 and later
    assert models.due_seq(4998) == 1 and models.due_seq(4999) == 2


def test_a_window_uses_the_due_fit_or_says_why_not(pathway):
    models = ReflexModels(FS, SETTINGS)
    assert models.model_for(5000) == (None, False)  # nothing yet: reflex_absent
    models.add(fitted(pathway, 2, 0, 4000))
    assert models.model_for(5000) == (models.model_for(5000)[0], False)
    assert models.model_for(5000)[0].seq == 2
    # fit 3 is due from 6999 on but has not arrived: the old one, stale
    update, stale = models.model_for(6999)
    assert update.seq == 2 and stale
    models.add(ReflexUpdate.failed(3, 0, 6000, "a gap"))
    assert models.model_for(6999)[0].seq == 2 and models.model_for(6999)[1]
    models.add(fitted(pathway, 4, 0, 8000))
    assert models.model_for(8999) == (models.model_for(8999)[0], False)
    # too old: more than stale_after_s since its data ended
    assert models.model_for(8000 + 10_001)[1]


def test_settings_are_checked_like_the_rest_of_the_config():
    with pytest.raises(ConfigError, match="stale_after_s"):
        SlowLaneSettings(update_s=5.0, apply_after_s=6.0, stale_after_s=10.0)
    with pytest.raises(ConfigError, match="horizon_s"):
        SlowLaneSettings(horizon_s=2.0)
    with pytest.raises(ConfigError, match="mode"):
        SlowLaneSettings(mode="fork")
    with pytest.raises(ConfigError, match="enabled"):
        ReflexModels(FS, SlowLaneSettings(enabled=False))


def test_lost_samples_are_bridged_when_few_and_short_and_refused_otherwise():
    x = np.arange(2000.0)
    valid = np.ones(2000, bool)
    valid[[10, 11, 500]] = False
    out = bridged(np.where(valid, x, np.nan), valid, FS, SETTINGS)
    assert np.allclose(out, x)
    valid[100:120] = False  # 20 samples: longer than a 10 ms model sample
    with pytest.raises(InputDataError, match="gap of 20 samples"):
        bridged(x, valid, FS, SETTINGS)
    valid = np.arange(2000) % 10 != 0  # 10 % lost
    with pytest.raises(InputDataError, match="10 % of the samples are lost"):
        bridged(x, valid, FS, SETTINGS)


def test_a_fit_on_bad_data_carries_the_error_instead_of_raising():
    short = fit_reflex_update(5, 100, np.zeros(500), np.zeros(500), None, FS, SETTINGS)
    assert short.pathway is None and "at least 3 s" in short.error
    assert (short.seq, short.start_index, short.end_index) == (5, 100, 600)
    nan = np.full(4000, np.nan)
    assert "NaN" in fit_reflex_update(6, 0, nan, nan, None, FS, SETTINGS).error


def test_the_prediction_needs_only_the_window_and_its_history(pathway):
    theta, _ = joint_with_reflex(seconds=6.0, seed=7)
    whole = pathway.torque(theta, FS_SIM)
    n, history = 750, round(pathway.history_s * FS_SIM)
    segment = theta[-(n + history) :]
    tail = predict_reflex_torque(pathway, segment, None, FS_SIM, n, SETTINGS)
    # the pathway's input is mean-removed over what it sees: an offset is free, the rest
    # agrees with the whole-record prediction except at the decimator's edge
    diff = (tail - whole[-n:])[: n - 100]
    assert np.std(diff - diff.mean()) < 0.05 * np.std(whole[-n:])


def test_warm_up_runs_a_fit():
    assert warm_up(2500.0, SETTINGS)


def _windows(theta, ends, n, history, pathway, stream=None, lost_at=(), short_at=()):
    """The stream's window torque at each window end (``stream``: one carried through all;
    None: a fresh one per window); ``short_at``: windows given a third of their history."""
    out = []
    for end in ends:
        given = history // 3 if end in short_at else history
        first = max(0, end - n - given + 1)  # the recording's first windows: less history
        segment = theta[first : end + 1].copy()
        valid = None
        if end in lost_at:  # a lost sample in the history: bridged, nothing kept
            valid = np.ones(segment.size, bool)
            valid[100] = False
            segment[100] = 0.0
        out.append(
            predict_reflex_torque(
                pathway, segment, valid, FS_SIM, n, SETTINGS, first_index=first, stream=stream
            )
        )
    return out


def _numpy_path(monkeypatch):
    from rtsid.ident import reflex

    monkeypatch.setattr(reflex, "_eureka", None)


@pytest.mark.parametrize("numpy_only", [False, True])
@pytest.mark.parametrize("hop", [50, 10, 37])
def test_the_stream_gives_the_numbers_of_each_window_formed_afresh(
    pathway, hop, numpy_only, monkeypatch
):
    # issue 22: each model sample's input and output are computed once and carried; the
    # numbers are those of forming every window from its samples alone, bit for bit, so a
    # replay reproduces live whichever windows either evaluated
    theta, _ = joint_with_reflex(seconds=6.0, seed=11)
    n, history = 750, round(pathway.history_s * FS_SIM)
    ends = list(range(n + history + 3, theta.size, hop))[:40]
    del ends[7:10]  # windows the fast lane skipped (late) or withheld
    lost, short = {ends[12]}, {ends[20]}  # short: values kept from before are not used
    if numpy_only:
        _numpy_path(monkeypatch)
    stream = ReflexStream()
    carried = _windows(theta, ends, n, history, pathway, stream, lost, short)
    afresh = _windows(theta, ends, n, history, pathway, None, lost, short)
    for got, want in zip(carried, afresh, strict=True):
        np.testing.assert_array_equal(got, want)
    assert stream._inputs.count > 0 and stream._outputs.count > 0  # values were carried
    # a new model (the slow lane's next fit) switches the outputs at once, not the inputs
    other = replace(pathway, irf=0.5 * pathway.irf)
    first = ends[-1] + hop - n - history + 1
    segment = theta[first : ends[-1] + hop + 1]
    got = predict_reflex_torque(
        other, segment, None, FS_SIM, n, SETTINGS, first_index=first, stream=stream
    )
    want = predict_reflex_torque(other, segment, None, FS_SIM, n, SETTINGS, first_index=first)
    np.testing.assert_array_equal(got, want)


def test_a_polynomial_pathway_streams_its_own_inputs(pathway):
    # a Hammerstein pathway's input depends on its polynomial: its values are its own, and a
    # switch between the variants forms the inputs anew (the numpy reference runs it)
    polynomial = replace(pathway, variant="hammerstein", polynomial=np.array([0.5, 0.2, -0.1]))
    theta, _ = joint_with_reflex(seconds=5.0, seed=14)
    n, history = 750, round(pathway.history_s * FS_SIM)
    ends = list(range(n + history, theta.size, 50))[:12]
    stream = ReflexStream()
    for k, end in enumerate(ends):
        model = polynomial if k % 4 < 2 else pathway
        carried = _windows(theta, [end], n, history, model, stream)[0]
        afresh = _windows(theta, [end], n, history, model)[0]
        np.testing.assert_array_equal(carried, afresh)
    rectified = _windows(theta, ends[-1:], n, history, pathway)[0]
    assert np.abs(_windows(theta, ends[-1:], n, history, polynomial)[0] - rectified).max() > 0


@pytest.mark.parametrize("n_last", [1, 750, 3000])
def test_the_compiled_hop_equals_the_numpy_reference(pathway, n_last, monkeypatch):
    from rtsid.ident.levinson import HAVE_COMPILED_KERNEL

    if not HAVE_COMPILED_KERNEL:
        pytest.skip("the compiled kernel is not built")
    theta, _ = joint_with_reflex(seconds=6.0, seed=12)
    history = round(pathway.history_s * FS_SIM)
    ends = [n_last + 300, *range(n_last + history + 7, theta.size, 61)][:25]  # short ones too
    compiled = _windows(theta, ends, n_last, history, pathway, ReflexStream())
    _numpy_path(monkeypatch)
    reference = _windows(theta, ends, n_last, history, pathway, ReflexStream())
    for got, want in zip(compiled, reference, strict=True):
        scale = np.abs(want).max()
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * scale)


def test_the_stream_predicts_the_torque_of_the_fitted_model(pathway):
    # the fit's pathway input is the zero-phase decimation of the rectified velocity of the
    # whole record; the stream's, hop by hop, agrees with it within a window, offset aside
    theta, _ = joint_with_reflex(seconds=8.0, seed=13)
    whole = pathway.torque(theta, FS_SIM)
    n, history = 750, round(pathway.history_s * FS_SIM)
    ends = list(range(n + history + 2500, theta.size - 2500, 125))
    windows = _windows(theta, ends, n, history, pathway, ReflexStream())
    for end, got in zip(ends, windows, strict=True):
        want = whole[end - n + 1 : end + 1]
        error = (got - got.mean()) - (want - want.mean())
        assert np.var(error) < 0.01 * np.var(want)


def test_the_streams_decimator_is_the_fits_zero_phase_one_within_the_band():
    from scipy import signal

    from rtsid.ident.reflex import _decimator, stream_taps

    taps = stream_taps(25)
    assert taps.size == 2 * 250 + 1 and np.array_equal(taps, taps[::-1])
    sos = _decimator(25).sos
    freqs = np.linspace(0.0, 30.0, 61)
    _, fits = signal.sosfreqz(sos, worN=freqs, fs=FS_SIM)
    _, ours = signal.freqz(taps, 1, worN=freqs, fs=FS_SIM)
    ours = np.abs(ours)  # zero phase: the taps are centred
    # within the Chebyshev's own passband ripple (0.05 dB, forwards and backwards: ±1.2 %),
    # which the taper smooths
    np.testing.assert_allclose(ours, np.abs(fits) ** 2, rtol=0.012)
    assert np.array_equal(stream_taps(1), [1.0])


def test_a_segment_shorter_than_the_decimators_reach_is_refused(pathway):
    with pytest.raises(InputDataError, match="at least 255 samples"):
        ReflexStream().torque_tail(pathway, np.zeros(200), 0, FS_SIM, 100)
    with pytest.raises(InputDataError, match="not a whole multiple"):
        ReflexStream().torque_tail(pathway, np.zeros(2000), 0, 2510.0, 100)


# ----------------------------------------------------------------- a fit's shared work (issue 22)
def _whole_horizon_gains(position, torque, reflex_torque, first):
    """The evidence as it was computed before issue 22: the basis over the whole horizon and
    two separate least-squares fits per window."""
    from rtsid.ident import reflex_lane
    from rtsid.ident.yardstick import WindowVafBasis

    basis = WindowVafBasis(position, torque, FS_SIM)
    n = round(reflex_lane.EVIDENCE_WINDOW_S * FS_SIM)
    first = max(first, position.size - round(reflex_lane.EVIDENCE_SPAN_S * FS_SIM))
    step = round(reflex_lane.EVIDENCE_STEP_S * FS_SIM)
    return np.array(
        [
            basis.least_squares_vaf(a, a + n, reflex_torque[a : a + n])
            - basis.least_squares_vaf(a, a + n)
            for a in range(first, position.size - n + 1, step)
        ]
    )


@pytest.mark.parametrize(("seconds", "first"), [(20.0, 0), (12.0, 2700), (4.0, 2700)])
def test_the_evidence_on_the_scored_span_equals_the_whole_horizons(seconds, first):
    from rtsid.ident.reflex_lane import window_vaf_gain, window_vaf_gains

    theta, torque = joint_with_reflex(seconds=seconds, seed=5)
    fit = fit_reflex_update(0, 0, theta, torque, None, FS_SIM, SETTINGS)
    reflex = fit.pathway.torque(theta, FS_SIM)
    want = _whole_horizon_gains(theta, torque, reflex, first)
    assert want.size >= 3 and np.ptp(want) > 1.0  # the windows differ: a real check
    np.testing.assert_allclose(
        window_vaf_gains(theta, torque, reflex, FS_SIM, first), want, rtol=0, atol=1e-9
    )
    median, improved = window_vaf_gain(theta, torque, reflex, FS_SIM, first)
    assert abs(median - np.median(want)) < 1e-9 and improved == np.mean(want > 0)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("fs_hz", [FS_SIM, 1000.0])
def test_all_windows_in_one_pass_equal_each_windows_own_least_squares(fs_hz, compiled, monkeypatch):
    from rtsid.ident import yardstick
    from rtsid.ident.yardstick import WindowVafBasis

    if not compiled:
        monkeypatch.setattr(yardstick, "_eureka", None)
    theta, torque = joint_with_reflex(seconds=4.0, seed=6)
    theta = theta + 0.2  # an offset far above the movement: the offset term must be exact
    basis = WindowVafBasis(theta, torque, fs_hz)
    extra = np.random.default_rng(0).standard_normal(theta.size)
    n = 750
    starts = np.arange(0, theta.size - n + 1, 1250)
    want = [
        basis.least_squares_vaf(a, a + n, extra[a : a + n]) - basis.least_squares_vaf(a, a + n)
        for a in starts
    ]
    got = basis.least_squares_vaf_gains(starts, n, extra)
    assert np.ptp(want) > 0.3  # the windows differ: a real check
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


@pytest.mark.parametrize("windows", [1, 4, 7, 40])
def test_the_evidence_four_windows_at_a_time_is_the_one_window_loop_bit_for_bit(windows):
    from rtsid.ident import yardstick
    from rtsid.ident.yardstick import WindowVafBasis

    if yardstick._eureka is None:
        pytest.skip("the compiled kernel is not built")
    theta, torque = joint_with_reflex(seconds=12.0, seed=6)
    basis = WindowVafBasis(theta + 0.2, torque, FS_SIM)
    extra = np.random.default_rng(windows).standard_normal(theta.size)
    n = 750
    starts = np.random.default_rng(1).integers(0, theta.size - n + 1, windows).astype(np.int64)
    want, got = np.empty(windows), np.empty(windows)
    args = (basis.torque, basis.regressors, extra, starts, n)
    yardstick._eureka.evidence_gains(*args, want)
    yardstick._eureka.evidence_gains_lanes(*args, got)
    assert np.ptp(want) > 0 or windows == 1
    np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="evidence_gains_lanes: inconsistent sizes"):
        yardstick._eureka.evidence_gains_lanes(*args, np.empty(windows + 1))


def test_the_compiled_evidence_checks_its_windows():
    from rtsid.ident import yardstick
    from rtsid.ident.yardstick import WindowVafBasis

    if yardstick._eureka is None:
        pytest.skip("the compiled kernel is not built")
    theta, torque = joint_with_reflex(seconds=4.0, seed=6)
    basis = WindowVafBasis(theta, torque, FS_SIM)
    with pytest.raises(ValueError, match="inconsistent sizes"):
        basis.least_squares_vaf_gains(np.array([theta.size - 10]), 750, np.zeros(theta.size))


@pytest.mark.parametrize("variant", ["rect", "hammerstein"])
def test_the_cascades_own_reflex_prediction_is_the_pathways(variant):
    from rtsid.ident.cascade import CascadeSettings, fit_parallel_cascade

    theta, torque = joint_with_reflex(seconds=6.0, seed=8)
    fit = fit_parallel_cascade(theta, torque, FS_SIM, CascadeSettings(variant=variant))
    # the rectifier's prediction is reused as it is: the very numbers
    np.testing.assert_array_equal(
        fit.record_reflex_torque(theta, FS_SIM), fit.reflex.torque(theta, FS_SIM)
    )


@pytest.mark.parametrize("compiled", [True, False])
def test_the_window_vaf_basis_is_scipys_low_pass_of_each_signal(compiled, monkeypatch):
    from scipy import signal

    from rtsid.ident import reflex
    from rtsid.ident.yardstick import WindowVafBasis, savgol_derivatives

    if not compiled:
        monkeypatch.setattr(reflex, "_eureka", None)
    theta, torque = joint_with_reflex(seconds=4.0, seed=9)
    for _ in range(2):  # the second basis uses the cached filter design
        basis = WindowVafBasis(theta, torque, FS_SIM)
        sos = signal.butter(4, 40.0, fs=FS_SIM, output="sos")
        d1, d2 = savgol_derivatives(theta, FS_SIM)
        np.testing.assert_array_equal(basis.torque, signal.sosfiltfilt(sos, torque))
        want = [signal.sosfiltfilt(sos, x) for x in (d2, d1, theta)]
        np.testing.assert_array_equal(basis.regressors, np.vstack(want))


def test_a_formed_toeplitz_system_gives_the_same_projection_and_rect_forms_it_once(monkeypatch):
    from rtsid.ident import reflex
    from rtsid.ident.cascade import CascadeSettings, fit_parallel_cascade
    from rtsid.ident.correlation import auto_correlation, cross_correlation

    rng = np.random.default_rng(4)
    r = np.maximum(rng.standard_normal(3000), 0.0)
    e = np.convolve(r, np.exp(-np.arange(30) / 5.0))[: r.size] + rng.standard_normal(r.size)
    phi_rr, phi_re = auto_correlation(r, 60), cross_correlation(r, e, 60)[60:]
    power = float(e @ e) / e.size
    alone = reflex.mdl_projection(phi_rr, phi_re, power, e.size)
    shared = reflex.mdl_projection(
        phi_rr, phi_re, power, e.size, reflex.ToeplitzSystem.of_input(r, 60)
    )
    np.testing.assert_array_equal(shared[0], alone[0])
    assert shared[1] == alone[1] < 61

    formed = []
    original = reflex.ToeplitzSystem.of_input.__func__
    monkeypatch.setattr(
        reflex.ToeplitzSystem,
        "of_input",
        classmethod(lambda cls, r, lags: formed.append(lags) or original(cls, r, lags)),
    )
    theta, torque = joint_with_reflex(seconds=6.0, seed=8)
    fit = fit_parallel_cascade(theta, torque, FS_SIM, CascadeSettings(variant="rect"))
    assert fit.iterations >= 2 and formed == [100]  # every alternation, one system


@pytest.mark.parametrize("factor", [2, 25])
def test_the_decimator_is_scipys_bit_for_bit_compiled_or_not(factor, monkeypatch):
    from scipy import signal

    from rtsid.ident import reflex

    x = np.random.default_rng(factor).standard_normal(20_000).cumsum()
    want = signal.decimate(x, factor)
    np.testing.assert_array_equal(reflex.decimated(x, factor), want)  # compiled, when built
    monkeypatch.setattr(reflex, "_eureka", None)
    np.testing.assert_array_equal(reflex.decimated(x, factor), want)


@pytest.mark.parametrize(("n_lags", "fs_model"), [(101, 100.0), (41, 200.0)])
def test_the_dynamics_grid_equals_every_grid_point_evaluated(n_lags, fs_model):
    from rtsid.ident import reflex

    grid = reflex._grid(n_lags, fs_model)
    params, shapes = grid.params, grid.shapes
    lags_s = np.arange(n_lags) / fs_model
    want = reflex._low_pass_response(
        lags_s[None, :] - params[:, :1], 2 * np.pi * params[:, 1:2], params[:, 2:3]
    )
    want /= np.maximum(np.linalg.norm(want, axis=1, keepdims=True), 1e-300)
    assert np.unique(params, axis=0).shape == params.shape  # every (δ, f_c, ζ) once
    # at 100 Hz the times are m × 2 ms, which lag − δ equals to rounding
    np.testing.assert_allclose(shapes, want, rtol=0, atol=1e-13)


@pytest.mark.parametrize(
    "x", [(0.0423, 3.1, 0.7), (0.0123, 7.5, 1.6), (0.0571, 2.0, 1.0 + 1e-7), (0.1033, 0.5, 2.9)]
)
@pytest.mark.parametrize("compiled", [True, False])
def test_the_dynamics_jacobian_is_the_residuals_derivative(x, compiled, monkeypatch):
    from scipy.optimize._numdiff import approx_derivative

    from rtsid.ident import reflex

    if not compiled:
        monkeypatch.setattr(reflex, "_eureka", None)
    lags_s = np.arange(101) / 100.0
    g = reflex._low_pass_response(lags_s - 0.04, 2 * np.pi * 3.0, 0.7) * 10.0
    g += np.random.default_rng(1).standard_normal(g.size)
    model = reflex._DelayedLowPass(g, lags_s)
    x = np.array(x)
    want = approx_derivative(model.residual, x, method="3-point")  # no lag at δ: no kink
    got = model.jacobian(x)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * np.abs(want).max())
    h, _ = reflex._low_pass_and_slopes(lags_s - x[0], 2 * np.pi * x[1], x[2])
    want_h = reflex._low_pass_response(lags_s - x[0], 2 * np.pi * x[1], x[2])
    np.testing.assert_array_equal(h, want_h)


@pytest.mark.parametrize(
    ("delay_s", "corner_hz", "zeta"), [(0.0437, 3.3, 0.62), (0.0211, 6.1, 1.4)]
)
def test_the_dynamics_fit_recovers_an_exact_delayed_low_pass(delay_s, corner_hz, zeta):
    from rtsid.ident.reflex import _low_pass_response, fit_reflex_dynamics

    lags_s = np.arange(101) / 100.0
    g = 12.5 * _low_pass_response(lags_s - delay_s, 2 * np.pi * corner_hz, zeta)
    found = fit_reflex_dynamics(g, 100.0)
    got = [found.gain, found.delay_s, found.corner_hz, found.damping_ratio]
    np.testing.assert_allclose(got, [12.5, delay_s, corner_hz, zeta], rtol=1e-6)
    assert found.vaf > 99.9999


@pytest.mark.parametrize(("n_lags", "fs_model"), [(101, 100.0), (51, 250.0), (41, 200.0)])
def test_the_grids_product_scores_equal_the_response_matrixs(n_lags, fs_model):
    from rtsid.ident import reflex

    grid = reflex._grid(n_lags, fs_model)
    assert bool(grid.residues) == (fs_model != 200.0)  # 5 ms is not a whole number of 2 ms
    rng = np.random.default_rng(n_lags)
    lags_s = np.arange(n_lags) / fs_model
    irfs = [rng.standard_normal(n_lags)] + [
        g * reflex._low_pass_response(lags_s - d, 2 * np.pi * f, z) + rng.standard_normal(n_lags)
        for g, d, f, z in [(10.0, 0.043, 3.1, 0.7), (-4.0, 0.021, 8.0, 1.3)]
    ]
    for g in irfs:
        got = grid.scores(g)
        want = np.abs(grid.shapes @ g)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * want.max())
        assert np.argmax(got) == np.argmax(want)


@pytest.mark.parametrize(("n_lags", "fs_model"), [(101, 100.0), (51, 250.0), (41, 200.0)])
def test_the_grids_norms_are_its_response_matrixs_bit_for_bit(n_lags, fs_model):
    # the norms are summed a delay at a time; the matrix is formed only when asked for
    from rtsid.ident import reflex

    grid = reflex._grid.__wrapped__(n_lags, fs_model)  # a grid of its own, matrix unformed
    assert "shapes" not in vars(grid)
    gathered = grid.table[:, grid.time_of].transpose(1, 0, 2).reshape(-1, n_lags)
    norms = np.linalg.norm(np.ascontiguousarray(gathered), axis=1)
    np.testing.assert_array_equal(grid.norms.ravel(), np.maximum(norms, 1e-300))
    grid.scores(np.ones(n_lags))
    # the product form (a lag step a whole number of 2 ms) scores without the 13 MB matrix
    assert ("shapes" in vars(grid)) == (not grid.residues)
    np.testing.assert_array_equal(grid.shapes, np.ascontiguousarray(gathered) / norms[:, None])


@pytest.mark.parametrize(
    ("n_lags", "fs_model"), [(101, 100.0), (51, 250.0), (101, 125.0), (3, 100.0)]
)
def test_the_grids_strided_placement_is_the_indexed_one_bit_for_bit(n_lags, fs_model):
    from rtsid.ident import reflex

    grid = reflex._grid(n_lags, fs_model)
    g = np.random.default_rng(n_lags).standard_normal(n_lags)
    dots = np.empty(grid.norms.shape)
    for r in grid.residues:
        assert r._strides is not None  # these grids' delays are slices, their rows in step
        indexed = np.zeros((r.table.shape[1], r.delays.size))
        indexed[r.rows, np.arange(r.delays.size)] = g[:, None]
        np.testing.assert_array_equal(r.place(g), indexed)
        dots[r.delays] = (r.table @ indexed).T
    np.testing.assert_array_equal(grid.scores(g), np.abs(dots / grid.norms).ravel())


def test_a_residue_whose_rows_are_not_in_step_is_placed_by_index():
    from rtsid.ident import reflex

    rows = np.array([[0, 3], [1, 5]])  # the second delay's lags two rows apart
    residue = reflex._Residue(np.ones((2, 6)), np.array([0, 1]), rows)
    assert residue._strides is None
    np.testing.assert_array_equal(
        residue.place(np.array([2.0, 7.0])), [[2, 0], [7, 0], [0, 0], [0, 2], [0, 0], [0, 7]]
    )


@pytest.mark.parametrize("fs_hz", [FS_SIM, 1000.0])
def test_the_savitzky_golay_derivatives_are_scipys(fs_hz):
    from scipy import signal

    from rtsid.ident.yardstick import savgol_derivatives

    x = np.random.default_rng(3).standard_normal(3000).cumsum()
    x += 5.0 * np.sin(np.arange(x.size) / 40.0)
    for _ in range(2):  # the second call uses the cached filters
        for deriv, got in zip((1, 2), savgol_derivatives(x, fs_hz), strict=True):
            want = signal.savgol_filter(x, 11, 3, deriv=deriv, delta=1 / fs_hz)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
            assert np.array_equal(got[5:-5], want[5:-5])  # inside the edges: the same filter


@pytest.mark.parametrize("x", [(3.1, 0.7), (7.5, 1.6), (2.0, 1.0 + 1e-7), (0.5, 2.9), (20.0, 0.2)])
def test_the_compiled_low_pass_and_slopes_equal_numpys(x, monkeypatch):
    from rtsid.ident import reflex

    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    t = np.arange(101) / 100.0 - 0.0423
    h, slopes = reflex._low_pass_and_slopes(t, 2 * np.pi * x[0], x[1])
    monkeypatch.setattr(reflex, "_eureka", None)
    want_h, want = reflex._low_pass_and_slopes(t, 2 * np.pi * x[0], x[1])
    np.testing.assert_allclose(h, want_h, rtol=0, atol=1e-12 * np.abs(want_h).max())
    for got_row, want_row in zip(slopes, want, strict=True):  # ζ ≈ 1: 4·10⁻¹⁰
        np.testing.assert_allclose(got_row, want_row, rtol=0, atol=1e-8 * np.abs(want_row).max())


@pytest.mark.parametrize("reflex_gain", [0.0, 10.0])
def test_a_fit_is_the_same_on_the_compiled_and_the_numpy_path(reflex_gain, monkeypatch):
    # the compiled kernels (the dynamics fit among them) against the numpy references, on a
    # horizon with a reflex and one without: decisions equal, every number within 1e-9
    from rtsid.ident import correlation, levinson, reflex, yardstick
    from tests.ident.test_cascade import REFLEX

    theta, torque = joint_with_reflex(8.0, replace(REFLEX, gain=reflex_gain), seed=3)
    compiled = fit_reflex_update(0, 0, theta, torque, None, FS_SIM, SETTINGS)
    for module, name in ((reflex, "_eureka"), (yardstick, "_eureka"), (correlation, "_KERNEL")):
        monkeypatch.setattr(module, name, None)
    monkeypatch.setattr(levinson, "_eureka", None)
    reference = fit_reflex_update(0, 0, theta, torque, None, FS_SIM, SETTINGS)
    assert compiled.error is None and reference.error is None
    assert (compiled.applied, compiled.iterations) == (reference.applied, reference.iterations)
    assert compiled.pathway.rank == reference.pathway.rank
    scale = np.abs(reference.pathway.irf).max()
    np.testing.assert_allclose(compiled.pathway.irf, reference.pathway.irf, atol=1e-9 * scale)
    for field in ("vaf_total", "vaf_intrinsic_only", "window_vaf_gain", "windows_improved"):
        assert getattr(compiled, field) == pytest.approx(getattr(reference, field), rel=1e-9)
    got, want = compiled.pathway.dynamics, reference.pathway.dynamics
    assert got.vaf == pytest.approx(want.vaf, rel=1e-9, abs=1e-9)
    if reflex_gain:  # a low-pass to find: a well-defined optimum
        for field in ("gain", "delay_s", "corner_hz", "damping_ratio"):
            assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-9)


def test_the_due_model_kept_per_due_fit_is_the_scan_of_the_kept_fits(pathway):
    # model_for keeps the newest usable fit of the latest due fit; every add forgets it, so
    # each answer is the scan of the fits kept then (a fit arriving late, for a due fit
    # already asked about, included)
    def scanned(models, end):
        due = models.due_seq(end)
        usable = [u for s, u in models._updates.items() if s <= due and u.pathway is not None]
        if not usable:
            return None, False
        update = max(usable, key=lambda u: u.seq)
        stale = update.seq != due or end + 1 - update.end_index > models.stale_after
        return update, stale

    models = ReflexModels(FS, SETTINGS)
    ends = range(4999, 30_000, 250)
    arrivals = {6000: fitted(pathway, 2, 0, 4000), 9000: ReflexUpdate.failed(3, 0, 6000, "gap")}
    arrivals |= {12_000: fitted(pathway, 4, 0, 8000), 12_500: fitted(pathway, 3, 0, 6000)}
    arrivals |= {20_000: fitted(pathway, 7, 0, 14_000)}
    for end in ends:
        if end + 1 in arrivals:  # a fit lands just before this window
            models.add(arrivals[end + 1])
        assert models.model_for(end) == scanned(models, end), end
        assert models.model_for(end) == scanned(models, end), end  # again, from what it kept
