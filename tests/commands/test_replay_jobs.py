"""``rtsid replay DIR --jobs N --timing JSON``: when each process was ready and replayed what."""

from __future__ import annotations

import itertools
import json
import os
import shutil
import time
from pathlib import Path

from rtsid.cli import main

REFERENCE = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"


def _folder(tmp_path: Path, names: tuple[str, ...]) -> Path:
    folder = tmp_path / "recs"
    folder.mkdir()
    for name in names:
        shutil.copy(REFERENCE, folder / name)
    return folder


def _check_timeline(document: dict, names: list[str]) -> list[dict]:
    """Every recording replayed once, by one process, after that process was ready, one at
    a time, before the end; each idle time is the wait from its last recording to the end."""
    processes = document["processes"]
    finished = document["finished_s"]
    replayed = sorted(r["recording"] for p in processes for r in p["recordings"])
    assert replayed == sorted(names)
    for p in processes:
        spans = [(r["started_s"], r["ended_s"]) for r in p["recordings"]]
        last = spans[-1][1] if spans else p["ready_s"]
        assert all(start < end for start, end in spans)
        assert all(a[1] <= b[0] for a, b in itertools.pairwise(spans))
        if spans:
            assert p["ready_s"] <= spans[0][0] and last <= finished
        assert p["idle_at_end_s"] == max(0.0, finished - last)
        # its CPU time by the end of its last recording, start-up included
        assert p["cpu_s"] > 0 if spans else p["cpu_s"] == 0
        # and when it was ready (the interpreter's start and the imports): no more than
        # by the end of its last recording
        assert 0 < p["ready_cpu_s"] <= (p["cpu_s"] if spans else p["ready_cpu_s"])
    return processes


def test_two_jobs_time_their_processes_the_command_first(tmp_path, capsys, monkeypatch):
    import rtsid.commands.replay as command

    folder = _folder(tmp_path, ("a.mcap", "b.mcap", "c.mcap"))
    out, timing = tmp_path / "out", tmp_path / "timing.json"
    replay_one = command._replay_one

    def after_the_child_replayed_one(path, args, out_path):
        # this process's (a child's is not patched): a 3 s recording replays faster than
        # a child starts, so this one waits until the child has written b.csv
        deadline = time.monotonic() + 120.0
        while path.name == "a.mcap" and not (out / "b.csv").exists():
            assert time.monotonic() < deadline, "the child replayed nothing"
            time.sleep(0.05)
        return replay_one(path, args, out_path)

    monkeypatch.setattr(command, "_replay_one", after_the_child_replayed_one)
    argv = ["replay", str(folder), "--jobs", "2", "--timing", str(timing), "-o", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    processes = _check_timeline(json.loads(timing.read_text()), ["a.mcap", "b.mcap", "c.mcap"])
    assert [p["role"] for p in processes] == ["command", "child"]
    assert processes[0]["pid"] == os.getpid() != processes[1]["pid"]
    # the command's process replays the first recording in the folder's order (the largest;
    # equal sizes keep the name order) while the child starts
    assert processes[0]["recordings"][0]["recording"] == "a.mcap"


def test_one_job_and_one_file_time_this_process_alone(tmp_path, capsys):
    folder = _folder(tmp_path, ("a.mcap", "b.mcap"))
    timing = tmp_path / "one.json"
    assert main(["replay", str(folder), "--jobs", "1", "--timing", str(timing)]) == 0
    (process,) = _check_timeline(json.loads(timing.read_text()), ["a.mcap", "b.mcap"])
    assert process["role"] == "command" and [r["recording"] for r in process["recordings"]] == [
        "a.mcap",
        "b.mcap",
    ]
    assert main(["replay", str(folder / "b.mcap"), "--timing", str(timing)]) == 0
    (process,) = _check_timeline(json.loads(timing.read_text()), ["b.mcap"])
    assert process["idle_at_end_s"] >= 0
    capsys.readouterr()


def test_a_timing_file_in_a_missing_folder_is_one_error(tmp_path, capsys):
    missing = tmp_path / "no" / "timing.json"
    assert main(["replay", str(REFERENCE), "--timing", str(missing)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("rtsid replay: error: ") and "no" in err[0]
    assert not missing.parent.exists()


def test_a_child_that_replayed_nothing_is_in_the_timing_too(tmp_path, capsys):
    # 3 s recordings replay faster than a child starts: the command may replay both before
    # its child is ready; the child is listed either way (ready, idle, no recordings)
    folder = _folder(tmp_path, ("a.mcap", "b.mcap"))
    timing = tmp_path / "timing.json"
    assert main(["replay", str(folder), "--jobs", "2", "--timing", str(timing)]) == 0
    capsys.readouterr()
    processes = _check_timeline(json.loads(timing.read_text()), ["a.mcap", "b.mcap"])
    assert [p["role"] for p in processes] == ["command", "child"]


def _probe_then_init_child(path: str) -> None:
    """A teardown probe registered before the replay child's initializer: the interpreter's
    exit runs it after the initializer's own exit step (exit handlers run last first)."""
    import atexit

    from rtsid.commands.replay import _init_child

    atexit.register(Path(path).write_text, "torn down")
    _init_child()


def _leave_unflushed_output() -> int:
    import sys

    sys.stdout.write("unflushed line from the child")  # no newline: still in the buffer
    return os.getpid()


def test_a_replay_child_exits_without_teardown_and_its_output_flushed(tmp_path, capfd):
    # the command waits for its children's exit: the interpreter's teardown of a child (its
    # modules and arrays) was on that path; its buffered output must still come out
    import concurrent.futures as cf
    import multiprocessing as mp

    probe = tmp_path / "teardown.txt"
    ctx = mp.get_context("spawn")
    init = _probe_then_init_child
    with cf.ProcessPoolExecutor(1, ctx, initializer=init, initargs=(str(probe),)) as pool:
        pid = pool.submit(_leave_unflushed_output).result(60)
        (process,) = pool._processes.values()
    assert pid != os.getpid() and process.exitcode == 0
    assert "unflushed line from the child" in capfd.readouterr().out
    assert not probe.exists()


def test_the_command_ends_without_teardown_its_outputs_whole_and_its_status_kept(tmp_path, capsys):
    # `python -m rtsid.cli replay DIR` skips the interpreter's teardown (rtsid.cli.console):
    # the table printed, every estimates file written whole, 0 when all replayed, 2 when one
    # recording failed (the others written)
    import subprocess
    import sys

    from tests.test_replay import _without_compute_time

    folder = _folder(tmp_path, ("a.mcap", "c.mcap"))
    assert main(["replay", str(folder), "-o", str(tmp_path / "here"), "--jobs", "1"]) == 0
    capsys.readouterr()

    def replay(out: str) -> subprocess.CompletedProcess[str]:
        command = [sys.executable, "-m", "rtsid.cli", "replay", str(folder), "--jobs", "2"]
        return subprocess.run(
            [*command, "-o", str(tmp_path / out)], capture_output=True, text=True, timeout=120
        )

    done = replay("whole")
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if line.startswith("| ")]
    assert [r.split("|")[1].strip() for r in rows[1:]] == ["a.mcap", "c.mcap"]
    (folder / "b.mcap").write_bytes(b"not a recording")
    failed = replay("failed")
    assert failed.returncode == 2 and "rtsid replay: error:" in failed.stderr
    for out in ("whole", "failed"):
        assert sorted(p.name for p in (tmp_path / out).iterdir()) == ["a.csv", "c.csv"]
        for name in ("a.csv", "c.csv"):
            here = _without_compute_time(tmp_path / "here" / name)
            assert len(here) > 100 and _without_compute_time(tmp_path / out / name) == here
