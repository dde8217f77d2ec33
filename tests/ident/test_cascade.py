import numpy as np
import pytest

from rtsid.errors import InputDataError
from rtsid.ident.cascade import (
    CascadeSettings,
    fit_parallel_cascade,
    intrinsic_parameters,
    sliding_cascades,
)
from rtsid.sim.joint import JointParameters, derivatives
from rtsid.sim.reflex import ReflexParameters, prbs_ankle_with_reflex, reflex_torque

FS = 2500.0
JOINT = JointParameters(0.015, 0.8, 150.0)
REFLEX = ReflexParameters(gain=10.0, delay_s=0.04, corner_hz=3.0, damping_ratio=0.7)


def joint_with_reflex(seconds=20.0, reflex=REFLEX, noise_percent=10.0, seed=1):
    """A PRBS-perturbed ankle (40 Hz band, 0.03 rad, 60 Hz servo) with a stretch reflex."""
    return prbs_ankle_with_reflex(
        seconds, FS, JOINT, reflex, noise_percent=noise_percent, seed=seed
    )


@pytest.mark.parametrize("variant", ["rect", "hammerstein"])
def test_the_cascade_recovers_a_known_reflex_and_the_intrinsic_stiffness(variant):
    theta, torque = joint_with_reflex()
    fit = fit_parallel_cascade(theta, torque, FS, CascadeSettings(variant=variant))
    assert fit.fs_hz == 100.0 and fit.reflex.irf.size == 101
    assert fit.vaf_total > fit.vaf_intrinsic_only + 10.0
    assert fit.vaf_total > 98.0
    assert fit.reflex.gain == pytest.approx(REFLEX.gain, rel=0.15)
    assert fit.reflex.delay_s == pytest.approx(REFLEX.delay_s, abs=0.005)
    assert 1 <= fit.reflex.rank <= fit.reflex.irf.size
    intrinsic = intrinsic_parameters(theta, torque, FS, fit.reflex)
    assert intrinsic.K == pytest.approx(JOINT.stiffness, rel=0.05)
    # without the reflex pathway the fit folds reflex torque into K and B
    plain = intrinsic_parameters(
        theta,
        torque,
        FS,
        fit.reflex.__class__(**{**fit.reflex.__dict__, "irf": np.zeros_like(fit.reflex.irf)}),
    )
    assert abs(plain.K - JOINT.stiffness) > abs(intrinsic.K - JOINT.stiffness)


def test_the_reflex_prediction_follows_the_true_reflex_torque():
    theta, torque = joint_with_reflex()
    fit = fit_parallel_cascade(theta, torque, FS)
    velocity, _ = derivatives(theta, FS)
    truth = reflex_torque(velocity, FS, REFLEX)
    predicted = fit.reflex.torque(theta, FS)
    skip = round(fit.reflex.history_s * FS)
    residual = (predicted - truth)[skip:]
    residual -= residual.mean()  # the pathway's input is mean-removed: an offset is free
    assert np.std(residual) < 0.15 * np.std(truth[skip:])


def test_without_a_reflex_the_cascade_adds_nothing():
    theta, torque = joint_with_reflex(reflex=None)
    fit = fit_parallel_cascade(theta, torque, FS)
    assert fit.vaf_total == pytest.approx(fit.vaf_intrinsic_only, abs=0.5)
    assert fit.vaf_reflex_path < 1.0


def test_a_record_too_short_for_the_reflex_horizon_names_the_minimum():
    theta, torque = joint_with_reflex(seconds=2.0)
    with pytest.raises(InputDataError, match="at least 3 s"):
        fit_parallel_cascade(theta, torque, FS)


def test_an_unknown_reflex_variant_is_refused_in_one_line():
    with pytest.raises(InputDataError, match="'wiener' is not one of"):
        CascadeSettings(variant="wiener")


def test_sliding_cascades_cover_the_record_window_by_window():
    theta, torque = joint_with_reflex(seconds=12.0)
    windows = list(sliding_cascades(theta, torque, FS, 6.0, 2.0))
    assert [(w.start_index, w.end_index) for w in windows] == [
        (0, 14999),
        (5000, 19999),
        (10000, 24999),
        (15000, 29999),
    ]
    for w in windows:
        assert w.cascade.reflex.gain == pytest.approx(REFLEX.gain, rel=0.3)
        assert w.intrinsic.K == pytest.approx(JOINT.stiffness, rel=0.05)


def test_the_shared_recording_matches_the_reference_figures(reklab_path):
    data = np.load(reklab_path)
    fit = fit_parallel_cascade(data["position_rad"], -data["torque_nm"], float(data["fs_hz"]))
    # shared/data/README: intrinsic-only ≈ 85 %, cascade ≈ 93 %
    assert fit.vaf_intrinsic_only == pytest.approx(85.0, abs=1.5)
    assert fit.vaf_total >= 92.0


def test_mdl_drops_the_components_noise_dominates_and_so_beats_the_full_rank_irf():
    from rtsid.ident.correlation import auto_correlation, cross_correlation
    from rtsid.ident.levinson import eureka
    from rtsid.ident.reflex import convolve_causal, mdl_projection

    rng = np.random.default_rng(3)
    r = np.convolve(rng.standard_normal(4000), np.ones(5) / 5, mode="same")  # coloured input
    g = REFLEX.impulse_response(100.0, 0.5)
    clean = convolve_causal(r, g, 100.0)
    lags = g.size - 1
    phi_rr = auto_correlation(r, lags)
    ranks = []
    for noise in (0.05, 1.0):
        e = clean + noise * np.std(clean) * rng.standard_normal(r.size)
        phi_re = cross_correlation(r, e, lags)[lags:]
        projected, rank = mdl_projection(phi_rr, phi_re, float(e @ e) / e.size, e.size)
        full = eureka(phi_rr, phi_re)
        ranks.append(rank)
        error_mdl = np.linalg.norm(projected * 100.0 - g)
        error_full = np.linalg.norm(full * 100.0 - g)
        assert error_mdl <= error_full
    assert ranks[1] < ranks[0] <= g.size


def test_a_delay_at_a_bound_of_its_search_is_flagged_and_a_found_one_is_not(reklab_path):
    # issue 19: the shared record's cascade printed "delay 10.0 ms", a delay pinned at the
    # first model lag (the same at 200 and 250 Hz), as if it were measured
    from rtsid.ident.reflex import delay_search_s

    theta, torque = joint_with_reflex()
    found = fit_parallel_cascade(theta, torque, FS).reflex.dynamics
    assert found.delay_search_s == delay_search_s(100.0) == (0.01, 0.2)
    assert found.delay_at_bound is None
    assert found.describe_delay() == f"delay {found.delay_s * 1e3:.1f} ms"
    data = np.load(reklab_path)
    real = fit_parallel_cascade(data["position_rad"], -data["torque_nm"], float(data["fs_hz"]))
    dynamics = real.reflex.dynamics
    assert dynamics.delay_at_bound == "lower"
    assert "at the lower bound of the 10–200 ms search" in dynamics.describe_delay()


def test_the_delay_search_never_starts_before_the_first_model_lag():
    from rtsid.ident.reflex import fit_reflex_dynamics

    lags_s = np.arange(101) / 100.0
    onset_at_lag_0 = np.exp(-lags_s / 0.05)  # a response from lag 0 on: no resolvable delay
    dynamics = fit_reflex_dynamics(onset_at_lag_0, 100.0)
    assert dynamics.delay_s >= 0.01 - 1e-9 and dynamics.delay_at_bound == "lower"
