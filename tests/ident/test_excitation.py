import numpy as np
import pytest

from rtsid.errors import InputDataError
from rtsid.ident.excitation import filtered_noise, multisine, prbs


def test_prbs_levels_hold_and_switch_rate():
    u = prbs(20000, 0.05, min_hold=4, seed=3)
    assert set(np.unique(u)) == {-0.05, 0.05}
    runs = np.diff(np.flatnonzero(np.diff(u) != 0))
    assert runs.min() >= 4 and np.all(runs % 4 == 0)
    switches = np.count_nonzero(np.diff(u[::4]) != 0) / (u.size // 4 - 1)
    assert switches == pytest.approx(0.5, abs=0.03)


def test_prbs_rejects_bad_hold():
    with pytest.raises(InputDataError, match="min_hold"):
        prbs(10, min_hold=0)


def test_filtered_noise_peak_and_band():
    fs = 2500.0
    x = filtered_noise(50000, fs, cutoff_hz=50.0, peak=0.05, seed=1)
    assert np.max(np.abs(x)) == pytest.approx(0.05)
    spectrum = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(x.size, 1 / fs)
    assert spectrum[f > 150].sum() < 1e-4 * spectrum[f < 50].sum()


def test_filtered_noise_rejects_cutoff_above_nyquist():
    with pytest.raises(InputDataError, match="Nyquist"):
        filtered_noise(100, 1000.0, cutoff_hz=600.0)


def test_multisine_excites_only_every_pth_bin_and_matches_evaluate():
    ms = multisine(200.0, 10.0, 10.0, every=4, rms=0.5, seed=2)
    x = ms.samples(2)
    assert x.size == 4000
    spectrum = np.abs(np.fft.rfft(x[:2000]))
    excited = spectrum > 1e-9 * spectrum.max()
    assert np.array_equal(np.flatnonzero(excited), ms.excited_bins)
    assert np.all(ms.excited_bins % 4 == 0)
    assert np.std(x) == pytest.approx(0.5, rel=1e-9)
    t = np.arange(50) / 200.0
    np.testing.assert_allclose(ms.evaluate(t), x[:50], atol=1e-12)


def test_multisine_rejects_fractional_period():
    with pytest.raises(InputDataError, match="whole number of samples"):
        multisine(200.0, 0.0123, 10.0)
