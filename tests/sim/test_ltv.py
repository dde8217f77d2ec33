import numpy as np
import pytest

from rtsid.errors import InputDataError
from rtsid.ident.excitation import multisine
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_admittance
from rtsid.sim.ltv import (
    STUDY_JOINT,
    multisine_experiment,
    simulate_ltv_admittance,
    simulate_ltv_block,
    study_stiffness,
)


def test_rk4_sub_steps_match_an_adaptive_dop853_reference():
    fs = 200.0
    ms = multisine(fs, 2.0, 10.0, every=2, rms=0.1, seed=3)
    stiffness = study_stiffness("CS3", 4.0)
    n = 800
    t = np.arange(n) / fs
    reference = simulate_admittance(
        lambda x: float(ms.evaluate(x)), t, STUDY_JOINT, stiffness, rtol=1e-11, atol=1e-14
    )
    fast = simulate_ltv_admittance(
        ms.evaluate, fs, n, STUDY_JOINT, stiffness, input_period_samples=ms.period_samples
    )
    rms = np.sqrt(np.mean(reference**2))
    assert np.sqrt(np.mean((fast - reference) ** 2)) < 1e-8 * rms
    # Coarser sub-steps are worse: the error really comes from the integrator (4th order).
    coarse = simulate_ltv_admittance(ms.evaluate, fs, n, STUDY_JOINT, stiffness, substeps=1)
    assert np.sqrt(np.mean((coarse - reference) ** 2)) > 100 * np.sqrt(
        np.mean((fast - reference) ** 2)
    )


def test_periodic_shortcut_equals_direct_evaluation():
    fs = 100.0
    ms = multisine(fs, 1.0, 5.0, rms=1.0, seed=1)
    joint = JointParameters(inertia=0.02, damping=0.05)
    k = StiffnessProfile.ramp(1.0, 3.0, 0.0, 3.0)
    direct = simulate_ltv_admittance(ms.evaluate, fs, 300, joint, k, substeps=4)
    tiled = simulate_ltv_admittance(
        ms.evaluate, fs, 300, joint, k, substeps=4, input_period_samples=100
    )
    np.testing.assert_allclose(tiled, direct, rtol=0, atol=1e-12 * np.max(np.abs(direct)))


def test_constant_stiffness_settles_to_the_frequency_response():
    fs, f = 200.0, 1.5
    joint = JointParameters(inertia=0.02, damping=0.05)
    k = 2.0
    n = 6000  # 30 s: the transient (time constant 2I/B = 0.8 s) has died out
    phi = simulate_ltv_admittance(
        lambda t: np.cos(2 * np.pi * f * t), fs, n, joint, StiffnessProfile.constant(k)
    )
    w = 2 * np.pi * f
    g = 1 / (k - joint.inertia * w**2 + 1j * joint.damping * w)
    t = np.arange(n) / fs
    expected = np.real(g * np.exp(1j * w * t))
    np.testing.assert_allclose(phi[-1000:], expected[-1000:], atol=1e-7 * abs(g))


def test_experiment_has_whole_periods_truth_and_the_requested_snr():
    exp = multisine_experiment(
        "CS1", period_s=2.0, n_periods=5, spacing_hz=1.0, snr_db=20.0, seed=4
    )
    assert exp.torque_nm.size == 5 * exp.period_samples == 2000
    assert exp.n_periods == 5
    np.testing.assert_allclose(exp.stiffness_nm_per_rad[[0, -1]], [0.4, 6.0], rtol=1e-3)
    noise = exp.position_rad - exp.position_clean_rad
    snr = 20 * np.log10(np.sqrt(np.mean(exp.position_clean_rad**2)) / np.std(noise))
    assert snr == pytest.approx(20.0, abs=0.5)
    np.testing.assert_allclose(exp.excited_bins, np.arange(2, 21, 2))
    saved = exp.as_npz_dict()
    assert {"torque_nm", "position_rad", "fs_hz", "excited_bins", "period_samples"} <= set(saved)


def test_bad_case_and_spacing_are_rejected():
    with pytest.raises(InputDataError, match="CS1, CS2, CS3"):
        study_stiffness("CS9", 10.0)
    with pytest.raises(InputDataError, match=r"multiple of 0\.1 Hz"):
        multisine_experiment("CS1", spacing_hz=0.25, n_periods=2)


@pytest.mark.parametrize("period", [None, 250])
def test_blocks_carrying_the_state_equal_one_long_simulation(period):
    fs = 250.0
    ms = multisine(fs, 1.0, 20.0, every=2, rms=0.5, seed=4)
    joint = JointParameters(inertia=0.015, damping=0.3)
    k = StiffnessProfile("raised_cosine", k0=20.0, k1=150.0, t0=0.0, t1=3.0)
    n = 750
    whole = simulate_ltv_admittance(
        ms.evaluate, fs, n, joint, k, substeps=3, input_period_samples=period
    )
    pieces, state, first = [], (0.0, 0.0), 0
    for size in (1, 99, 250, 37, 363):  # seams anywhere, also mid-period
        angle, state = simulate_ltv_block(
            ms.evaluate,
            fs,
            first,
            size,
            joint,
            k,
            state=state,
            substeps=3,
            input_period_samples=period,
        )
        pieces.append(angle)
        first += size
    blocks = np.concatenate(pieces)
    np.testing.assert_allclose(blocks, whole, rtol=0, atol=1e-12 * np.max(np.abs(whole)))
    with pytest.raises(InputDataError, match="first_sample"):
        simulate_ltv_block(ms.evaluate, fs, -1, 10, joint, k)
