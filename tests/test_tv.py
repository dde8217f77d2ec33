import numpy as np
import pytest

from rtsid.cli import main
from rtsid.errors import RtsidError
from rtsid.sim.ltv import multisine_experiment
from rtsid.tv import load_tv_npz, require_matplotlib


@pytest.fixture
def small_experiment(tmp_path):
    """The study's geometry (200 s, 0.8 Hz lines, CS3) at 25 Hz to keep the test quick."""
    exp = multisine_experiment("CS3", fs_hz=25.0, f_max_hz=8.0, spacing_hz=0.8, snr_db=22.0, seed=3)
    path = tmp_path / "exp.npz"
    np.savez(path, **exp.as_npz_dict())
    return path, exp


def test_tv_command_identifies_a_recording_and_writes_track_and_figure(
    small_experiment, tmp_path, capsys
):
    path, exp = small_experiment
    csv, png = tmp_path / "track.csv", tmp_path / "tv.png"
    assert main(["tv", str(path), "-p", "10", "-o", str(csv), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "10 excited lines 0.8…8 Hz" in out
    assert "quantisation floor" in out
    table = np.genfromtxt(csv, delimiter=",", names=True)
    fn_true = np.sqrt(table["K_true"] / exp.inertia) / (2 * np.pi)
    inner = slice(2, -2)
    err = table["f_n_hz"][inner] - fn_true[inner]
    assert np.sqrt(np.mean(err**2)) < 0.1
    assert png.stat().st_size > 10_000


def test_simulate_to_an_unwritable_place_is_a_clear_error(tmp_path, capsys):
    out = tmp_path / "missing-dir" / "exp.npz"
    assert main(["tv", "--simulate", "CS2", "--save-simulation", str(out)]) == 2
    assert "cannot write" in capsys.readouterr().err
    assert not out.parent.exists()


def test_simulate_writes_a_recording_the_command_reads(tmp_path, capsys):
    out = tmp_path / "cs1.npz"
    assert main(["tv", "--simulate", "CS1", "--save-simulation", str(out), "--spacing", "1.4"]) == 0
    data = load_tv_npz(out)
    assert data.torque_nm.size == 40000 and data.period_samples == 2000
    np.testing.assert_array_equal(data.excited_bins, np.arange(14, 101, 14))
    assert "rtsid tv" in capsys.readouterr().out


def test_missing_arrays_and_partial_periods_are_clear_errors(small_experiment, tmp_path, capsys):
    _, exp = small_experiment
    bad = tmp_path / "bad.npz"
    np.savez(bad, torque_nm=exp.torque_nm, position_rad=exp.position_rad, fs_hz=25.0)
    assert main(["tv", str(bad)]) == 2
    assert "lacks excited_bins, period_samples" in capsys.readouterr().err
    arrays = exp.as_npz_dict()
    arrays["fs_hz"] = np.array([25.0, 25.0])
    np.savez(bad, **arrays)
    assert main(["tv", str(bad)]) == 2
    assert "fs_hz must be one finite number" in capsys.readouterr().err
    cut = tmp_path / "cut.npz"
    arrays = exp.as_npz_dict()
    arrays["torque_nm"] = exp.torque_nm[:-30]
    arrays["position_rad"] = exp.position_rad[:-30]
    np.savez(cut, **arrays)
    assert main(["tv", str(cut)]) == 2
    assert "not a whole number of 250-sample periods" in capsys.readouterr().err
    assert main(["tv", str(cut), "--trim", "-p", "4", "--times", "3"]) == 0
    assert "19 periods of 250" in capsys.readouterr().out


def test_common_inertia_option_holds_one_inertia(small_experiment, tmp_path):
    path, exp = small_experiment
    csv = tmp_path / "held.csv"
    assert main(["tv", str(path), "-p", "10", "--common-inertia", "-o", str(csv)]) == 0
    table = np.genfromtxt(csv, delimiter=",", names=True)
    assert np.ptp(table["I"]) < 1e-9
    # 25 Hz sampling puts 8× more noise per bin than the study (SNR per line is lower).
    assert table["I"][0] == pytest.approx(exp.inertia, rel=0.15)


def test_auto_basis_takes_the_largest_well_conditioned_n_p(small_experiment, capsys):
    path, _ = small_experiment
    assert main(["tv", str(path), "-p", "auto", "--times", "2"]) == 0
    assert "N_p = 20 (auto" in capsys.readouterr().out
    assert main(["tv", str(path), "-p", "many"]) == 2
    assert "positive integer or 'auto'" in capsys.readouterr().err


def test_too_many_basis_functions_print_a_warning(small_experiment, capsys):
    path, _ = small_experiment
    assert main(["tv", str(path), "-p", "36", "--times", "2"]) == 0
    assert "warning: N_p = 36 is too large" in capsys.readouterr().err


def test_missing_matplotlib_is_a_one_line_error(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(RtsidError, match=r"pip install 'rtsid\[plot\]'"):
        require_matplotlib()


@pytest.fixture
def cyclic_experiment(tmp_path):
    """Two sinusoidal cycles of K(t) per 200 s record (SIN2), 0.8 Hz lines, 22 dB, at 25 Hz."""
    exp = multisine_experiment(
        "SIN2", fs_hz=25.0, f_max_hz=8.0, spacing_hz=0.8, snr_db=22.0, seed=3
    )
    path = tmp_path / "sin2.npz"
    np.savez(path, **exp.as_npz_dict())
    return path


def _fn_rmse(csv, inertia=0.02):
    table = np.genfromtxt(csv, delimiter=",", names=True)
    fn_true = np.sqrt(table["K_true"] / inertia) / (2 * np.pi)
    return float(np.sqrt(np.nanmean((table["f_n_hz"] - fn_true) ** 2)))


def test_fourier_family_tracks_a_cyclic_stiffness_that_legendre_cannot(
    cyclic_experiment, tmp_path, capsys
):
    rmse = {}
    for family in ("legendre", "fourier"):
        csv = tmp_path / f"{family}.csv"
        args = ["tv", str(cyclic_experiment), "-p", "auto", "--basis-family", family]
        assert main([*args, "--times", "2", "-o", str(csv)]) == 0
        rmse[family] = _fn_rmse(csv)
    out = capsys.readouterr().out
    assert "(auto, fourier: best predicted validation VAF" in out
    assert "Fourier terms (harmonics up to" in out
    assert rmse["fourier"] < 0.05 < 0.1 < rmse["legendre"]


def test_bad_basis_family_or_size_is_a_one_line_error(cyclic_experiment, capsys):
    with pytest.raises(SystemExit):
        main(["tv", str(cyclic_experiment), "--basis-family", "wavelet"])
    assert "invalid choice: 'wavelet'" in capsys.readouterr().err
    assert main(["tv", str(cyclic_experiment), "-p", "201", "--basis-family", "fourier"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    assert "reach harmonic 100 of the record" in err and "use N_p <= 159" in err
