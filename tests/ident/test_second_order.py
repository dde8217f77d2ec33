import numpy as np
import pytest

from rtsid.ident.second_order import fit_linear, fit_logmag, impedance_response


def exact_dft_problem(inertia, damping, stiffness):
    """A 'DFT matrix' that is the identity on stacked frequencies (H given directly)."""
    f = np.linspace(1.0, 60.0, 25)
    z = impedance_response(inertia, damping, stiffness, f)
    # Represent H as dft @ h with a complex identity-like map: h = [Re z, Im z].
    e = np.hstack((np.eye(f.size), 1j * np.eye(f.size)))
    h = np.r_[z.real, z.imag]
    return f, e, h


@pytest.mark.parametrize("params", [(0.015, 0.8, 150.0), (0.03, 2.0, 30.0), (0.01, 0.3, 400.0)])
def test_linear_fit_is_exact_on_a_second_order_response(params):
    f, e, h = exact_dft_problem(*params)
    fit = fit_linear(f, e, h)
    np.testing.assert_allclose(fit.params, params, rtol=1e-9)
    # Sensitivity is the exact linear map: params = M @ h.
    np.testing.assert_allclose(fit.sensitivity @ h, params, rtol=1e-9)


def test_logmag_fit_converges_from_the_linear_seed_and_from_a_poor_guess():
    params = (0.015, 0.8, 150.0)
    f, e, h = exact_dft_problem(*params)
    np.testing.assert_allclose(fit_logmag(f, e, h).params, params, rtol=1e-4)
    poor = fit_logmag(f, e, h, start=(0.05, 5.0, 20.0))
    # Magnitude alone cannot always pin B: the seeded fit is the reliable one.
    assert abs(poor.params[2] - 150.0) / 150.0 < 0.5


def test_weights_ignore_unexcited_frequencies():
    f, e, h = exact_dft_problem(0.015, 0.8, 150.0)
    corrupted = h.copy()
    corrupted[20:25] *= 3.0  # garbage where the input had no power
    weights = np.where(np.arange(f.size) < 20, 1.0, 1e-9)
    fit = fit_linear(f, e, corrupted, weights=weights)
    np.testing.assert_allclose(fit.params, (0.015, 0.8, 150.0), rtol=1e-6)
