import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import solve_toeplitz, toeplitz

from rtsid.errors import InputDataError, NotPositiveDefiniteError
from rtsid.ident import levinson
from rtsid.ident.levinson import eureka, eureka_numpy


def random_spd_column(rng: np.random.Generator, n: int) -> np.ndarray:
    """Biased autocorrelation of a random signal: always positive definite."""
    u = rng.standard_normal(n + rng.integers(2, 4 * n + 3))
    u = np.convolve(u, rng.standard_normal(rng.integers(1, 6)), mode="same")
    full = np.correlate(u, u, mode="full") / u.size
    return full[u.size - 1 : u.size - 1 + n] + 1e-3 * (np.arange(n) == 0)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 120), seed=st.integers(0, 2**32 - 1))
def test_matches_dense_and_scipy_on_random_spd_systems(n, seed):
    rng = np.random.default_rng(seed)
    r = random_spd_column(rng, n)
    b = rng.standard_normal(n)
    dense = np.linalg.solve(toeplitz(r), b)
    cond = np.linalg.cond(toeplitz(r))
    tol = 1e-12 * cond * max(1.0, np.max(np.abs(dense)))
    for solver in (eureka, eureka_numpy):
        x = solver(r, b)
        np.testing.assert_allclose(x, dense, atol=tol, rtol=0)
    np.testing.assert_allclose(eureka(r, b), solve_toeplitz(r, b), atol=tol, rtol=0)


def test_compiled_and_numpy_agree_to_rounding():
    rng = np.random.default_rng(7)
    r = random_spd_column(rng, 800)
    b = rng.standard_normal(800)
    np.testing.assert_allclose(eureka(r, b), eureka_numpy(r, b), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("solver", [eureka, eureka_numpy])
def test_not_positive_definite_is_an_error_not_garbage(solver):
    r = np.array([1.0, 1.0, 1.0])  # singular: all-ones matrix
    with pytest.raises(NotPositiveDefiniteError, match="not positive definite") as info:
        solver(r, np.ones(3))
    assert info.value.step == 1
    with pytest.raises(NotPositiveDefiniteError, match="step 0"):
        solver(np.array([0.0, 0.0]), np.ones(2))
    indefinite = np.array([1.0, 0.9, -0.9])
    assert np.min(np.linalg.eigvalsh(toeplitz(indefinite))) < 0
    with pytest.raises(NotPositiveDefiniteError):
        solver(indefinite, np.ones(3))


@pytest.mark.parametrize("solver", [eureka, eureka_numpy])
def test_bad_shapes_and_nan_are_named(solver):
    with pytest.raises(InputDataError, match="same non-zero length"):
        solver(np.ones(3), np.ones(2))
    with pytest.raises(InputDataError, match="NaN"):
        solver(np.array([1.0, np.nan]), np.ones(2))


def test_the_compiled_kernel_is_used_when_built_unless_switched_off():
    # CI builds with a compiler and runs the suite once more with RTSID_NUMPY_ONLY=1.
    import importlib.util
    import os

    built = importlib.util.find_spec("rtsid.ident._eureka") is not None
    switched_off = os.environ.get("RTSID_NUMPY_ONLY", "") not in ("", "0")
    assert levinson.HAVE_COMPILED_KERNEL == (built and not switched_off)
