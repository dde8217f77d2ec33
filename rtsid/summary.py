"""Per-trial results: the recordings' own estimates summarised per trial, condition or subject.

``rtsid summary`` reads what the daemon (or ``rtsid replay``) recorded — the ``/estimate``
windows, the ``/reflex`` fits, the ``/status`` counters, the session (metadata record
``rtsid.session`` and channel ``/session``) and the ``/marker`` channel — and never estimates
again. The steps, one function each:

1. :func:`find_recordings`: files and folders → recordings (the rotated parts of one session
   joined, as every reader does);
2. :func:`read_study_recording`: one recording's messages (one pass per part);
3. :func:`trials_from_markers`: markers → trials (the one definition, below);
4. :func:`segments_of`: windows → segments, one per trial and condition in force;
5. :func:`summarise`: segments grouped ``by`` trial, condition or subject → rows
   (:data:`COLUMNS`), written by :func:`write_summary` with the estimate CSV's encodings.

**Trials from markers.** Markers are taken in time order, and each one ends the trial that is
open. A marker labelled ``"<name> start"`` (or ``"<name> begin"``) opens trial ``<name>``; one
labelled ``"<name> end"`` (or ``"<name> stop"``) opens nothing (it closed the open trial; a note
says so when that trial had another name, or when none was open); a marker with any other
label opens a trial named by the label. The last trial runs to the end of the recording. The
words and names are matched case-insensitively; a bare ``start``/``end`` names the trial ``trial``.
Markers that open no trial at all (end markers only) leave the recording one trial, noted.
Windows belong to the trial in force at their last sample (``t_end_s``; a marker at ``t_s``
is in force from ``t_s`` on); windows before the first marker or after an end marker are
*between trials*, left out unless asked for. Trials of the same name in one session are
numbered (``repeat`` 1, 2, … in time order, across the session's recordings). A recording
without markers is one trial, ``(whole recording)``; one made before sessions existed has
empty subject, session and condition, and its row says so.

**Conditions.** A condition applies from its ``/session`` message's ``t_s`` on; a trial during
which the condition changed is reported as one row per condition (same trial and repeat), each
noted.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from rtsid.errors import InputDataError
from rtsid.io.estimate_csv import encode_value
from rtsid.io.recording import (
    SESSION_TOPICS,
    RecordedMessages,
    SessionRecord,
    read_messages,
    session_parts,
    session_record,
)
from rtsid.verdicts import Reason

__all__ = [
    "BETWEEN",
    "BY",
    "COLUMNS",
    "WHOLE",
    "Marker",
    "Segment",
    "StudyRecording",
    "Trial",
    "find_recordings",
    "read_study_recording",
    "segments_of",
    "summarise",
    "trials_from_markers",
    "write_summary",
]

#: The session contract (branch ``session``): metadata record, channels.
TOPICS = ("/estimate", "/reflex", "/status", *SESSION_TOPICS)

#: Trial name of a recording without markers, and of the windows outside every trial.
WHOLE = "(whole recording)"
BETWEEN = "(between trials)"
#: The groupings of ``--by``.
BY = ("trial", "condition", "subject")

NO_SESSION_NOTE = (
    "no session metadata (recorded before sessions): subject, session and condition unknown; "
    "the whole recording is one trial"
)

_REASONS = tuple(str(r) for r in Reason)
#: The summary table's columns, in order (units: s, N·m/rad, N·m·s/rad, kg·m², %, ms).
COLUMNS: tuple[str, ...] = (
    "robot",
    "joint",
    "subject",
    "session",
    "condition",
    "trial",
    "repeat",
    "trials",
    "recording",
    "recording_start_utc",
    "t_start_s",
    "t_end_s",
    "duration_s",
    "windows",
    "K_track_median",
    "K_track_q25",
    "K_track_q75",
    "K_median",
    "K_q25",
    "K_q75",
    "B_median",
    "B_held_share",
    "I_median",
    "I_held_share",
    "vaf_median",
    "reflex_windows",
    "reflex_gain",
    "reflex_delay_ms",
    "withheld",
    "withheld_share",
    *(f"withheld_{r}" for r in _REASONS),
    "lost_samples",
    "notes",
)


# ---------------------------------------------------------------------------- recordings
def find_recordings(paths: Sequence[str | Path]) -> list[list[Path]]:
    """The recordings among files and folders: each a list of its parts, in order.

    A folder contributes every ``*.mcap`` below it (recursively, sorted); the rotated parts of
    a daemon's session are joined into one recording (:func:`rtsid.io.recording.session_parts`).

    Raises
    ------
    InputDataError
        A path does not exist, or the folders hold no ``.mcap`` file.
    """
    files: list[Path] = []
    for given in paths:
        p = Path(given)
        if p.is_dir():
            found = sorted(f for f in p.rglob("*.mcap") if f.is_file())
            if not found:
                raise InputDataError(
                    f"{p}: no .mcap recordings in this folder; give a study folder"
                )
            files += found
        elif p.exists():
            files.append(p)
        else:
            raise InputDataError(f"{p}: no such file or folder; check the path")
    recordings: list[list[Path]] = []
    seen: set[Path] = set()
    for f in files:
        if f in seen:
            continue
        parts = session_parts(f)
        seen.update(parts)
        recordings.append(parts)
    return recordings


@dataclass(frozen=True)
class Marker:
    """A trial marker: its sample time (s) and label."""

    t_s: float
    label: str


@dataclass(frozen=True)
class Trial:
    """A trial: ``name`` in force from ``t_start_s`` up to (not including) ``t_end_s``."""

    name: str
    t_start_s: float
    t_end_s: float
    notes: tuple[str, ...] = ()


@dataclass
class StudyRecording:
    """What ``rtsid summary`` takes from one recording.

    Attributes
    ----------
    parts : list of Path
        Its files, in order.
    robot, joint, subject, session : str
        Identity ('' when not recorded).
    start_utc : str
        When the session (or the recording) started, ISO 8601 ('' when not recorded).
    estimates : list of dict
        ``/estimate`` messages sorted by ``t_end_s``.
    reflex : dict[int, dict]
        ``/reflex`` fits by ``seq``.
    conditions : list of (float, str)
        Condition changes ``(t_s, condition)`` in time order; the first covers the start.
    markers : list of Marker
        In time order.
    lost : tuple of arrays or None
        ``(t_s, cumulative lost samples)`` from the status counters, or None without status.
    has_session : bool
        The recording carries session information (metadata or ``/session``).
    complete : bool
        Every part was read to its footer.
    """

    parts: list[Path]
    robot: str = ""
    joint: str = ""
    subject: str = ""
    session: str = ""
    start_utc: str = ""
    estimates: list[dict[str, Any]] = field(default_factory=list)
    reflex: dict[int, dict[str, Any]] = field(default_factory=dict)
    conditions: list[tuple[float, str]] = field(default_factory=list)
    markers: list[Marker] = field(default_factory=list)
    lost: tuple[np.ndarray, np.ndarray] | None = None
    has_session: bool = False
    complete: bool = True

    @property
    def name(self) -> str:
        """The recording's file names, joined by ``;``."""
        return ";".join(p.name for p in self.parts)

    @property
    def end_s(self) -> float:
        """The last sample time known: the last window's end or the last marker."""
        ends = [m.get("t_end_s") or 0.0 for m in self.estimates[-1:]]
        ends += [m.t_s for m in self.markers[-1:]]
        return float(max(ends, default=0.0))

    @property
    def begin_s(self) -> float:
        """The first window's first sample time (0 without windows)."""
        return float(self.estimates[0].get("t_start_s") or 0.0) if self.estimates else 0.0


#: What a row needs of an estimate message.
_KEPT = (
    "robot",
    "joint",
    "t_start_s",
    "t_end_s",
    "ok",
    "reason",
    "K_track",
    "K",
    "B",
    "B_held",
    "I",
    "I_held",
    "vaf",
    "reflex_seq",
    "host_time_ns",
)


def read_study_recording(parts: Sequence[Path]) -> StudyRecording:
    """One recording's estimates, reflex fits, status counters, session and markers.

    Raises
    ------
    RecordingError
        A part is missing, empty, not MCAP, or holds a message that is not JSON.
    InputDataError
        The recording holds no ``/estimate`` message (raw samples only).
    """
    read = read_messages(list(parts), TOPICS)
    kept = [{k: m.get(k) for k in _KEPT} for m in read.messages["/estimate"]]
    read.messages["/estimate"].clear()  # a study holds millions of windows: keep what is used
    estimates = sorted(kept, key=lambda m: float(m.get("t_end_s") or 0.0))
    if not estimates:
        raise InputDataError(
            f"{parts[0]} has no /estimate messages (raw samples only?); estimate them first "
            f"with: rtsid replay {parts[0]} -o OUT.mcap, then rtsid summary OUT.mcap"
        )
    rec = StudyRecording(list(read.parts), estimates=estimates, complete=read.complete)
    session = session_record(read)
    _identity(rec, read, session)
    rec.reflex = {int(f["seq"]): f for f in read.messages["/reflex"] if "seq" in f}
    rec.markers = _markers(session)
    rec.lost = _lost_counter(read.messages["/status"], estimates)
    return rec


def _markers(session: SessionRecord) -> list[Marker]:
    """The recording's markers (each ``marker_id`` once) in time order."""
    out = [
        Marker(float(m["t_s"]), str(m.get("label", "")))
        for m in session.markers
        if isinstance(m.get("t_s"), int | float)
    ]
    return sorted(out, key=lambda m: m.t_s)


def _identity(rec: StudyRecording, read: RecordedMessages, session: SessionRecord) -> None:
    """Robot, joint, subject, session, start and the condition changes of ``rec``."""
    session_meta = session.metadata[0] if session.metadata else {}
    rtsid_meta = read.metadata[0].get("rtsid", {}) if read.metadata else {}
    changes = [m for m in session.sessions if isinstance(m.get("t_s"), int | float)]
    first = changes[0] if changes else {}
    rec.has_session = bool(session_meta or changes)
    rec.robot = str(rec.estimates[0].get("robot") or rtsid_meta.get("robot", ""))
    rec.joint = str(rec.estimates[0].get("joint") or rtsid_meta.get("joint", ""))
    rec.subject = str(session_meta.get("subject", first.get("subject", "")))
    rec.session = str(session_meta.get("session", first.get("session", "")))
    rec.start_utc = str(
        session_meta.get("started_utc") or rtsid_meta.get("session_start_utc", "") or ""
    )
    initial = str(session_meta.get("condition", first.get("condition", "")))
    rec.conditions = [(-np.inf, initial)]
    for m in changes:
        condition = str(m.get("condition", ""))
        if condition != rec.conditions[-1][1]:
            rec.conditions.append((float(m["t_s"]), condition))


def _lost_counter(
    status: Sequence[Mapping[str, Any]], estimates: Sequence[Mapping[str, Any]]
) -> tuple[np.ndarray, np.ndarray] | None:
    """Cumulative lost samples against sample time, from the status messages' link counters.

    A status carries host time only: it is placed in sample time through the estimates' own
    (host_time_ns, t_end_s) pairs (to within a status period, 0.5–1 s). A counter that goes
    down (a restarted daemon) starts again from its new value. None when there is no status
    with a ``lost_samples`` counter or no host time to place it by.
    """
    rows = [
        (int(s["host_time_ns"]), int(s["acquisition"]["lost_samples"]))
        for s in status
        if isinstance(s.get("acquisition"), dict)
        and isinstance(s["acquisition"].get("lost_samples"), int)
        and isinstance(s.get("host_time_ns"), int)
    ]
    clock = sorted(
        (int(m["host_time_ns"]), float(m["t_end_s"]))
        for m in estimates
        if isinstance(m.get("host_time_ns"), int) and isinstance(m.get("t_end_s"), int | float)
    )
    if not rows or len(clock) < 2:
        return None
    rows.sort()
    host = np.array([h for h, _ in clock], dtype=np.float64)
    t_of_host = np.array([t for _, t in clock])
    t = np.interp(np.array([h for h, _ in rows], dtype=np.float64), host, t_of_host)
    values = np.array([v for _, v in rows], dtype=np.int64)
    steps = np.diff(values, prepend=0)
    steps = np.where(steps < 0, values, steps)  # a reset counter counts again from its value
    return t, np.cumsum(steps)


# ---------------------------------------------------------------------------- trials
_START = ("start", "begin")
_END = ("end", "stop")


def _parse_label(label: str) -> tuple[str, str]:
    """``(kind, name)``: kind ``start``, ``end`` or ``label``."""
    words = label.strip().rsplit(maxsplit=1)
    last = words[-1].lower() if words else ""
    name = words[0].strip() if len(words) == 2 else "trial"
    if last in _START:
        return "start", name
    if last in _END:
        return "end", name
    return "label", label.strip() or "trial"


def trials_from_markers(markers: Sequence[Marker], end_s: float) -> list[Trial]:
    """The trials markers define (the rules are in this module's docstring).

    Parameters
    ----------
    markers : sequence of Marker
        The recording's markers (any order).
    end_s : float
        Sample time at which the recording ends, s (the last trial runs to it).

    Returns
    -------
    list of Trial
        In time order; each carries notes on unmatched or mismatched markers.
    """
    trials: list[Trial] = []
    open_name: str | None = None
    open_kind = ""
    open_t = 0.0
    pending: list[str] = []

    def close(t: float, note: str | None = None) -> None:
        nonlocal open_name
        if open_name is not None:
            trials.append(Trial(open_name, open_t, t, tuple(pending + ([note] if note else []))))
            pending.clear()
        open_name = None

    for m in sorted(markers, key=lambda m: m.t_s):
        kind, name = _parse_label(m.label)
        if kind == "end":
            if open_name is None:  # nothing to close: the note goes on the next trial
                pending.append(f"marker '{m.label}' at {m.t_s:.2f} s closes no open trial")
            elif open_name.casefold() == name.casefold():
                close(m.t_s)
            else:
                close(m.t_s, f"ended by marker '{m.label}' at {m.t_s:.2f} s (another name)")
            continue
        if open_name is not None and open_kind == "start":
            close(m.t_s, f"no '{open_name} end' marker: ended by '{m.label}' at {m.t_s:.2f} s")
        else:
            close(m.t_s)
        open_name, open_kind, open_t = name, kind, m.t_s
    if open_name is not None and open_kind == "start":
        close(end_s, f"no '{open_name} end' marker: runs to the end of the recording")
    else:
        close(end_s)
    if pending and trials:  # unmatched ends after the last trial
        last = trials[-1]
        trials[-1] = Trial(last.name, last.t_start_s, last.t_end_s, (*last.notes, *pending))
    elif pending:  # only end markers: no trial opened, the recording is one, noted
        trials.append(Trial(WHOLE, -np.inf, np.inf, tuple(pending)))
    return trials


# ---------------------------------------------------------------------------- segments
@dataclass
class Segment:
    """Windows of one recording in one trial under one condition (the rows of ``--by trial``)."""

    rec: StudyRecording
    trial: str
    repeat: int | None
    condition: str
    t_start_s: float
    t_end_s: float
    windows: list[dict[str, Any]]
    notes: list[str]
    span: tuple[float, float] = (-np.inf, np.inf)

    @property
    def lost_samples(self) -> int | None:
        """Samples the link lost during the segment (status counters), None when unknown."""
        if self.rec.lost is None:
            return None
        t, cumulative = self.rec.lost

        def at(time_s: float) -> int:
            k = int(np.searchsorted(t, time_s, side="right"))
            return int(cumulative[k - 1]) if k else 0

        return at(self.span[1]) - at(self.span[0])


def _condition_spans(rec: StudyRecording, t0: float, t1: float) -> list[tuple[float, float, str]]:
    """``(start, end, condition)`` pieces of ``[t0, t1)`` by the condition in force (one
    piece, the condition at ``t0``, for an empty trial)."""
    spans = []
    changes = rec.conditions
    for k, (t, condition) in enumerate(changes):
        nxt = changes[k + 1][0] if k + 1 < len(changes) else np.inf
        lo, hi = max(t0, t), min(t1, nxt)
        if hi > lo:
            spans.append((float(lo), float(hi), condition))
    if not spans:
        at_start = [c for t, c in changes if t <= t0] or [changes[0][1]]
        spans.append((t0, t1, at_start[-1]))
    return spans


def segments_of(
    rec: StudyRecording, repeats: dict[tuple[str, str, str], int], *, include_between: bool
) -> list[Segment]:
    """The recording's windows cut by trial and condition.

    Parameters
    ----------
    rec : StudyRecording
    repeats : dict
        Trials of each name seen so far per (subject, session); updated (numbering runs over
        the recordings of one session, given in time order).
    include_between : bool
        Also the windows outside every trial, as :data:`BETWEEN` segments.
    """
    notes = [] if rec.has_session else [NO_SESSION_NOTE]
    if not rec.complete:
        notes.append("a part ends early (incomplete recording): read to its last message")
    begin, end = rec.begin_s, max(rec.end_s, rec.begin_s)
    if rec.markers:
        trials = trials_from_markers(rec.markers, end)
    else:
        trials = [Trial(WHOLE, -np.inf, np.inf)]
    pieces: list[tuple[Trial, int | None]] = []
    for trial in trials:
        key = (rec.subject, rec.session, trial.name) if rec.session else (rec.name, "", trial.name)
        repeats[key] = repeats.get(key, 0) + 1
        pieces.append((trial, repeats[key]))
    if include_between:
        pieces += [(Trial(BETWEEN, lo, hi), None) for lo, hi in _gaps(trials, begin, end)]
    t_end = np.array([float(m.get("t_end_s") or 0.0) for m in rec.estimates])
    segments = []
    for trial, repeat in sorted(pieces, key=lambda p: p[0].t_start_s):
        spans = _condition_spans(rec, trial.t_start_s, trial.t_end_s)
        for lo, hi, condition in spans:
            inside = (t_end >= lo) & (t_end < hi)
            extra = list(trial.notes)
            if len(spans) > 1:
                extra.append(
                    f"condition changed during the trial: this row is its part under "
                    f"'{condition}' ({_clip(lo, begin, end):.2f}–{_clip(hi, begin, end):.2f} s)"
                )
            windows = [rec.estimates[i] for i in np.flatnonzero(inside)]
            if not windows and trial.name != BETWEEN:
                extra.append("no windows in this trial")
            if windows or trial.name != BETWEEN:
                segments.append(
                    Segment(
                        rec,
                        trial.name,
                        repeat,
                        condition,
                        _clip(lo, begin, end),
                        _clip(hi, begin, end),
                        windows,
                        notes + extra,
                        (lo, hi),
                    )
                )
    return segments


def _clip(t: float, begin: float, end: float) -> float:
    return float(min(max(t, begin), end))


def _gaps(trials: Sequence[Trial], begin: float, end: float) -> list[tuple[float, float]]:
    """The stretches of ``[begin, end]`` outside every trial."""
    gaps, t = [], -np.inf
    for trial in trials:
        if trial.t_start_s > t:
            gaps.append((t, trial.t_start_s))
        t = max(t, trial.t_end_s)
    if t < np.inf:
        gaps.append((t, np.inf))
    return [(lo, hi) for lo, hi in gaps if _clip(hi, begin, end) > _clip(lo, begin, end)]


# ---------------------------------------------------------------------------- rows
def _group_key(segment: Segment, by: str) -> tuple[Any, ...]:
    rec = segment.rec
    base = (rec.robot, rec.joint, rec.subject)
    if by == "subject":
        return base
    if by == "condition":
        return (*base, segment.condition)
    return (id(segment),)


def summarise(
    recordings: Iterable[StudyRecording], by: str = "trial", *, include_between: bool = False
) -> list[dict[str, Any]]:
    """One row per trial, condition or subject (``by``), keyed by :data:`COLUMNS`.

    Rows of ``by = "condition"`` gather a subject's windows under one condition over all its
    trials, sessions and recordings (``session``: the sessions, ``;``-joined); ``"subject"``
    all of a subject's windows. Robot and joint are always part of the key.
    """
    if by not in BY:
        raise InputDataError(f"--by {by!r}: use one of {', '.join(BY)}")
    ordered = sorted(recordings, key=lambda r: (r.subject, r.session, r.start_utc, r.name))
    repeats: dict[tuple[str, str, str], int] = {}
    groups: dict[tuple[Any, ...], list[Segment]] = {}
    for rec in ordered:
        for segment in segments_of(rec, repeats, include_between=include_between):
            groups.setdefault(_group_key(segment, by), []).append(segment)
    return [_row(segments, by) for segments in groups.values()]


def _joined(values: Iterable[Any]) -> str:
    out: list[str] = []
    for v in values:
        if str(v) not in out:
            out.append(str(v))
    return ";".join(out)


def _row(segments: list[Segment], by: str) -> dict[str, Any]:
    first = segments[0]
    windows = [w for s in segments for w in s.windows]
    lost = [s.lost_samples for s in segments]
    single = by == "trial"
    row: dict[str, Any] = {
        "robot": first.rec.robot,
        "joint": first.rec.joint,
        "subject": first.rec.subject,
        "session": _joined(s.rec.session for s in segments),
        "condition": _joined(s.condition for s in segments),
        "trial": first.trial if single else "",
        "repeat": first.repeat if single else None,
        "trials": len({(id(s.rec), s.trial, s.repeat) for s in segments if s.trial != BETWEEN}),
        "recording": _joined(s.rec.name for s in segments),
        "recording_start_utc": min(
            (s.rec.start_utc for s in segments if s.rec.start_utc), default=""
        ),
        "t_start_s": first.t_start_s if single else None,
        "t_end_s": first.t_end_s if single else None,
        "duration_s": round(sum(s.t_end_s - s.t_start_s for s in segments), 6),
        "lost_samples": None if all(v is None for v in lost) else sum(v or 0 for v in lost),
        "notes": _joined(n for s in segments for n in s.notes),
        **_window_statistics(windows),
        **_reflex_statistics(segments),
    }
    return row


def _quartiles(values: Sequence[Any]) -> tuple[float | None, float | None, float | None]:
    x = np.array([v for v in values if isinstance(v, int | float)], dtype=np.float64)
    x = x[np.isfinite(x)]
    if not x.size:
        return None, None, None
    q25, q50, q75 = np.percentile(x, [25, 50, 75])
    return float(q50), float(q25), float(q75)


def _share(values: Sequence[Any]) -> float | None:
    known = [bool(v) for v in values if isinstance(v, bool)]
    return sum(known) / len(known) if known else None


def _window_statistics(windows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Medians and quartiles over the published (``ok``) windows; withheld counts by reason."""
    ok = [w for w in windows if w.get("ok")]
    withheld = [w for w in windows if not w.get("ok")]
    out: dict[str, Any] = {"windows": len(windows), "withheld": len(withheld)}
    out["withheld_share"] = len(withheld) / len(windows) if windows else None
    for reason in _REASONS:
        out[f"withheld_{reason}"] = sum(1 for w in withheld if w.get("reason") == reason)
    for key in ("K_track", "K"):
        med, q25, q75 = _quartiles([w.get(key) for w in ok])
        out.update({f"{key}_median": med, f"{key}_q25": q25, f"{key}_q75": q75})
    for key in ("B", "I", "vaf"):
        out[f"{key}_median"] = _quartiles([w.get(key) for w in ok])[0]
    out["B_held_share"] = _share([w.get("B_held") for w in ok])
    out["I_held_share"] = _share([w.get("I_held") for w in ok])
    return out


def _reflex_statistics(segments: Sequence[Segment]) -> dict[str, Any]:
    """Windows whose slow-lane fit (``reflex_seq``) was applied — judged present, its torque
    subtracted — and the median gain and delay of those fits over the windows. A window
    naming a fit judged absent (``applied`` false) or missing from ``/reflex`` counts not."""
    fits = []
    for segment in segments:
        for w in segment.windows:
            seq = w.get("reflex_seq")
            fit = segment.rec.reflex.get(seq, {}) if w.get("ok") and isinstance(seq, int) else {}
            if fit.get("applied") is True:
                fits.append(fit)
    return {
        "reflex_windows": len(fits),
        "reflex_gain": _quartiles([f.get("gain") for f in fits])[0],
        "reflex_delay_ms": _quartiles([f.get("delay_ms") for f in fits])[0],
    }


def write_summary(rows: Iterable[Mapping[str, Any]], fh: IO[str]) -> int:
    """The header and one line per row, encoded as the estimate CSV is
    (:func:`rtsid.io.estimate_csv.encode_value`); returns the number of rows."""
    writer = csv.DictWriter(fh, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    count = 0
    for row in rows:
        writer.writerow({k: encode_value(row.get(k)) for k in COLUMNS})
        count += 1
    return count
