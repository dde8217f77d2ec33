"""The reflex dynamics fit's own bounded solver, held to scipy's ``least_squares`` (TRF)."""

import numpy as np
import pytest
from scipy import optimize

from rtsid.ident import reflex
from rtsid.ident.levinson import eureka
from rtsid.ident.reflex import bounded_least_squares, fit_reflex_dynamics

LAGS_S = np.arange(101) / 100.0
LOW, HIGH = np.array([0.01, 0.3, 0.2]), np.array([0.2, 20.0, 3.0])


def _rosenbrock(x):
    return np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])


def _rosenbrock_jacobian(x):
    return np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]])


def test_the_solver_finds_scipys_optimum_of_a_bounded_rosenbrock():
    # scipy's documented example: the bound x1 >= 1.5 holds at the optimum
    low, high = np.array([-10.0, 1.5]), np.array([10.0, 10.0])
    want = optimize.least_squares(
        _rosenbrock, [2.0, 2.0], jac=_rosenbrock_jacobian, bounds=(low, high)
    )
    x, cost = bounded_least_squares(
        _rosenbrock, _rosenbrock_jacobian, np.array([2.0, 2.0]), low, high, np.ones(2)
    )
    assert x[1] == 1.5  # on the bound exactly, where TRF stays strictly inside
    np.testing.assert_allclose(x, want.x, rtol=1e-7)
    assert cost <= want.cost * (1 + 1e-12)
    # the unbounded parameter is at its optimum along the bound: zero slope
    r, j = _rosenbrock(x), _rosenbrock_jacobian(x)
    assert abs((j.T @ r)[0]) < 1e-8


def test_a_start_outside_the_box_is_clipped_into_it():
    x, _ = bounded_least_squares(
        _rosenbrock,
        _rosenbrock_jacobian,
        np.array([-30.0, 40.0]),
        np.array([-2.0, -2.0]),
        np.array([2.0, 2.0]),
        np.ones(2),
    )
    np.testing.assert_allclose(x, [1.0, 1.0], rtol=1e-8)


def _noisy_irf(seed, delay_s, corner_hz, zeta, noise):
    g = 10.0 * reflex._low_pass_response(LAGS_S - delay_s, 2 * np.pi * corner_hz, zeta)
    return g + noise * np.random.default_rng(seed).standard_normal(g.size)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize(
    ("seed", "delay_s", "corner_hz", "zeta", "noise", "same_point"),
    [
        (0, 0.043, 3.1, 0.7, 0.5, True),
        (1, 0.021, 6.0, 1.3, 1.0, True),
        (2, 0.052, 2.2, 0.5, 2.0, True),
        # hardly a low-pass: a flat valley, where TRF stops early
        (3, 0.04, 3.0, 0.7, 30.0, False),
        # the delay and corner end at their bounds, which TRF only approaches from inside
        # (its ζ then stops 3e-5 short of the optimum along them)
        (4, 0.0, 19.0, 0.7, 0.2, False),
    ],
)
def test_the_dynamics_fit_is_no_worse_than_scipys_trf_from_the_same_start(
    seed, delay_s, corner_hz, zeta, noise, same_point, compiled, monkeypatch
):
    if not compiled:
        monkeypatch.setattr(reflex, "_eureka", None)
    g = _noisy_irf(seed, delay_s, corner_hz, zeta, noise)
    model = reflex._DelayedLowPass(g, LAGS_S)
    start = np.array(reflex._best_on_grid(g, 100.0))
    trf = optimize.least_squares(  # the fit's solver before it had its own
        model.residual,
        start,
        jac=model.jacobian,
        bounds=(LOW, HIGH),
        x_scale=[0.01, 1.0, 0.3],
    )
    x, cost = bounded_least_squares(
        model.residual, model.jacobian, start, LOW, HIGH, reflex.DYNAMICS_SCALE
    )
    assert np.all((x >= LOW) & (x <= HIGH))
    assert cost <= trf.cost * (1 + 1e-9)
    assert cost == pytest.approx(0.5 * float(model.residual(x) @ model.residual(x)), rel=1e-15)
    if same_point:  # a well-defined optimum inside the box
        np.testing.assert_allclose(x, trf.x, rtol=1e-6, atol=1e-12)
    found = fit_reflex_dynamics(g, 100.0)
    got = [found.delay_s, found.corner_hz, found.damping_ratio]
    if compiled:  # the compiled solver: the same steps, sums in another order
        np.testing.assert_allclose(got, x, rtol=1e-9)
    else:
        np.testing.assert_array_equal(got, x)


@pytest.mark.parametrize("seed", range(12))
def test_the_compiled_dynamics_fit_reaches_the_numpy_solvers_optimum(seed):
    # shaped and noise-only IRFs (flat valleys, parameters on their bounds), and a singular
    # start: the compiled loop's cost equals the numpy reference's to the solver's tolerance
    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    rng = np.random.default_rng(seed)
    shape = 10.0 * reflex._low_pass_response(
        LAGS_S - rng.uniform(0.0, 0.1), 2 * np.pi * rng.uniform(0.5, 15.0), rng.uniform(0.3, 2.0)
    )
    g = shape * (seed % 3 != 0) + rng.uniform(0.01, 5.0) * rng.standard_normal(LAGS_S.size)
    start = np.array(reflex._best_on_grid(g, 100.0))
    model = reflex._DelayedLowPass(g, LAGS_S)
    want_x, want = bounded_least_squares(
        model.residual, model.jacobian, start, LOW, HIGH, reflex.DYNAMICS_SCALE
    )
    x, cost = reflex._dynamics_solution(g, LAGS_S, start, (LOW, HIGH))
    assert cost == pytest.approx(want, rel=reflex.FIT_TOLERANCE)
    assert cost == pytest.approx(0.5 * float(model.residual(x) @ model.residual(x)), rel=1e-12)
    np.testing.assert_allclose(x, want_x, rtol=1e-6)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize(
    ("rows", "n", "factor"), [(3, 20_000, 25), (1, 5_001, 10), (6, 600, 2), (2, 5_003, 25)]
)
def test_rows_decimated_together_are_scipys_decimate_of_each_bit_for_bit(
    rows, n, factor, compiled, monkeypatch
):
    from scipy import signal

    if not compiled:
        monkeypatch.setattr(reflex, "_eureka", None)
    x = np.random.default_rng(n).standard_normal((rows, n)).cumsum(axis=1)
    got = reflex.decimated_rows(list(x), factor)
    np.testing.assert_array_equal(got, np.vstack([signal.decimate(r, factor) for r in x]))


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize(("rows", "n"), [(4, 7_000), (3, 2_500), (1, 40), (5, 1_003), (7, 2_502)])
def test_zero_phase_rows_is_scipys_sosfiltfilt_of_each_row_bit_for_bit(
    rows, n, compiled, monkeypatch
):
    from scipy import signal

    if not compiled:
        monkeypatch.setattr(reflex, "_eureka", None)
    x = np.random.default_rng(rows).standard_normal((rows, n)).cumsum(axis=1)
    for sos in (signal.butter(4, 40.0, fs=2500.0, output="sos"), reflex._decimator(10).sos):
        want = np.vstack([signal.sosfiltfilt(sos, r) for r in x])
        np.testing.assert_array_equal(reflex.zero_phase_rows(sos, x), want)


def test_the_compiled_rows_kernel_names_inconsistent_sizes():
    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    d = reflex._decimator(10)
    x = np.zeros((2, 100))
    with pytest.raises(ValueError, match="zero_phase_rows: inconsistent sizes"):
        reflex._eureka.zero_phase_rows(d.sos, d.zi, x, 100, d.edge, 10, np.empty((2, 9)))
    with pytest.raises(ValueError, match="zero_phase_rows: inconsistent sizes"):
        rows = (np.zeros(100), np.zeros(99))
        reflex._eureka.zero_phase_rows(d.sos, d.zi, rows, 100, d.edge, 10, np.empty((2, 10)))
    with pytest.raises(TypeError, match="each row must be a contiguous float64 buffer"):
        rows = (np.zeros(100), np.zeros(100, dtype=np.float32))
        reflex._eureka.zero_phase_rows(d.sos, d.zi, rows, 100, d.edge, 10, np.empty((2, 10)))


def test_a_cascades_inputs_decimated_with_its_record_are_those_formed_alone():
    x = np.random.default_rng(5).standard_normal((2, 10_000)).cumsum(axis=1) * 1e-3
    inputs, (u, y) = reflex.ReflexInputs.decimating(x[0], (x[0], x[1]), 2500.0, 25, "rect")
    alone = reflex.ReflexInputs(x[0], 2500.0, 25, "rect")
    np.testing.assert_array_equal(inputs.rectified, alone.rectified)
    assert inputs.scale == alone.scale
    np.testing.assert_array_equal(u, reflex.decimated(x[0], 25))
    np.testing.assert_array_equal(y, reflex.decimated(x[1], 25))


def test_the_stretch_velocity_is_the_window_paths_first_derivative():
    from rtsid.ident.correlation import detrend
    from rtsid.ident.filters import derivatives

    for n in (9, 12, 5_000):
        x = np.random.default_rng(n).standard_normal(n).cumsum()
        want, _ = derivatives(detrend(x, "linear"), 2500.0)
        np.testing.assert_array_equal(reflex.stretch_velocity(x, 2500.0), want)
    with pytest.raises(reflex.InputDataError, match="at least 9 samples"):
        reflex.stretch_velocity(np.zeros(8), 2500.0)


def test_the_stretch_velocitys_ends_are_numpys_gradient_bit_for_bit():
    rng = np.random.default_rng(5)
    for _ in range(500):
        x = rng.standard_normal(10).cumsum() * 10.0 ** rng.uniform(-6, 2)
        dt = 1.0 / float(rng.choice([100.0, 1000.0, 2500.0, 2999.0]))
        head, tail = reflex._gradient_ends(x[:5].tolist(), x[-5:].tolist(), dt)
        np.testing.assert_array_equal(head, np.gradient(x[:5], dt, edge_order=2)[:4])
        np.testing.assert_array_equal(tail, np.gradient(x[-5:], dt, edge_order=2)[-4:])


@pytest.mark.parametrize("n", [9, 10, 300, 50_001])
def test_the_compiled_stencil_velocity_is_numpys_correlation_bit_for_bit(n):
    from rtsid.ident import filters

    x = np.random.default_rng(n).standard_normal(n).cumsum() * 1e-3
    want = np.correlate(x, filters._D1, mode="valid") * 2500.0
    np.testing.assert_array_equal(filters.stencil_velocity(x, 2500.0), want)
    into = np.full(n + 2, np.nan)
    filters.stencil_velocity(x, 2500.0, out=into[5 : n - 3])  # a view of a longer array
    np.testing.assert_array_equal(into[5 : n - 3], want)
    assert np.isnan(into[:5]).all() and np.isnan(into[n - 3 :]).all()
    backwards = x[::-1]  # not contiguous: numpy's own correlation
    np.testing.assert_array_equal(
        filters.stencil_velocity(backwards, 2500.0),
        np.correlate(backwards, filters._D1, mode="valid") * 2500.0,
    )
    if filters._KERNEL is None:
        pytest.skip("the compiled kernel is not built: the numpy path was checked")
    with pytest.raises(ValueError, match="stencil_correlate: out must have"):
        filters._KERNEL.stencil_correlate(x, filters._D1, 2500.0, np.empty(n))


def test_a_prediction_at_the_data_rate_from_a_sample_on_is_the_same_numbers():
    low = np.random.default_rng(2).standard_normal(200)
    whole = reflex.to_data_rate(low, 10, 2_000)
    np.testing.assert_array_equal(reflex.to_data_rate(low, 10, 2_000, 777), whole[777:])
    np.testing.assert_array_equal(reflex.to_data_rate(low, 1, 200, 50), low[50:])


def test_the_evidence_reads_the_reflex_prediction_from_its_lead_on_only():
    from rtsid.ident.cascade import fit_parallel_cascade
    from rtsid.ident.reflex_lane import evidence_lead, window_vaf_gains
    from tests.ident.test_cascade import FS, joint_with_reflex

    theta, torque = joint_with_reflex(seconds=14.0, seed=3)
    fit = fit_parallel_cascade(theta, torque, FS)
    first = round(fit.reflex.history_s * FS)
    whole = fit.record_reflex_torque(theta, FS)
    lead = evidence_lead(theta.size, FS, first)
    assert 0 < lead < theta.size
    tail = fit.record_reflex_torque(theta, FS, lead)
    np.testing.assert_array_equal(tail, whole[lead:])
    padded = np.zeros(theta.size)
    padded[lead:] = tail
    want = window_vaf_gains(theta, torque, whole, FS, first)
    np.testing.assert_array_equal(window_vaf_gains(theta, torque, padded, FS, first), want)


@pytest.mark.parametrize("n", [11, 12, 40, 27_500])
def test_the_savitzky_golay_derivatives_are_the_same_compiled_or_not(n, monkeypatch):
    from rtsid.ident import yardstick

    x = np.random.default_rng(n).standard_normal(n).cumsum()
    compiled = yardstick.savgol_derivatives(x, 2500.0)
    monkeypatch.setattr(yardstick, "_eureka", None)
    reference = yardstick.savgol_derivatives(x, 2500.0)
    for got, want in zip(compiled, reference, strict=True):
        np.testing.assert_array_equal(got, want)


def test_the_compiled_convolution_is_ndimages_for_any_taps():
    from scipy import ndimage

    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    rng = np.random.default_rng(4)
    x = rng.standard_normal(3_000).cumsum()
    general = rng.standard_normal(7)
    symmetric = np.concatenate((general[:3], general[3:4], general[:3][::-1]))
    antisymmetric = np.concatenate((general[:3], [0.0], -general[:3][::-1]))
    for a, b in ((symmetric, antisymmetric), (general, general[::-1].copy())):
        d1, d2 = np.empty(x.size), np.empty(x.size)
        reflex._eureka.savgol_pair(x, a, b, d1, d2)
        np.testing.assert_array_equal(d1, ndimage.convolve1d(x, a, mode="constant"))
        np.testing.assert_array_equal(d2, ndimage.convolve1d(x, b, mode="constant"))
    for n in (3, 6, 7, 8, 13):  # shorter than the taps, and interiors not a whole vector
        short = x[:n].copy()
        d1, d2 = np.empty(n), np.empty(n)
        reflex._eureka.savgol_pair(short, symmetric, general, d1, d2)
        np.testing.assert_array_equal(d1, ndimage.convolve1d(short, symmetric, mode="constant"))
        np.testing.assert_array_equal(d2, ndimage.convolve1d(short, general, mode="constant"))
    with pytest.raises(ValueError, match="savgol_pair: inconsistent sizes"):
        reflex._eureka.savgol_pair(x, np.ones(4), np.ones(4), d1, d2)


@pytest.mark.parametrize("lags", [3, 4, 5, 60, 101])
def test_the_toeplitz_systems_halves_give_the_whole_matrixs_eigenpairs(lags):
    from rtsid.ident.correlation import auto_correlation

    r = np.maximum(np.random.default_rng(lags).standard_normal(4000), 0.0)
    phi = auto_correlation(r - r.mean(), lags - 1)
    matrix = phi[np.abs(np.arange(lags)[:, None] - np.arange(lags)[None, :])]
    system = reflex.ToeplitzSystem.of(phi)
    want = np.linalg.eigh(matrix)[0]
    scale = float(want.max())
    assert np.all(np.diff(system.eigenvalues) >= 0)  # ascending, as numpy's
    np.testing.assert_allclose(system.eigenvalues, want, rtol=0, atol=1e-13 * scale)
    v = system.vectors
    np.testing.assert_allclose(v.T @ v, np.eye(lags), rtol=0, atol=1e-13)
    np.testing.assert_allclose(matrix @ v, v * system.eigenvalues, rtol=0, atol=1e-13 * scale)
    # the MDL projection of a reflex-like cross-correlation is the whole matrix's to rounding
    e = np.convolve(r - r.mean(), np.exp(-np.arange(30) / 8.0))[: r.size]
    e += np.random.default_rng(1).standard_normal(r.size)
    phi_re = np.array([(r - r.mean())[: r.size - k] @ e[k:] for k in range(lags)]) / r.size
    full = eureka(phi, phi_re)
    power = float(e @ e) / e.size
    got, rank = reflex.mdl_on_eigenpairs(system.eigenvalues, v, full, power, e.size)
    ref, ref_rank = reflex.mdl_on_eigenpairs(*np.linalg.eigh(matrix), full, power, e.size)
    assert rank == ref_rank
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11 * np.abs(ref).max())


def _mdl_problem(lags, seed):
    """A rectified input's autocorrelation, a reflex-like output's cross-correlation (noise
    from small to dominant), the output's power and its samples."""
    from rtsid.ident.correlation import auto_correlation

    rng = np.random.default_rng(1000 * seed + lags)
    r = np.maximum(rng.standard_normal(4000), 0.0)
    r -= r.mean()
    e = np.convolve(r, np.exp(-np.arange(30) / (2.0 + seed)))[: r.size]
    e += (0.1 + seed / 5.0) * rng.standard_normal(r.size)
    phi_re = np.array([r[: r.size - k] @ e[k:] for k in range(lags)]) / r.size
    return auto_correlation(r, lags - 1), phi_re, float(e @ e) / e.size, e.size


@pytest.mark.parametrize("lags", [4, 5, 6, 7, 60, 100, 101])
def test_the_compiled_mdl_rank_is_the_eigendecompositions_to_rounding(lags, monkeypatch):
    # branch fits7: tridiagonal QL with its rotations on the coefficients, no eigenvectors
    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    ranks = set()
    for seed in range(12):
        phi, phi_re, power, n = _mdl_problem(lags, seed)
        got, rank = reflex.mdl_projection(phi, phi_re, power, n)
        system = reflex.ToeplitzSystem.of(phi)
        want, want_rank = reflex.mdl_on_eigenpairs(
            system.eigenvalues, system.vectors, eureka(phi, phi_re), power, n
        )
        assert rank == want_rank
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * np.abs(want).max())
        ranks.add(rank)
    assert len(ranks) > 1  # the noise moves the rank: the criterion is exercised, not pinned
    with monkeypatch.context() as m:  # the numpy path is the eigenpairs' (the reference)
        m.setattr(reflex, "_eureka", None)
        np.testing.assert_array_equal(reflex.mdl_projection(phi, phi_re, power, n)[0], want)


def test_the_compiled_mdl_rank_of_an_output_it_all_explains_is_one_component():
    # power_e 0: every residual is at the 1e-300 floor, the description length grows with M
    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    phi, phi_re, _, n = _mdl_problem(101, 0)
    full = eureka(phi, phi_re)
    out = np.empty(101)
    system = reflex.ToeplitzSystem.of(phi)
    assert reflex._eureka.mdl_rank(system.decomposition, full, 0.0, float(n), out) == 1
    want, rank = reflex.mdl_on_eigenpairs(system.eigenvalues, system.vectors, full, 0.0, n)
    assert rank == 1
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-11 * np.abs(want).max())


def test_the_compiled_mdl_rank_names_inconsistent_sizes():
    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    with pytest.raises(ValueError, match="mdl_decompose: at least 4 lags"):
        reflex._eureka.mdl_decompose(np.ones(3))
    decomposition = reflex.ToeplitzSystem.of(_mdl_problem(8, 0)[0]).decomposition
    with pytest.raises(ValueError, match="mdl_rank: inconsistent sizes"):
        reflex._eureka.mdl_rank(decomposition, np.ones(7), 1.0, 10.0, np.empty(8))
    with pytest.raises(ValueError, match="mdl_rank: not a decomposition"):
        reflex._eureka.mdl_rank(decomposition[:-8], np.ones(8), 1.0, 10.0, np.empty(8))


def test_a_rect_cascade_forms_no_eigenvectors_on_the_compiled_path(monkeypatch):
    from rtsid.ident.cascade import CascadeSettings, fit_parallel_cascade
    from rtsid.sim.joint import JointParameters
    from rtsid.sim.reflex import ReflexParameters, prbs_ankle_with_reflex

    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    formed = []
    halves = reflex._centrosymmetric_halves
    monkeypatch.setattr(reflex, "_centrosymmetric_halves", lambda p: formed.append(1) or halves(p))
    theta, torque = prbs_ankle_with_reflex(
        6.0, 2500.0, JointParameters(0.015, 0.8, 150.0), ReflexParameters(10.0, 0.04, 3.0, 0.7)
    )
    fit = fit_parallel_cascade(theta, torque, 2500.0, CascadeSettings(variant="rect"))
    assert fit.reflex.rank >= 1 and formed == []
    monkeypatch.setattr(reflex, "_eureka", None)  # the numpy path forms them, once
    fit = fit_parallel_cascade(theta, torque, 2500.0, CascadeSettings(variant="rect"))
    assert fit.reflex.rank >= 1 and formed == [1]


@pytest.mark.parametrize(
    ("m", "factor", "n", "first"),
    [
        (2000, 25, 50_000, 22_500),
        (2000, 25, 50_030, 17),
        (3, 10, 40, 0),
        (1, 5, 9, 2),
        (10, 4, 100, 39),
    ],
)
def test_a_prediction_at_the_data_rate_is_numpys_interpolation_bit_for_bit(m, factor, n, first):
    low = np.random.default_rng(m + first).standard_normal(m)
    want = np.interp(np.arange(first, n), np.arange(m) * factor, low)
    np.testing.assert_array_equal(reflex.to_data_rate(low, factor, n, first), want)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize(("n", "lags"), [(2000, 100), (300, 60), (50, 3)])
def test_the_causal_cross_correlation_is_the_two_sided_ones_right_half(
    n, lags, compiled, monkeypatch
):
    from rtsid.ident import correlation

    if not compiled:
        monkeypatch.setattr(correlation, "_KERNEL", None)
    u, y = np.random.default_rng(n).standard_normal((2, n))
    want = correlation.cross_correlation(u, y, lags)[lags:]
    np.testing.assert_array_equal(correlation.causal_cross_correlation(u, y, lags), want)


@pytest.mark.parametrize(("n", "taps"), [(2000, 101), (2000, 9), (60, 101), (101, 101), (1, 1)])
def test_the_compiled_causal_convolution_is_numpys_to_rounding(n, taps):
    # the cascade's pathway prediction: the first n samples of numpy.convolve, taps longer or
    # shorter than the signal; each output summed in another order than numpy's BLAS dots
    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    r, g = np.random.default_rng(n + taps).standard_normal((2, max(n, taps)))
    r, g = r[:n].cumsum(), g[:taps] * 1e3
    want = reflex.convolve_causal_reference(r, g, 100.0)
    got = reflex.convolve_causal(r, g, 100.0)
    assert got.shape == want.shape == (n,)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.max(np.abs(want)))
    assert got[0] == want[0] == r[0] * (g[0] / 100.0)


def test_the_numpy_path_convolves_with_numpy(monkeypatch):
    monkeypatch.setattr(reflex, "_eureka", None)
    r, g = np.random.default_rng(5).standard_normal((2, 300))
    want = np.convolve(r, g[:40] / 100.0)[:300]
    np.testing.assert_array_equal(reflex.convolve_causal(r, g[:40], 100.0), want)


def test_the_compiled_convolution_names_inconsistent_sizes():
    if reflex._eureka is None:
        pytest.skip("the compiled kernel is not built")
    with pytest.raises(ValueError, match="causal_convolve: out must have r's size"):
        reflex._eureka.causal_convolve(np.zeros(10), np.ones(3), 1.0, np.empty(9))
    with pytest.raises(ValueError, match="causal_convolve: out must have r's size"):
        reflex._eureka.causal_convolve(np.zeros(10), np.ones(0), 1.0, np.empty(10))
    with pytest.raises(TypeError, match="out must be a contiguous float64 buffer"):
        reflex._eureka.causal_convolve(np.zeros(10), np.ones(3), 1.0, np.empty(10, np.float32))
