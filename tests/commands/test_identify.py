import csv
import itertools

import numpy as np
import pytest

from rtsid.cli import main
from rtsid.ident.excitation import filtered_noise
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance


@pytest.fixture
def ramp_recording(tmp_path):
    fs = 2500.0
    theta = filtered_noise(5000, fs, 30.0, peak=0.03, seed=1)
    stiffness = StiffnessProfile.ramp(100.0, 200.0, 0.0, 2.0)
    tau = simulate_impedance(
        theta, fs, JointParameters(0.015, 0.8, 100.0), stiffness, seed=2, noise_percent=5.0
    )
    path = tmp_path / "sim.npz"
    np.savez(path, position_rad=theta, torque_nm=-tau, fs_hz=fs)
    return path


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_identify_tracks_a_stiffness_ramp_with_inverted_torque(ramp_recording, tmp_path, capsys):
    out = tmp_path / "est.csv"
    assert (
        main(
            [
                "identify",
                str(ramp_recording),
                "--torque-sign",
                "-1",
                "--hop",
                "0.25",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    rows = read_rows(out)
    assert len(rows) == 7  # windows ending at 0.2996 … 1.7996 s
    t_end = np.array([float(r["t_end_s"]) for r in rows])
    k = np.array([float(r["K"]) for r in rows])
    truth = 100.0 + 50.0 * (t_end - 0.15)  # stiffness at the window's centre
    np.testing.assert_allclose(k, truth, rtol=0.08)
    assert all(r["ok"] == "true" for r in rows)
    assert "7 windows (0 withheld)" in capsys.readouterr().err


def test_identify_refuses_nan_unless_allowed_and_leaves_no_partial_file(tmp_path, capsys):
    fs = 1000.0
    theta = filtered_noise(2000, fs, 30.0, peak=0.03, seed=3)
    tau = simulate_impedance(theta, fs)
    tau[1500] = np.nan
    path = tmp_path / "gap.npz"
    np.savez(path, position_rad=theta, torque_nm=tau, fs_hz=fs)
    out = tmp_path / "est.csv"
    assert main(["identify", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "1 sample(s) are NaN or inf, the first at index 1500" in err and "--allow-nan" in err
    assert not out.exists() and list(tmp_path.glob("*.part")) == []
    assert main(["identify", str(path), "-o", str(out), "--allow-nan"]) == 0
    rows = read_rows(out)
    # the NaN row is a lost sample: windows across it are estimated from the rest, counted
    across = [r for r in rows if 1500 / fs <= float(r["t_end_s"]) < 1800 / fs]
    assert across and all(r["ok"] == "true" and r["lost_samples"] == "1" for r in across)
    tau[1500:1520] = np.nan  # 20 ms lost: more than max_gap_s, withheld as a gap
    np.savez(path, position_rad=theta, torque_nm=tau, fs_hz=fs)
    assert main(["identify", str(path), "-o", str(out), "--allow-nan"]) == 0
    withheld = [r for r in read_rows(out) if r["ok"] == "false"]
    assert withheld and all(r["reason"] == "gap" and r["K"] == "" for r in withheld)


def test_identify_errors_are_one_line(tmp_path, capsys):
    assert main(["identify", str(tmp_path / "missing.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no such file" in err
    short = tmp_path / "short.npz"
    np.savez(short, position_rad=np.zeros(100), torque_nm=np.zeros(100), fs_hz=1000.0)
    assert main(["identify", str(short)]) == 2
    assert "shorter than one 0.3 s window" in capsys.readouterr().err
    bad_cfg = tmp_path / "bad.toml"
    bad_cfg.write_text("[estimator]\nfit_methd = 'linear'\n")
    assert main(["identify", str(short), "--config", str(bad_cfg)]) == 2
    assert "unknown config key estimator.fit_methd" in capsys.readouterr().err


def test_identify_real_recording_with_its_preset(reklab_path, tmp_path):
    out = tmp_path / "real.csv"
    preset = __import__("pathlib").Path(__file__).resolve().parents[2] / "replay" / "reklab.toml"
    assert (
        main(["identify", str(reklab_path), "--config", str(preset), "--hop", "1", "-o", str(out)])
        == 0
    )
    rows = read_rows(out)
    assert len(rows) == 60
    # the window ending at 40 s falls where the perturbation paused (K ≈ −1800 if estimated)
    withheld = [(r["t_end_s"], r["reason"]) for r in rows if not r["K"]]
    assert withheld == [("39.999", "no_excitation")]
    k = np.median([float(r["K"]) for r in rows if r["K"]])
    vaf = np.median([float(r["vaf"]) for r in rows if r["vaf"]])
    assert 80.0 < k < 120.0 and vaf > 65.0


def test_identify_and_replay_cut_the_same_windows_and_agree(tmp_path):
    from rtsid.replay import replay_file

    fs = 2500.0
    theta = filtered_noise(12_500, fs, 30.0, peak=0.03, seed=5)
    tau = simulate_impedance(theta, fs, noise_percent=5.0, seed=6)
    path = tmp_path / "rec.npz"
    np.savez(path, position_rad=theta, torque_nm=tau, fs_hz=fs)
    rec = tmp_path / "rec.mcap"
    assert main(["convert", str(path), "-o", str(rec)]) == 0
    out = tmp_path / "est.csv"
    assert main(["identify", str(path), "-o", str(out), "--hop", "0.02"]) == 0
    identified = {round(float(r["t_end_s"]) * fs): r for r in read_rows(out)}
    replayed = {m["window_end_index"]: m for m in replay_file(rec).messages}
    assert set(identified) == set(replayed)
    for end, m in replayed.items():
        assert float(identified[end]["K"]) == pytest.approx(m["K"], rel=1e-5)


def test_identify_cascade_separates_intrinsic_from_reflex_stiffness(reklab_path, tmp_path, capsys):
    out = tmp_path / "cascade.csv"
    argv = ["identify", str(reklab_path), "--torque-sign", "-1", "--model", "cascade"]
    assert main([*argv, "-o", str(out)]) == 0
    (row,) = read_rows(out)
    # shared/data/README: cascade ≈ 93 %, its intrinsic K ≈ 80 (plain least squares ≈ 106)
    assert float(row["vaf_cascade"]) >= 92.0
    assert 70.0 < float(row["K"]) < 90.0 < 95.0 < float(row["K_no_reflex_model"])
    err = capsys.readouterr().err
    assert "reflex gain" in err
    # issue 19: its delay sits at the lower bound of the search, and the output says so
    assert row["reflex_delay_at_bound"] == "lower"
    assert "delay 10.0 ms (at the lower bound of the 10–200 ms search" in err


def test_identify_cascade_names_the_minimum_record_length(tmp_path, capsys):
    path = tmp_path / "short.npz"
    theta = filtered_noise(2000, 1000.0, 30.0, peak=0.03, seed=1)
    np.savez(path, position_rad=theta, torque_nm=simulate_impedance(theta, 1000.0), fs_hz=1000.0)
    assert main(["identify", str(path), "--model", "cascade"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "at least 3 s" in err


def test_identify_cascade_on_sliding_windows_writes_a_row_per_window_and_a_plot(
    reklab_path, tmp_path, capsys
):
    pytest.importorskip("matplotlib")
    out, png = tmp_path / "windows.csv", tmp_path / "windows.png"
    argv = ["identify", str(reklab_path), "--torque-sign", "-1", "--model", "cascade"]
    argv += ["--window", "20", "--hop", "10", "--reflex", "hammerstein", "--plot", str(png)]
    assert main([*argv, "-o", str(out)]) == 0
    rows = read_rows(out)
    assert [float(r["t_start_s"]) for r in rows] == [0.0, 10.0, 20.0, 30.0, 40.0]
    for r in rows:
        assert float(r["vaf_cascade"]) > float(r["vaf_intrinsic_irf"]) + 3.0
        assert float(r["K"]) < float(r["K_no_reflex_model"])
    assert png.stat().st_size > 10_000
    assert "5 cascade windows of 20 s every 10 s" in capsys.readouterr().err


def test_identify_cascade_window_longer_than_the_record_is_refused(reklab_path, capsys):
    argv = ["identify", str(reklab_path), "--torque-sign", "-1", "--model", "cascade"]
    assert main([*argv, "--window", "90"]) == 2
    assert "longer than the record" in capsys.readouterr().err


def test_identify_refuses_an_inverted_torque_sign_naming_the_switch(reklab_path, tmp_path, capsys):
    # issue 19: without --torque-sign the shared recording printed median K −97.8 and exited 0
    out = tmp_path / "est.csv"
    assert main(["identify", str(reklab_path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    # refused once the first 50 estimable windows are in (as live), not after the whole file
    assert "most windows read K, B, I < 0 (" in err[0] and "of 50)" in err[0]
    assert "--torque-sign -1" in err[0] and "[estimator] torque_sign = -1" in err[0]
    assert not out.exists()  # nothing written half-way
    assert main(["identify", str(reklab_path), "--torque-sign", "-1", "-o", str(out)]) == 0
    capsys.readouterr()
    # the cascade judges the same windows first
    cascade = ["identify", str(reklab_path), "--model", "cascade", "-o", str(tmp_path / "c.csv")]
    assert main(cascade) == 2 and "--torque-sign -1" in capsys.readouterr().err
    assert not (tmp_path / "c.csv").exists()


def test_identify_sign_check_does_not_fire_on_a_correct_sign(ramp_recording, tmp_path):
    # the ramp's torque is stored inverted: read with sign +1 it is refused, with -1 it is
    # not (86 windows at a 20 ms hop: enough to judge, rtsid.ident.sign.MIN_WINDOWS = 50)
    out = tmp_path / "est.csv"
    argv = ["identify", str(ramp_recording), "--hop", "0.02", "-o", str(out)]
    assert main(argv) == 2
    assert main([*argv, "--torque-sign", "-1"]) == 0


def test_identify_takes_the_window_and_hop_of_its_config(tmp_path, capsys):
    # review: [worker] window_s from --config was overridden with 0.3 s
    theta = filtered_noise(6000, 1000.0, 30.0, peak=0.03, seed=2)
    path = tmp_path / "rec.npz"
    np.savez(path, position_rad=theta, torque_nm=simulate_impedance(theta, 1000.0), fs_hz=1000.0)
    config = tmp_path / "daemon.toml"
    config.write_text("[worker]\nwindow_s = 0.5\nhop_s = 0.2\n[slow_lane]\nenabled = false\n")
    out = tmp_path / "est.csv"
    assert main(["identify", str(path), "--config", str(config), "-o", str(out)]) == 0
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    first = rows[0]
    span = (int(first["window_end_index"]) - int(first["window_start_index"]) + 1) / 1000.0
    ends = [float(r["t_end_s"]) for r in rows]
    hops = {round(b - a, 6) for a, b in itertools.pairwise(ends)}
    assert span == 0.5 and hops == {0.2}


def test_identify_cascade_refuses_a_config_section_that_is_not_a_table(tmp_path, capsys):
    theta = filtered_noise(4000, 1000.0, 30.0, peak=0.03, seed=1)
    path = tmp_path / "rec.npz"
    np.savez(path, position_rad=theta, torque_nm=simulate_impedance(theta, 1000.0), fs_hz=1000.0)
    config = tmp_path / "bad.toml"
    config.write_text("slow_lane = 3\n")
    assert main(["identify", str(path), "--model", "cascade", "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'slow_lane' = 3 is not accepted" in err
