"""``rtsid plant``: config errors are one line; player mode serves a recording and stops."""

import json

import numpy as np

from rtsid.cli import main
from rtsid.link.serve import PlantServerOptions, serve_plant


def test_bad_plant_config_is_one_line_naming_the_key(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[plant]\namplitude = 0.05\n")
    assert main(["plant", "--port", "0", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rtsid plant: error: unknown config key plant.amplitude;")
    assert "amplitude_rad" in err and "\n" not in err


def test_player_mode_serves_for_a_bounded_time(tmp_path, capsys):
    rec = tmp_path / "rec.npz"
    t = np.arange(2000) / 1000.0
    np.savez(rec, position_rad=0.01 * np.sin(8 * t), torque_nm=np.cos(8 * t), fs_hz=1000.0)
    options = PlantServerOptions(port=0, player_file=str(rec), duration_s=0.3)
    assert serve_plant(options) == 0
    banner, report = capsys.readouterr().out.strip().splitlines()
    assert "socketcand server on 127.0.0.1:" in banner and "(player, 2500 Hz)" in banner
    counters = json.loads(report)
    assert counters["plant"]["samples"] > 0 and counters["server"]["clients_total"] == 0
