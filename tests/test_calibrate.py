"""Robot-dynamics calibration: identify the robot alone, subtract it, get the ankle back."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rtsid.calibrate import (
    Calibration,
    calibrate_file,
    contiguous_segments,
    load_calibration,
    read_samples,
    save_calibration,
)
from rtsid.cli import main
from rtsid.errors import ConfigError, InputDataError
from rtsid.ident.robot import identify_robot
from rtsid.ident.window import EstimatorOptions, estimate_window
from rtsid.io.mcap_read import iter_estimates, read_metadata
from rtsid.link.config import PlantConfig
from rtsid.link.signals import SimSource
from rtsid.replay import recording_config, replay_file
from rtsid.runtime.daemon import Daemon, DaemonConfig
from rtsid.runtime.worker import WindowEvaluator, WorkerConfig

FS = 2500.0
ROBOT_INERTIA = 0.05  # kg·m²: a footplate about three times the ankle's own inertia
ANKLE = {"I": 0.015, "B": 0.8, "K": 150.0}
PLANT = PlantConfig(
    perturbation="filtered_noise", bandwidth_hz=30.0, robot_inertia=ROBOT_INERTIA, seed=3
)
NO_PERSON = replace(PLANT, inertia=0.0, damping=0.0, stiffness=0.0)


def simulate(cfg: PlantConfig, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Position and torque of the plant's simulation, quantised as the CAN frame does."""
    source = SimSource(cfg)
    blocks = [source.next_block() for _ in range(round(seconds / cfg.block_s))]
    position = np.concatenate([b.position_rad for b in blocks])
    torque = np.concatenate([b.torque_nm for b in blocks])
    return np.rint(position / 1e-6) * 1e-6, np.rint(torque / 1e-3) * 1e-3


def median_estimates(position, torque, offset=None) -> dict[str, float]:
    n = round(0.3 * FS)
    rows = []
    for start in range(0, position.size - n, n // 2):
        p, t = position[start : start + n], torque[start : start + n]
        if offset is not None:
            t = t - offset(p)
        e = estimate_window(p, t, FS)
        rows.append((e.I, e.B, e.K))
    med = np.median(rows, axis=0)
    return dict(zip(("I", "B", "K"), med.tolist(), strict=True))


def test_identifies_the_simulated_robot_inertia_with_high_vaf():
    position, torque = simulate(NO_PERSON, 4.0)
    robot = identify_robot([(position, torque)], FS)
    assert robot.inertia == pytest.approx(ROBOT_INERTIA, rel=0.02)
    assert robot.vaf > 99.0  # the source reached ≈ 90 % with its 10 Hz double differentiation
    assert robot.lags_s[robot.max_lag] == 0.0
    # the IRF is concentrated at lag 0 (an inertia), not smeared over the lag span
    assert abs(robot.irf[robot.max_lag]) > 5 * np.max(np.abs(robot.irf[: robot.max_lag - 5]))


def test_subtracting_the_calibration_brings_the_ankle_back_to_the_truth():
    position, torque = simulate(NO_PERSON, 4.0)
    calibration = Calibration(identify_robot([(position, torque)], FS))
    p, t = simulate(PLANT, 3.0)
    biased = median_estimates(p, t)
    assert biased["I"] == pytest.approx(ANKLE["I"] + ROBOT_INERTIA, rel=0.15)
    corrected = median_estimates(p, t, calibration.torque_offset)
    assert corrected["I"] == pytest.approx(ANKLE["I"], rel=0.1)
    assert corrected["B"] == pytest.approx(ANKLE["B"], rel=0.1)
    assert corrected["K"] == pytest.approx(ANKLE["K"], rel=0.05)


def test_a_calibrated_worker_analyses_within_the_calibrations_band():
    # A servoed PRBS excites the robot far above the calibration's 100 Hz band, where its
    # torque is not predicted. Analysed up to the PRBS's own edge (~200 Hz) the ankle's K
    # erred by 48 %; the worker keeps its analysis within the calibration's band.
    prbs = replace(PLANT, perturbation="prbs", bandwidth_hz=40.0)
    position, torque = simulate(replace(prbs, inertia=0.0, damping=0.0, stiffness=0.0), 4.0)
    calibration = Calibration(identify_robot([(position, torque)], FS))
    p, t = simulate(prbs, 3.0)
    published = []
    worker = WindowEvaluator(
        FS, WorkerConfig(hop_s=0.15), EstimatorOptions(), published.append, calibration=calibration
    )
    n = round(0.3 * FS)
    ks = []
    for start in range(0, p.size - n, n // 2):
        window = p[start : start + n]
        corrected = t[start : start + n] - calibration.torque_offset(window)
        ks.append(worker.stream.estimate(window, corrected).K)
    assert worker.stream.plan.lowpass_hz <= calibration.robot.analysis_cutoff_hz
    assert np.median(ks) == pytest.approx(ANKLE["K"], rel=0.03)


def test_prediction_is_as_long_as_the_window_and_exact_for_a_pure_inertia():
    position, torque = simulate(NO_PERSON, 2.0)
    robot = identify_robot([(position, torque)], FS)
    window = position[1000:1750]
    predicted = robot.predict_torque(window)
    assert predicted.shape == window.shape
    inner = slice(robot.max_lag + 40, -robot.max_lag - 40)
    measured = torque[1000:1750]
    err = measured[inner] - predicted[inner]
    assert np.std(err) < 0.05 * np.std(measured[inner])


def test_segments_split_at_gaps_and_discontinuities(tmp_path):
    position, torque = simulate(NO_PERSON, 2.0)
    position[1000:1010] = np.nan  # a gap
    np.savez(tmp_path / "base.npz", position_rad=position, torque_nm=torque, fs_hz=FS)
    rows = read_samples(tmp_path / "base.npz")
    segments = list(contiguous_segments(rows))
    assert [s[0].size for s in segments] == [1000, position.size - 1010]
    breaks = np.zeros(position.size, dtype=bool)
    breaks[3000] = True
    rows = replace(rows, breaks=breaks)
    assert [s[0].size for s in contiguous_segments(rows)] == [1000, 1990, position.size - 3000]
    cal = calibrate_file(tmp_path / "base.npz")
    assert cal.robot.segments == 2 and cal.robot.inertia == pytest.approx(ROBOT_INERTIA, rel=0.02)


def test_file_round_trip_and_bad_files(tmp_path):
    position, torque = simulate(NO_PERSON, 2.0)
    cal = Calibration(identify_robot([(position, torque)], FS), source="base.npz")
    path = save_calibration(cal, tmp_path / "cal.json")
    loaded = load_calibration(path)
    np.testing.assert_array_equal(loaded.robot.irf, cal.robot.irf)
    assert (
        loaded.fs_hz == FS and loaded.source == "base.npz" and loaded.software.startswith("rtsid")
    )
    document = json.loads(path.read_text())
    assert document["lags_s"][0] == pytest.approx(-0.01) and "vaf" in document
    with pytest.raises(InputDataError, match="does not exist"):
        load_calibration(tmp_path / "missing.json")
    (tmp_path / "other.json").write_text('{"a": 1}')
    with pytest.raises(InputDataError, match="not an rtsid calibration"):
        load_calibration(tmp_path / "other.json")
    with pytest.raises(ConfigError, match="worker.calibration_file"):
        WorkerConfig(calibration_file=str(tmp_path / "other.json"))
    with pytest.raises(ConfigError, match="1000 Hz"):
        loaded.check_rate(1000.0)
    with pytest.raises(InputDataError, match="no acceleration"):
        identify_robot([(np.zeros(4000), np.zeros(4000))], FS)


def daemon_config(
    tmp_path: Path, port: int, plant: PlantConfig, name: str, **worker
) -> DaemonConfig:
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"], "robot": name},
            "mcap": {"directory": str(tmp_path / name)},
        }
    )
    return replace(config, plant=plant, worker=replace(config.worker, **worker))


@pytest.mark.slow  # a real-time daemon run of seconds
def test_daemon_end_to_end_baseline_calibrate_and_subtract(tmp_path, free_port, monkeypatch):
    baseline = daemon_config(tmp_path, free_port, NO_PERSON, "baseline")
    Daemon(baseline).run(duration_s=2.0)
    (recording,) = (tmp_path / "baseline").glob("*.mcap")
    cal_path = tmp_path / "cal.json"
    assert main(["calibrate", str(recording), "-o", str(cal_path)]) == 0
    cal = load_calibration(cal_path)
    assert cal.robot.inertia == pytest.approx(ROBOT_INERTIA, rel=0.03) and cal.vaf > 99.0

    person = daemon_config(tmp_path, free_port, PLANT, "person", calibration_file=str(cal_path))
    summary = Daemon(person).run(duration_s=2.0)
    (recording,) = (tmp_path / "person").glob("*.mcap")
    live = [e for e in iter_estimates(recording) if e["ok"]]
    assert len(live) == summary.estimates > 30
    for key, truth in ANKLE.items():
        assert np.median([e[key] for e in live]) == pytest.approx(truth, rel=0.1), key

    # replay with the recording's own config (calibration included) gives the same numbers
    stored = recording_config(recording)
    assert stored.worker.calibration_file == str(cal_path)
    # (the live worker stops at shutdown before the last windows the log holds: compare the
    # windows it estimated)
    replayed = {m["window_end_index"]: m for m in replay_file(recording).messages}
    assert [replayed[e["window_end_index"]]["K"] for e in live] == [e["K"] for e in live]
    # the recording carries the calibration: replayed where the file is gone (or was
    # edited since), the live run's calibration is used from a cached copy
    assert read_metadata(recording)["calibration"]["json"] == cal_path.read_text()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    cal_path.unlink()
    moved = recording_config(recording)
    assert Path(moved.worker.calibration_file).parent == tmp_path / "cache/rtsid/calibrations"
    replayed = {m["window_end_index"]: m for m in replay_file(recording).messages}
    assert [replayed[e["window_end_index"]]["K"] for e in live] == [e["K"] for e in live]
    # and without the calibration the robot's inertia is back in I
    plain = replace(stored, worker=replace(stored.worker, calibration_file=""))
    biased = [m["I"] for m in replay_file(recording, plain).messages if m["ok"]]
    assert np.median(biased) == pytest.approx(ANKLE["I"] + ROBOT_INERTIA, rel=0.15)


def test_a_relative_calibration_path_is_kept_absolute(tmp_path, monkeypatch):
    position, torque = simulate(NO_PERSON, 1.0)
    save_calibration(Calibration(identify_robot([(position, torque)], FS)), tmp_path / "c.json")
    monkeypatch.chdir(tmp_path)
    config = WorkerConfig(calibration_file="c.json")
    assert config.calibration_file == str(tmp_path / "c.json")
    monkeypatch.chdir(tmp_path.parent)  # a stored config still finds it from elsewhere
    assert WorkerConfig(calibration_file=config.calibration_file) == config


def test_a_config_files_relative_calibration_path_is_taken_from_its_folder(tmp_path, monkeypatch):
    """As ``protocol.dbc`` and ``plant.player_file``: a rig folder's config finds the
    calibration beside it from whatever folder the daemon is started in."""
    rig = tmp_path / "rig"
    rig.mkdir()
    position, torque = simulate(NO_PERSON, 1.0)
    save_calibration(Calibration(identify_robot([(position, torque)], FS)), rig / "c.json")
    (rig / "rig.toml").write_text('[worker]\ncalibration_file = "c.json"\n')
    monkeypatch.chdir(tmp_path)  # not the rig's folder
    assert DaemonConfig.load(rig / "rig.toml").worker.calibration_file == str(rig / "c.json")
    (rig / "rig.toml").write_text('[worker]\ncalibration_file = "missing.json"\n')
    with pytest.raises(ConfigError, match="worker.calibration_file.*missing.json"):
        DaemonConfig.load(rig / "rig.toml")


def test_benchmark_table_shows_the_calibration_beating_the_source(capsys):
    assert main(["bench", "calibrate", "--quick"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("|")]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines[2:]]
    ours = [r for r in rows if r[1].startswith("rtsid")]
    source = [r for r in rows if r[1].startswith("source")]
    assert len(ours) == len(source) == 4
    for mine, theirs in zip(ours, source, strict=True):
        assert float(mine[3]) > 99.0 > float(theirs[3])  # VAF inside the estimator's band
        assert float(mine[4]) == pytest.approx(ROBOT_INERTIA, rel=0.02)


def test_a_recorded_calibration_is_used_only_when_the_stored_file_differs(tmp_path, monkeypatch):
    from rtsid.calibrate import with_recorded_calibration

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    cal = tmp_path / "cal.json"
    cal.write_text('{"format": "rtsid-calibration"}')
    document = {"worker": {"calibration_file": str(cal)}}
    recorded = {"json": cal.read_text()}
    assert with_recorded_calibration(document, recorded) is document  # unchanged file: kept
    assert with_recorded_calibration(document, None) is document  # older recording: kept
    cal.write_text("edited since the run")
    moved = with_recorded_calibration(document, recorded)
    copy = Path(moved["worker"]["calibration_file"])
    assert copy.parent == tmp_path / "cache" / "rtsid" / "calibrations"
    assert copy.read_text() == recorded["json"]
    assert with_recorded_calibration(document, recorded) == moved  # same content, same copy


def test_a_baseline_with_an_ankle_attached_is_refused_unless_forced(tmp_path, capsys):
    # issue 19: calibrate on a run with an ankle attached reported VAF 99.3 % and wrote the
    # file without a word
    position, torque = simulate(PLANT, 4.0)  # the ankle (K 150) on the robot
    np.savez(tmp_path / "with_ankle.npz", position_rad=position, torque_nm=torque, fs_hz=FS)
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(tmp_path / "with_ankle.npz"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a joint seems attached" in err[0] and "--force" in err[0]
    assert "K = 1" in err[0]  # the stiffness found, ≈ 150 N·m/rad
    assert not out.exists()
    argv = ["calibrate", str(tmp_path / "with_ankle.npz"), "-o", str(out), "--force"]
    assert main(argv) == 0
    assert out.exists()
    assert "warning: the baseline's torque follows position like a spring" in (
        capsys.readouterr().err
    )


@pytest.mark.parametrize(
    "plant",
    [
        replace(PLANT, stiffness=20.0, damping=0.3),  # a weak ankle, still seen
        replace(PLANT, perturbation="prbs", bandwidth_hz=40.0, noise_percent=10.0),
    ],
)
def test_the_joint_check_sees_a_weak_ankle_and_not_a_noisy_robot_alone(plant):
    from rtsid.ident.robot import baseline_stiffness

    position, torque = simulate(plant, 4.0)
    assert baseline_stiffness([(position, torque)], FS).joint_attached
    inverted = baseline_stiffness([(position, -torque)], FS)  # a rig reporting torque inverted
    assert inverted.joint_attached and inverted.K > 0
    alone = replace(plant, inertia=0.0, damping=0.0, stiffness=0.0, noise_percent=30.0)
    position, torque = simulate(alone, 4.0)
    found = baseline_stiffness([(position, torque)], FS)
    assert not found.joint_attached and abs(found.t) < 2.0


def test_a_calibration_of_another_rate_is_refused_when_the_config_loads(tmp_path):
    # it was refused only once the daemon had started, after its start-up line
    position, torque = simulate(NO_PERSON, 1.0)
    save_calibration(Calibration(identify_robot([(position, torque)], FS)), tmp_path / "c.json")
    config = tmp_path / "rig.toml"
    worker = f'[worker]\ncalibration_file = "{tmp_path / "c.json"}"\n'
    config.write_text("[link]\nfs_hz = 2000.0\n[plant]\nfs_hz = 2000.0\n" + worker)
    with pytest.raises(ConfigError, match=f"identified at {FS:g} Hz but the samples are at 2000"):
        DaemonConfig.load(config)
    config.write_text(worker)  # the calibration's own rate
    assert DaemonConfig.load(config).worker.calibration_file == str(tmp_path / "c.json")
