"""The daemon over the two new paths (the second CAN protocol and the UDP source): its I, B,
K of the simulated ankle (I 0.015, B 0.8, K 150) within 20 / 10 / 5 % of the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsid.io.mcap_read import iter_estimates
from rtsid.io.recording import read_session
from rtsid.link.mapping import compile_protocol
from rtsid.replay import recording_config
from rtsid.runtime.daemon import Daemon, DaemonConfig

HW = Path(__file__).resolve().parents[2] / "hw"
TRUTH_AND_TOLERANCE = {"I": (0.015, 0.20), "B": (0.8, 0.10), "K": (150.0, 0.05)}

LINKS = {
    "twoframe": """
[link]
interface = "embedded"
fs_hz = 2000.0

[link.protocol]
dbc = "twoframe.dbc"                   # copied next to the config by the test
position = "JointPosition.Position"
torque = "JointTorque.Torque"
counter = ""
position_saturated = "JointPosition.PositionSaturated"
torque_saturated = "JointTorque.TorqueSaturated"
perturbation_on = "JointPosition.PerturbationOn"
discontinuity = "JointPosition.Discontinuity"
marker = "JointPosition.TrialMarker"
command = "PerturbationCommand"
diagnostics = ""
checksum = "none"

[plant]
fs_hz = 2000.0
diagnostics_hz = 0.0
marker_every_s = 1.0
""",
    "udp": """
[link]
interface = "udp"

[link.udp]
port = 0
sample_format = "IiiiB"
fields = ["counter", "position", "torque", "status", "marker"]
samples_per_datagram = 10
embedded_plant = true

[plant]
diagnostics_hz = 0.0
marker_every_s = 1.0
""",
}


@pytest.mark.slow  # a real-time daemon run of seconds
@pytest.mark.parametrize("path", sorted(LINKS))
def test_the_daemon_identifies_the_ankle_over_the_new_paths(tmp_path, free_port, path):
    (tmp_path / "twoframe.dbc").write_bytes((HW / "protocols" / "twoframe.dbc").read_bytes())
    config_file = tmp_path / "rtsid.toml"
    config_file.write_text(
        LINKS[path]
        + f"""
[zenoh]
listen = ["tcp/127.0.0.1:{free_port}"]
robot = "testbot"

[mcap]
directory = "{tmp_path / "rec"}"
"""
    )
    summary = Daemon(DaemonConfig.load(config_file)).run(duration_s=3.0)
    assert summary.clean_shutdown and summary.failure is None
    assert summary.lost_samples == 0 and summary.samples > 4000
    (recording,) = sorted((tmp_path / "rec").glob("*.mcap"))
    ok = [e for e in iter_estimates(recording) if e["ok"]]
    assert len(ok) > 40
    for key, (truth, tolerance) in TRUTH_AND_TOLERANCE.items():
        assert np.median([e[key] for e in ok]) == pytest.approx(truth, rel=tolerance), key
    markers = read_session(recording).markers
    fs = 2000.0 if path == "twoframe" else 2500.0
    label = "TrialMarker" if path == "twoframe" else "marker"
    assert [(m["sample_index"], m["label"], m["source"]) for m in markers] == [
        (round(k * fs), f"{label}={k}", "wire") for k in range(1, len(markers) + 1)
    ]
    assert len(markers) >= 2  # the markers stepped on the wire reach the recording
    (tmp_path / "twoframe.dbc").unlink()  # a replay elsewhere has the samples, not the DBC
    compile_protocol.cache_clear()  # as in a fresh process
    replayed = recording_config(recording)
    assert replayed.link.fs_hz == (2000.0 if path == "twoframe" else 2500.0)
