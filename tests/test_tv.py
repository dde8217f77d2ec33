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


def test_inertia_is_common_by_default_and_free_on_request(small_experiment, tmp_path):
    path, exp = small_experiment
    tables = {}
    for name, flags in (
        ("default", []),
        ("old flag", ["--common-inertia"]),
        ("free", ["--free-inertia"]),
    ):
        csv = tmp_path / f"{name}.csv"
        assert main(["tv", str(path), "-p", "10", *flags, "-o", str(csv)]) == 0
        tables[name] = np.genfromtxt(csv, delimiter=",", names=True)
    for name in ("default", "old flag"):
        inertia = tables[name]["I"]
        assert np.ptp(inertia) < 1e-9
        # 25 Hz sampling puts 8× more noise per bin than the study (SNR per line is lower).
        assert inertia[0] == pytest.approx(exp.inertia, rel=0.15)
    assert np.ptp(tables["free"]["I"]) > 1e-4


def test_auto_basis_takes_the_largest_well_conditioned_n_p(small_experiment, capsys):
    path, _ = small_experiment
    assert main(["tv", str(path), "-p", "auto", "--basis-family", "legendre", "--times", "2"]) == 0
    out = capsys.readouterr().out
    assert "model chosen from the data: legendre N_p = 20," in out
    assert "runners-up" not in out and "cap:" not in out  # one family, its whole range
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
    assert "model chosen from the data: fourier N_p = " in out
    assert "Fourier terms (harmonics up to" in out
    assert rmse["fourier"] < 0.03 < 0.05 < rmse["legendre"]


def test_bad_basis_family_or_size_is_a_one_line_error(cyclic_experiment, capsys):
    with pytest.raises(SystemExit):
        main(["tv", str(cyclic_experiment), "--basis-family", "wavelet"])
    assert "invalid choice: 'wavelet'" in capsys.readouterr().err
    assert main(["tv", str(cyclic_experiment), "-p", "201", "--basis-family", "fourier"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    assert "reach harmonic 100 of the record" in err and "use N_p <= 159" in err


def _validation_vaf(estimate, case, seed):
    """VAF (%) of the model's prediction of another realisation's noiseless output."""
    val = multisine_experiment(case, fs_hz=25.0, f_max_hz=8.0, spacing_hz=0.8, seed=seed)
    error = val.position_clean_rad - estimate.simulate(val.torque_nm)
    return 100.0 * (1.0 - np.var(error) / np.var(val.position_clean_rad))


def test_defaults_follow_a_sinusoidal_stiffness_that_the_old_defaults_cannot(
    cyclic_experiment, tmp_path, capsys
):
    """Issue 19's floor on the bench's sinusoidal case (SIN2, lines 0.8 Hz apart, 22 dB, here
    at 25 Hz): with no options the validation VAF is ≥ 99 % and f_n(t) within 0.03 Hz RMS;
    the old defaults (Legendre N_p = 8, free inertia) reach neither."""
    from rtsid.tv import choose_model, identify_recording

    new_csv, old_csv = tmp_path / "new.csv", tmp_path / "old.csv"
    assert main(["tv", str(cyclic_experiment), "--times", "2", "-o", str(new_csv)]) == 0
    out = capsys.readouterr().out
    assert "model chosen from the data: " in out and "runners-up: " in out
    old = ["-p", "8", "--basis-family", "legendre", "--free-inertia", "-o", str(old_csv)]
    assert main(["tv", str(cyclic_experiment), "--times", "2", *old]) == 0
    assert _fn_rmse(new_csv) <= 0.03 < 0.1 < _fn_rmse(old_csv)

    data = load_tv_npz(cyclic_experiment)
    chosen = choose_model(data)
    assert chosen.chosen.basis_family in ("fourier", "bspline")
    assert f"{chosen.chosen.basis_family} N_p = {chosen.chosen.n_basis}," in out
    assert [s.chosen_vaf for s in chosen.families] == sorted(
        (s.chosen_vaf for s in chosen.families), reverse=True
    )
    old_model = identify_recording(data, n_basis=8, basis_family="legendre", common=())
    assert _validation_vaf(chosen.estimate, "SIN2", seed=13) >= 99.0
    assert _validation_vaf(old_model.estimate, "SIN2", seed=13) < 90.0


def test_a_capped_search_says_why_with_the_numbers(tmp_path, capsys):
    """Lines 0.2 Hz apart over 20 periods (40 record bins): no family gets its whole range,
    and each says where it stopped and why."""
    exp = multisine_experiment("CS3", fs_hz=25.0, f_max_hz=4.0, spacing_hz=0.2, seed=2)
    path = tmp_path / "close.npz"
    np.savez(path, **exp.as_npz_dict())
    assert main(["tv", str(path), "--times", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    caps = {line.split(" cap: ")[0]: line for line in lines if " cap: " in line}
    assert set(caps) == {"legendre", "fourier", "bspline"}
    assert caps["legendre"].startswith("legendre cap: N_p ≤ 15 of 20: at N_p = 16 the skirts")
    assert "40 record bins (0.2 Hz) apart" in caps["legendre"] and "variance ×" in caps["legendre"]
    assert caps["fourier"].startswith("fourier cap: N_p ≤ 39 of 101: harmonic 20 of the record")


def test_help_states_the_ranges_the_search_covers(cyclic_experiment, capsys):
    from rtsid.commands.tv import auto_range_text
    from rtsid.ident.skirt import AUTO_MAX_BASIS
    from rtsid.tv import choose_model

    with pytest.raises(SystemExit):
        main(["tv", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert auto_range_text() in help_text
    assert "legendre 1…20, fourier 1…101, bspline 1…80" == auto_range_text()
    # Lines 0.8 Hz apart over 20 periods: each family searches up to its stated maximum, or
    # says why not.
    for sel in choose_model(load_tv_npz(cyclic_experiment)).families:
        assert sel.n_cap == AUTO_MAX_BASIS[sel.basis_family]
        assert sel.candidates[0] == 1
        if sel.cap_reason:
            assert sel.candidates[-1] < sel.n_cap
            assert sel.cap_reason.startswith(f"N_p ≤ {sel.candidates[-1]} of {sel.n_cap}: ")
        else:
            assert sel.candidates[-1] == sel.n_cap
