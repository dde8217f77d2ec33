"""rtsid plot: the estimates of a recording as a figure; a clear hint when it has none."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsid.cli import main
from rtsid.commands.plot import estimate_series
from rtsid.io.mcap_read import iter_estimates

pytest.importorskip("matplotlib")

REFERENCE = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_plots_a_daemon_recording_and_its_histograms(tmp_path, capsys):
    out, hist = tmp_path / "fig.png", tmp_path / "hist.png"
    assert main(["plot", str(REFERENCE), "-o", str(out), "--hist", str(hist)]) == 0
    for path in (out, hist):
        assert path.read_bytes()[:8] == PNG_MAGIC and path.stat().st_size > 10_000
    messages = list(iter_estimates(REFERENCE))
    ok = [m for m in messages if m["ok"]]
    printed = capsys.readouterr().out
    assert f"over {len(ok)} windows ({len(messages) - len(ok)} withheld" in printed
    assert f"median K {np.median([m['K'] for m in ok]):.1f}" in printed


def test_withheld_windows_are_gaps_in_the_series():
    messages = list(iter_estimates(REFERENCE))
    t, series, flagged = estimate_series(messages)
    withheld = np.array([not m["ok"] for m in messages])
    assert withheld.any() and np.all(np.isnan(series["K"][withheld]))
    assert np.all(np.isfinite(series["K"][~withheld]))
    assert not flagged[withheld].any()
    assert np.all(np.diff(t) > 0)


def test_a_recording_without_estimates_says_how_to_make_them(tmp_path, capsys):
    rng = np.random.default_rng(1)
    np.savez(
        tmp_path / "r.npz",
        position_rad=rng.normal(size=300),
        torque_nm=rng.normal(size=300),
        fs_hz=1000.0,
    )
    rec = tmp_path / "r.mcap"
    assert main(["convert", str(tmp_path / "r.npz"), "-o", str(rec)]) == 0
    capsys.readouterr()
    assert main(["plot", str(rec), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "no /estimate messages" in err and f"rtsid replay {rec} -o OUT.mcap" in err
    assert not (tmp_path / "x.png").exists()


def test_replayed_estimates_plot(tmp_path):
    replayed = tmp_path / "replayed.mcap"
    assert main(["replay", str(REFERENCE), "-o", str(replayed)]) == 0
    assert main(["plot", str(replayed), "-o", str(tmp_path / "r.png"), "--every", "3"]) == 0
    assert (tmp_path / "r.png").read_bytes()[:8] == PNG_MAGIC


def _leaves(node):
    if isinstance(node, str):
        return [node]
    return _leaves(node["first"]) + _leaves(node["second"])


def test_foxglove_layout_shows_fields_the_recordings_have():
    import json

    from rtsid.io.schemas import SCHEMAS

    layout_path = REFERENCE.parents[1] / "foxglove_layout.json"
    layout = json.loads(layout_path.read_text(encoding="utf-8"))
    panels = layout["configById"]
    assert sorted(_leaves(layout["layout"])) == sorted(panels)
    fields = {topic: set(schema["properties"]) for schema, topic in SCHEMAS.values()}
    plotted = set()
    for panel_id, config in panels.items():
        if panel_id.startswith("Plot!"):
            for path in config["paths"]:
                topic, field = path["value"].split(".", 1)
                assert field in fields[topic], path["value"]
                plotted.add(path["value"])
        else:
            assert config["topicPath"] in fields
    assert {"/estimate.K", "/estimate.B", "/estimate.I", "/estimate.vaf"} <= plotted
    assert any(p.startswith("/samples.") for p in plotted)


def test_parts_of_a_rotated_session_plot_as_one(tmp_path, capsys):
    from rtsid.replay import recording_config, replay_file, write_estimates_mcap

    messages = replay_file(REFERENCE).messages
    config = recording_config(REFERENCE)
    half = len(messages) // 2
    parts = [tmp_path / "part-000.mcap", tmp_path / "part-001.mcap"]
    for path, chunk in zip(parts, (messages[half:], messages[:half]), strict=True):
        with path.open("wb") as fh:
            write_estimates_mcap(chunk, fh, source=str(REFERENCE), config=config)
    capsys.readouterr()
    assert main(["plot", *map(str, parts), "-o", str(tmp_path / "p.png")]) == 0
    ok = sum(m["ok"] for m in messages)
    assert f"over {ok} windows ({len(messages) - ok} withheld" in capsys.readouterr().out
