import math

import numpy as np
import pytest

import rtsid
from rtsid.errors import ConfigError, WindowError
from rtsid.ident import check
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.window import EstimatorOptions, estimate_window, resolve_plan
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance

FS = 2500.0
ANKLE = JointParameters(inertia=0.015, damping=0.8, stiffness=150.0)


def simulated_window(seed, *, noise=10.0, joint=ANKLE, n=750, bandwidth_hz=30.0, stiffness=None):
    rng = np.random.default_rng(seed)
    theta = filtered_noise(n + 2000, FS, bandwidth_hz, peak=0.03, seed=rng)
    tau = simulate_impedance(
        theta, FS, joint, stiffness, noise_percent=noise, seed=rng, t0_s=-1000 / FS
    )
    return theta[1000 : 1000 + n], tau[1000 : 1000 + n]


def relative_errors(estimates, joint=ANKLE):
    truth = np.array([joint.inertia, joint.damping, joint.stiffness])
    got = np.array([[e.I, e.B, e.K] for e in estimates])
    return np.abs(got - truth) / truth


def test_public_entry_point_is_estimate_window():
    assert rtsid.estimate_window is estimate_window


def test_noise_free_window_recovers_the_joint():
    est = estimate_window(*simulated_window(0, noise=0.0), FS)
    np.testing.assert_allclose([est.I, est.B, est.K], [0.015, 0.8, 150.0], rtol=0.05)
    # Not 100 %: the 8th-order derivative stencils lose accuracy in the anti-alias
    # transition band (100–250 Hz at the 500 Hz analysis rate), where inertia still acts.
    assert est.vaf > 97.0 and est.vaf_irf > 97.0
    assert est.irf.shape == est.lags_s.shape
    assert est.lags_s[-1] == pytest.approx(0.02, abs=1 / est.fs_hz)
    assert est.flags == ()


def test_median_errors_with_ten_percent_noise():
    estimates = [estimate_window(*simulated_window(s), FS) for s in range(12)]
    median = np.median(relative_errors(estimates), axis=0)
    assert median[0] < 0.10 and median[1] < 0.06 and median[2] < 0.05, median
    assert min(e.vaf for e in estimates) > 95.0


def test_stiff_ankle_is_identified():
    joint = JointParameters(0.01, 0.3, 400.0)
    estimates = [estimate_window(*simulated_window(s, joint=joint), FS) for s in range(6)]
    median = np.median(relative_errors(estimates, joint), axis=0)
    assert median[2] < 0.05 and median[1] < 0.20, median


def test_soft_ankle_in_a_short_window_is_resolved_by_output_error():
    # K = 30 N·m/rad with I = 0.03 kg·m² resonates at 5 Hz, where |Z| is smallest. The
    # relative (1/|Z|) criterion puts its weight there and loses K (errors of 50–150 %);
    # the output-error fit keeps it within 15 %, and its standard error says how well.
    joint = JointParameters(0.03, 2.0, 30.0)
    for seed in range(4):
        window = simulated_window(seed, joint=joint)
        est = estimate_window(*window, FS)
        assert est.K == pytest.approx(30.0, rel=0.15)
        assert abs(est.K - 30.0) < 3 * est.K_se
        assert est.B == pytest.approx(2.0, rel=0.05)
        relative = estimate_window(*window, FS, fit_method="relative")
        assert "stiffness_uncertain" in relative.flags


def test_standard_errors_match_the_spread_across_realisations():
    estimates = [estimate_window(*simulated_window(100 + s, noise=20.0), FS) for s in range(30)]
    spread = np.std([[e.I, e.B, e.K] for e in estimates], axis=0)
    reported = np.mean([[e.I_se, e.B_se, e.K_se] for e in estimates], axis=0)
    ratio = spread / reported
    assert np.all((ratio > 0.4) & (ratio < 2.5)), ratio


def test_inverted_torque_sign():
    theta, tau = simulated_window(3, noise=0.0)
    plain = estimate_window(theta, tau, FS)
    flipped = estimate_window(theta, -tau, FS, torque_sign=-1.0)
    assert flipped.K == pytest.approx(plain.K)
    wrong = estimate_window(theta, -tau, FS)
    assert wrong.K < 0 and "negative_stiffness" in wrong.flags


def test_logmag_fit_agrees_with_the_linear_fit():
    theta, tau = simulated_window(4, noise=5.0)
    linear = estimate_window(theta, tau, FS)
    logmag = estimate_window(theta, tau, FS, fit_method="logmag")
    assert logmag.method == "logmag"
    assert logmag.K == pytest.approx(linear.K, rel=0.1)


def test_stiffness_change_within_the_window_keeps_vaf_high():
    ramp = StiffnessProfile.ramp(150.0, 375.0, 0.0, 0.3)  # +150 % over the window
    theta, tau = simulated_window(5, stiffness=ramp)
    est = estimate_window(theta, tau, FS)
    assert est.vaf > 90.0
    assert 150.0 < est.K < 375.0


@pytest.mark.parametrize(
    "mutate,reason",
    [
        (lambda p, t: (np.where(np.arange(p.size) == 10, np.nan, p), t), "nan"),
        (lambda p, t: (p, np.where(np.arange(t.size) == 3, np.inf, t)), "nan"),
        (lambda p, t: (np.zeros_like(p), t), "no_excitation"),
        (lambda p, t: (p[:12], t[:12]), "too_short"),
        (lambda p, t: (np.linspace(0.0, 0.05, p.size), t), "no_excitation"),  # a drift
    ],
)
def test_bad_windows_are_withheld_with_a_reason(mutate, reason):
    with pytest.raises(WindowError) as info:
        estimate_window(*mutate(*simulated_window(6)), FS)
    assert info.value.reason == reason


def test_options_are_validated_with_the_key_named():
    with pytest.raises(ConfigError, match="fit_method"):
        EstimatorOptions(fit_method="magic")
    with pytest.raises(ConfigError, match="fit_band_hz"):
        EstimatorOptions(lowpass_hz=100.0, fit_band_hz=(10.0, 150.0))
    with pytest.raises(ConfigError, match="hold"):
        EstimatorOptions(hold="stiffness")
    with pytest.raises(ConfigError, match="torque_sign"):
        EstimatorOptions(torque_sign=2.0)


def test_works_at_1000_hz_with_the_analysis_chosen_from_the_data(rng):
    theta = filtered_noise(3300, 1000.0, 30.0, peak=0.03, seed=rng)
    tau = simulate_impedance(theta, 1000.0, ANKLE, noise_percent=5.0, seed=rng)
    window = theta[1000:1300], tau[1000:1300]
    plan = resolve_plan(window[0], 1000.0, EstimatorOptions())
    # A 30 Hz band (4th order): its 99.9 % power edge lies between 30 and 80 Hz.
    assert 30.0 < plan.edge_hz < 80.0 and plan.lowpass_hz == pytest.approx(1.5 * plan.edge_hz)
    assert plan.analysis_fs_hz >= 10 * plan.lowpass_hz or plan.factor == 1
    est = estimate_window(*window, 1000.0)
    assert est.fs_hz == plan.analysis_fs_hz
    assert est.K == pytest.approx(150.0, rel=0.05)


def test_real_recording_whole_record_matches_the_reference(reklab_path):
    data = np.load(reklab_path)
    est = estimate_window(
        data["position_rad"], data["torque_nm"], float(data["fs_hz"]), torque_sign=-1.0
    )
    # Reference (shared/data/README): |K| ≈ 107 N·m/rad, |B| ≈ 1.3, VAF ≈ 76 %, IRF VAF ≈ 85 %.
    assert 90.0 < est.K < 125.0
    assert 0.6 < est.B < 1.8
    assert 70.0 < est.vaf < 90.0
    assert est.vaf_irf > 80.0


def test_standard_errors_are_positive_for_a_servoed_prbs_perturbation():
    # PRBS through a position servo (what the virtual plant sends) once made the
    # cross-correlation covariance indefinite and a variance clip to zero.
    from rtsid.ident.excitation import prbs
    from rtsid.sim.joint import robot_servo

    rng = np.random.default_rng(11)
    theta = robot_servo(prbs(25_000, 0.03, min_hold=31, seed=rng), FS, 60.0)
    tau = simulate_impedance(theta, FS, ANKLE, noise_percent=3.0, seed=rng)
    z = []
    for start in range(0, theta.size - 750, 400):
        est = estimate_window(theta[start : start + 750], tau[start : start + 750], FS)
        assert est.K_se > 0 and est.B_se > 0 and est.I_se > 0
        z.append((est.K - 150.0) / est.K_se)
    assert np.mean(np.abs(z) > 3) < 0.05


@pytest.mark.parametrize(
    "overrides",
    [
        {},
        {"detrend": "mean", "torque_sign": -1.0},
        {"detrend": "none", "refine": 0},
        {"analysis_fs_hz": None, "lowpass_hz": None, "lag_s": 0.004, "fit_band_hz": (1.0, 60.0)},
        {"analysis_fs_hz": 250.0, "lowpass_hz": 80.0, "fit_band_hz": (1.0, 60.0), "ridge": 0.0},
    ],
)
def test_compiled_front_end_matches_the_numpy_reference(overrides):
    from rtsid.ident import front
    from rtsid.ident.irf import estimate_irf

    if front._eureka is None:
        pytest.skip("compiled kernel not built")
    options = EstimatorOptions(**overrides)
    theta, tau = simulated_window(21, noise=10.0)
    plan = resolve_plan(theta, FS, options)
    u, y, irf = front.front_end(theta, tau, FS, options, plan)
    u_ref, y_ref = front.prepare_window(theta, tau, options, plan)
    fs_a = plan.analysis_fs_hz
    ref = estimate_irf(u_ref, y_ref, fs_a, plan.lag, ridge=options.ridge, refine=options.refine)
    np.testing.assert_allclose(u, u_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(y, y_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(irf.phi_uu, ref.phi_uu, rtol=1e-10)
    np.testing.assert_allclose(irf.h, ref.h, rtol=1e-8, atol=1e-8 * np.max(np.abs(ref.h)))
    assert irf.fs_hz == fs_a


SCALARS = ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit")


@pytest.mark.parametrize(
    "overrides",
    [
        {},
        {"detrend": "mean", "torque_sign": -1.0},
        {"uncertainty": False},
        {"weight_power": 1.0, "fit_points": 7, "fit_band_hz": (0.0, 40.0)},
        {"analysis_fs_hz": None, "lowpass_hz": None, "lag_s": 0.004, "fit_band_hz": (1.0, 60.0)},
        {"analysis_fs_hz": 250.0, "lowpass_hz": 80.0, "fit_band_hz": (1.0, 60.0), "ridge": 0.0},
        {"lag_s": 0.004},  # 2 lags at 500 Hz: fewer than the derivative stencils' 4
    ],
)
def test_compiled_back_end_matches_the_numpy_reference(overrides):
    from rtsid.ident import legacy, window

    if legacy._eureka is None:
        pytest.skip("compiled kernel not built")
    options = EstimatorOptions(fit_method="relative", **overrides)
    theta, tau = simulated_window(23, noise=10.0)
    plan = resolve_plan(theta, FS, options)
    u, y, irf = window.front_end(theta, tau, FS, options, plan)
    compiled = window.back_end(irf, u, y, options, plan)
    reference = legacy.numpy_back_end(irf, u, y, options, plan)
    for name in SCALARS:
        np.testing.assert_allclose(
            getattr(compiled, name), getattr(reference, name), rtol=1e-9, err_msg=name
        )
    assert compiled.flags == reference.flags
    assert np.isnan(compiled.K_se) == (not options.uncertainty)


def test_back_end_rejects_a_window_whose_torque_does_not_respond():
    from rtsid.errors import NumericalError
    from rtsid.ident import window

    # Zero torque (an unplugged sensor): the IRF is zero, so is the fitted response.
    theta, _ = simulated_window(24)
    for method in window.FIT_METHODS:
        options = EstimatorOptions(fit_method=method)
        plan = window.resolve_plan(theta, FS, options)
        u, y, irf = window.front_end(theta, np.zeros_like(theta), FS, options, plan)
        assert not np.any(irf.h)
        with pytest.raises(NumericalError, match="torque does not follow position"):
            window.back_end(irf, u, y, options, plan)
    with pytest.raises(NumericalError, match="torque does not follow position"):
        window.numpy_back_end(irf, u, y, EstimatorOptions(fit_method="relative"), plan)


def test_every_status_of_the_compiled_fit_names_its_problem():
    from rtsid.errors import NotPositiveDefiniteError, NumericalError
    from rtsid.ident import legacy

    kernel = legacy._eureka
    if kernel is None:
        pytest.skip("compiled kernel not built")
    legacy._raise_for_fit_status(kernel.FIT_OK)  # no error
    expected = {
        kernel.FIT_FIRST_SINGULAR: "cannot separate inertia from stiffness",
        kernel.FIT_FINAL_SINGULAR: "cannot separate inertia from stiffness",
        kernel.FIT_ZERO_RESPONSE: "torque does not follow position",
        kernel.FIT_NOT_PD: "not positive definite",
    }
    for status, message in expected.items():
        with pytest.raises(NumericalError, match=message):
            legacy._raise_for_fit_status(status)
    with pytest.raises(NotPositiveDefiniteError):
        legacy._raise_for_fit_status(kernel.FIT_NOT_PD)


@pytest.mark.parametrize(
    "held",
    [{}, {"inertia": 0.015}, {"inertia": 0.015, "damping": 0.8}],
)
@pytest.mark.parametrize("uncertainty", [True, False])
def test_compiled_output_error_fit_matches_the_numpy_reference(held, uncertainty, monkeypatch):
    from rtsid.ident import second_order, window

    if second_order._eureka is None:
        pytest.skip("compiled kernel not built")
    options = EstimatorOptions()
    theta, tau = simulated_window(25, noise=10.0)
    plan = resolve_plan(theta, FS, options)
    u, y, irf = window.front_end(theta, tau, FS, options, plan)
    compiled = second_order.OutputErrorDesign(u, y, irf.fs_hz)
    monkeypatch.setattr(second_order, "_eureka", None)
    reference = second_order.OutputErrorDesign(u, y, irf.fs_hz)
    np.testing.assert_allclose(compiled.gram, reference.gram, rtol=1e-9)
    args = {"uncertainty": uncertainty, "noise_lags": 25, **held}
    got, want = compiled.fit(**args), reference.fit(**args)
    np.testing.assert_allclose(got.params, want.params, rtol=1e-9)
    np.testing.assert_allclose(got.se, want.se, rtol=1e-9)  # NaN where held / not computed
    np.testing.assert_allclose(
        got.model, want.model, rtol=1e-9, atol=1e-9 * np.abs(want.model).max()
    )
    assert np.isnan(got.se[0]) == (bool(held) or not uncertainty)


@pytest.mark.parametrize("explained", [False, True])
def test_compiled_output_error_assessment_matches_the_numpy_reference(explained, monkeypatch):
    from rtsid.ident import assess, second_order, window

    if assess._eureka is None:
        pytest.skip("compiled kernel not built")
    options = EstimatorOptions()
    theta, tau = simulated_window(26, noise=10.0)
    reflex = 0.3 * np.sin(np.arange(theta.size) / 40.0) if explained else None
    plan = resolve_plan(theta, FS, options)
    analysed = window.analyse_window(theta, tau, FS, options, plan, explained=reflex)
    irf, u, y = analysed.signals
    fit = second_order.OutputErrorDesign(u, y, irf.fs_hz).fit(uncertainty=True, noise_lags=25)
    compiled = assess.assess(irf, u, y, fit, options, score=analysed.score)
    monkeypatch.setattr(assess, "_eureka", None)
    reference = assess.assess(irf, u, y, fit, options, score=analysed.score)
    for name in ("vaf", "vaf_irf", "vaf_fit"):
        np.testing.assert_allclose(getattr(compiled, name), getattr(reference, name), rtol=1e-9)
    assert compiled.flags == reference.flags


@pytest.mark.skipif(check._eureka is None, reason="compiled kernel not built")
def test_the_compiled_window_sums_are_numpys(monkeypatch):
    rng = np.random.default_rng(21)
    position = 0.03 * rng.standard_normal(750) + 0.2  # an offset: the squares' sum is large
    torque = 40.0 * rng.standard_normal(750) - 3.0
    lost = torque.copy()
    lost[100] = np.nan  # a lost sample recorded as NaN: the torque's sum says so
    got, got_lost = check.window_sums(position, torque), check.window_sums(position, lost)
    monkeypatch.setattr(check, "_eureka", None)
    want = check.window_sums(position, torque)
    assert all(type(v) is float for v in got + want)
    assert got == pytest.approx(want, rel=1e-9, abs=1e-9 * float(np.abs(torque).sum()))
    assert math.isnan(got_lost[1]) and math.isnan(check.window_sums(position, lost)[1])
    assert got_lost[0] == got[0] and got_lost[2] == got[2]


@pytest.mark.parametrize(("samples", "lag"), [(750, 50), (188, 12), (101, 3), (400, 1)])
def test_the_sweeps_gram_matrix_from_the_correlation_sums_is_the_lagged_rows_own(samples, lag):
    from numpy.lib.stride_tricks import sliding_window_view

    from rtsid.ident.correlation import auto_sums, cross_sums, lagged_cross, lagged_gram

    theta, tau = simulated_window(31 + samples, n=samples)
    lagged = sliding_window_view(theta, 2 * lag + 1)[:, ::-1]  # row t: u(t − k), k = −L … L
    gram = lagged_gram(theta, auto_sums(theta, 2 * lag), lag)
    cross = lagged_cross(theta, tau, cross_sums(theta, tau, lag), lag)
    want_gram, want_cross = lagged.T @ lagged, lagged.T @ tau[lag : samples - lag]
    np.testing.assert_allclose(gram, want_gram, rtol=0, atol=1e-13 * np.abs(want_gram).max())
    np.testing.assert_allclose(cross, want_cross, rtol=0, atol=1e-13 * np.abs(want_cross).max())
    assert np.array_equal(gram, gram.T)


@pytest.mark.parametrize("left_out", [False, True])
def test_a_gram_sweep_is_the_residual_sweep_and_they_converge_to_least_squares(left_out, rng):
    # one sweep's gradient X'y − X'X·h/fs is the correlation of the input with the residual
    # over the rows; many converge to the (ridge-free) least-squares IRF on the rows kept
    from numpy.lib.stride_tricks import sliding_window_view

    from rtsid.ident.irf import estimate_irf
    from rtsid.ident.levinson import eureka_unchecked

    fs, lag, n = 500.0, 6, 300
    u = rng.standard_normal(n)
    y = np.convolve(u, rng.standard_normal(2 * lag + 1), mode="same") + rng.standard_normal(n)
    rows = np.ones(n - 2 * lag, dtype=bool)
    if left_out:
        rows[40:70] = False
    lagged = sliding_window_view(u, 2 * lag + 1)[:, ::-1]
    first = estimate_irf(u, y, fs, lag, rows=rows)
    error = (y[lag:-lag] - lagged @ (first.h / fs)) * rows
    residual_sweep = first.h + eureka_unchecked(first.phi_uu, error @ lagged / rows.sum()) * fs
    one = estimate_irf(u, y, fs, lag, refine=1, rows=rows)
    np.testing.assert_allclose(one.h, residual_sweep, rtol=0, atol=1e-12 * np.abs(one.h).max())
    converged = estimate_irf(u, y, fs, lag, refine=60, rows=rows)
    least_squares = np.linalg.lstsq(lagged[rows], y[lag:-lag][rows], rcond=None)[0] * fs
    np.testing.assert_allclose(
        converged.h, least_squares, rtol=0, atol=1e-9 * np.abs(converged.h).max()
    )
