"""``rtsid tv REC.mcap``: the virtual plant's torque-multisine experiment, recorded by the
daemon, identified from the recording with the multisine its stored config declares."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsid.cli import main
from rtsid.errors import IncompleteRecordingWarning, InputDataError
from rtsid.io.convert import ImportedSamples, write_recording
from rtsid.io.mcap_read import recording_parts
from rtsid.link.config import plant_config_from_mapping
from rtsid.link.signals import TorqueMultisineSource
from rtsid.runtime.daemon import Daemon, DaemonConfig
from rtsid.tv import load_tv_mcap

FS = 2500.0
PERIOD_S = 1.0
N_PERIODS = 6
K_LOW, K_HIGH = 20.0, 150.0  # N·m/rad: f_n = 5.8 … 15.9 Hz with I = 0.015 kg·m²


def plant_table(realtime: bool = True, **extra) -> dict:
    """A torque multisine (lines 2…20 Hz, 2 Hz apart) on a raised-cosine K(t) over 6 s."""
    return {
        "mode": "torque_multisine",
        "realtime": realtime,
        "noise_percent": 0.5,
        "position_noise_rad": 1e-4,
        "torque_multisine": {"period_s": PERIOD_S, "every": 2, "f_max_hz": 20.0, "rms_nm": 2.0},
        "stiffness_profile": {
            "kind": "raised_cosine",
            "k0": K_LOW,
            "k1": K_HIGH,
            "t0_s": 0.0,
            "t1_s": N_PERIODS * PERIOD_S,
        },
        **extra,
    }


@pytest.mark.slow  # a real-time daemon run of seconds
def test_virtual_plant_recording_to_stiffness_track(tmp_path, free_port, capsys):
    n = round(N_PERIODS * PERIOD_S * FS)
    sent = n + 400  # a little more than 6 periods
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"], "robot": "tv"},
            # parts of ~0.1 MB: the session rotates, tv reads every part
            "mcap": {"directory": str(tmp_path / "rec"), "rotate_size_mb": 0.1},
            # as fast as the acquisition takes frames
            "plant": plant_table(realtime=False, max_samples=sent),
        }
    )
    daemon = Daemon(config)

    def stop_once_every_sample_is_in(status: dict, _estimate: dict | None) -> None:
        if status["acquisition"]["samples"] + status["acquisition"]["lost_samples"] >= sent:
            daemon.request_stop()  # the plant is done: no fixed 4 s of waiting on its silence

    daemon.on_status = stop_once_every_sample_is_in
    summary = daemon.run(duration_s=60.0)  # ends through request_stop, not the duration
    assert summary.lost_samples == 0 and summary.samples >= n
    recording, *later_parts = recording_parts(next((tmp_path / "rec").glob("*.mcap")))
    assert later_parts  # rotated
    csv = tmp_path / "track.csv"
    argv = ["tv", str(recording), "-o", str(csv)]  # the defaults
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "used periods 0..5 of the multisine (6 × 2500 samples: rows 0..14999" in out
    assert "10 excited lines 2…20 Hz, 2 Hz apart" in out
    track = np.genfromtxt(csv, delimiter=",", names=True)
    k_true = track["K_true"]
    fn_true = np.sqrt(k_true / 0.015) / (2 * np.pi)
    # Tolerances: the Legendre expansion is weakest at the record's two ends, so judge
    # 10 … 90 % of it. There, over 8 phase/noise seeds of this experiment (rtsid.tv on the
    # plant's blocks), K(t) is within 1.8–3.3 % of its 130 N·m/rad range and f_n(t) within
    # 0.08–0.12 Hz RMS — the same without noise: what remains is the model (N_p = 7 over
    # 6 periods, and a frozen second-order fit to a joint whose K changes by 40 % per
    # second), not the noise. Limits: 5 % of the range, 0.15 Hz (this seed: 1.8 %, 0.08 Hz).
    inner = slice(track.size // 10, -track.size // 10)
    k_err = track["K"][inner] - k_true[inner]
    fn_err = track["f_n_hz"][inner] - fn_true[inner]
    assert np.max(np.abs(k_err)) < 0.05 * (K_HIGH - K_LOW)
    assert np.sqrt(np.mean(fn_err**2)) < 0.15
    assert track["I"][0] == pytest.approx(0.015, rel=0.05)
    # a recording cut short (no footer, as after a crash) gives the periods it still holds
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recording.read_bytes()[: recording.stat().st_size * 2 // 3])
    with pytest.warns(IncompleteRecordingWarning, match=r"cut\.mcap ends early.*read \d+ samples"):
        data = load_tv_mcap(cut)
    assert data.selection.startswith("periods 0..")
    assert 1 <= data.torque_nm.size // 2500 < N_PERIODS


def write_plant_recording(
    path: Path, plant: dict | None, *, first_index: int = 0, lost: slice | None = None
) -> Path:
    """The samples of ``plant_table()``'s experiment (simulated without the link) written
    as an rtsid recording whose stored config has ``plant`` as its ``[plant]`` table (or no
    config at all), whatever that table declares."""
    cfg = plant_config_from_mapping(plant_table())
    source = TorqueMultisineSource(cfg)
    blocks = [source.next_block() for _ in range(round(N_PERIODS * PERIOD_S / cfg.block_s))]
    position = np.concatenate([b.position_rad for b in blocks])[first_index:]
    torque = np.concatenate([b.torque_nm for b in blocks])[first_index:]
    valid = np.ones(position.size, dtype=bool)
    if lost is not None:
        valid[lost] = False
        position[lost] = torque[lost] = np.nan
    samples = ImportedSamples(
        first_index, FS, position, torque, valid, np.zeros(position.size, np.int64), 0, "npz"
    )
    run_config = {} if plant is None else {"plant": plant}
    return write_recording(samples, path, run_config=run_config, batch_samples=250, source="test")


def test_longest_run_of_whole_periods_without_lost_samples(tmp_path):
    # rows start at sample 1300 (mid-period 0); samples 8700..8709 (period 3) lost:
    # periods 1-2 and 4-5 are whole, the earlier of the two longest runs is used
    path = write_plant_recording(
        tmp_path / "gap.mcap", plant_table(), first_index=1300, lost=slice(7400, 7410)
    )
    data = load_tv_mcap(path)
    assert data.selection.startswith("periods 1..2 of the multisine (2 × 2500 samples: rows")
    assert "rows 2500..7499, t = 1..3 s" in data.selection
    assert data.torque_nm.size == 5000 and np.all(np.isfinite(data.position_rad))
    np.testing.assert_array_equal(data.excited_bins, np.arange(2, 21, 2))
    assert data.inertia == pytest.approx(0.015)
    truth_t = 1.0 + np.arange(5000) / FS  # the truth follows the plant's clock
    k = data.stiffness_nm_per_rad
    assert k is not None and k[0] == pytest.approx(
        K_LOW + (K_HIGH - K_LOW) * 0.5 * (1 - np.cos(2 * np.pi * truth_t[0] / 6))
    )


@pytest.mark.parametrize(
    ("plant", "message"),
    [
        (None, "declares no torque multisine"),
        ({"mode": "sim"}, "declares no torque multisine"),
    ],
)
def test_a_recording_without_a_declared_multisine_is_a_one_line_error(
    tmp_path, capsys, plant, message
):
    path = write_plant_recording(tmp_path / "plain.mcap", plant)
    assert main(["tv", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err and 'mode = "torque_multisine"' in err
    assert err.count("\n") == 1


def test_no_whole_period_is_a_one_line_error(tmp_path, capsys):
    # a sample lost in every period
    plant = plant_table()
    path = write_plant_recording(tmp_path / "holes.mcap", plant, lost=slice(100, None, 2500))
    with pytest.raises(InputDataError, match="no whole 1 s multisine period without lost"):
        load_tv_mcap(path)
    assert main(["tv", str(path)]) == 2
    assert "record at least two periods" in capsys.readouterr().err


def test_other_files_and_missing_recordings_are_clear_errors(tmp_path, capsys):
    assert main(["tv", str(tmp_path / "nothing.mcap")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["tv", str(tmp_path / "rec.csv")]) == 2
    assert "rtsid convert" in capsys.readouterr().err


def test_a_declared_multisine_the_torque_does_not_follow_is_refused(tmp_path, capsys):
    # the plant excited every 2nd bin; the config claims every 3rd
    plant = plant_table()
    plant["torque_multisine"] = {**plant["torque_multisine"], "every": 3}
    path = write_plant_recording(tmp_path / "wrong.mcap", plant)
    assert main(["tv", str(path)]) == 2
    err = capsys.readouterr().err
    assert "not a periodic multisine on the declared excited bins" in err
    assert err.count("\n") == 1
