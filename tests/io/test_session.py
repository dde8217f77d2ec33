"""Sessions and markers in files: the [session] section, recording names from its pattern,
and what the MCAP logger writes (rtsid.session metadata, /session, /marker) read back with
the one recording reader."""

from __future__ import annotations

import json
import threading
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from rtsid.errors import ConfigError
from rtsid.io.mcap_log import McapConfig, McapLogger, recording_name
from rtsid.io.mcap_read import read_metadata, recording_parts
from rtsid.io.messages import MarkerMessage, SessionMessage
from rtsid.io.recording import read_recording, read_session
from rtsid.io.schemas import encode_json
from rtsid.io.session import PATTERN_FIELDS, SessionConfig
from rtsid.io.validate import MalformedMessage, decode_message
from rtsid.runtime.daemon import DaemonConfig

START = datetime(2026, 11, 26, 18, 48, 39, tzinfo=UTC)


# ---------------------------------------------------------------------- config
@pytest.mark.parametrize(
    ("pattern", "match"),
    [
        ("{subject}_{trial}_{start}", r"\{trial\}; accepted fields: \{subject\}, \{session\}"),
        ("{subject}_{start:%Y}", r"accepted fields"),
        ("{subject}/{start}", r"no path separators"),
        ("{subject} {start}", r"no path separators or spaces"),
        ("{subject}_{session}", r"holding \{start\}"),
        ("{subject_{start}", r"fields in braces"),
    ],
)
def test_a_bad_recording_pattern_is_one_config_error(pattern, match):
    with pytest.raises(ConfigError, match=match) as err:
        DaemonConfig.from_mapping({"session": {"recording_pattern": pattern}})
    assert "session.recording_pattern" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("name", ["a/b", "a\\b", "tab\there", "esc\x1b[31m", "x" * 65, "new\nline"])
@pytest.mark.parametrize("key", ["subject", "session", "condition"])
def test_bad_session_names_are_refused_with_the_key(key, name):
    with pytest.raises(ConfigError, match=rf"'session\.{key}'.*at most 64 characters"):
        DaemonConfig.from_mapping({"session": {key: name}})
    with pytest.raises(ConfigError, match=rf"^--{key} .*not accepted"):
        SessionConfig().with_overrides(**{key: name})


def test_session_section_loads_and_flags_override_it():
    config = DaemonConfig.from_mapping(
        {"session": {"subject": "S01", "session": "2", "condition": "baseline"}}
    )
    assert config.session == SessionConfig("S01", "2", "baseline")
    assert config.as_dict()["session"]["recording_pattern"] == SessionConfig.recording_pattern
    moved = config.session.with_overrides(condition="fatigue", subject=None)
    assert moved == SessionConfig("S01", "2", "fatigue")
    with pytest.raises(ConfigError, match=r"unknown config key session\.subjet"):
        DaemonConfig.from_mapping({"session": {"subjet": "S01"}})
    with pytest.raises(ConfigError, match=r"session\.subject.*type str"):
        DaemonConfig.from_mapping({"session": {"subject": 1}})


# ---------------------------------------------------------------------- names
def test_recording_name_follows_the_pattern_with_a_subject():
    session = SessionConfig("S01", "2", "baseline")
    assert recording_name("rig", "ankle", START, 0, session) == (
        "S01_2_rig-ankle_20261126T184839Z.mcap"
    )
    assert recording_name("rig", "ankle", START, 3, session) == (
        "S01_2_rig-ankle_20261126T184839Z-003.mcap"
    )
    every = SessionConfig(
        "Jo Ann", "2 b", "walk:fast", "_".join("{" + f + "}" for f in PATTERN_FIELDS)
    )
    assert recording_name("rig", "ankle", START, 0, every) == (
        "Jo_Ann_2_b_walk_fast_rig_ankle_20261126T184839Z.mcap"
    )


def test_recording_name_without_a_subject_is_the_old_one():
    for session in (None, SessionConfig(session="2", condition="baseline")):
        assert recording_name("rig-1", "ankle", START, 0, session) == (
            "rtsid-rig_1-ankle-20261126T184839Z.mcap"
        )
        assert recording_name("rig", "ankle", START, 1, session).endswith("Z-001.mcap")


def test_parts_of_a_patterned_recording_are_found_together(tmp_path):
    session = SessionConfig("S01", "2")
    names = [recording_name("rig", "ankle", START, k, session) for k in (0, 1, 2)]
    other = recording_name("rig", "ankle", START.replace(minute=49), 0, session)
    for name in [*names, other, names[0].replace(".mcap", "-recovered.mcap")]:
        (tmp_path / name).write_bytes(b"")
    assert recording_parts(tmp_path / names[1]) == [tmp_path / n for n in names]
    assert recording_parts(tmp_path / other) == [tmp_path / other]


# ---------------------------------------------------------------------- logger and reader
def session_message(index: int, condition: str) -> dict:
    return SessionMessage(
        robot="rig",
        joint="ankle",
        t_s=index / 2500.0,
        sample_index=index,
        subject="S01",
        session="2",
        condition=condition,
        host_time_ns=1_000 + index,
    ).as_dict()


def marker_message(index: int, label: str, marker_id: str, source: str = "zenoh") -> dict:
    return MarkerMessage(
        robot="rig",
        joint="ankle",
        t_s=index / 2500.0,
        sample_index=index,
        label=label,
        source=source,
        marker_id=marker_id,
        host_time_ns=2_000 + index,
    ).as_dict()


def record(directory: Path, steps, **config) -> list[Path]:
    """Run a logger through ``steps`` (callables of the logger) and return its files."""
    cfg = McapConfig(directory=str(directory), flush_interval_s=0.05, **config)
    logger = McapLogger(
        cfg,
        robot="rig",
        joint="ankle",
        fs_hz=2500.0,
        session=SessionConfig("S01", "2", "baseline"),
        session_message=session_message(0, "baseline"),
    )
    with logger:
        for step in steps:
            step(logger)
    return logger.files


def test_logger_writes_session_metadata_session_and_markers(tmp_path):
    outcomes: list[bool] = []
    samples = np.zeros(250)

    def steps():
        yield lambda m: m.log_samples(0, samples, samples)
        yield lambda m: m.log_marker(
            marker_message(100, "trial 1 <b>start</b>", "id-1"), on_written=outcomes.append
        )
        yield lambda m: m.log_session(session_message(200, "fatigue"))
        yield lambda m: m.log_marker(marker_message(300, "trial 1 end", "id-2", "wire"))

    (path,) = record(tmp_path, steps())
    assert path.name.startswith("S01_2_rig-ankle_") and path.name.endswith("Z.mcap")
    assert outcomes == [True]  # called once the marker was written and flushed
    meta = read_metadata(path)["rtsid.session"]
    assert set(meta) == {
        "subject",
        "session",
        "condition",
        "robot",
        "joint",
        "started_utc",
        "rtsid_version",
    }
    assert (meta["subject"], meta["session"], meta["condition"]) == ("S01", "2", "baseline")
    assert datetime.fromisoformat(meta["started_utc"]).tzinfo is not None
    got = read_session(path)
    assert got.subject == "S01" and got.session == "2"
    assert [(s["sample_index"], s["condition"]) for s in got.sessions] == [
        (0, "baseline"),
        (200, "fatigue"),
    ]
    assert [(m["sample_index"], m["label"], m["source"]) for m in got.markers] == [
        (100, "trial 1 <b>start</b>", "zenoh"),
        (300, "trial 1 end", "wire"),
    ]
    assert got.condition_at(199) == "baseline" and got.condition_at(200) == "fatigue"
    assert len(read_recording(path).samples) == 250  # samples read as before


def test_every_part_starts_with_its_session_and_markers_are_read_once(tmp_path):
    ready = threading.Event()

    def rotate(logger: McapLogger) -> None:
        logger.log_session(session_message(500, "fatigue"))
        logger.log_marker(
            marker_message(600, "trial 2", "same-id"), on_written=lambda _: ready.set()
        )
        assert ready.wait(5.0)
        _wait_for_parts(logger, len(logger.files) + 1)  # a part that starts after the change

    parts = record(
        tmp_path,
        [
            lambda m: m.log_marker(marker_message(10, "trial 1", "id-a")),
            rotate,
            lambda m: m.log_marker(marker_message(600, "trial 2 (resent)", "same-id")),
        ],
        rotate_interval_s=0.2,
    )
    assert len(parts) >= 2
    metas = [read_metadata(p)["rtsid.session"] for p in parts]
    assert metas[0]["condition"] == "baseline" and metas[-1]["condition"] == "fatigue"
    got = read_session(parts[-1])  # any part: the whole session is read
    assert got.parts == parts and len(got.metadata) == len(parts)
    assert [(s["sample_index"], s["condition"]) for s in got.sessions] == [
        (0, "baseline"),
        (500, "fatigue"),
    ]
    assert [(m["marker_id"], m["label"]) for m in got.markers] == [
        ("id-a", "trial 1"),
        ("same-id", "trial 2"),  # the resent one (same id) is dropped
    ]


def _wait_for_parts(logger: McapLogger, n: int) -> None:
    for _ in range(200):
        if len(logger.files) >= n:
            return
        threading.Event().wait(0.02)
    raise AssertionError(f"the logger never rotated to {n} parts")


def test_a_marker_without_a_file_is_reported_not_written(tmp_path):
    outcomes: list[bool] = []

    def refuse(path: Path):
        raise PermissionError(13, "Permission denied", str(path))

    logger = McapLogger(
        McapConfig(directory=str(tmp_path), retry_interval_s=60.0),
        robot="rig",
        joint="ankle",
        fs_hz=2500.0,
        open_file=refuse,
    )
    done = threading.Event()
    with logger:
        assert logger.log_marker(
            marker_message(1, "x", "id"), on_written=lambda ok: (outcomes.append(ok), done.set())
        )
        assert done.wait(5.0)
    assert outcomes == [False]


# ---------------------------------------------------------------------- hostile labels
def test_hostile_labels_are_refused_by_the_views_checks():
    key = "rtsid/rig/ankle/marker"
    html = marker_message(1, '<img src=x onerror="alert(1)">', "id")
    assert decode_message("marker", encode_json(html), key)["label"] == html["label"]  # text
    for label, why in (("x" * 10_000, "characters"), ("a\x1b[2Jb", "control characters")):
        with pytest.raises(MalformedMessage, match=why):
            decode_message("marker", encode_json(marker_message(1, label, "id")), key)
    bad_source = {**marker_message(1, "x", "id"), "source": "mallory"}
    with pytest.raises(MalformedMessage, match="source"):
        decode_message("marker", json.dumps(bad_source).encode(), key)
    long_condition = {**session_message(1, "x"), "condition": "c" * 65}
    with pytest.raises(MalformedMessage, match="condition"):
        decode_message("session", json.dumps(long_condition).encode(), "rtsid/rig/ankle/session")


def test_watch_shows_labels_as_text_and_refuses_escapes():
    from rtsid.io.watch import WatchState, render_view

    state = WatchState()
    key = "rtsid/rig/ankle/marker"
    html = marker_message(5, "<b>trial</b> 1", "a")
    assert state.update(key, encode_json(html), 0) == html
    assert state.update(key, encode_json(html), 0) is None  # the same marker once
    assert state.update(key, encode_json(marker_message(6, "x\x1b[2J", "b")), 0) is None
    assert state.rejected == 1
    state.update("rtsid/rig/ankle/session", encode_json(session_message(0, "baseline")), 0)
    status = {"robot": "rig", "joint": "ankle", "host_time_ns": 1, "uptime_s": 1.0}
    counters = {"markers": 2, "refused": 1, "duplicates": 0, "condition_changes": 1}
    state.update("rtsid/rig/ankle/status", encode_json({**status, "session": counters}), 0)
    view = render_view(state, title="t", now_s=0.0)
    assert "markers 2 (refused 1, duplicates 0)  condition changes 1" in view
    assert "rig/ankle subject S01  session 2  condition baseline (from t=0.000s)" in view
    assert "rig/ankle marker '<b>trial</b> 1' at t=0.002s (sample 5, zenoh)" in view


def test_the_web_board_relays_session_and_markers_as_data_and_refuses_hostile_ones():
    import time as _time

    from rtsid.io.watch import FeedEvent
    from rtsid.io.web.server import LabBoard

    def event(kind: str, message: dict) -> FeedEvent:
        payload = json.dumps(message).encode()
        return FeedEvent(kind, f"rtsid/rig/ankle/{kind}", payload, _time.time_ns())

    board = LabBoard()
    board.take(event("session", session_message(0, "baseline")))
    board.take(event("marker", marker_message(5, "<script>alert(1)</script>", "a")))
    board.take(event("marker", marker_message(6, "x" * 10_000, "b")))
    board.take(event("marker", marker_message(7, "bell\x07", "c")))
    _, snap = board.snapshot()
    channels = snap["joints"]["rig/ankle"]["channels"]
    assert channels["session"]["condition"] == "baseline"
    assert channels["marker"]["label"] == "<script>alert(1)</script>"  # data, for textContent
    assert snap["rejected"] == 2
    script = (Path(__file__).resolve().parents[2] / "rtsid/io/web/static/app.js").read_text()
    assert "innerHTML" not in script and "insertAdjacentHTML" not in script
