"""Replay: same windows and numbers as the live daemon, reference outputs, damaged files."""

from __future__ import annotations

import csv
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from rtsid.cli import main
from rtsid.errors import IncompleteRecordingWarning
from rtsid.ident.reflex_lane import ReflexModels, ReflexUpdate, SlowLaneSettings
from rtsid.io.mcap_read import iter_estimates
from rtsid.io.recording import read_estimates, session_parts
from rtsid.replay import (
    LiveDecisions,
    is_announcement,
    recording_config,
    replay_file,
    write_estimates_mcap,
)
from rtsid.runtime.daemon import Daemon, DaemonConfig
from tests.runtime.test_slow_lane import run_until_fits

REFERENCE = Path(__file__).resolve().parents[1] / "replay" / "reference"
NUMBERS = (
    "I",
    "B",
    "K",
    "I_se",
    "B_se",
    "K_se",
    "K_track",
    "K_track_se",
    "B_track",
    "B_track_se",
    "vaf",
    "vaf_irf",
)


def by_window(messages):
    return {m["window_end_index"]: m for m in messages}


def live_windows(messages):
    """The live run's evaluations by window (not its announcements that a window's samples
    had not come: such a window was evaluated later, or skipped)."""
    return by_window(m for m in messages if not is_announcement(m))


def assert_same_estimates(expected, got, rtol=0.0):
    for end, e in expected.items():
        g = got[end]
        assert (g["ok"], g["reason"]) == (e["ok"], e["reason"]), end
        if e["ok"]:
            np.testing.assert_allclose(
                [np.nan if g[k] is None else g[k] for k in NUMBERS],
                [np.nan if e[k] is None else e[k] for k in NUMBERS],
                rtol=rtol,
                equal_nan=True,  # a held parameter has no standard error (null)
            )


@pytest.mark.slow  # a real-time daemon run of seconds
def test_replay_gives_the_live_daemons_windows_and_numbers_exactly(tmp_path, free_port):
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path)},
            "plant": {"stiffness_profile": {"kind": "sinusoidal", "amplitude": 50.0}},
        }
    )
    Daemon(config).run(duration_s=2.0)
    recording = next(tmp_path.glob("*.mcap"))
    live = live_windows(iter_estimates(recording))
    replayed = by_window(replay_file(recording).messages)
    assert len(live) > 60 and set(live) <= set(replayed)
    assert_same_estimates(live, replayed)  # bit for bit


@pytest.mark.slow  # a real-time daemon run of seconds
def test_a_4_ms_hop_with_the_slow_lane_replays_exactly_as_live(tmp_path, free_port):
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path)},
            "worker": {"hop_s": 0.004},
            "slow_lane": {
                "enabled": True,
                "mode": "thread",
                "horizon_s": 3.0,
                "update_s": 0.5,
                "apply_after_s": 0.3,
            },
            "plant": {"reflex": {"enabled": True}},
        }
    )
    # until the lane has made two fits (the first needs 3 s of data, then its thread's time on
    # a busy machine) and 1 s more for the windows that use them, instead of a fixed 7 s
    run_until_fits(Daemon(config), fits=2, least_s=0.0, then_samples=2500)
    recording = next(tmp_path.glob("*.mcap"))
    live = live_windows(iter_estimates(recording))
    replayed = replay_file(recording)
    assert {(end + 1) % 10 for end in live} == {0}  # a window every 10 samples at 2500 Hz
    assert len(live) > 150 and set(live) <= set(by_window(replayed.messages))
    assert replayed.reflex and any(m["reflex_seq"] is not None for m in live.values())
    assert_same_estimates(live, by_window(replayed.messages))  # bit for bit


@pytest.mark.slow  # a real-time daemon run of seconds
def test_replay_follows_a_live_worker_that_started_late(tmp_path, free_port, monkeypatch):
    # Under load the live worker can start after the first windows' samples are in: it begins
    # at the newest window (earlier ones are history). The replay must not learn from those.
    from rtsid.runtime.worker import WindowWorker

    started = WindowWorker._starting_window_end

    def late(self, newest):
        return started(self, newest) + 8 * self.hop_samples

    monkeypatch.setattr(WindowWorker, "_starting_window_end", late)
    config = DaemonConfig.from_mapping(
        {"zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]}, "mcap": {"directory": str(tmp_path)}}
    )
    Daemon(config).run(duration_s=1.5)
    monkeypatch.undo()
    recording = next(tmp_path.glob("*.mcap"))
    live = live_windows(iter_estimates(recording))
    replayed = replay_file(recording).messages
    assert min(m["window_end_index"] for m in replayed) == min(live)  # nothing before
    assert len(live) > 20 and set(live) <= set(by_window(replayed))
    assert_same_estimates(live, by_window(replayed))
    held = {m["window_end_index"]: m["I_held"] for m in replayed}
    assert all(held[end] == m["I_held"] for end, m in live.items())


def test_replay_reproduces_the_stored_reference_output():
    with (REFERENCE / "sim_3s.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    stored = {
        int(r["window_end_index"]): {
            "ok": r["ok"] == "true",
            "reason": r["reason"] or None,
            **{k: float(r[k]) if r[k] else None for k in NUMBERS},
        }
        for r in rows
    }
    replayed = by_window(replay_file(REFERENCE / "sim_3s.mcap").messages)
    assert set(stored) == set(replayed)
    assert_same_estimates(stored, replayed, rtol=1e-9)


def test_a_recording_cut_short_replays_up_to_the_cut(tmp_path):
    full = replay_file(REFERENCE / "sim_3s.mcap").messages
    cut = tmp_path / "cut.mcap"
    data = (REFERENCE / "sim_3s.mcap").read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])  # no footer, last chunk torn
    with pytest.warns(IncompleteRecordingWarning, match=r"read \d+ samples, [\d.]+ s") as caught:
        result = replay_file(cut)
    size_kib = int(len(data) * 0.6) / 1024
    assert len(caught) == 1 and f"of {size_kib:.1f} KiB" in str(caught[0].message)
    partial = by_window(result.messages)
    said = re.search(r"read (\d+) samples", str(caught[0].message))
    assert said and result.samples == int(said.group(1))
    assert 0 < len(partial) < len(full) and 0 < result.samples < 7500
    assert_same_estimates(partial, by_window(full))


@pytest.mark.slow  # a real-time daemon run of seconds
def test_lost_samples_are_bridged_alike_live_and_in_replay(tmp_path, free_port):
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path)},
            "plant": {"faults": {"drop_rate": 0.0005}},
        }
    )
    summary = Daemon(config).run(duration_s=2.0)
    assert summary.lost_samples > 0
    recording = next(tmp_path.glob("*.mcap"))
    live = live_windows(iter_estimates(recording))
    replayed = by_window(replay_file(recording).messages)
    assert_same_estimates(live, replayed)
    bridged = [m for m in replayed.values() if m["ok"] and m["lost_samples"]]
    # windows across a lost sample, estimated from the rest (15 per lost sample, fewer when
    # a loaded live worker skipped some: replay follows it)
    assert len(bridged) >= 5
    assert all(
        live[end]["lost_samples"] == m["lost_samples"]
        for end, m in replayed.items()
        if end in live and m["ok"]
    )


def test_replay_command_outputs_and_directories(tmp_path, capsys):
    folder = tmp_path / "recs"
    folder.mkdir()
    for name in ("a.mcap", "b.mcap"):
        shutil.copy(REFERENCE / "sim_3s.mcap", folder / name)
    assert main(["replay", str(folder), "-o", str(tmp_path / "out"), "--jobs", "2"]) == 0
    table = capsys.readouterr().out
    assert "a.mcap" in table and "b.mcap" in table
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.csv", "b.csv"]
    out_mcap = tmp_path / "one.mcap"
    assert main(["replay", str(folder / "a.mcap"), "-o", str(out_mcap), "--rate", "50"]) == 0
    assert len(list(iter_estimates(out_mcap))) == len(replay_file(folder / "a.mcap").messages)


def test_a_directory_replays_the_same_with_one_job_or_two(tmp_path, capsys):
    folder = tmp_path / "recs"
    folder.mkdir()
    for name in ("a.mcap", "b.mcap", "c.mcap"):
        shutil.copy(REFERENCE / "sim_3s.mcap", folder / name)
    tables = {}
    for jobs in ("1", "2"):
        assert main(["replay", str(folder), "-o", str(tmp_path / jobs), "--jobs", jobs]) == 0
        captured = capsys.readouterr()
        # every column but the last (× real time: how busy the computer was)
        tables[jobs] = [line.rsplit("|", 2)[0] for line in captured.out.splitlines()]
        progress = [line for line in captured.err.splitlines() if line.startswith("replayed")]
        assert [line.split(" (")[0] for line in progress] == [
            f"replayed {k}/3 recordings" for k in (1, 2, 3)
        ]
    assert tables["1"] == tables["2"]
    for name in ("a.csv", "b.csv", "c.csv"):
        one, two = (_without_compute_time(tmp_path / jobs / name) for jobs in ("1", "2"))
        assert len(one) > 100 and one == two


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_a_failing_recording_in_a_directory_is_one_error_and_the_others_are_written(
    tmp_path, capsys, jobs
):
    folder = tmp_path / "recs"
    folder.mkdir()
    for name in ("a.mcap", "c.mcap"):
        shutil.copy(REFERENCE / "sim_3s.mcap", folder / name)
    (folder / "b.mcap").write_bytes(b"not a recording")
    assert main(["replay", str(folder), "-o", str(tmp_path / "out"), "--jobs", jobs]) == 2
    err = capsys.readouterr().err.splitlines()
    assert [line for line in err if not line.startswith("replayed")] == [
        f"rtsid replay: error: '{folder / 'b.mcap'}' is not an MCAP file (bad magic bytes); "
        "pass an .mcap recording"
    ]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.csv", "c.csv"]


def test_one_job_replays_in_this_process_and_two_share_the_folder_with_it(
    tmp_path, capsys, monkeypatch
):
    """This process has imported rtsid already: it replays the first (largest) recording at
    once while a spawned child starts, and with --jobs 1 it spawns nothing."""
    import concurrent.futures as cf

    import rtsid.commands.replay as command

    folder = tmp_path / "recs"
    folder.mkdir()
    for name in ("a.mcap", "b.mcap"):
        shutil.copy(REFERENCE / "sim_3s.mcap", folder / name)
    here: list[str] = []
    replay_one = command._replay_one

    def replayed_here(path, args, out):
        here.append(path.name)
        if out is not None and out.parent.name == "2":  # busy until the child wrote its own
            deadline = time.monotonic() + 120.0
            while not (out.parent / "b.csv").exists():
                assert time.monotonic() < deadline, "the child replayed nothing"
                time.sleep(0.05)
        return replay_one(path, args, out)

    monkeypatch.setattr(command, "_replay_one", replayed_here)  # this process's, not a child's
    with monkeypatch.context() as no_pool:
        no_pool.setattr(cf, "ProcessPoolExecutor", None)  # --jobs 1 must not need one
        assert main(["replay", str(folder), "-o", str(tmp_path / "1"), "--jobs", "1"]) == 0
    assert here == ["a.mcap", "b.mcap"]
    here.clear()
    assert main(["replay", str(folder), "-o", str(tmp_path / "2"), "--jobs", "2"]) == 0
    assert here == ["a.mcap"]  # the largest first; b.mcap went to the child meanwhile
    capsys.readouterr()
    for name in ("a.csv", "b.csv"):
        one, two = (_without_compute_time(tmp_path / jobs / name) for jobs in ("1", "2"))
        assert len(one) > 100 and one == two


def test_ctrl_c_stops_a_directory_replay_and_its_children(tmp_path):
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) ends ``replay DIR --jobs
    2`` with status 130 and one line; no child prints a traceback or outlives it."""
    import os
    import signal
    import subprocess
    import sys

    folder, out = tmp_path / "recs", tmp_path / "out"
    folder.mkdir()
    for k in range(20):
        shutil.copy(REFERENCE / "sim_3s.mcap", folder / f"r{k:02d}.mcap")
    command = [sys.executable, "-m", "rtsid.cli", "replay", str(folder), "--jobs", "2"]
    proc = subprocess.Popen(
        [*command, "-o", str(out)],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120.0
        while not (out.exists() and any(out.iterdir())):  # the first recording replayed
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    assert proc.returncode == 130, err
    assert "rtsid replay: interrupted" in err and "Traceback" not in err
    assert len(list(out.iterdir())) < 20  # it stopped: nothing more was sent
    deadline = time.monotonic() + 10.0
    while True:  # no process of the group is left
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        assert time.monotonic() < deadline, "a child outlived the interrupted command"
        time.sleep(0.05)


def test_the_replay_command_is_parsed_before_the_replay_is_imported():
    """``rtsid replay DIR --jobs N`` spawns its children before it imports the replay
    (numpy, the reader, the window path: ≈ 2 G instructions here, where every process
    compiles rtsid from source), so that they import it while this process does too."""
    import subprocess
    import sys

    code = (
        "import sys; from rtsid.cli import build_parser; build_parser(['replay']); "
        "print(sorted(m for m in ('numpy', 'rtsid.replay', 'rtsid.io.recording') "
        "if m in sys.modules))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.strip() == "[]", done.stdout


def _without_compute_time(path):
    """The rows of an estimates CSV without ``compute_ms`` (how long this run took)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [{k: v for k, v in row.items() if k != "compute_ms"} for row in rows]


@pytest.mark.parametrize(
    "argv,message",
    [
        (["replay", "missing.mcap"], "no such file"),
        (["replay", str(REFERENCE / "sim_3s.mcap"), "--rate", "fast"], "--rate 'fast'"),
        (["replay", str(REFERENCE / "sim_3s.mcap"), "-o", "x.txt"], "use a .csv or .mcap"),
        (["replay", str(REFERENCE), "--jobs", "-1"], "--jobs -1: use a number"),
    ],
)
def test_replay_errors_are_one_line(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


@pytest.mark.slow  # a real-time daemon run of seconds
def test_any_part_of_a_rotated_session_replays_the_whole_session_as_live(tmp_path, free_port):
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path), "rotate_size_mb": 0.05, "chunk_size": 8192},
        }
    )
    Daemon(config).run(duration_s=2.0)
    parts = session_parts(next(tmp_path.glob("*.mcap")))
    assert len(parts) >= 2  # rotated
    live = live_windows(read_estimates(parts))
    replayed = by_window(replay_file(parts[-1]).messages)
    assert len(live) > 60 and set(live) <= set(replayed)
    assert_same_estimates(live, replayed)  # windows across the part boundary too, bit for bit


@pytest.mark.slow  # a real-time daemon run of seconds
def test_replay_follows_the_windows_a_live_worker_skipped(tmp_path, free_port, monkeypatch):
    """A worker that falls behind skips windows (some after announcing them ``stale`` while
    their samples had not come) and withholds windows whose samples were too old when it
    ran: the held I/B and the tracker see neither, and a replay must follow both (it once
    estimated the announced-then-skipped windows, one held-I/B step off live)."""
    from rtsid.runtime.worker import WindowEvaluator, WindowWorker

    process_window = WindowWorker.process_window
    stale = WindowEvaluator._stale
    skipped, too_old = [], []

    def fall_behind(self, end_index):  # as if the worker had been late for these windows
        hop = end_index // self.hop_samples
        if 2000 <= end_index <= 3500 and hop % 4 == 0:
            if hop % 8 == 0:
                self.evaluator.publish_stale(end_index)  # announced while waiting, then skipped
            skipped.append(end_index)
            return None
        return process_window(self, end_index)

    def aged(self, arrival_s, end):  # samples too old when the window ran
        if 4000 <= end <= 4500 and (end // 50) % 3 == 0:
            too_old.append(end)
            return True
        return stale(self, arrival_s, end)

    monkeypatch.setattr(WindowWorker, "process_window", fall_behind)
    monkeypatch.setattr(WindowEvaluator, "_stale", aged)
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path)},
            "plant": {"stiffness_profile": {"kind": "sinusoidal", "amplitude": 50.0}},
        }
    )
    Daemon(config).run(duration_s=2.0)
    monkeypatch.undo()
    recording = next(tmp_path.glob("*.mcap"))
    messages = list(iter_estimates(recording))
    announced = {m["window_end_index"] for m in messages if is_announcement(m)}
    live = live_windows(messages)
    assert skipped and announced and not set(skipped) & set(live)
    assert too_old and all(live[end]["reason"] == "stale" for end in too_old)
    followed = by_window(replay_file(recording).messages)
    assert not set(skipped) & set(followed)
    # held I/B and the tracker saw the same windows: every number as live, bit for bit
    assert_same_estimates(live, followed)
    for end, m in live.items():
        assert (followed[end]["K_track"], followed[end]["B_track"]) == (m["K_track"], m["B_track"])
    # ... and so does the command a researcher runs (it passed the recording's own config to
    # replay_file, a re-analysis: it estimated the skipped windows, and every number after)
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(recording), "-o", str(out)]) == 0
    assert_same_estimates(live, by_window(iter_estimates(out)))
    assert not set(skipped) & set(by_window(iter_estimates(out)))
    # a re-analysis with a config given estimates every window
    again = by_window(replay_file(recording, recording_config(recording)).messages)
    assert set(skipped) <= set(again)


def test_replay_refuses_an_inverted_torque_sign_as_live_does(tmp_path, capsys):
    # issue 19: the live check (rtsid.ident.sign) runs in replay's windows too
    config = tmp_path / "inverted.toml"
    config.write_text("[estimator]\ntorque_sign = -1.0\n")
    out = tmp_path / "out.csv"
    argv = ["replay", str(REFERENCE / "sim_3s.mcap"), "--config", str(config), "-o", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the torque sign is inverted" in err[0]
    assert "[estimator] torque_sign = 1 " in err[0]
    assert not out.exists()


def test_the_python_api_pins_blas_to_one_thread_as_the_command_line_does():
    # A multi-threaded BLAS sums in another order: a replay through the Python API gave other
    # numbers than the live run it replays (the slow lane's fits use BLAS).
    import os
    import subprocess
    import sys

    blas = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
    env = {k: v for k, v in os.environ.items() if k not in blas}
    code = f"import os, rtsid.replay; print(*(os.environ[k] for k in {blas!r}))"
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["1", "1", "1"]
    kept = subprocess.run(
        [sys.executable, "-c", code],
        env={**env, "OPENBLAS_NUM_THREADS": "2"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert kept.stdout.split() == ["2", "1", "1"]  # a user's own setting stays


def test_a_directory_goes_to_the_pool_largest_recording_first(tmp_path):
    """A long recording started last would leave the other processes idle while it ends: the
    pool takes them by size (a rotated session's parts summed), the table keeps their names'
    order (tested above)."""
    from rtsid.commands.replay import _longest_first

    sizes = {"a.mcap": 10, "b.mcap": 300, "c.mcap": 40}
    for name, size in sizes.items():
        (tmp_path / name).write_bytes(b"x" * size)
    session = "rtsid-r-j-20261127T010000Z"
    (tmp_path / f"{session}.mcap").write_bytes(b"x" * 200)
    (tmp_path / f"{session}-001.mcap").write_bytes(b"x" * 200)  # 400 bytes in all
    order = _longest_first([tmp_path / n for n in (*sizes, f"{session}.mcap")])
    assert [p.name for p in order] == [f"{session}.mcap", "b.mcap", "c.mcap", "a.mcap"]


def test_a_replay_keeps_each_fit_until_the_last_live_window_that_used_it():
    """A live slow lane that fell behind leaves windows on a fit the schedule replaced long
    ago; the replay's store (which drops fits older than the stale horizon) keeps it until
    the last live window that used it."""
    live = LiveDecisions(
        first_end=99,
        last_end=699,
        reflex={
            99: (None, True, False),
            199: (3, False, True),
            299: (5, False, False),
            399: (4, False, True),
            499: (6, False, False),
            599: (None, False, False),
            699: (None, True, False),
        },
    )
    ends = (0, 199, 200, 300, 400, 500, 700)
    assert [live.oldest_reflex_from(end) for end in ends] == [3, 3, 4, 4, 6, None, None]
    settings = SlowLaneSettings(horizon_s=5.0, update_s=1.0, apply_after_s=0.8, stale_after_s=2.0)
    for keep_from, kept in ((None, False), (3, True)):
        models = ReflexModels(100.0, settings)
        for seq in range(3, 20):
            models.add(ReflexUpdate.failed(seq, 0, seq * 100, "-"), keep_from)
        assert (models.update_of(3) is not None) is kept
        assert models.update_of(19) is not None
        assert (models.update_of(10) is not None) is kept  # older than 19's horizon


@pytest.mark.slow  # a real-time daemon run of seconds
def test_replay_says_when_the_recording_lacks_samples_live_windows_used(
    tmp_path, free_port, monkeypatch
):
    """A housekeeping thread held up past the ring's length (a stop that waited for a slow
    fit did it, at load 15) loses samples the live worker estimated: a replay cannot equal
    live across them, and says so in one line."""
    from rtsid.errors import RtsidWarning

    forward = Daemon._forward_samples
    capacity = 2500  # ring_capacity_s = 1 s at 2500 Hz

    def stalled(self, ring, mcap, zenoh):  # by sample index: from 1 s for 1.5 ring lengths
        if not 2500 <= ring.newest_index < 2500 + 3 * capacity // 2:
            forward(self, ring, mcap, zenoh)

    monkeypatch.setattr(Daemon, "_forward_samples", stalled)
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path)},
            "link": {"ring_capacity_s": capacity / 2500},
            "slow_lane": {"enabled": False},  # its horizon needs a longer ring
        }
    )
    Daemon(config).run(duration_s=3.0)
    monkeypatch.undo()
    recording = next(tmp_path.glob("*.mcap"))
    with pytest.warns(
        RtsidWarning, match=r"logger lost [1-9]\d* samples, 0 sample batches and 0 estimates"
    ):
        replayed = by_window(replay_file(recording).messages)
    live = live_windows(iter_estimates(recording))
    assert any(m["ok"] and replayed[end]["reason"] == "gap" for end, m in live.items())
    # a replay of a complete recording says nothing (warnings are errors here)
    again = tmp_path / "again"
    again.mkdir()
    config = DaemonConfig.from_mapping(
        {"zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]}, "mcap": {"directory": str(again)}}
    )
    Daemon(config).run(duration_s=1.0)
    assert replay_file(next(again.glob("*.mcap"))).messages


def test_a_replay_process_starts_without_importing_scipy():
    # A spawned child (rtsid replay DIR --jobs N, the slow lane's process) paid ≈ 1 s of CPU
    # importing scipy.signal (which imports scipy.stats) before its first window, although
    # the window path never calls scipy: scipy is imported where it is used.
    import subprocess
    import sys

    code = (
        "import sys, rtsid.commands.replay, rtsid.replay, rtsid.runtime.worker, "
        "rtsid.runtime.slow_lane, rtsid.ident.stream; "
        "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.strip() == "[]", done.stdout
    # ... while a live daemon imports scipy.signal before its threads start, so that its first
    # window's plan does not pay the import inside the deadline
    live = (
        "import sys; from rtsid.runtime.daemon import Daemon, DaemonConfig; "
        "before = 'scipy.signal' in sys.modules; Daemon(DaemonConfig()); "
        "print(before, 'scipy.signal' in sys.modules)"
    )
    done = subprocess.run(
        [sys.executable, "-c", live], capture_output=True, text=True, timeout=120, check=True
    )
    assert done.stdout.split() == ["False", "True"], done.stdout


def test_the_windows_replay_cuts_are_the_snapshots_their_constructor_gives():
    # replay builds each hop's Snapshot without its frozen __init__ (rtsid.ident.records)
    import dataclasses

    from rtsid.io.schemas import SampleBatch
    from rtsid.link.ring import Snapshot
    from rtsid.replay import iter_windows, recorded_evaluator

    config = DaemonConfig.from_mapping({"slow_lane": {"enabled": False}})
    evaluator = recorded_evaluator(config, lambda message: None)
    fs, n, first = config.link.fs_hz, 2500, 100
    rng = np.random.default_rng(1)
    position, torque = rng.normal(size=n), rng.normal(size=n)
    batch = SampleBatch(first, fs, position, torque, np.ones(n, bool), np.zeros(n, np.int64))
    snaps = list(iter_windows([batch], evaluator))
    hop, window = evaluator.hop_samples, evaluator.window_samples
    ends = [e for e in range(first, first + n) if (e + 1) % hop == 0 and e - window + 1 >= first]
    assert [int(snap.sample_index[-1]) for snap in snaps] == ends  # the live worker's grid
    for snap in snaps:
        values = {f.name: getattr(snap, f.name) for f in dataclasses.fields(Snapshot)}
        assert set(vars(snap)) == set(values)  # every field set, nothing else
        again = Snapshot(**values)
        assert all(getattr(again, name) is value for name, value in values.items())
        with pytest.raises(dataclasses.FrozenInstanceError):
            snap.overwritten = 1  # type: ignore[misc]
        start = int(snap.sample_index[0])
        np.testing.assert_array_equal(snap.sample_index, np.arange(start, start + len(snap)))
        rows = slice(start - first, start - first + len(snap))
        np.testing.assert_array_equal(snap.position_rad, position[rows])
        np.testing.assert_array_equal(snap.torque_nm, torque[rows])
        assert len(snap) == window and snap.overwritten == 0
        newest = snap.tail(hop)  # the evaluator's cut (built the same way)
        values = {f.name: getattr(newest, f.name) for f in dataclasses.fields(Snapshot)}
        assert set(vars(newest)) == set(values)
        assert all(getattr(Snapshot(**values), k) is v for k, v in values.items())
        np.testing.assert_array_equal(newest.sample_index, snap.sample_index[-hop:])


def test_a_replays_mcap_carries_the_summary_table_its_messages_give(tmp_path):
    # write_estimates_mcap feeds the summary table the estimate dicts it encoded plainly
    # (not their payloads decoded again): the table must be the one the messages give
    import io
    import math

    from rtsid.io.recording import read_table

    result = replay_file(REFERENCE / "sim_3s.mcap")
    messages = [dict(m) for m in result.messages]
    messages[5]["K"] = math.nan  # a payload the reference encodes (null), decoded for the table
    messages[6]["lost_samples"] = np.int64(2)
    out = tmp_path / "out.mcap"
    buffer = io.BytesIO()
    config = recording_config(REFERENCE / "sim_3s.mcap")
    count = write_estimates_mcap(messages, buffer, source="x", config=config, reflex=result.reflex)
    out.write_bytes(buffer.getvalue())
    attached, decoded = read_table(out), read_table(out, from_messages=True)
    assert attached.from_attachments and not decoded.from_attachments
    assert attached.table.counts == decoded.table.counts and count == len(messages)
    assert set(attached.table.columns) == set(decoded.table.columns)
    for name, column in attached.table.columns.items():
        np.testing.assert_array_equal(column, decoded.table.columns[name], err_msg=name)
    assert math.isnan(attached.table.columns["K"][5])
    assert [m["K"] for m in iter_estimates(out)][4:6] == [messages[4]["K"], None]


def test_a_replay_reads_what_live_decided_and_the_session_in_one_pass_per_part(
    tmp_path, monkeypatch
):
    # the live decisions, the logger's losses and the session come from one pass over each
    # part (rtsid.io.mcap_read.read_json_topics), the same as the readers of each give them
    from rtsid.io import mcap_read
    from rtsid.io.recording import read_session
    from rtsid.replay import _RecordedRun

    recording = REFERENCE / "sim_3s.mcap"
    passes = []
    real = mcap_read.read_json_topics
    monkeypatch.setattr(
        mcap_read, "read_json_topics", lambda *a, **k: passes.append(a[0]) or real(*a, **k)
    )
    monkeypatch.setattr("rtsid.io.recording.read_json_topics", mcap_read.read_json_topics)
    run = _RecordedRun.read([recording], follow_live=True)
    assert passes == [recording]
    assert run.live == LiveDecisions.of([recording]) and run.live is not None
    assert run.session == read_session(recording) and run.lost == (0, 0, 0)
    again = _RecordedRun.read([recording], follow_live=False)
    assert again.live is None and again.session == run.session
