"""rtsid plot: the estimates of a recording as a figure; a clear hint when it has none."""

from __future__ import annotations

import sys
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
    # issue 19: the first plot leads with the tracked stiffness, the window's K beside it
    first = layout["layout"]
    while not isinstance(first, str):
        first = first["first"]
    leading = [p["value"] for p in panels[first]["paths"]]
    assert leading[:2] == ["/estimate.K_track", "/estimate.K"]
    assert any(p.startswith("/samples.") for p in plotted)
    shown = {c["topicPath"] for i, c in panels.items() if i.startswith("RawMessages!")}
    assert {"/marker", "/session"} <= shown  # trial markers and the session beside the plots


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


# ------------------------------------------------------------------- --plot draws or refuses
def _plot_commands(tmp: Path) -> list[list[str]]:
    missing, png = str(tmp / "missing.npz"), str(tmp / "fig.png")
    return [
        ["identify", missing, "--plot", png, "-o", str(tmp / "est.csv")],
        ["identify", missing, "--model", "cascade", "--plot", png],
        ["identify", missing, "--model", "cascade", "--window", "20", "--plot", png],
        ["tv", missing, "--plot", png],
        ["tv", "--simulate", "CS1", "-o", str(tmp / "sim.npz"), "--plot", png],
        ["plot", str(tmp / "missing.mcap"), "-o", png],
    ]


@pytest.mark.parametrize("which", range(6))
def test_plot_without_matplotlib_refuses_in_one_line_before_any_work(
    which, tmp_path, monkeypatch, capsys
):
    # issue 19: `identify --plot` in window mode drew nothing and said nothing. The inputs here
    # do not exist: a command that looked at them before matplotlib would say so instead.
    for name in ("matplotlib", "matplotlib.pyplot", "matplotlib.figure"):
        monkeypatch.setitem(sys.modules, name, None)  # `import matplotlib` raises ImportError
    argv = _plot_commands(tmp_path)[which]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'rtsid[plot]'" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written


def test_identify_plot_in_window_mode_writes_the_figure(tmp_path, capsys):
    from rtsid.ident.excitation import filtered_noise
    from rtsid.sim.joint import simulate_impedance

    fs = 1000.0
    theta = filtered_noise(4000, fs, 30.0, peak=0.03, seed=1)
    np.savez(
        tmp_path / "sim.npz",
        position_rad=theta,
        torque_nm=simulate_impedance(theta, fs, noise_percent=3.0, seed=2),
        fs_hz=fs,
    )
    png = tmp_path / "fig.png"
    argv = ["identify", str(tmp_path / "sim.npz"), "-o", str(tmp_path / "e.csv")]
    assert main([*argv, "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 10_000
    assert f"wrote {png}" in capsys.readouterr().err


def test_tv_simulate_with_plot_names_the_recording_to_give(tmp_path, capsys):
    argv = ["tv", "--simulate", "CS1", "-o", str(tmp_path / "s.npz"), "--plot", "f.png"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"-o {tmp_path / 's.npz'} {tmp_path / 's.npz'} --plot f.png" in err
    assert not (tmp_path / "s.npz").exists()


# ------------------------------------------------------------ what the figure leads with
def _legend(ax) -> list[str]:
    legend = ax.get_legend()
    return [] if legend is None else [t.get_text() for t in legend.get_texts()]


def _series(n: int, *, b_held_from: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    held = np.arange(n) >= b_held_from
    return {
        "K": 100.0 + 30.0 * rng.standard_normal(n),
        "K_se": np.full(n, 8.0),
        "K_track": np.full(n, 100.0),
        "K_track_se": np.full(n, 2.0),
        "B": np.where(held, 1.350, 1.3 + 0.05 * rng.standard_normal(n)),
        "B_se": np.where(held, np.nan, 0.05),
        "B_held": held.astype(float),
        "I": np.full(n, 0.0155),
        "I_se": np.full(n, np.nan),
        "I_held": np.ones(n),
        "vaf": np.full(n, 90.0),
    }


def test_the_figure_leads_with_k_track_and_shows_held_values_as_held():
    # issue 19: held medians were drawn as a "windowed estimate" with a "95 % interval"
    # legend and no band, on axes zoomed until a 20 s running median looked like a joint
    import matplotlib.pyplot as plt

    from rtsid.plots import HELD_LABEL, impedance_figure

    t = np.arange(200) * 0.1
    fig = impedance_figure(t, _series(200, b_held_from=6), title="t")
    try:
        k_ax, b_ax, i_ax, _ = fig.axes
        assert _legend(k_ax)[:3] == [
            "K (each 300 ms window)",
            "K_track 95 % interval",
            "K_track (tracked stiffness)",
        ]
        assert k_ax.get_lines()[-1].get_label() == "K_track (tracked stiffness)"  # drawn on top
        # B: fitted in its first six windows (with their band), held after (no band)
        assert set(_legend(b_ax)) == {"95 % interval", "B (fitted in the window)", HELD_LABEL}
        # I: held throughout: a held line, no band, no "95 % interval" in the legend
        assert _legend(i_ax) == [HELD_LABEL]
        assert not i_ax.collections  # no band
        for ax in (k_ax, b_ax, i_ax):
            low, high = ax.get_ylim()
            assert low <= 0.0 < high  # from zero: a held median cannot look like a wiggle
        assert i_ax.get_ylim()[1] < 0.0155 * 1.5
    finally:
        plt.close(fig)


def test_replayed_estimates_carry_what_the_figure_needs():
    from rtsid.replay import replay_file

    messages = replay_file(REFERENCE).messages
    _, series, _ = estimate_series(messages)
    assert np.isfinite(series["K_track"]).any() and np.isfinite(series["K_track_se"]).any()
    assert set(np.unique(series["B_held"][np.isfinite(series["B_held"])])) <= {0.0, 1.0}


def test_identify_plot_in_whole_record_cascade_mode_writes_the_figure(tmp_path):
    from rtsid.sim.joint import JointParameters
    from rtsid.sim.reflex import ReflexParameters, prbs_ankle_with_reflex

    theta, torque = prbs_ankle_with_reflex(5.0, 1000.0, JointParameters(), ReflexParameters())
    np.savez(tmp_path / "r.npz", position_rad=theta, torque_nm=torque, fs_hz=1000.0)
    png = tmp_path / "cascade.png"
    argv = ["identify", str(tmp_path / "r.npz"), "--model", "cascade", "--plot", str(png)]
    assert main([*argv, "-o", str(tmp_path / "c.csv")]) == 0
    assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 10_000


def test_markers_are_carried_through_replay_and_drawn(tmp_path, capsys):
    from rtsid.io.mcap_log import McapConfig, McapLogger
    from rtsid.io.mcap_read import read_run_config
    from rtsid.io.recording import iter_batches, read_session
    from rtsid.io.session import SessionConfig
    from rtsid.plots import impedance_figure

    fs = 2500.0
    labels = {2500: "trial $1$ start", 6250: "<b>trial 1 end</b>"}
    logger = McapLogger(
        McapConfig(directory=str(tmp_path / "rec")),
        robot="rig",
        joint="ankle",
        fs_hz=fs,
        run_config=read_run_config(REFERENCE),
        session=SessionConfig("S01", "2", "baseline"),
    )
    with logger:
        for batch in iter_batches(REFERENCE):
            logger.log_samples(
                batch.first_index, batch.position_rad, batch.torque_nm, batch.valid, batch.status
            )
        for k, (index, label) in enumerate(labels.items()):
            marker = {
                "robot": "rig",
                "joint": "ankle",
                "t_s": index / fs,
                "sample_index": index,
                "label": label,
                "source": "zenoh",
                "marker_id": f"m{k}",
                "host_time_ns": k,
            }
            logger.log_marker(marker)
    (recording,) = logger.files
    replayed = tmp_path / "replayed.mcap"
    capsys.readouterr()
    assert main(["replay", str(recording), "-o", str(replayed)]) == 0
    header, _, row = capsys.readouterr().out.splitlines()[2:5]
    columns = dict(zip(header.split("|"), row.split("|"), strict=True))
    assert columns[" markers "].strip() == "2"  # counted in the replay's summary
    carried = read_session(replayed)
    assert [(m["sample_index"], m["label"]) for m in carried.markers] == list(labels.items())
    assert carried.subject == "S01" and carried.metadata[0]["condition"] == "baseline"
    png = tmp_path / "m.png"
    assert main(["plot", str(replayed), "-o", str(png)]) == 0
    assert "2 markers" in capsys.readouterr().out and png.read_bytes()[:8] == PNG_MAGIC

    t = np.array([0.5, 1.5, 2.5])
    series = {k: np.ones(3) for k in ("K", "B", "I", "vaf")}
    fig = impedance_figure(t, series, title="x", markers=[(1.0, "trial $1$ start")])
    texts = [a.get_text() for a in fig.axes[0].texts]
    assert texts == [r"trial \$1\$ start"]  # plain text, never mathtext
    lines = [ln for ax in fig.axes for ln in ax.get_lines() if list(ln.get_xdata()) == [1, 1]]
    assert len(lines) == len(fig.axes)  # one vertical line per panel
