"""The summary table: what ``rtsid summary`` reads of a recording, as columns.

``rtsid summary`` needs of every ``/estimate`` message fifteen fields, and a few fields of the
low-rate channels (``/reflex``, ``/status``, ``/session``, ``/marker``). Decoding a ten-minute
recording's 30 000 estimate messages costs about 2 s; the same fields kept as numpy columns
read in milliseconds. So:

* the MCAP logger (:class:`rtsid.io.mcap_log.McapLogger`, the one writer) feeds every message
  it writes into a :class:`TableBuilder` and, when a part closes (rotation or stop), writes the
  part's table as one MCAP Attachment named :data:`ATTACHMENT_NAME` (an ``.npz``: numpy
  ``savez_compressed``, no pickled object);
* the reader (:func:`rtsid.io.mcap_read.read_summary_table`) finds it through the file's
  summary section with one seek and returns it only when it is consistent with the file (its
  :data:`VERSION`, and its message counts equal the Statistics record's channel counts);
* a file without one (a killed daemon, a recovered or older recording) is read message by
  message, and those messages go through the same :class:`TableBuilder`, so both ways give one
  table and ``rtsid summary`` one result.

The columns, their units and encodings are listed in docs/io.md ("The summary table").
"""

from __future__ import annotations

import io
import json
import math
import time
from array import array
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtsid.errors import InputDataError
from rtsid.io.files import read_npz

__all__ = [
    "ATTACHMENT_NAME",
    "KINDS",
    "MEDIA_TYPE",
    "NO_INT",
    "VERSION",
    "SummaryTable",
    "TableBuilder",
    "TableError",
    "attach_table",
]

#: The attachment's name and media type.
ATTACHMENT_NAME = "rtsid.summary.npz"
MEDIA_TYPE = "application/x-npz"
#: Format version, stored as ``version``; a reader takes only the version it knows.
VERSION = 1
#: The channels the table covers (by kind, as :data:`rtsid.io.schemas.SCHEMAS`), in the order
#: of its ``counts`` column.
KINDS = ("estimate", "reflex", "status", "session", "marker")
#: An integer that was missing or not an integer (int64 columns).
NO_INT = -(2**63)

#: Estimate columns of float64 (NaN: null or not a number), int8 flags (1 true, 0 false,
#: -1 null), int64 (:data:`NO_INT`: null) and text codes (index into ``<name>_names``, -1 null).
_FLOAT = ("t_start_s", "t_end_s", "K_track", "K", "B", "I", "vaf")
_FLAG = ("B_held", "I_held")
_INT = ("reflex_seq", "host_time_ns")
_TEXT = ("robot", "joint", "reason")
#: Reflex and status columns.
_REFLEX_FLOAT = ("reflex_gain", "reflex_delay_ms")
_STATUS_INT = ("status_host_time_ns", "status_lost_samples")


class TableError(ValueError):
    """An attachment that is not a summary table this version reads (the reader then falls
    back to the messages)."""


#: The value types :meth:`TableBuilder.add_estimates` converts to float columns in one call.
_FLOAT_OR_NONE = frozenset({float, type(None)})


def _number(value: Any) -> float:
    """``value`` as float when it is a JSON number (bools count, as ``isinstance(v, int)``
    does), else NaN."""
    if isinstance(value, int | float):
        try:
            return float(value)
        except OverflowError:
            return math.nan
    return math.nan


def _integer(value: Any) -> int:
    if isinstance(value, int) and NO_INT < value < 2**63:
        return int(value)
    return NO_INT


def _flag(value: Any) -> int:
    return 1 if value is True else 0 if value is False else -1


class _Codes:
    """A text column: codes into a vocabulary that grows as texts come."""

    def __init__(self) -> None:
        self.codes = array("i")
        self.names: dict[str, int] = {}

    def add(self, text: str | None) -> None:
        self.codes.append(-1 if text is None else self.names.setdefault(text, len(self.names)))

    def extend(self, texts: Iterable[str | None]) -> None:
        """:meth:`add` each of ``texts`` in turn."""
        names = self.names
        self.codes.extend(
            [-1 if text is None else names.setdefault(text, len(names)) for text in texts]
        )


class TableBuilder:
    """Collects the summary table of one recording part, message by message.

    Columns are :class:`array.array` (8 bytes a number, 15 numbers an estimate: ≈ 22 MB per
    hour at the 20 ms hop), turned into numpy arrays by :meth:`table`.
    """

    def __init__(self) -> None:
        self.counts = dict.fromkeys(KINDS, 0)
        self._float = {k: array("d") for k in (*_FLOAT, *_REFLEX_FLOAT)}
        self._int = {k: array("q") for k in (*_INT, "reflex_seq_id", *_STATUS_INT)}
        self._flag = {k: array("b") for k in (*_FLAG, "ok", "reflex_applied")}
        self._text = {k: _Codes() for k in _TEXT}
        self._json: dict[str, list[dict[str, Any]]] = {"session": [], "marker": []}
        self.undecodable = 0

    def add_payload(self, kind: str, payload: bytes) -> None:
        """Add a message as written (JSON bytes); one that is not a JSON object is counted in
        :attr:`undecodable` (a table with such is not written: the reader would refuse it)."""
        if kind not in self.counts:
            return
        try:
            message = json.loads(payload)
        except (ValueError, RecursionError):
            message = None
        if not isinstance(message, dict):
            self.counts[kind] += 1
            self.undecodable += 1
            return
        self.add(kind, message)

    def add(self, kind: str, message: Mapping[str, Any]) -> None:
        """Add one decoded message of channel ``kind`` (other kinds are ignored)."""
        if kind not in self.counts:
            return
        self.counts[kind] += 1
        if kind == "estimate":
            self._add_estimate(message)
        elif kind == "reflex":
            self._add_reflex(message)
        elif kind == "status":
            self._add_status(message)
        else:
            self._json[kind].append(dict(message))

    def add_estimates(self, messages: Sequence[Mapping[str, Any]]) -> None:
        """``add("estimate", m)`` for each of ``messages`` in turn — the same rows — column by
        column (a replay's output adds tens of thousands at once: no calls per field)."""
        self.counts["estimate"] += len(messages)
        for key in _FLOAT:
            values = [m.get(key) for m in messages]
            if {type(v) for v in values} <= _FLOAT_OR_NONE:  # numpy: None → NaN, as _number
                self._float[key].frombytes(np.array(values, dtype=np.float64).tobytes())
            else:
                self._float[key].extend([_number(v) for v in values])
        for key in _FLAG:
            self._flag[key].extend([_flag(m.get(key)) for m in messages])
        for key in _INT:
            self._int[key].extend([_integer(m.get(key)) for m in messages])
        self._flag["ok"].extend([1 if m.get("ok") else 0 for m in messages])
        for key in ("robot", "joint"):
            texts = [m.get(key) for m in messages]
            self._text[key].extend([str(text) if text else None for text in texts])
        reasons = [m.get("reason") for m in messages]
        self._text["reason"].extend([r if isinstance(r, str) else None for r in reasons])

    def _add_estimate(self, m: Mapping[str, Any]) -> None:
        for key in _FLOAT:
            self._float[key].append(_number(m.get(key)))
        for key in _FLAG:
            self._flag[key].append(_flag(m.get(key)))
        for key in _INT:
            self._int[key].append(_integer(m.get(key)))
        self._flag["ok"].append(1 if m.get("ok") else 0)
        robot, joint, reason = m.get("robot"), m.get("joint"), m.get("reason")
        self._text["robot"].add(str(robot) if robot else None)
        self._text["joint"].add(str(joint) if joint else None)
        self._text["reason"].add(reason if isinstance(reason, str) else None)

    def _add_reflex(self, m: Mapping[str, Any]) -> None:
        if "seq" not in m:
            return
        try:
            seq = int(m["seq"])
        except (TypeError, ValueError, OverflowError):
            return
        if _integer(seq) == NO_INT:
            return
        self._int["reflex_seq_id"].append(seq)
        self._flag["reflex_applied"].append(1 if m.get("applied") is True else 0)
        self._float["reflex_gain"].append(_number(m.get("gain")))
        self._float["reflex_delay_ms"].append(_number(m.get("delay_ms")))

    def _add_status(self, m: Mapping[str, Any]) -> None:
        acquisition, host = m.get("acquisition"), m.get("host_time_ns")
        if not isinstance(acquisition, dict):
            return
        lost = _integer(acquisition.get("lost_samples"))
        host_ns = _integer(host)
        if lost == NO_INT or host_ns == NO_INT:
            return
        self._int["status_host_time_ns"].append(host_ns)
        self._int["status_lost_samples"].append(lost)

    def table(self) -> SummaryTable:
        """The columns collected so far."""
        columns: dict[str, np.ndarray] = {}
        for key, values in self._float.items():
            columns[key] = np.frombuffer(values, dtype=np.float64).copy()
        for key, ints in self._int.items():
            columns[key] = np.frombuffer(ints, dtype=np.int64).copy()
        for key, flags in self._flag.items():
            columns[key] = np.frombuffer(flags, dtype=np.int8).copy()
        for key, text in self._text.items():
            columns[key] = np.frombuffer(text.codes, dtype=np.int32).astype(np.int32)
            names = sorted(text.names, key=text.names.__getitem__)
            columns[f"{key}_names"] = np.array(names, dtype=np.str_)
        return SummaryTable(
            dict(self.counts), columns, list(self._json["session"]), list(self._json["marker"])
        )


@dataclass(frozen=True)
class SummaryTable:
    """One recording's (or part's) summary columns.

    Attributes
    ----------
    counts : dict[str, int]
        Messages per kind (:data:`KINDS`) the table was made from.
    columns : dict[str, numpy.ndarray]
        Estimate rows in file order (``t_start_s``, ``t_end_s`` s; ``K_track``, ``K`` N·m/rad;
        ``B`` N·m·s/rad; ``I`` kg·m²; ``vaf`` %; ``B_held``, ``I_held``, ``ok`` flags;
        ``reflex_seq``, ``host_time_ns``; ``robot``, ``joint``, ``reason`` codes into
        ``<name>_names``), reflex fits (``reflex_seq_id``, ``reflex_applied``,
        ``reflex_gain``, ``reflex_delay_ms`` ms) and status counters
        (``status_host_time_ns``, ``status_lost_samples``).
    sessions, markers : list of dict
        The ``/session`` and ``/marker`` messages, whole, in file order.
    """

    counts: dict[str, int]
    columns: dict[str, np.ndarray]
    sessions: list[dict[str, Any]]
    markers: list[dict[str, Any]]

    def __len__(self) -> int:
        return int(self.columns["t_end_s"].size)

    def text(self, key: str) -> list[str | None]:
        """Text column ``key`` (robot, joint, reason) decoded, None for null."""
        names = [str(n) for n in self.columns[f"{key}_names"]]
        return [names[c] if c >= 0 else None for c in self.columns[key].tolist()]

    # ------------------------------------------------------------------ npz
    def to_npz(self) -> bytes:
        """The table as ``.npz`` bytes (``savez_compressed``; no object arrays)."""
        out = io.BytesIO()
        members: dict[str, Any] = {
            "version": np.array([VERSION], dtype=np.int64),
            "kinds": np.array(KINDS, dtype=np.str_),
            "counts": np.array([self.counts[k] for k in KINDS], dtype=np.int64),
            "sessions_json": _json_bytes(self.sessions),
            "markers_json": _json_bytes(self.markers),
            **self.columns,
        }
        np.savez_compressed(out, **members)
        return out.getvalue()

    @classmethod
    def from_npz(cls, data: bytes) -> SummaryTable:
        """Read and check a table written by :meth:`to_npz`.

        Raises
        ------
        TableError
            Not a zip of ``.npy`` members, a member too large, of an object or unexpected
            dtype, a column missing or of the wrong length, another version, a code outside its
            vocabulary, or session/marker JSON that is not a list of objects.
        """
        try:
            arrays = read_npz(ATTACHMENT_NAME, (), hint="", content=data)
        except InputDataError as exc:
            raise TableError(str(exc)) from None
        version = _member(arrays, "version", "i")
        if version.shape != (1,) or int(version[0]) != VERSION:
            raise TableError(
                f"summary table version {version.tolist()}, this rtsid reads {VERSION}"
            )
        kinds = _member(arrays, "kinds", "U").tolist()
        counts = _member(arrays, "counts", "i").tolist()
        if kinds != list(KINDS) or len(counts) != len(KINDS) or min(counts) < 0:
            raise TableError("summary table counts do not name the channels this rtsid reads")
        columns = _checked_columns(arrays, dict(zip(KINDS, counts, strict=True)))
        sessions = _json_list(_member(arrays, "sessions_json", "u"), "sessions_json")
        markers = _json_list(_member(arrays, "markers_json", "u"), "markers_json")
        table = cls(dict(zip(KINDS, counts, strict=True)), columns, sessions, markers)
        if len(sessions) != table.counts["session"] or len(markers) != table.counts["marker"]:
            raise TableError("summary table session/marker lists disagree with its counts")
        return table

    @classmethod
    def concatenate(cls, tables: Sequence[SummaryTable]) -> SummaryTable:
        """The tables of a recording's parts as one (rows in part order, text codes joined)."""
        if len(tables) == 1:
            return tables[0]
        counts = {k: sum(t.counts[k] for t in tables) for k in KINDS}
        columns: dict[str, np.ndarray] = {}
        for key in tables[0].columns:
            if key.endswith("_names") or key in _TEXT:
                continue
            columns[key] = np.concatenate([t.columns[key] for t in tables])
        for key in _TEXT:
            names: dict[str, int] = {}
            parts = []
            for t in tables:
                local = [names.setdefault(str(n), len(names)) for n in t.columns[f"{key}_names"]]
                lookup = np.array([*local, -1], dtype=np.int32)  # code -1 → last entry: -1
                parts.append(lookup[t.columns[key]])
            columns[key] = np.concatenate(parts).astype(np.int32)
            columns[f"{key}_names"] = np.array(list(names), dtype=np.str_)
        sessions = [m for t in tables for m in t.sessions]
        markers = [m for t in tables for m in t.markers]
        return cls(counts, columns, sessions, markers)


def _json_bytes(messages: Iterable[Mapping[str, Any]]) -> np.ndarray:
    text = json.dumps(list(messages), separators=(",", ":"), allow_nan=True)
    return np.frombuffer(text.encode(), dtype=np.uint8)


def _json_list(data: np.ndarray, name: str) -> list[dict[str, Any]]:
    try:
        value = json.loads(data.tobytes())
    except (ValueError, RecursionError):
        raise TableError(f"summary table {name} is not JSON") from None
    if not isinstance(value, list) or not all(isinstance(m, dict) for m in value):
        raise TableError(f"summary table {name} is not a list of JSON objects")
    return value


#: Each column: its dtype kind(s) and the count its length must equal ('estimate' rows), or be
#: at most ('reflex', 'status': only the messages with the fields are kept).
_SHAPES: dict[str, tuple[str, str, str]] = {
    **{k: ("f", "estimate", "==") for k in _FLOAT},
    **{k: ("i", "estimate", "==") for k in (*_FLAG, "ok", *_INT, *_TEXT)},
    **{k: ("f", "reflex", "<=") for k in _REFLEX_FLOAT},
    **{k: ("i", "reflex", "<=") for k in ("reflex_seq_id", "reflex_applied")},
    **{k: ("i", "status", "<=") for k in _STATUS_INT},
}


def _checked_columns(arrays: Mapping[str, np.ndarray], counts: dict[str, int]) -> dict[str, Any]:
    columns: dict[str, np.ndarray] = {}
    lengths: dict[str, int] = {}
    for key, (dtype_kind, kind, rule) in _SHAPES.items():
        column = _member(arrays, key, dtype_kind)
        n = column.size
        if (rule == "==" and n != counts[kind]) or n > counts[kind]:
            raise TableError(f"summary table column {key} has {n} rows for {counts[kind]} {kind}")
        if lengths.setdefault(kind, n) != n:
            raise TableError(f"summary table {kind} columns differ in length")
        columns[key] = column.astype(np.float64 if dtype_kind == "f" else column.dtype)
    for key in ("B_held", "I_held", "ok", "reflex_applied"):
        if columns[key].size and (columns[key].min() < -1 or columns[key].max() > 1):
            raise TableError(f"summary table flag column {key} holds values other than -1, 0, 1")
        columns[key] = columns[key].astype(np.int8)
    for key in ("reflex_seq", "host_time_ns", "reflex_seq_id", *_STATUS_INT):
        columns[key] = columns[key].astype(np.int64)
    for key in _TEXT:
        names = _member(arrays, f"{key}_names", "U")
        codes = columns[key].astype(np.int64)
        if names.ndim != 1 or (codes.size and (codes.min() < -1 or codes.max() >= names.size)):
            raise TableError(f"summary table text column {key} has codes outside its names")
        columns[key] = codes.astype(np.int32)
        columns[f"{key}_names"] = names
    return columns


def _member(arrays: Mapping[str, np.ndarray], name: str, kinds: str) -> np.ndarray:
    """Member ``name``, whose dtype kind is one of ``kinds`` (``i`` takes ``u`` and ``b`` too)."""
    if name not in arrays:
        raise TableError(f"summary table has no column {name}")
    value = arrays[name]
    if value.ndim != 1:
        raise TableError(f"summary table member {name} has shape {value.shape}, not 1-D")
    allowed = set(kinds) | ({"u", "b"} if "i" in kinds else set())
    if value.dtype.kind not in allowed:
        raise TableError(f"summary table column {name} has dtype {value.dtype}")
    return value


def attach_table(writer: Any, builder: TableBuilder | None) -> bool:
    """Write ``builder``'s table into a started ``mcap.writer.Writer`` as the file's summary
    attachment (call it just before ``finish``); nothing when a message the builder saw was not
    a JSON object (the reader would read the messages anyway). Returns whether it wrote."""
    if builder is None or builder.undecodable:
        return False
    now = time.time_ns()
    writer.add_attachment(
        create_time=now,
        log_time=now,
        name=ATTACHMENT_NAME,
        media_type=MEDIA_TYPE,
        data=builder.table().to_npz(),
    )
    return True
