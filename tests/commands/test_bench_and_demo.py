import re

import pytest

from rtsid.cli import main


def test_toeplitz_benchmark_prints_its_table(capsys):
    assert main(["bench", "toeplitz", "--quick", "--sizes", "50", "120"]) == 0
    out = capsys.readouterr().out
    assert "EUREKA C" in out and "scipy/EUREKA" in out
    rows = [
        line for line in out.splitlines() if line.startswith("|") and line[2:6].strip().isdigit()
    ]
    assert [int(r.split("|")[1]) for r in rows] == [50, 120]


def test_window_benchmark_lists_every_stage(capsys):
    assert main(["bench", "window", "--quick", "--windows", "20"]) == 0
    out = capsys.readouterr().out
    for stage in (
        "front end, compiled",
        "prepare",
        "IRF",
        "fit I, B, K",
        "standard errors",
        "baseline: source method",
        "full path (reflex + estimate + tracker)",  # the stream's per-window path
        "numpy / compiled",
        "Floors: median",
        "10 kHz robot",  # how the cost grows
        "% of a core",
    ):
        assert stage in out
    scaling = [
        line.split("|")[2].strip() for line in out.splitlines() if "|       window |" in line
    ]
    assert scaling == ["0.1 s", "0.3 s", "1 s", "2 s"]


def test_unknown_benchmark_option_is_refused(capsys):
    try:
        main(["bench", "toeplitz", "--bogus"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err


def test_demo_tracks_the_simulated_stiffness(capsys):
    assert main(["demo", "--duration", "1.5", "--hop", "0.3"]) == 0
    out = capsys.readouterr().out
    note = next(line for line in out.splitlines() if line.startswith("median |K error|"))
    assert float(note.split("=")[1].split("%")[0]) < 10.0


def test_real_benchmark_tables_and_figures(reklab_path, tmp_path, capsys):
    figures = tmp_path / "fig"
    argv = ["bench", "real", "--quick", "--data", str(reklab_path), "--figures", str(figures)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "least squares (reference)" in out and "Floors" in out and "× real time" in out
    assert "parallel cascade" in out and "intrinsic IRF alone" in out
    pngs = sorted(p.name for p in figures.glob("*.png"))
    assert pngs == [
        "real_defaults.png",
        "real_defaults_hist.png",
    ]
    assert all((figures / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for name in pngs)


def test_replay_benchmark_compares_replay_with_the_bare_estimator(capsys):
    assert main(["bench", "replay", "--minutes", "0.1", "--pairs", "2"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("|") and "windows" not in line]
    paths = ("rtsid replay", "same replay", "baseline")
    windows = [int(r.split("|")[2]) for r in rows if r.split("|")[1].strip().startswith(paths)]
    # replay, the same on the numpy path, the bare estimator: 6 s, 300 ms every 20 ms
    assert windows == [286, 286, 286]
    assert "numpy path" in out and "Floor (issue 22)" in out
    # the folder table: --pairs alternated pairs (1-2, 2-1) and their medians
    runs = [
        [c.strip() for c in r.split("|")[1:3]] for r in rows if r.startswith(("| pair", "| median"))
    ]
    assert runs == [
        *(["pair 1", "1"], ["pair 1", "2"], ["pair 2", "1"], ["pair 2", "2"]),
        *(["median", "1"], ["median", "2"]),
    ]
    assert "--jobs 2 ≥ 1.7× --jobs 1, the median of the pairs' speed-ups" in out
    # each run's start-up per process (--timing) and its CPU: one for --jobs 1, two for 2
    by_jobs = {}
    for r in rows:
        if r.startswith("| pair"):
            cells = [c.strip() for c in r.split("|")]
            by_jobs.setdefault(cells[2], []).append((cells[6], cells[7], cells[8], cells[11]))
    assert "By CPU, --jobs 1's process over --jobs 2's busiest" in out
    for jobs, count in (("1", 1), ("2", 2)):
        for startup, startup_cpu, idle, busiest_cpu in by_jobs[jobs]:
            assert float(busiest_cpu) > 0
            for cell in (startup, startup_cpu, idle):
                assert len(cell.split(" / ")) == count
            assert all(float(s) > 0 for s in (*startup.split(" / "), *startup_cpu.split(" / ")))
            assert all(float(s) >= 0 for s in idle.split(" / "))
    # where the replay's CPU went: the three parts add up to the whole
    split = {r.split("|")[1].strip(): r.split("|") for r in rows}
    parts = [v for k, v in split.items() if k.startswith(("window path", "slow-lane", "the rest"))]
    total = split["replay, all of it"]
    assert len(parts) == 3 and all(float(p[2]) >= 0 for p in parts)
    assert sum(float(p[2]) for p in parts) == pytest.approx(float(total[2]), rel=0.02)
    fits = re.search(r"(\d+) slow-lane fits \(([\d.]+) ms of CPU each\)", out)
    assert fits and int(fits[1]) >= 1 and float(fits[2]) > 0  # one fit's cost, named


def test_the_replay_benchmark_takes_one_pair_or_more(capsys):
    assert main(["bench", "replay", "--minutes", "0.1", "--pairs", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--pairs 0" in err[0]


def test_service_benchmark_config_runs_the_daemon_at_the_hop_asked(tmp_path):
    from rtsid.benchmarks.service import _config_file
    from rtsid.runtime.daemon import DaemonConfig

    path = _config_file(tmp_path, 7447, 29536, -1, "process", True, 0.004, 0.001)
    config = DaemonConfig.load(path)
    assert config.worker.hop_s == 0.004 and config.daemon.gil_switch_interval_s == 0.001
    assert config.slow_lane.enabled and config.plant.reflex.enabled
    assert config.link.interface == "socketcand" and config.link.port == 29536
    assert config.daemon.realtime_priority == 0
    path = _config_file(tmp_path, 7447, None, -1, "off", realtime_priority=10)
    assert DaemonConfig.load(path).daemon.realtime_priority == 10


def test_service_benchmark_counts_worker_cpu_and_replayed_equality():
    from rtsid.benchmarks.service import Phase, identical_to_live, worker_cpu_per_window_ms
    from rtsid.replay import ReplayResult

    status = {
        "worker": {
            "estimates": 8,
            "withheld": {"gap": 2},
            "compute_s": 0.03,
            "compute_cpu_s": 0.02,
        }
    }
    assert worker_cpu_per_window_ms(status) == pytest.approx((2.0, 3.0))
    phase = Phase("idle")
    phase.live_values = {49: (150.0, 0.8, 0.015), 99: (151.0, 0.8, 0.015)}
    phase.replay = ReplayResult(
        source="x",
        messages=[
            {"window_end_index": 49, "K": 150.0, "B": 0.8, "I": 0.015},
            {"window_end_index": 99, "K": 151.5, "B": 0.8, "I": 0.015},
        ],
    )
    assert identical_to_live(phase) == (1, 2)


def test_bench_markers_quick_keeps_every_acknowledged_marker(capsys):
    assert main(["bench", "markers", "--quick"]) == 0  # non-zero if one was lost or doubled
    out = capsys.readouterr().out
    assert "round trip (ms)" in out and "After kill -9 and rtsid recover" in out
