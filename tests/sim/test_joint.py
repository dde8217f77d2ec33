import numpy as np
import pytest

from rtsid.errors import InputDataError
from rtsid.ident.excitation import multisine
from rtsid.sim.joint import (
    JointParameters,
    StiffnessProfile,
    add_noise,
    derivatives,
    robot_servo,
    simulate_admittance,
    simulate_impedance,
)


def test_derivatives_of_a_sine_are_exact_in_band():
    fs, f = 2500.0, 40.0
    t = np.arange(2500) / fs
    x = np.sin(2 * np.pi * f * t)
    d1, d2 = derivatives(x, fs)
    w = 2 * np.pi * f
    inner = slice(4, -4)
    np.testing.assert_allclose(d1[inner], w * np.cos(w * t)[inner], atol=1e-6 * w)
    np.testing.assert_allclose(d2[inner], -(w**2) * x[inner], atol=1e-6 * w**2)


def test_impedance_torque_of_a_sine_matches_the_analytic_response():
    fs, f = 2500.0, 5.0
    joint = JointParameters(inertia=0.02, damping=1.0, stiffness=100.0)
    t = np.arange(5000) / fs
    theta = 0.01 * np.sin(2 * np.pi * f * t)
    tau = simulate_impedance(theta, fs, joint)
    w = 2 * np.pi * f
    expected = 0.01 * (
        (joint.stiffness - joint.inertia * w**2) * np.sin(w * t) + joint.damping * w * np.cos(w * t)
    )
    np.testing.assert_allclose(tau[10:-10], expected[10:-10], atol=1e-8)


def test_stiffness_profiles():
    t = np.array([0.0, 0.5, 1.0])
    np.testing.assert_allclose(StiffnessProfile.ramp(100, 250, 0, 1).at(t), [100, 175, 250])
    hyp = StiffnessProfile("hyperbolic", k0=1.0, k1=4.0, t0=0, t1=1).at(t)
    np.testing.assert_allclose(1 / hyp, [1.0, 0.625, 0.25])
    rc = StiffnessProfile("raised_cosine", k0=0.4, k1=6.0, t0=0, t1=1).at(t)
    np.testing.assert_allclose(rc, [0.4, 6.0, 0.4])
    sin = StiffnessProfile.sinusoid(100, 20, 1.0).at(np.array([0.25]))
    np.testing.assert_allclose(sin, [120.0])
    with pytest.raises(InputDataError, match="kind"):
        StiffnessProfile("wobbly")


def test_noise_percent_is_relative_to_signal_std():
    y = np.sin(np.linspace(0, 100, 100000))
    noisy = add_noise(y, 10.0, seed=1)
    assert np.std(noisy - y) == pytest.approx(0.1 * np.std(y), rel=1e-9)


def test_servo_smooths_steps_and_has_unit_gain():
    cmd = np.r_[np.zeros(100), np.ones(2000)]
    out = robot_servo(cmd, 2500.0, 60.0)
    assert out[-1] == pytest.approx(1.0, abs=1e-6)
    assert np.max(np.abs(np.diff(out))) < 0.2


def test_admittance_static_gain_and_resonance():
    joint = JointParameters(inertia=0.02, damping=0.05)
    k = StiffnessProfile.constant(2.0)
    fs = 200.0
    ms = multisine(fs, 10.0, 5.0, every=20, rms=1.0, seed=0)
    t = np.arange(4000) / fs
    phi = simulate_admittance(ms.evaluate, t, joint, k)
    # Steady state (second half): compare each excited line with the analytic admittance.
    seg = phi[2000:]
    spec = np.fft.rfft(seg) / (seg.size / 2)
    for kb, amp, ph in zip(ms.excited_bins, ms.amplitudes, ms.phases_rad, strict=True):
        w = 2 * np.pi * kb * fs / 2000
        g = 1 / (2.0 - 0.02 * w**2 + 1j * 0.05 * w)
        assert spec[kb] == pytest.approx(amp * np.exp(1j * ph) * g, rel=1e-4, abs=1e-9)
