"""``rtsid summary``: per-trial rows from the recordings' own estimates.

The recordings are written here with the project's MCAP layout (``register_channels``) plus
the session contract's metadata record ``rtsid.session`` and channels ``/session`` and
``/marker``, with estimates whose numbers the tests choose, so every figure checked is known.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rtsid.cli import main
from rtsid.io.mcap_log import register_channels
from rtsid.io.schemas import ESTIMATE_FIELDS, encode_estimate, encode_json, encode_status
from rtsid.summary import (
    BETWEEN,
    COLUMNS,
    NO_SESSION_NOTE,
    WHOLE,
    Marker,
    find_recordings,
    read_study_recording,
    summarise,
    trials_from_markers,
)

HOP_S = 0.1
T0_NS = 1_800_000_000_000_000_000  # host time of sample time 0


def window(t_end_s: float, K: float, **extra: Any) -> dict[str, Any]:
    """An estimate message (every field) for the window ending at ``t_end_s``."""
    message = dict.fromkeys(ESTIMATE_FIELDS)
    ok = extra.pop("ok", True)
    message.update(
        robot="rig",
        joint="ankle",
        t_end_s=t_end_s,
        t_start_s=t_end_s - 0.3,
        window_start_index=round((t_end_s - 0.3) * 1000),
        window_end_index=round(t_end_s * 1000),
        seq=round(t_end_s / HOP_S),
        ok=ok,
        reason=None if ok else extra.pop("reason", "gap"),
        flags=[],
        K_track=K + 1.0 if ok else None,
        K=K if ok else None,
        B=0.8 if ok else None,
        B_held=True if ok else None,
        I=0.015 if ok else None,
        I_held=False if ok else None,
        vaf=90.0 if ok else None,
        host_time_ns=T0_NS + round(t_end_s * 1e9) + 2_000_000,
    )
    message.update(extra)
    return message


def windows(t0: float, t1: float, K: Callable[[float], float], **extra: Any) -> list[dict]:
    """Windows ending at t0 + HOP_S, …, up to t1 (inclusive), K as a function of t_end_s."""
    ends = np.round(np.arange(t0 + HOP_S, t1 + 1e-9, HOP_S), 6)
    return [window(float(t), K(float(t)), **extra) for t in ends]


def write_recording(
    path: Path,
    estimates: Sequence[dict[str, Any]],
    *,
    session: dict[str, str] | None = None,
    changes: Sequence[tuple[float, str]] = (),
    markers: Sequence[tuple[float, str] | tuple[float, str, str]] = (),
    status: Sequence[tuple[float, int]] = (),
    reflex: Sequence[dict[str, Any]] = (),
    finish: bool = True,
    attachment: bytes | None = None,
) -> Path:
    """An rtsid recording: the daemon's channels (estimates, status, reflex) and, given
    ``session`` (subject, session, condition), the contract's metadata, ``/session`` at the
    start and at each ``changes`` (t_s, condition), and ``/marker`` (t_s, label)."""
    from mcap.writer import CompressionType, Writer

    fh = path.open("wb")
    writer = Writer(fh, chunk_size=2048, compression=CompressionType.ZSTD)
    writer.start(profile="", library="rtsid test")
    channels = register_channels(writer)
    writer.add_metadata("rtsid", {"software": "rtsid", "robot": "rig", "joint": "ankle"})
    extra: dict[str, int] = {}
    for topic in ("/session", "/marker"):
        extra[topic] = writer.register_channel(topic=topic, message_encoding="json", schema_id=0)

    def put(channel: int, t_s: float, data: bytes) -> None:
        t = T0_NS + round(t_s * 1e9)
        writer.add_message(channel_id=channel, log_time=t, data=data, publish_time=t)

    if session is not None:
        writer.add_metadata(
            "rtsid.session",
            {**session, "robot": "rig", "joint": "ankle", "started_utc": "2026-11-26T10:00:00Z"},
        )
        for t_s, condition in [(0.0, session["condition"]), *changes]:
            body = {**session, "condition": condition, "robot": "rig", "joint": "ankle"}
            body.update(t_s=t_s, sample_index=round(t_s * 1000), host_time_ns=T0_NS)
            put(extra["/session"], t_s, encode_json(body))
    for k, (t_s, label, *marker_id) in enumerate(markers):
        body = {"robot": "rig", "joint": "ankle", "t_s": t_s, "sample_index": round(t_s * 1000)}
        body.update(label=label, source="zenoh", host_time_ns=T0_NS)
        body["marker_id"] = marker_id[0] if marker_id else f"{path.name}-{k}"
        put(extra["/marker"], t_s, encode_json(body))
    for fit in reflex:
        put(channels["reflex"], fit["applies_from_index"] / 1000, encode_json(fit))
    for t_s, lost in status:
        body = {"robot": "rig", "joint": "ankle", "uptime_s": t_s}
        body.update(host_time_ns=T0_NS + round(t_s * 1e9), acquisition={"lost_samples": lost})
        put(channels["status"], t_s, encode_status(body))
    for message in estimates:
        put(channels["estimate"], message["t_end_s"], encode_estimate(message))
    written = fh.tell()  # the chunks closed so far
    if attachment is not None:  # a summary table (rtsid.io.summary_table)
        writer.add_attachment(T0_NS, T0_NS, "rtsid.summary.npz", "application/x-npz", attachment)
    writer.finish()
    fh.close()
    if not finish:  # cut inside the last closed chunk, as a kill -9 or a torn copy leaves it
        path.write_bytes(path.read_bytes()[: written // 2])
    return path


def rows_of(*paths: Path, by: str = "trial", between: bool = False) -> list[dict[str, Any]]:
    recordings = [read_study_recording(parts) for parts in find_recordings(paths)]
    return summarise(recordings, by, include_between=between)


def cli_table(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> tuple[int, list[dict], list[str]]:
    """Exit status, the CSV rows on stdout, the lines on stderr."""
    code = main(["summary", *argv])
    out, err = capsys.readouterr()
    return code, list(csv.DictReader(io.StringIO(out))), err.strip().splitlines()


SUBJECT = {"subject": "S01", "session": "visit1", "condition": "relaxed"}


# ---------------------------------------------------------------------------- trial rules
def names(trials: Sequence[Any]) -> list[tuple[str, float, float]]:
    return [(t.name, t.t_start_s, t.t_end_s) for t in trials]


def test_start_and_end_markers_make_trials_and_other_labels_run_to_the_next_marker():
    markers = [
        Marker(1.0, "walk start"),
        Marker(3.0, "walk end"),
        Marker(4.0, "Hop BEGIN"),
        Marker(5.0, "hop stop"),
        Marker(6.0, "rest"),
        Marker(7.0, "squat"),
    ]
    trials = trials_from_markers(markers[::-1], end_s=9.0)  # any order in, time order out
    assert names(trials) == [
        ("walk", 1.0, 3.0),
        ("Hop", 4.0, 5.0),
        ("rest", 6.0, 7.0),
        ("squat", 7.0, 9.0),
    ]
    assert all(t.notes == () for t in trials)


def test_unmatched_start_and_end_markers_are_noted_not_dropped():
    trials = trials_from_markers(
        [Marker(0.5, "ghost end"), Marker(1.0, "a start"), Marker(2.0, "b start")], end_s=4.0
    )
    assert names(trials) == [("a", 1.0, 2.0), ("b", 2.0, 4.0)]
    assert any("'ghost end' at 0.50 s closes no open trial" in n for n in trials[0].notes)
    assert any("no 'a end' marker: ended by 'b start'" in n for n in trials[0].notes)
    assert any("runs to the end of the recording" in n for n in trials[1].notes)
    (only_ends,) = trials_from_markers([Marker(1.0, "a end")], end_s=3.0)
    assert only_ends.name == WHOLE and "closes no open trial" in only_ends.notes[0]
    mismatched = trials_from_markers([Marker(1.0, "a start"), Marker(2.0, "b end")], end_s=3.0)
    assert names(mismatched) == [("a", 1.0, 2.0)]
    assert "another name" in mismatched[0].notes[0]


# ---------------------------------------------------------------------------- rows
def test_windows_go_to_the_trial_in_force_at_their_end_and_repeats_are_numbered(tmp_path):
    # K 100 in the first walk, 200 in the second, 300 between trials
    def k_of(t: float) -> float:
        return 100.0 + t if 1.0 <= t < 3.0 else 200.0 + t if 5.0 <= t < 7.0 else 300.0

    rec = write_recording(
        tmp_path / "rec.mcap",
        windows(0.0, 8.0, k_of),
        session=SUBJECT,
        markers=[
            (1.0, "walk start"),
            (3.0, "walk end", "e1"),
            (3.0, "walk end", "e1"),  # resent after a restart: recorded twice, counted once
            (5.0, "walk start"),
            (7.0, "walk end"),
        ],
    )
    rows = rows_of(rec)
    assert [(r["trial"], r["repeat"]) for r in rows] == [("walk", 1), ("walk", 2)]
    first, second = rows
    assert first["windows"] == 20  # t_end 1.0 … 2.9
    assert first["K_median"] == pytest.approx(101.95)
    assert first["K_track_median"] == pytest.approx(102.95)
    assert first["K_q25"] == pytest.approx(np.percentile(100 + np.arange(1.0, 2.95, 0.1), 25))
    assert (first["t_start_s"], first["t_end_s"], first["duration_s"]) == (1.0, 3.0, 2.0)
    assert second["K_median"] == pytest.approx(205.95)
    assert (first["subject"], first["session"], first["condition"]) == ("S01", "visit1", "relaxed")
    between = [r for r in rows_of(rec, between=True) if r["trial"] == BETWEEN]
    assert [r["windows"] for r in between] == [9, 20, 11]  # before, between, after
    assert all(r["K_median"] == 300.0 for r in between)


def test_a_condition_change_mid_trial_splits_the_trial_into_a_row_per_condition(tmp_path):
    rec = write_recording(
        tmp_path / "rec.mcap",
        windows(0.0, 4.0, lambda t: 100.0 if t < 2.5 else 180.0),
        session=SUBJECT,
        changes=[(2.5, "co-contract")],
        markers=[(1.0, "hold start"), (4.0, "hold end")],
    )
    rows = rows_of(rec)
    assert [(r["trial"], r["repeat"], r["condition"]) for r in rows] == [
        ("hold", 1, "relaxed"),
        ("hold", 1, "co-contract"),
    ]
    assert [r["windows"] for r in rows] == [15, 15]
    assert [r["K_median"] for r in rows] == [100.0, 180.0]
    assert [(r["t_start_s"], r["t_end_s"]) for r in rows] == [(1.0, 2.5), (2.5, 4.0)]
    assert all("condition changed during the trial" in r["notes"] for r in rows)
    by_condition = rows_of(rec, by="condition")
    assert [(r["condition"], r["windows"], r["trials"]) for r in by_condition] == [
        ("relaxed", 15, 1),
        ("co-contract", 15, 1),
    ]


def test_a_recording_from_before_sessions_is_one_trial_and_says_so(tmp_path):
    rec = write_recording(tmp_path / "old.mcap", windows(0.0, 3.0, lambda t: 120.0))
    (row,) = rows_of(rec)
    assert (row["subject"], row["session"], row["condition"]) == ("", "", "")
    assert (row["trial"], row["repeat"], row["windows"], row["K_median"]) == (WHOLE, 1, 30, 120.0)
    assert NO_SESSION_NOTE in row["notes"]
    assert (row["t_start_s"], row["t_end_s"]) == pytest.approx((-0.2, 3.0))


def test_rotated_parts_are_read_as_one_recording_and_trials_span_them(tmp_path):
    stem = "rtsid-rig-ankle-20261126T100000Z"
    first = write_recording(
        tmp_path / f"{stem}.mcap",
        windows(0.0, 2.0, lambda t: 100.0),
        session=SUBJECT,
        markers=[(1.05, "walk start")],
    )
    write_recording(
        tmp_path / f"{stem}-001.mcap",
        windows(2.0, 4.0, lambda t: 140.0),
        session=SUBJECT,
        markers=[(3.05, "walk end")],
    )
    assert find_recordings([tmp_path]) == [[first, tmp_path / f"{stem}-001.mcap"]]
    (row,) = rows_of(first)  # one part given: the session is read whole
    assert row["windows"] == 20 and row["trials"] == 1
    assert row["K_median"] == pytest.approx(120.0)  # 10 windows at 100, 10 at 140
    assert row["recording"] == f"{stem}.mcap;{stem}-001.mcap"


def study(folder: Path) -> None:
    """Two subjects; S01 in two conditions over two sessions, S02 in one."""
    folder.mkdir()
    s01 = {"subject": "S01", "session": "visit1", "condition": "relaxed"}
    write_recording(
        folder / "a.mcap",
        windows(0.0, 6.0, lambda t: 100.0 if t < 3.0 else 150.0),
        session=s01,
        changes=[(3.0, "active")],
        markers=[(0.0, "t1 start"), (3.0, "t1 end"), (3.0, "t2 start"), (6.0, "t2 end")],
    )
    write_recording(
        folder / "b.mcap",
        windows(0.0, 2.0, lambda t: 110.0),
        session={**s01, "session": "visit2"},
        markers=[(0.0, "t1 start"), (2.0, "t1 end")],
    )
    write_recording(
        folder / "c.mcap",
        windows(0.0, 2.0, lambda t: 90.0),
        session={"subject": "S02", "session": "visit1", "condition": "relaxed"},
    )


def test_rows_by_trial_condition_and_subject(tmp_path, capsys):
    study(tmp_path / "study")
    code, by_trial, _ = cli_table([str(tmp_path / "study")], capsys)
    assert code == 0
    assert [(r["subject"], r["session"], r["trial"], r["condition"]) for r in by_trial] == [
        ("S01", "visit1", "t1", "relaxed"),
        ("S01", "visit1", "t2", "active"),
        ("S01", "visit2", "t1", "relaxed"),
        ("S02", "visit1", WHOLE, "relaxed"),
    ]
    assert [r["K_median"] for r in by_trial] == ["100.0", "150.0", "110.0", "90.0"]
    code, by_condition, _ = cli_table([str(tmp_path / "study"), "--by", "condition"], capsys)
    assert code == 0
    got = [
        (r["subject"], r["condition"], r["session"], r["trials"], r["windows"])
        for r in by_condition
    ]
    assert got == [
        ("S01", "relaxed", "visit1;visit2", "2", "48"),  # 29 + 19: t_end 2.0 ends t1
        ("S01", "active", "visit1", "1", "30"),
        ("S02", "relaxed", "visit1", "1", "20"),
    ]
    assert by_condition[0]["K_median"] == "100.0"  # 29 windows at 100, 19 at 110
    assert by_condition[0]["trial"] == "" and by_condition[0]["t_start_s"] == ""
    code, by_subject, _ = cli_table([str(tmp_path / "study"), "--by", "subject"], capsys)
    assert [(r["subject"], r["condition"], r["windows"], r["trials"]) for r in by_subject] == [
        ("S01", "relaxed;active", "78", "3"),
        ("S02", "relaxed", "20", "1"),
    ]
    assert float(by_subject[0]["duration_s"]) == pytest.approx(8.0)


def test_csv_columns_and_encodings(tmp_path, capsys):
    est = windows(0.0, 2.0, lambda t: 100.0)
    est[3] = window(est[3]["t_end_s"], 0.0, ok=False, reason="gap")
    est[4] = window(est[4]["t_end_s"], 0.0, ok=False, reason="no_excitation")
    est[5] = window(est[5]["t_end_s"], 0.0, ok=False, reason="gap")
    rec = write_recording(tmp_path / "rec.mcap", est, session=SUBJECT)
    out = tmp_path / "table.csv"
    assert main(["summary", str(rec), "-o", str(out)]) == 0
    text = out.read_text()
    assert text.splitlines()[0] == ",".join(COLUMNS)
    (row,) = list(csv.DictReader(io.StringIO(text)))
    assert row["windows"] == "20" and row["withheld"] == "3"
    assert row["withheld_share"] == "0.15"
    assert (row["withheld_gap"], row["withheld_no_excitation"], row["withheld_nan"]) == (
        "2",
        "1",
        "0",
    )
    assert (row["B_median"], row["B_held_share"], row["I_held_share"]) == ("0.8", "1.0", "0.0")
    assert row["I_median"] == "0.015" and row["vaf_median"] == "90.0"
    # no /status, no /reflex: unknown is an empty field, not 0
    assert (row["lost_samples"], row["reflex_gain"], row["reflex_windows"]) == ("", "", "0")
    assert row["repeat"] == "1" and row["recording"] == "rec.mcap"
    assert row["recording_start_utc"] == "2026-11-26T10:00:00Z"
    assert "rtsid summary: wrote" in capsys.readouterr().err


def test_lost_samples_from_the_status_counters_and_reflex_gain_and_delay(tmp_path):
    absent = {"seq": 6, "applies_from_index": 500, "applied": False, "ok": True, "gain": 0.1}
    fit = {"seq": 7, "applies_from_index": 2000, "applied": True, "ok": True}
    fit.update(gain=12.5, delay_ms=42.0)
    est = windows(0.0, 4.0, lambda t: 100.0, reflex_seq=None)
    for w in est:  # windows name the fit in force, applied (present) or not (absent)
        w["reflex_seq"] = 7 if w["t_end_s"] >= 2.0 else 6 if w["t_end_s"] >= 0.5 else None
    rec = write_recording(
        tmp_path / "rec.mcap",
        est,
        session=SUBJECT,
        markers=[(0.5, "a start"), (1.5, "a end"), (2.5, "b start"), (3.5, "b end")],
        status=[(0.25, 0), (1.0, 5), (2.0, 5), (3.0, 12), (4.0, 20)],
        reflex=[absent, fit],
    )
    a, b = rows_of(rec)
    assert (a["lost_samples"], b["lost_samples"]) == (5, 7)  # 0.5–1.5 s: 0 → 5; 2.5–3.5: 5 → 12
    assert (a["reflex_windows"], a["reflex_gain"]) == (0, None)
    assert (b["reflex_windows"], b["reflex_gain"], b["reflex_delay_ms"]) == (10, 12.5, 42.0)


def test_a_truncated_recording_is_summarised_up_to_its_last_message_with_exit_3(tmp_path, capsys):
    rec = write_recording(
        tmp_path / "cut.mcap", windows(0.0, 6.0, lambda t: 100.0), session=SUBJECT, finish=False
    )
    code, rows, err = cli_table([str(rec)], capsys)
    assert code == 3
    warning = [line for line in err if "warning" in line]
    assert len(warning) == 1 and "cut.mcap ends early" in warning[0]
    assert "rtsid recover" in warning[0]
    assert len(rows) == 1 and 0 < int(rows[0]["windows"]) < 60
    assert "incomplete recording" in rows[0]["notes"]


def test_bad_inputs_are_one_line_and_exit_2(tmp_path, capsys):
    junk = tmp_path / "notes.mcap"
    junk.write_text("these are not the recordings you are looking for\n")
    assert main(["summary", str(junk)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "notes.mcap" in err[0] and "not an MCAP file" in err[0]

    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["summary", str(empty), "-o", str(tmp_path / "t.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no .mcap recordings" in err[0]
    assert not (tmp_path / "t.csv").exists()

    assert main(["summary", str(tmp_path / "missing.mcap")]) == 2
    assert "no such file" in capsys.readouterr().err

    raw = write_recording(tmp_path / "raw.mcap", [])
    assert main(["summary", str(raw)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no /estimate messages" in err[0] and "rtsid replay" in err[0]


def test_one_bad_file_in_a_study_is_skipped_by_name_and_the_rest_summarised(tmp_path, capsys):
    folder = tmp_path / "study"
    folder.mkdir()
    write_recording(folder / "a.mcap", windows(0.0, 4.0, lambda t: 100.0), session=SUBJECT)
    (folder / "notes.mcap").write_text("not a recording\n")
    write_recording(folder / "raw.mcap", [])
    code, rows, err = cli_table([str(folder)], capsys)
    assert code == 3  # the table is not the whole folder
    warnings = [line for line in err if "warning" in line]
    assert len(warnings) == 2, err
    assert any("notes.mcap" in w and "not an MCAP file" in w for w in warnings)
    assert any("raw.mcap" in w and "no /estimate messages" in w for w in warnings)
    assert [r["subject"] for r in rows] == ["S01"] and int(rows[0]["windows"]) == 40


def test_a_recovered_copy_is_read_in_place_of_its_damaged_original(tmp_path, capsys):
    # rtsid recover writes X-recovered.mcap beside a damaged X.mcap: a folder holding both
    # counted every window twice
    folder = tmp_path / "study"
    folder.mkdir()
    estimates = windows(0.0, 6.0, lambda t: 100.0)
    write_recording(folder / "s1.mcap", estimates, session=SUBJECT, finish=False)
    write_recording(folder / "s1-recovered.mcap", estimates, session=SUBJECT)
    code, rows, err = cli_table([str(folder)], capsys)
    assert code == 0, err
    assert len(rows) == 1 and int(rows[0]["windows"]) == 60
    assert rows[0]["recording"] == "s1-recovered.mcap"
    assert any("s1-recovered.mcap in place of s1.mcap" in line for line in err)


def test_plot_writes_a_figure_per_subject(tmp_path, capsys):
    study(tmp_path / "study")
    fig = tmp_path / "fig.png"
    code = main(
        ["summary", str(tmp_path / "study"), "--plot", str(fig), "-o", str(tmp_path / "t.csv")]
    )
    assert code == 0
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {fig}" in capsys.readouterr().err


def test_markers_without_session_metadata_still_make_trials(tmp_path):
    rec = write_recording(
        tmp_path / "rec.mcap", windows(0.0, 3.0, lambda t: 100.0), markers=[(1.0, "x")]
    )
    (row,) = rows_of(rec)
    assert (row["trial"], row["windows"]) == ("x", 20)
    assert NO_SESSION_NOTE in row["notes"]
    assert json.loads(json.dumps(row["K_median"])) == 100.0


def test_the_figure_takes_labels_as_plain_text(tmp_path, capsys):
    rec = write_recording(
        tmp_path / "rec.mcap",
        windows(0.0, 3.0, lambda t: 100.0),
        session={"subject": "$S^$", "session": "1", "condition": "a$^$b"},
        markers=[(1.0, "$x^{$ start"), (2.0, "$x^{$ end")],
    )
    fig = tmp_path / "fig.png"
    assert main(["summary", str(rec), "--plot", str(fig)]) == 0
    assert fig.stat().st_size > 0
    out = capsys.readouterr().out
    assert "$x^{$" in out  # the CSV keeps the label as recorded


def test_the_summary_benchmark_times_summary_beside_replay(tmp_path, capsys):
    from rtsid.commands.bench import benchmark_parser

    parser, module = benchmark_parser("summary")
    args = parser.parse_args(["--quick", "--folder", str(tmp_path / "study")])
    assert module.run(args) == 0  # type: ignore[attr-defined]
    out = capsys.readouterr().out
    assert "study: 2 recordings" in out
    assert "rtsid replay SUBSET --jobs 1 |          1 |" in out
    assert "rtsid summary FOLDER (summary tables) |          2 |" in out
    assert "... from the messages (no table) |          2 |" in out
    assert "the two tables are byte for byte the same: yes" in out
    (row,) = rows_of(tmp_path / "study", by="subject")  # S01: one relaxed, one active
    assert row["condition"] == "relaxed;active" and row["windows"] > 0
    assert row["K_median"] == pytest.approx(160.0, rel=0.1)  # 120 and 200


def test_trials_are_numbered_over_the_recordings_of_one_session(tmp_path):
    # a.mcap was started after b.mcap (a daemon restarted in the session): b's trial is #1
    for name, hhmm, k in (("a.mcap", "10:30", 200.0), ("b.mcap", "10:00", 100.0)):
        path = write_recording(
            tmp_path / name,
            windows(0.0, 2.0, lambda t, k=k: k),
            session=SUBJECT,
            markers=[(0.5, "walk")],
        )
        _restart(path, hhmm)
    rows = rows_of(tmp_path)
    assert [(r["recording"], r["repeat"], r["K_median"]) for r in rows] == [
        ("b.mcap", 1, 100.0),
        ("a.mcap", 2, 200.0),
    ]
    assert rows[1]["recording_start_utc"] == "2026-11-26T10:30:00Z"


def _restart(path: Path, hhmm: str) -> None:
    """Rewrite ``path``'s rtsid.session started_utc (a recording started at ``hhmm``)."""
    text = path.read_bytes().replace(b"2026-11-26T10:00:00Z", f"2026-11-26T{hhmm}:00Z".encode())
    path.write_bytes(text)


def test_plot_without_matplotlib_refuses_before_any_work(tmp_path, monkeypatch, capsys):
    import rtsid.plots
    from rtsid.errors import InputDataError

    def missing() -> None:
        raise InputDataError("plots need matplotlib; install the extra with: pip install x")

    monkeypatch.setattr(rtsid.plots, "require_matplotlib", missing)
    rec = write_recording(tmp_path / "rec.mcap", windows(0.0, 1.0, lambda t: 100.0))
    out = tmp_path / "t.csv"
    assert main(["summary", str(rec), "-o", str(out), "--plot", str(tmp_path / "f.png")]) == 2
    assert "plots need matplotlib" in capsys.readouterr().err
    assert not out.exists()


# ---------------------------------------------------------------------------- the summary table
def log_recording(
    folder: Path,
    estimates: Sequence[dict[str, Any]],
    *,
    session: dict[str, str],
    changes: Sequence[tuple[float, str]] = (),
    markers: Sequence[tuple[float, str]] = (),
    status: Sequence[tuple[float, int]] = (),
    reflex: Sequence[dict[str, Any]] = (),
    parts: int = 1,
) -> list[Path]:
    """A recording written by rtsid's MCAP logger (as the daemon writes one), its events in
    time order; rotated into ``parts`` pieces or more (each piece waits for the logger to
    rotate; a part is closed at each flush once it holds its header, so there may be more)."""
    import time

    from rtsid.io.mcap_log import McapConfig, McapLogger
    from rtsid.io.session import SessionConfig

    where = {"robot": "rig", "joint": "ankle"}
    events: list[tuple[float, str, dict[str, Any]]] = []
    for t_s, condition in changes:
        body = {**where, **session, "condition": condition, "t_s": t_s}
        events.append((t_s, "session", {**body, "sample_index": round(t_s * 1000)}))
    for k, (t_s, label) in enumerate(markers):
        body = {**where, "t_s": t_s, "sample_index": round(t_s * 1000), "label": label}
        events.append((t_s, "marker", {**body, "source": "zenoh", "marker_id": f"m{k}"}))
    for t_s, lost in status:
        body = {**where, "uptime_s": t_s, "acquisition": {"lost_samples": lost}}
        events.append((t_s, "status", {**body, "host_time_ns": T0_NS + round(t_s * 1e9)}))
    events += [(fit["applies_from_index"] / 1000, "reflex", fit) for fit in reflex]
    events += [(m["t_end_s"], "estimate", m) for m in estimates]
    events.sort(key=lambda e: e[0])
    config = McapConfig(
        directory=str(folder),
        flush_interval_s=0.01,
        chunk_size=1024,
        rotate_size_mb=0.001 if parts > 1 else 0.0,
        queue_size=100_000,
    )
    start = {**where, **session, "t_s": 0.0, "sample_index": 0, "host_time_ns": T0_NS}
    with McapLogger(
        config,
        robot="rig",
        joint="ankle",
        fs_hz=1000.0,
        session=SessionConfig(**session),
        session_message=start,
    ) as logger:
        logged = 0
        for piece in np.array_split(np.arange(len(events)), parts):
            for k in piece:
                t_s, kind, message = events[k]
                t_ns = T0_NS + round(t_s * 1e9)
                if kind in ("session", "marker"):
                    message = {**message, "host_time_ns": t_ns}
                assert getattr(logger, f"log_{kind}")(message, log_time_ns=t_ns)
            logged += len(piece)
            for _ in range(1000):  # bounded: the piece is written, then its part closes
                if logger.stats()["written"] >= logged:
                    break
                time.sleep(0.01)
            opened = len(logger.files)
            for _ in range(1000):  # bounded: the next piece goes into a later part
                if parts == 1 or len(logger.files) > opened:
                    break
                time.sleep(0.01)
    return logger.files


def summary_csv(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert main(["summary", *argv]) == 0
    return capsys.readouterr().out


def test_the_loggers_table_gives_the_csv_the_messages_give(tmp_path, capsys, monkeypatch):
    from rtsid.io.mcap_read import read_summary_table
    from rtsid.io.recording import read_table
    from rtsid.summary import BY, FROM_MESSAGES_ENV

    fit = {"seq": 7, "applies_from_index": 2000, "applied": True, "ok": True}
    fit.update(gain=12.5, delay_ms=42.0)
    absent = {"seq": 6, "applies_from_index": 500, "applied": False, "ok": True, "gain": 0.1}
    est = windows(0.0, 8.0, lambda t: 100.0 + 3 * t, reflex_seq=None)
    for w in est:
        w["reflex_seq"] = 7 if w["t_end_s"] >= 2.0 else 6 if w["t_end_s"] >= 0.5 else None
    est[12].update(ok=False, reason="gap", K=None, K_track=None, B=None, I=None, vaf=None)
    est[13].update(B_held=None, vaf=float("nan"))
    study = tmp_path / "study"
    rotated = log_recording(
        study / "a",
        est,
        session=SUBJECT,
        changes=[(2.0, "active")],
        markers=[(1.0, "walk start"), (3.0, "walk end"), (4.0, "hop start"), (6.5, "rest")],
        status=[(0.25, 0), (1.0, 5), (3.0, 12), (7.0, 20)],
        reflex=[absent, fit],
        parts=3,
    )
    other = {"subject": "S02", "session": "visit1", "condition": "relaxed"}
    plain = log_recording(study / "b", windows(0.0, 3.0, lambda t: 150.0), session=other)
    assert len(rotated) >= 3 and len(plain) == 1
    for part in [*rotated, *plain]:
        found = read_summary_table(part)
        assert found is not None, part
        assert found[1]["rtsid.session"]["subject"] in ("S01", "S02")
    counts = [found[0].counts["estimate"] for found in map(read_summary_table, rotated) if found]
    assert sum(counts) == len(est) and sum(n > 0 for n in counts) >= 3
    assert read_table(rotated).from_attachments
    assert not read_table(rotated, from_messages=True).from_attachments
    for argv in ([str(study), "--by", by] for by in BY):
        fast = summary_csv(argv, capsys)
        monkeypatch.setenv(FROM_MESSAGES_ENV, "1")
        slow = summary_csv(argv, capsys)
        monkeypatch.delenv(FROM_MESSAGES_ENV)
        assert fast == slow
    fast = summary_csv([str(study), "--include-between"], capsys)
    rows = list(csv.DictReader(io.StringIO(fast)))
    relaxed, active = (r for r in rows if r["trial"] == "walk")
    assert (relaxed["condition"], relaxed["withheld_gap"], relaxed["reflex_windows"]) == (
        "relaxed",
        "1",
        "0",
    )
    assert (active["reflex_windows"], active["reflex_gain"], active["lost_samples"]) == (
        "10",
        "12.5",
        "7",
    )
    assert "condition changed" in active["notes"]
    assert len(rows) == 7  # walk ×2 conditions, hop, rest, S02's whole recording, 2 between


def test_a_table_that_does_not_match_its_file_is_not_used(tmp_path):
    from rtsid.io.mcap_read import read_summary_table
    from rtsid.io.summary_table import TableBuilder

    est = windows(0.0, 3.0, lambda t: 120.0)

    def table_of(messages: Sequence[dict[str, Any]], **edit: Any) -> bytes:
        builder = TableBuilder()
        for m in messages:
            builder.add("estimate", m)
        table = builder.table()
        table.columns.update(edit)
        return table.to_npz()

    whole = write_recording(tmp_path / "whole.mcap", est, attachment=table_of(est))
    assert read_summary_table(whole) is not None
    stale = write_recording(tmp_path / "stale.mcap", est, attachment=table_of(est[:-1]))
    assert read_summary_table(stale) is None
    bad_code = table_of(est, reason=np.full(len(est), 5, dtype=np.int32))
    for attachment in (b"PK\x03\x04 not a zip", bad_code, table_of(est)[:-50]):
        damaged = write_recording(tmp_path / "damaged.mcap", est, attachment=attachment)
        assert read_summary_table(damaged) is None
    # every cut of a whole file: no table (the message reader then says what is wrong), never
    # an exception (a file shorter than a footer raised OSError from the footer's seek)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    for size in (0, 1, 8, 20, 37, len(data) // 2, len(data) - 1):
        cut.write_bytes(data[:size])
        assert read_summary_table(cut) is None, size
    reference = rows_of(write_recording(tmp_path / "plain.mcap", est))
    for path in (stale, damaged):
        rows = rows_of(path)
        assert [{k: v for k, v in r.items() if k != "recording"} for r in rows] == [
            {k: v for k, v in r.items() if k != "recording"} for r in reference
        ]


def test_a_killed_loggers_file_has_no_table_and_still_summarises(tmp_path, capsys, monkeypatch):
    from rtsid.io.mcap_read import read_summary_table
    from rtsid.summary import FROM_MESSAGES_ENV

    (path,) = log_recording(tmp_path, windows(0.0, 4.0, lambda t: 100.0), session=SUBJECT)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 200])  # the footer and summary gone, as after kill -9
    assert read_summary_table(path) is None
    code, rows, err = cli_table([str(path)], capsys)
    assert code == 3 and any("ends early" in line for line in err)
    assert rows[0]["windows"] == "40" and rows[0]["subject"] == "S01"
    (tmp_path / "recovered").mkdir()
    recovered = tmp_path / "recovered" / "cut.mcap"
    assert main(["recover", str(path), "-o", str(recovered)]) == 0
    capsys.readouterr()
    assert read_summary_table(recovered) is not None  # rtsid recover writes the table too
    fast = summary_csv([str(recovered)], capsys)
    monkeypatch.setenv(FROM_MESSAGES_ENV, "1")
    assert summary_csv([str(recovered)], capsys) == fast
    assert next(csv.DictReader(io.StringIO(fast)))["windows"] == "40"


def test_a_replays_mcap_output_carries_the_table(tmp_path, capsys, monkeypatch):
    from rtsid.io.mcap_read import read_summary_table
    from rtsid.summary import FROM_MESSAGES_ENV

    source = Path(__file__).resolve().parents[1] / "replay" / "reference" / "sim_3s.mcap"
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(source), "-o", str(out), "--rate", "max"]) == 0
    capsys.readouterr()
    assert read_summary_table(out) is not None
    fast = summary_csv([str(out)], capsys)
    monkeypatch.setenv(FROM_MESSAGES_ENV, "1")
    assert summary_csv([str(out)], capsys) == fast
    assert int(next(csv.DictReader(io.StringIO(fast)))["windows"]) > 0
