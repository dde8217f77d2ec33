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
import os
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from rtsid.errors import (
    IncompleteRecordingWarning,
    InputDataError,
    RecordingError,
    RtsidError,
    RtsidWarning,
)
from rtsid.io.estimate_csv import encode_value
from rtsid.io.recording import (
    RecordedMessages,
    SessionRecord,
    read_table,
    session_parts,
    session_record,
)
from rtsid.io.summary_table import NO_INT, SummaryTable
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

#: Set to 1, ``rtsid summary`` reads every recording's messages even when it carries its
#: summary table (the reference path, for the bench and the tests).
FROM_MESSAGES_ENV = "RTSID_SUMMARY_FROM_MESSAGES"

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
    # originals first, so that a recovered copy is taken in its original's place, once
    for f in sorted(files, key=lambda f: f.stem.endswith("-recovered")):
        if f in seen:
            continue
        parts = session_parts(f)
        seen.update(parts)
        parts = [_recovered_copy(p) for p in parts]
        seen.update(parts)
        recordings.append(parts)
    return recordings


def _recovered_copy(part: Path) -> Path:
    """``part``, or the copy ``rtsid recover`` made of it beside it (``…-recovered.mcap``).

    The copy holds everything the damaged original still had; reading both would count the
    same windows twice, so the original is left out with a note.
    """
    copy = part.with_name(part.stem + "-recovered.mcap")
    if not copy.is_file():
        return part
    warnings.warn(
        RtsidWarning(f"read {copy.name} in place of {part.name}, the damaged file it recovers"),
        stacklevel=3,
    )
    return copy


def read_study(
    recordings: Sequence[Sequence[Path]], *, from_messages: bool | None = None
) -> list[StudyRecording]:
    """Every recording of a study that can be read (:func:`read_study_recording`).

    One that cannot (not MCAP, no ``/estimate`` message, …) is skipped with an
    :class:`~rtsid.errors.IncompleteRecordingWarning` naming it and why, so that one bad file
    in a study's folder does not cost the table of all the others; ``rtsid summary`` then
    exits with status 3.

    Raises
    ------
    RecordingError, InputDataError
        No recording could be read (the first one's error).
    """
    read: list[StudyRecording] = []
    errors: list[RtsidError] = []
    for parts in recordings:
        try:
            read.append(read_study_recording(parts, from_messages=from_messages))
        except (RecordingError, InputDataError) as exc:
            errors.append(exc)
            if len(recordings) > 1:
                warnings.warn(IncompleteRecordingWarning(f"skipped: {exc}"), stacklevel=2)
    if not read and errors:
        raise errors[0]
    return read


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
    windows : Windows
        The ``/estimate`` windows as columns, sorted by ``t_end_s``.
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
    windows: Windows
    robot: str = ""
    joint: str = ""
    subject: str = ""
    session: str = ""
    start_utc: str = ""
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
        ends = [float(t) for t in self.windows.t_end_s[-1:]]
        ends += [m.t_s for m in self.markers[-1:]]
        return float(max(ends, default=0.0))

    @property
    def begin_s(self) -> float:
        """The first window's first sample time (0 without windows)."""
        return float(self.windows.t_start_s[0]) if len(self.windows) else 0.0


@dataclass(frozen=True)
class Windows:
    """A recording's estimate windows as columns (one row per ``/estimate`` message), sorted
    by ``t_end_s``; what a row of the table needs of them.

    Attributes
    ----------
    t_start_s, t_end_s : ndarray of float, shape (n,)
        The window's first and last sample time, s (0 when not recorded).
    ok : ndarray of bool
        Published (not withheld).
    reason : ndarray of int
        Code of the withholding reason in ``reasons`` (-1: none).
    reasons : tuple of str
    values : dict[str, ndarray of float]
        ``K_track``, ``K`` (N·m/rad), ``B`` (N·m·s/rad), ``I`` (kg·m²), ``vaf`` (%); NaN
        where not a number.
    held : dict[str, ndarray of int8]
        ``B_held``, ``I_held``: 1, 0, or -1 when not said.
    reflex_gain, reflex_delay_ms : ndarray of float
        The fit the window names (``reflex_seq``) when the window is published and that fit
        was applied (judged present); NaN otherwise.
    reflex_applied : ndarray of bool
        The window is published and its fit was applied.
    """

    t_start_s: np.ndarray
    t_end_s: np.ndarray
    ok: np.ndarray
    reason: np.ndarray
    reasons: tuple[str, ...]
    values: dict[str, np.ndarray]
    held: dict[str, np.ndarray]
    reflex_applied: np.ndarray
    reflex_gain: np.ndarray
    reflex_delay_ms: np.ndarray

    def __len__(self) -> int:
        return int(self.t_end_s.size)

    def column(self, name: str) -> np.ndarray:
        """A value (``K``, …), held flag (``B_held``, …) or other column by name."""
        if name in self.values:
            return self.values[name]
        if name in self.held:
            return self.held[name]
        column: np.ndarray = getattr(self, name)
        return column


def _windows(table: SummaryTable, order: np.ndarray) -> Windows:
    """The table's estimate rows in ``order``, with the reflex fit each names."""
    c = table.columns
    ok = c["ok"][order] == 1
    seq = c["reflex_seq"][order]
    applied, gain, delay = _reflex_of_windows(table, seq)
    applied &= ok
    return Windows(
        t_start_s=np.nan_to_num(c["t_start_s"][order], nan=0.0),
        t_end_s=np.nan_to_num(c["t_end_s"][order], nan=0.0),
        ok=ok,
        reason=c["reason"][order],
        reasons=tuple(str(n) for n in c["reason_names"]),
        values={k: c[k][order] for k in ("K_track", "K", "B", "I", "vaf")},
        held={k: c[k][order] for k in ("B_held", "I_held")},
        reflex_applied=applied,
        reflex_gain=np.where(applied, gain, np.nan),
        reflex_delay_ms=np.where(applied, delay, np.nan),
    )


def _reflex_of_windows(
    table: SummaryTable, seq: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each window's ``reflex_seq``: whether the ``/reflex`` fit of that seq (the last
    one recorded, when several share it) was applied, its gain and delay (ms)."""
    c = table.columns
    ids = c["reflex_seq_id"]
    applied = np.zeros(seq.size, dtype=bool)
    gain = np.full(seq.size, np.nan)
    delay = np.full(seq.size, np.nan)
    if not ids.size:
        return applied, gain, delay
    last = ids.size - 1 - np.unique(ids[::-1], return_index=True)[1]  # each seq's last fit
    keys = ids[last]
    at = np.clip(np.searchsorted(keys, seq), 0, keys.size - 1)
    found = (keys[at] == seq) & (seq != NO_INT)
    fit = last[at]
    applied = found & (c["reflex_applied"][fit] == 1)
    return applied, c["reflex_gain"][fit], c["reflex_delay_ms"][fit]


def read_study_recording(
    parts: Sequence[Path], *, from_messages: bool | None = None
) -> StudyRecording:
    """One recording's estimates, reflex fits, status counters, session and markers.

    Read from the parts' summary tables when each carries a consistent one, else from their
    messages (:func:`rtsid.io.recording.read_table`); the result is the same.

    Parameters
    ----------
    parts : sequence of Path
        The recording's files, in order.
    from_messages : bool, optional
        Read the messages even when the tables are there (default: when the environment
        variable :data:`FROM_MESSAGES_ENV` is ``1``).

    Raises
    ------
    RecordingError
        A part is missing, empty, not MCAP, or holds a message that is not JSON.
    InputDataError
        The recording holds no ``/estimate`` message (raw samples only).
    """
    if from_messages is None:
        from_messages = os.environ.get(FROM_MESSAGES_ENV, "") == "1"
    recorded = read_table(list(parts), from_messages=from_messages)
    table, read = recorded.table, recorded.read
    if not len(table):
        raise InputDataError(
            f"{parts[0]} has no /estimate messages (raw samples only?); estimate them first "
            f"with: rtsid replay {parts[0]} -o OUT.mcap, then rtsid summary OUT.mcap"
        )
    order = np.argsort(np.nan_to_num(table.columns["t_end_s"], nan=0.0), kind="stable")
    rec = StudyRecording(list(read.parts), _windows(table, order), complete=read.complete)
    session = session_record(read)
    _identity(rec, table.text("robot")[order[0]], table.text("joint")[order[0]], read, session)
    rec.markers = _markers(session)
    rec.lost = _lost_counter(table, order)
    return rec


def _markers(session: SessionRecord) -> list[Marker]:
    """The recording's markers (each ``marker_id`` once) in time order."""
    out = [
        Marker(float(m["t_s"]), str(m.get("label", "")))
        for m in session.markers
        if isinstance(m.get("t_s"), int | float)
    ]
    return sorted(out, key=lambda m: m.t_s)


def _identity(
    rec: StudyRecording,
    robot: str | None,
    joint: str | None,
    read: RecordedMessages,
    session: SessionRecord,
) -> None:
    """Robot, joint (of the first window, else the metadata), subject, session, start and
    the condition changes of ``rec``."""
    session_meta = session.metadata[0] if session.metadata else {}
    rtsid_meta = read.metadata[0].get("rtsid", {}) if read.metadata else {}
    changes = [m for m in session.sessions if isinstance(m.get("t_s"), int | float)]
    first = changes[0] if changes else {}
    rec.has_session = bool(session_meta or changes)
    rec.robot = str(robot or rtsid_meta.get("robot", ""))
    rec.joint = str(joint or rtsid_meta.get("joint", ""))
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


def _lost_counter(table: SummaryTable, order: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Cumulative lost samples against sample time, from the status messages' link counters.

    A status carries host time only: it is placed in sample time through the estimates' own
    (host_time_ns, t_end_s) pairs (to within a status period, 0.5–1 s). A counter that goes
    down (a restarted daemon) starts again from its new value. None when there is no status
    with a ``lost_samples`` counter or no host time to place it by.
    """
    c = table.columns
    host_ns, t_end = c["host_time_ns"][order], c["t_end_s"][order]
    known = (host_ns != NO_INT) & ~np.isnan(t_end)
    host_ns, t_end = host_ns[known], t_end[known]
    status_ns, lost = c["status_host_time_ns"], c["status_lost_samples"]
    if not status_ns.size or host_ns.size < 2:
        return None
    clock = np.lexsort((t_end, host_ns))
    rows = np.lexsort((lost, status_ns))
    host = host_ns[clock].astype(np.float64)
    t = np.interp(status_ns[rows].astype(np.float64), host, t_end[clock])
    values = lost[rows]
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
    windows: np.ndarray
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
    t_end = rec.windows.t_end_s
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
            windows = np.flatnonzero(inside)
            if not windows.size and trial.name != BETWEEN:
                extra.append("no windows in this trial")
            if windows.size or trial.name != BETWEEN:
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
        **_window_statistics(segments),
        **_reflex_statistics(segments),
    }
    return row


def _quartiles(values: np.ndarray) -> tuple[float | None, float | None, float | None]:
    """Median, 25th and 75th percentile of the finite ``values`` (None when there are none)."""
    x = values[np.isfinite(values)]
    if not x.size:
        return None, None, None
    q25, q50, q75 = np.percentile(x, [25, 50, 75])
    return float(q50), float(q25), float(q75)


def _share(flags: np.ndarray) -> float | None:
    """The share of 1 among the flags said (1 or 0; -1 is not said), None when none is."""
    known = int(np.count_nonzero(flags >= 0))
    return int(np.count_nonzero(flags == 1)) / known if known else None


def _column(segments: Sequence[Segment], name: str, *, ok: bool = False) -> np.ndarray:
    """Column ``name`` of the recordings' :class:`Windows` at the segments' windows, segment
    after segment (only the published windows with ``ok``)."""
    parts = []
    for s in segments:
        rows = s.windows[s.rec.windows.ok[s.windows]] if ok else s.windows
        parts.append(s.rec.windows.column(name)[rows])
    return np.concatenate(parts) if parts else np.zeros(0)


def _window_statistics(segments: Sequence[Segment]) -> dict[str, Any]:
    """Medians and quartiles over the published (``ok``) windows; withheld counts by reason."""
    count = sum(int(s.windows.size) for s in segments)
    ok = _column(segments, "ok")
    withheld = count - int(np.count_nonzero(ok))
    out: dict[str, Any] = {"windows": count, "withheld": withheld}
    out["withheld_share"] = withheld / count if count else None
    for reason in _REASONS:
        out[f"withheld_{reason}"] = sum(
            int(np.count_nonzero(_withheld_for(s, reason))) for s in segments
        )
    for key in ("K_track", "K"):
        med, q25, q75 = _quartiles(_column(segments, key, ok=True))
        out.update({f"{key}_median": med, f"{key}_q25": q25, f"{key}_q75": q75})
    for key in ("B", "I", "vaf"):
        out[f"{key}_median"] = _quartiles(_column(segments, key, ok=True))[0]
    out["B_held_share"] = _share(_column(segments, "B_held", ok=True))
    out["I_held_share"] = _share(_column(segments, "I_held", ok=True))
    return out


def _withheld_for(segment: Segment, reason: str) -> np.ndarray:
    """Which of the segment's windows were withheld for ``reason``."""
    w = segment.rec.windows
    if reason not in w.reasons:
        return np.zeros(0, dtype=bool)
    rows = segment.windows
    return ~w.ok[rows] & (w.reason[rows] == w.reasons.index(reason))


def _reflex_statistics(segments: Sequence[Segment]) -> dict[str, Any]:
    """Windows whose slow-lane fit (``reflex_seq``) was applied — judged present, its torque
    subtracted — and the median gain and delay of those fits over the windows. A window
    naming a fit judged absent (``applied`` false) or missing from ``/reflex`` counts not."""
    applied = _column(segments, "reflex_applied")
    gain = _column(segments, "reflex_gain")
    delay = _column(segments, "reflex_delay_ms")
    return {
        "reflex_windows": int(np.count_nonzero(applied)),
        "reflex_gain": _quartiles(gain[applied])[0],
        "reflex_delay_ms": _quartiles(delay[applied])[0],
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
