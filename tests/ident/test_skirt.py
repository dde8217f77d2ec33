import warnings

import numpy as np
import pytest

from rtsid.errors import InputDataError, NumericalError
from rtsid.ident.excitation import multisine
from rtsid.ident.skirt import (
    BASIS_FAMILIES,
    WARN_VARIANCE_INFLATION,
    LtvEstimate,
    SkirtConditioningWarning,
    _band_limited,
    _design,
    _layouts,
    _SearchRecord,
    basis_functions,
    fit_admittance,
    identify_ltv,
    legendre_basis,
    max_stable_basis,
    select_basis_size,
    select_model,
    skirt_conditioning,
)

FS = 100.0
PERIODS = 10
INERTIA, DAMPING = 0.02, 0.05


@pytest.fixture
def ms():
    """2 s period (0.5 Hz grid), every 2nd bin up to 10 Hz: lines 1 Hz = 20 record bins apart."""
    return multisine(FS, 2.0, 10.0, every=2, rms=0.1, seed=7)


def ltv_output(u, bins, g_p):
    """Exact output of y = Σ_p b_p(t)·(g_p * u)(t) for a periodic u (steady state)."""
    n = u.size
    record_bins = bins * (n // (2 * int(FS)))
    x = np.zeros((g_p.shape[0], n // 2 + 1), dtype=complex)
    x[:, record_bins] = np.fft.rfft(u)[record_bins] * g_p
    return np.sum(legendre_basis(n, g_p.shape[0]) * np.fft.irfft(x, n, axis=1), axis=0)


def admittance(k, w):
    return 1.0 / (k - INERTIA * w**2 + 1j * DAMPING * w)


def test_lti_system_is_recovered_exactly_with_one_basis_function(ms):
    u = ms.samples(PERIODS)
    g = admittance(2.0, 2 * np.pi * ms.frequencies_hz)
    y = ltv_output(u, ms.excited_bins, g[None, :])
    est = identify_ltv(u, y, FS, ms.excited_bins, ms.period_samples, n_basis=1)
    np.testing.assert_allclose(est.G_p[0], g, rtol=1e-10)
    np.testing.assert_allclose(est.frequencies_hz, ms.frequencies_hz)
    np.testing.assert_allclose(est.simulate(u), y, atol=1e-10 * np.std(y))


@pytest.mark.parametrize(
    ("n_transient", "neighbours", "tolerance"), [(None, 1, 5e-2), (2, 1, 5e-3), (2, 3, 1e-4)]
)
def test_known_ltv_system_is_recovered_and_reproduced(ms, n_transient, neighbours, tolerance):
    rng = np.random.default_rng(1)
    n_basis = 4
    g_p = rng.standard_normal((n_basis, ms.excited_bins.size)) + 1j * rng.standard_normal(
        (n_basis, ms.excited_bins.size)
    )
    g_p /= np.arange(1, n_basis + 1)[:, None]
    u = ms.samples(PERIODS)
    y = ltv_output(u, ms.excited_bins, g_p)
    est = identify_ltv(
        u,
        y,
        FS,
        ms.excited_bins,
        ms.period_samples,
        n_basis=n_basis,
        n_transient=n_transient,
        neighbours=neighbours,
    )
    # Lines beyond the modelled neighbours (and the mirror lines at negative frequencies)
    # leak into each window. This synthetic system has large high-order G_p at every line,
    # the worst case: the defaults recover it to a few %, and modelling more neighbours plus
    # the transient polynomial (which absorbs far leakage) converges towards exact.
    assert np.max(np.abs(est.G_p - g_p)) < tolerance * np.max(np.abs(g_p))
    # Another realisation of the multisine through the estimated model.
    u_val = multisine(FS, 2.0, 10.0, every=2, rms=0.1, seed=8).samples(PERIODS)
    y_val = ltv_output(u_val, ms.excited_bins, g_p)
    assert np.std(est.simulate(u_val) - y_val) < tolerance * np.std(y_val)
    # G(t) is the basis expansion at any time.
    t = np.array([0.0, 3.3, est.duration_s])
    expected = legendre_basis(est.n_samples, n_basis)[:, [0, 330, -1]].T @ g_p
    np.testing.assert_allclose(est.G(t), expected, rtol=0, atol=10 * tolerance)


def test_skirt_columns_are_the_dft_of_the_modulated_basis_with_1_over_n_and_wrap():
    n, n_basis = 600, 4
    basis = legendre_basis(n, n_basis)
    skirts = np.fft.fft(basis, axis=1)
    bins = np.array([6, 18, 30])  # the first line's window reaches down to bin 1: offsets wrap
    layout = _layouts(bins, n, window_lines=1.0, neighbours=1)[0]
    design, n_own = _design(layout, skirts, n, n_transient=None)
    k = bins[0] + layout.offsets
    t = np.arange(n)
    own_expected = [
        np.fft.fft(basis[p] * np.exp(2j * np.pi * bins[0] * t / n))[k] / n for p in range(n_basis)
    ]
    np.testing.assert_allclose(design[:, :n_own], np.array(own_expected).T, atol=1e-12)
    # A numpy cosine of amplitude A has U(k_e) = N·A/2·e^{jφ}: the model needs its 1/N.
    a, phi = 0.3, 0.7
    u = a * np.cos(2 * np.pi * bins[0] * t / n + phi)
    assert np.fft.fft(u)[bins[0]] == pytest.approx(n * a / 2 * np.exp(1j * phi))
    # The line above (18) lies inside this wide window, so its p = 0 column enters.
    assert layout.neighbours == (12,)
    assert design.shape[1] == 2 * n_basis


def test_neighbour_constant_skirt_is_dropped_outside_the_window():
    n = 600
    skirts = np.fft.fft(legendre_basis(n, 3), axis=1)
    layout = _layouts(np.array([20, 40, 60]), n, window_lines=0.5, neighbours=1)[1]
    design, n_own = _design(layout, skirts, n, n_transient=None)
    assert layout.neighbours == (-20, 20)
    assert design.shape[1] == n_own + 2 * 2  # neighbours contribute p = 1, 2 only


def test_time_varying_joint_from_the_ode_reaches_high_vaf():
    from rtsid.sim.ltv import multisine_experiment

    # The published study's geometry (200 s, 20 periods of 10 s, lines 0.8 Hz apart, CS3,
    # SNR 22 dB) at 25 Hz sampling to keep the test fast.
    kw = dict(fs_hz=25.0, period_s=10.0, n_periods=20, f_max_hz=8.0, spacing_hz=0.8)
    est_exp = multisine_experiment("CS3", snr_db=22.0, seed=1, **kw)
    val_exp = multisine_experiment("CS3", snr_db=None, seed=2, **kw)
    est = identify_ltv(
        est_exp.torque_nm,
        est_exp.position_rad,
        est_exp.fs_hz,
        est_exp.excited_bins,
        est_exp.period_samples,
        n_basis=12,
    )
    y = val_exp.position_clean_rad
    vaf = 100 * (1 - np.var(y - est.simulate(val_exp.torque_nm)) / np.var(y))
    assert vaf > 88.0
    # At the record's very ends (t = 0, T) the Legendre expansion is least reliable and
    # K/I can come out negative (no resonance): the track is NaN there, so start 1 s in.
    track = est.fit_second_order(np.linspace(1.0, est.duration_s - 1.0, 199))
    k_true = np.interp(track.t_s, np.arange(y.size) / 25.0, est_exp.stiffness_nm_per_rad)
    fn_true = np.sqrt(k_true / INERTIA) / (2 * np.pi)
    assert np.sqrt(np.mean((track.natural_frequency_hz - fn_true) ** 2)) < 0.1
    assert np.all(np.isfinite(track.natural_frequency_hz))
    inner = slice(20, -20)
    assert np.sqrt(np.mean((track.stiffness - k_true)[inner] ** 2)) < 0.5
    # The paper's peak-picking metric cannot beat the line grid (0.8 Hz / √12 ≈ 0.23 Hz).
    peak = est.resonance_from_peak(track.t_s)
    assert np.sqrt(np.mean((peak - fn_true) ** 2)) > 0.8 / np.sqrt(12) * 0.8


def test_second_order_fit_recovers_k_b_i_exactly():
    w = 2 * np.pi * np.arange(1.0, 10.0)
    k = np.array([0.4, 2.0, 6.0])
    g = admittance(k[:, None], w[None, :])
    theta, err = fit_admittance(g, w)
    np.testing.assert_allclose(theta[:, 0], k, rtol=1e-9)
    np.testing.assert_allclose(theta[:, 1], INERTIA, rtol=1e-9)
    np.testing.assert_allclose(theta[:, 2], DAMPING, rtol=1e-9)
    assert np.all(err < 1e-9)


def test_common_inertia_is_fitted_jointly_while_stiffness_stays_free():
    w = 2 * np.pi * np.arange(1.0, 10.0)
    k = np.linspace(0.4, 6.0, 25)
    g = admittance(k[:, None], w[None, :])
    rng = np.random.default_rng(2)
    noisy = g * (1 + 0.02 * (rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape)))
    free, _ = fit_admittance(noisy, w)
    held, _ = fit_admittance(noisy, w, common=("inertia",))
    assert np.ptp(held[:, 1]) == 0.0  # one inertia for every time
    assert held[0, 1] == pytest.approx(INERTIA, rel=0.01)
    assert np.std(held[:, 0] - k) < np.std(free[:, 0] - k)
    exact, _ = fit_admittance(g, w, common=("inertia", "damping"))
    np.testing.assert_allclose(exact[:, 0], k, rtol=1e-8)
    np.testing.assert_allclose(exact[:, 2], DAMPING, rtol=1e-8)
    with pytest.raises(InputDataError, match="'inertia', 'damping'"):
        fit_admittance(g, w, common=("mass",))


def test_resonance_from_peak_picks_the_line_of_largest_gain(ms):
    g = admittance(3.2, 2 * np.pi * ms.frequencies_hz)  # f_n = 2.01 Hz
    est = LtvEstimate(
        g[None, :],
        np.zeros((1, g.size)),
        ms.frequencies_hz,
        ms.excited_bins,
        FS,
        ms.period_samples,
        PERIODS,
        2,
        1.0,
    )
    np.testing.assert_allclose(est.resonance_from_peak([0.0, 5.0]), [2.0, 2.0])
    track = est.fit_second_order([1.0])
    assert track.natural_frequency_hz[0] == pytest.approx(np.sqrt(3.2 / INERTIA) / (2 * np.pi))


def test_input_that_is_not_the_declared_multisine_is_rejected(ms):
    rng = np.random.default_rng(0)
    u = rng.standard_normal(ms.period_samples * PERIODS)
    with pytest.raises(InputDataError, match="not a periodic multisine"):
        identify_ltv(u, u, FS, ms.excited_bins, ms.period_samples)
    u = ms.samples(PERIODS)
    with pytest.raises(InputDataError, match="not a periodic multisine"):
        identify_ltv(u, u, FS, ms.excited_bins[::2], ms.period_samples)  # bins missing
    with pytest.raises(InputDataError, match="DC offset of 0.5"):
        identify_ltv(u + 0.5, u, FS, ms.excited_bins, ms.period_samples)
    with pytest.raises(InputDataError, match="carries no power"):
        identify_ltv(u, u, FS, np.r_[ms.excited_bins, ms.excited_bins[-1] + 1], ms.period_samples)


def test_record_that_is_not_whole_periods_is_rejected(ms):
    u = ms.samples(PERIODS)[:-37]
    with pytest.raises(InputDataError, match="whole number of 200-sample periods"):
        identify_ltv(u, u, FS, ms.excited_bins, ms.period_samples)
    u = ms.samples(PERIODS)
    with pytest.raises(InputDataError, match="periods of 200 samples"):
        identify_ltv(u, u, FS, ms.excited_bins, ms.period_samples, n_periods=9)
    with pytest.raises(InputDataError, match="differ in length"):
        identify_ltv(u, u[:-1], FS, ms.excited_bins, ms.period_samples)
    y = u.copy()
    y[5] = np.nan
    with pytest.raises(InputDataError, match="non-finite value at sample 5"):
        identify_ltv(u, y, FS, ms.excited_bins, ms.period_samples)


def test_too_many_basis_functions_for_the_line_spacing_warn_then_fail(ms):
    u = ms.samples(PERIODS)
    y = ltv_output(u, ms.excited_bins, admittance(2.0, 2 * np.pi * ms.frequencies_hz)[None, :])
    stable = max_stable_basis(u.size, 20)
    assert 3 <= stable <= 10
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        identify_ltv(u, y, FS, ms.excited_bins, ms.period_samples, n_basis=stable)
    with pytest.warns(SkirtConditioningWarning, match=rf"use N_p <= {stable} for lines 1 Hz"):
        est = identify_ltv(u, y, FS, ms.excited_bins, ms.period_samples, n_basis=stable + 2)
    assert est.variance_inflation > WARN_VARIANCE_INFLATION
    with pytest.raises(NumericalError, match="too large for Δf_exc = 1 Hz"):
        identify_ltv(u, y, FS, ms.excited_bins, ms.period_samples, n_basis=17)


def test_conditioning_worsens_with_basis_size_and_eases_with_spacing():
    n = 4000
    narrow = [skirt_conditioning(n, 40, p).max_variance_inflation for p in (2, 6, 10)]
    assert narrow[0] < narrow[1] < narrow[2]
    assert skirt_conditioning(n, 160, 10).max_variance_inflation < narrow[2]
    assert max_stable_basis(n, 160, n_max=16) > max_stable_basis(n, 40, n_max=16)
    with pytest.raises(InputDataError, match="no bins for the skirts"):
        skirt_conditioning(n, 1, 2)


def test_validation_input_must_match_the_record(ms):
    u = ms.samples(PERIODS)
    est = identify_ltv(u, 0.5 * u, FS, ms.excited_bins, ms.period_samples, n_basis=2)
    np.testing.assert_allclose(est.G_p[0], 0.5, rtol=1e-10)
    np.testing.assert_allclose(est.G_p[1], 0.0, atol=1e-10)
    with pytest.raises(InputDataError, match="same length"):
        est.simulate(u[:-200])
    with pytest.raises(InputDataError, match="not a periodic multisine"):
        est.simulate(np.random.default_rng(0).standard_normal(u.size))


# --------------------------------------------------------------------------------------
# basis families
# --------------------------------------------------------------------------------------


def family_output(u, bins, g_p, family):
    """Exact output of y = Σ_p b_p(t)·(g_p * u)(t) with b_p of ``family`` (steady state)."""
    n = u.size
    record_bins = bins * (n // (2 * int(FS)))
    x = np.zeros((g_p.shape[0], n // 2 + 1), dtype=complex)
    x[:, record_bins] = np.fft.rfft(u)[record_bins] * g_p
    basis = basis_functions(n, g_p.shape[0], family)
    return np.sum(basis * np.fft.irfft(x, n, axis=1), axis=0)


def test_families_and_their_skirts():
    assert BASIS_FAMILIES == ("legendre", "fourier", "bspline")
    n = 1000
    np.testing.assert_array_equal(basis_functions(n, 5), legendre_basis(n, 5))
    # Fourier: 1, cos θ, sin θ, cos 2θ, sin 2θ with θ = 2πn/N; each skirt is bins ±h only.
    skirts = np.fft.fft(basis_functions(n, 5, "fourier"), axis=1) / n
    for p, h in enumerate((0, 1, 1, 2, 2)):
        on = np.abs(skirts[p]) > 1e-9
        assert set(np.flatnonzero(on)) == {h % n, -h % n}
    # B-splines: clamped (1 at the record's first sample), a partition of unity, local.
    b = basis_functions(n, 12, "bspline")
    np.testing.assert_allclose(b.sum(axis=0), 1.0, atol=1e-12)
    assert b[0, 0] == 1.0 and b[-1, -1] == 1.0 and b.min() >= 0.0
    assert np.count_nonzero(b[6]) < n * 4 / 9 + 2  # support: 4 of the 9 knot intervals
    with pytest.raises(InputDataError, match="unknown basis family 'wavelet'; choose one of"):
        basis_functions(n, 3, "wavelet")


@pytest.mark.parametrize("family", ["legendre", "fourier", "bspline"])
def test_estimate_evaluates_its_own_family(family):
    """G(t), simulate() and the estimate's basis use the family it was estimated with."""
    ms = multisine(FS, 2.0, 40.0, every=8, rms=0.1, seed=7)  # lines 80 record bins apart
    rng = np.random.default_rng(3)
    n_basis = 5
    g_p = (rng.standard_normal((n_basis, ms.excited_bins.size)) + 1j) / 4
    g_p[0] += admittance(2.0, 2 * np.pi * ms.frequencies_hz)
    u = ms.samples(PERIODS)
    y = family_output(u, ms.excited_bins, g_p, family)
    # Lines beyond the neighbours leak into the windows of Legendre and B-spline skirts (see
    # test_known_ltv_system_is_recovered_and_reproduced): model three each side and the
    # transient polynomial. Fourier skirts are two bins no other line reaches: exact as is.
    exact = family == "fourier"
    est = identify_ltv(
        u,
        y,
        FS,
        ms.excited_bins,
        ms.period_samples,
        n_basis=n_basis,
        basis_family=family,
        n_transient=None if exact else 2,
        neighbours=1 if exact else 3,
    )
    assert est.basis_family == family
    t = np.arange(u.size) / FS
    np.testing.assert_allclose(est.basis(t), basis_functions(u.size, n_basis, family), atol=1e-12)
    tolerance = 1e-9 if exact else 1e-3
    assert np.max(np.abs(est.G_p - g_p)) < tolerance * np.max(np.abs(g_p))
    assert np.std(est.simulate(u) - y) < tolerance * np.std(y)
    with pytest.raises(InputDataError, match="unknown basis family"):
        identify_ltv(u, y, FS, ms.excited_bins, ms.period_samples, basis_family="Fourier")


def test_fourier_recovers_a_cyclic_change_that_legendre_cannot(ms):
    """G(jω, t) = G_0·(1 + 0.3·sin(4θ)): four cycles per record, exactly N_p = 9 Fourier terms."""
    g0 = admittance(2.0, 2 * np.pi * ms.frequencies_hz)
    g_p = np.zeros((9, g0.size), dtype=complex)
    g_p[0], g_p[8] = g0, 0.3 * g0  # row 8: sin 4θ
    u = ms.samples(PERIODS)
    y = family_output(u, ms.excited_bins, g_p, "fourier")
    t = np.arange(u.size) / FS
    truth = basis_functions(u.size, 9, "fourier").T @ g_p
    errors = {}
    for family in ("fourier", "legendre"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkirtConditioningWarning)
            est = identify_ltv(
                u, y, FS, ms.excited_bins, ms.period_samples, n_basis=9, basis_family=family
            )
        errors[family] = np.max(np.abs(est.G(t) - truth)) / np.max(np.abs(truth))
    assert errors["fourier"] < 1e-9
    assert errors["legendre"] > 0.3
    # Chosen from noisy data, N_p reaches the 4th harmonic and the model predicts well.
    rng = np.random.default_rng(5)
    noisy = y + 0.05 * np.std(y) * rng.standard_normal(y.size)
    sel = select_basis_size(
        u, noisy, FS, ms.excited_bins, ms.period_samples, basis_family="fourier"
    )
    assert sel.n_basis >= 9 and sel.n_stable == 19  # lines 20 bins apart: harmonics ≤ 9
    assert sel.n_cap == 101 and sel.cap_reason.startswith(
        "N_p ≤ 19 of 101: harmonic 10 of the record would put a line's skirt on the next "
        "line's, 20 record bins (1 Hz) away"
    )
    assert all(c % 2 for c in sel.candidates)  # whole harmonics only
    below = [v for c, v in zip(sel.candidates, sel.predicted_vaf, strict=True) if c < 9]
    assert sel.chosen_vaf > max(below)
    assert np.max(np.abs(sel.estimate.G(t) - truth)) < 0.1 * np.max(np.abs(truth))


def test_bsplines_follow_a_local_change_that_legendre_cannot():
    """A 0.8 s bump in G at t = 12 s of 20 s: each family at its largest stable N_p."""
    wide = multisine(FS, 2.0, 40.0, every=8, rms=0.1, seed=7)  # lines 80 record bins apart
    u = wide.samples(PERIODS)
    t = np.arange(u.size) / FS
    record_bins = wide.excited_bins * PERIODS
    g0 = 1.0 / (
        200.0
        - 0.02 * (2 * np.pi * wide.frequencies_hz) ** 2
        + 0.5j * 2 * np.pi * wide.frequencies_hz
    )
    x = np.zeros(u.size // 2 + 1, dtype=complex)
    x[record_bins] = np.fft.rfft(u)[record_bins] * g0
    modulation = 1.0 + 0.5 * np.exp(-0.5 * ((t - 12.0) / 0.8) ** 2)
    y = modulation * np.fft.irfft(x, u.size)
    truth = modulation[:, None] * g0[None, :]
    stable = {
        f: max_stable_basis(u.size, 80, n_max=60, basis_family=f) for f in ("legendre", "bspline")
    }
    assert stable["bspline"] > stable["legendre"]  # narrower skirts: more functions fit
    errors = {}
    for family, n_basis in stable.items():
        est = identify_ltv(
            u, y, FS, wide.excited_bins, wide.period_samples, n_basis=n_basis, basis_family=family
        )
        errors[family] = np.sqrt(
            np.mean(np.abs(est.G(t) - truth) ** 2) / np.mean(np.abs(truth) ** 2)
        )
    assert errors["bspline"] < 0.005 < 0.01 < errors["legendre"]


def test_a_family_that_cannot_fit_the_line_spacing_is_refused_in_one_line(ms):
    u = ms.samples(PERIODS)
    y = 0.5 * u
    # Lines 20 record bins apart: harmonic 10 of line k reaches bin k + 10 = (k + 20) − 10.
    est = identify_ltv(
        u, y, FS, ms.excited_bins, ms.period_samples, n_basis=19, basis_family="fourier"
    )
    assert est.variance_inflation == pytest.approx(1.0)
    with pytest.raises(NumericalError) as info:
        identify_ltv(
            u, y, FS, ms.excited_bins, ms.period_samples, n_basis=21, basis_family="fourier"
        )
    message = str(info.value)
    assert "\n" not in message
    assert "harmonic 10 of the record" in message and "use N_p <= 19" in message
    # B-splines far too many for the spacing: the local problems are singular.
    with pytest.raises(
        NumericalError, match="cubic B-spline skirts .* use N_p <= 1[0-9] for lines 1 Hz"
    ):
        identify_ltv(
            u, y, FS, ms.excited_bins, ms.period_samples, n_basis=40, basis_family="bspline"
        )
    with pytest.warns(SkirtConditioningWarning, match="B-spline"):
        identify_ltv(
            u, y, FS, ms.excited_bins, ms.period_samples, n_basis=13, basis_family="bspline"
        )


def test_bspline_conditioning_ignores_the_basis_own_correlation():
    """B-splines are not orthogonal; what is checked is what the skirts cost, not that."""
    n = 4000
    cond = skirt_conditioning(n, 160, 12, basis_family="bspline")
    assert cond.max_variance_inflation < 1.5
    assert max_stable_basis(n, 160, n_max=40, basis_family="bspline") > max_stable_basis(
        n, 160, n_max=40
    )


def _cyclic_record(ms, noise=0.02, seed=5):
    """A Fourier-exact LTV output (2 cycles per record) with white noise, at FS."""
    g0 = admittance(2.0, 2 * np.pi * ms.frequencies_hz)
    g_p = np.zeros((5, g0.size), dtype=complex)
    g_p[0], g_p[3] = g0, 0.4 * g0  # row 3: cos 2θ
    u = ms.samples(PERIODS)
    y = family_output(u, ms.excited_bins, g_p, "fourier")
    rng = np.random.default_rng(seed)
    return u, y + noise * np.std(y) * rng.standard_normal(y.size)


def test_the_search_runs_on_the_band_limited_record_with_the_same_lines():
    """Lines up to 5 Hz sampled at 100 Hz: the search keeps the bins up to the highest line
    + 2.5 spacings and resamples to the fewest samples per period that hold them."""
    low = multisine(FS, 2.0, 5.0, every=2, rms=0.1, seed=7)  # lines 20 record bins apart
    u, y = _cyclic_record(low)
    full = _SearchRecord.build(u, y, FS, low.excited_bins, low.period_samples, None)
    short, d, band_hz = _band_limited(full)
    assert d == 5 and short.n_samples == u.size // 5 and short.period_samples == 40
    assert band_hz == pytest.approx((100 + 2.5 * 20) * FS / u.size)
    # The kept bins are the record's (scaled by 1/d), so the local problems see the same data.
    kept = np.arange(151)
    np.testing.assert_allclose(np.fft.rfft(short.y)[kept] * d, np.fft.rfft(y)[kept], atol=1e-9)
    np.testing.assert_allclose(np.fft.rfft(short.u)[kept] * d, np.fft.rfft(u)[kept], atol=1e-9)
    # The estimates from it: the same for Fourier terms (periodic over either record); the
    # other bases sampled at the lower rate move G_p by well under 1 %.
    tolerance = {"fourier": 1e-9, "legendre": 1e-2, "bspline": 1e-2}
    for family in BASIS_FAMILIES:
        a = identify_ltv(
            u, y, FS, low.excited_bins, low.period_samples, n_basis=5, basis_family=family
        )
        b = identify_ltv(
            short.u,
            short.y,
            FS / d,
            low.excited_bins,
            short.period_samples,
            n_basis=5,
            basis_family=family,
        )
        assert np.max(np.abs(a.G_p - b.G_p)) < tolerance[family] * np.max(np.abs(a.G_p))


def test_select_model_chooses_the_family_and_n_p_of_best_predicted_vaf(ms):
    u, y = _cyclic_record(ms)
    chosen = select_model(u, y, FS, ms.excited_bins, ms.period_samples)
    scores = [sel.chosen_vaf for sel in chosen.families]
    assert scores == sorted(scores, reverse=True)
    assert {sel.basis_family for sel in chosen.families} == set(BASIS_FAMILIES)
    assert chosen.chosen.basis_family == "fourier" and chosen.chosen.n_basis >= 5
    # Each family's choice is select_basis_size's on the record the search ran on.
    assert chosen.decimation == 2
    one = select_model(u, y, FS, ms.excited_bins, ms.period_samples, families=("legendre",))
    assert one.families[0].n_basis == chosen.families[-1].n_basis or len(one.families) == 1
    # The chosen model comes back estimated on the whole record.
    assert chosen.estimate.n_samples == u.size
    assert chosen.estimate.basis_family == "fourier"
    assert chosen.estimate.n_basis == chosen.chosen.n_basis
    with pytest.raises(InputDataError, match="unknown basis family"):
        select_model(u, y, FS, ms.excited_bins, ms.period_samples, families=("wavelet",))
