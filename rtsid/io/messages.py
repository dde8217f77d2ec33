"""Typed messages: one dataclass per channel, its JSON schema generated from the type.

The estimate message is built as an :class:`EstimateMessage` (the worker, replay), the status
as a :class:`StatusMessage` (the daemon); each goes out as its ``as_dict()`` — the JSON object
described by :data:`ESTIMATE_SCHEMA` / :data:`STATUS_SCHEMA`, generated here from the fields,
their types and descriptions, and the closed vocabularies of :mod:`rtsid.verdicts` (a reason outside
:class:`~rtsid.verdicts.Reason` or a flag outside :class:`~rtsid.verdicts.Flag` cannot be
declared without being emitted, or emitted without being declared).
"""

from __future__ import annotations

import dataclasses
import math
import operator
import time
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rtsid.ident.levinson import compiled_kernel
from rtsid.link.counters import LinkCounters
from rtsid.verdicts import Flag, Reason

if TYPE_CHECKING:  # the numerics (scipy) are imported by who runs them, not by readers
    from rtsid.ident.reflex_lane import ReflexUpdate
    from rtsid.ident.stream import Tracked
    from rtsid.ident.window import WindowEstimate

__all__ = [
    "ESTIMATE_SCHEMA",
    "MARKER_SCHEMA",
    "MARKER_SOURCES",
    "MAX_LABEL_CHARS",
    "MAX_MARKER_ID_CHARS",
    "REFLEX_SCHEMA",
    "SESSION_SCHEMA",
    "STATUS_SCHEMA",
    "EstimateMessage",
    "MarkerMessage",
    "ReflexMessage",
    "SessionMessage",
    "StatusMessage",
    "schema_of",
]

DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _meta(text: str, **schema: Any) -> dict[str, Any]:
    """A field's description (and any extra schema keywords), its dataclass metadata."""
    return {"description": text, **schema}


@dataclass(frozen=True, slots=True, kw_only=True)
class EstimateMessage:
    """One identification window: I, B, K of tau = I*ddq + B*dq + K*q, or why not.

    The fields' order is every output's: the JSON keys (zenoh, MCAP) and the CSV columns of
    ``rtsid identify`` and ``rtsid replay`` (:mod:`rtsid.io.estimate_csv`) lead with the
    window's time, the tracked stiffness, then K, B, I with their standard errors and held
    markers, the VAF and the verdict.
    """

    robot: str = field(metadata=_meta("robot name from the config"))
    joint: str = field(metadata=_meta("joint name from the config"))
    t_end_s: float = field(metadata=_meta("sample time of the last sample, s"))
    K_track: float | None = field(
        metadata=_meta(
            "tracked stiffness now (causal Kalman filter over the windows, rtsid.ident.tracker;"
            " a withheld window advances the prediction), N·m/rad; null before the first "
            "estimate or with the tracker off"
        )
    )
    K_track_se: float | None = field(metadata=_meta("standard error of K_track, N·m/rad"))
    K: float | None = field(metadata=_meta("stiffness, N·m/rad"))
    K_se: float | None = field(metadata=_meta("standard error of K, N·m/rad"))
    B: float | None = field(metadata=_meta("damping, N·m·s/rad"))
    B_se: float | None = field(metadata=_meta("standard error of B, N·m·s/rad (null when held)"))
    B_held: bool | None = field(
        default=None,
        metadata=_meta(
            "true: B is a held value (hold = inertia_damping), not fitted in this window; B_se "
            "and B_track are then null; null when withheld"
        ),
    )
    I: float | None = field(metadata=_meta("inertia, kg·m² (N·m·s²/rad)"))  # noqa: E741 - the physical symbol
    I_se: float | None = field(
        metadata=_meta("standard error of I, kg·m² (null when held or not computed)")
    )
    I_held: bool | None = field(
        default=None,
        metadata=_meta(
            "true: I is a held value (median of the stream's full fits over hold_horizon_s, or "
            "estimator.hold_inertia), not fitted in this window; I_se is then null; null when "
            "withheld"
        ),
    )
    vaf: float | None = field(
        metadata=_meta(
            "share of the measured torque's variance in the perturbation's band (above DC up to "
            "the plan's band edge) explained by the published model: I, B, K plus any reflex "
            "torque the slow lane subtracted; window mean removed, trend kept, %"
        )
    )
    ok: bool = field(metadata=_meta("true: I, B, K are usable"))
    reason: Reason | None = field(metadata=_meta("why the estimate is withheld (null when ok)"))
    flags: tuple[Flag, ...] = field(metadata=_meta("warnings on a published estimate"))
    B_track: float | None = field(
        metadata=_meta("tracked damping, N·m·s/rad; null while B is held (hold = inertia_damping)")
    )
    B_track_se: float | None = field(metadata=_meta("standard error of B_track, N·m·s/rad"))
    vaf_irf: float | None = field(metadata=_meta("variance accounted for by the IRF's torque, %"))
    vaf_fit: float | None = field(
        metadata=_meta("variance of the IRF's torque accounted for by the I, B, K model, %")
    )
    lost_samples: int | None = field(
        metadata=_meta(
            "lost samples in the window, bridged by sums over valid samples only (never "
            "interpolated); null when withheld",
            minimum=0,
        )
    )
    seq: int = field(metadata=_meta("estimate counter (0, 1, …)", minimum=0))
    window_start_index: int = field(metadata=_meta("first sample index"))
    window_end_index: int = field(metadata=_meta("last sample index (inclusive)"))
    t_start_s: float = field(metadata=_meta("sample time of the first sample, s (index / fs)"))
    compute_ms: float | None = field(metadata=_meta("time spent identifying the window, ms"))
    latency_ms: float | None = field(
        metadata=_meta("time from the window's last sample to publication, ms")
    )
    reflex_seq: int | None = field(
        default=None,
        metadata=_meta(
            "the slow lane's reflex model whose torque was subtracted before the estimate "
            "(its seq on /reflex); null: none (slow lane off, no model yet, or withheld)"
        ),
    )
    host_time_ns: int = field(metadata=_meta("host UNIX time at publication, ns"))

    @classmethod
    def window_dict(
        cls,
        estimate: WindowEstimate | None,
        reason: Reason | None,
        track: Tracked | None,
        *,
        seq: int,
        first: int,
        last: int,
        fs_hz: float,
        robot: str = "",
        joint: str = "",
        flags: Sequence[Flag] = (),
        compute_ms: float | None = None,
        latency_ms: float | None = None,
        reflex_seq: int | None = None,
    ) -> dict[str, Any]:
        """The JSON object of one window's message: its estimate (None when withheld, with
        ``reason``), the stream's track after it, and the flags the caller adds to the
        estimate's own (e.g. ``over_budget``; ignored when withheld). Keys in field order;
        built as a dict, not as the dataclass (the evaluator publishes one every window, a
        replay builds tens of thousands a minute): the field values in one tuple, made the
        JSON object in one step (:func:`_json_object`), without a call per field."""
        if estimate is not None and track is not None:
            return _estimate_dict(
                estimate,
                track,
                seq,
                first,
                last,
                fs_hz,
                robot,
                joint,
                flags,
                compute_ms,
                latency_ms,
                reflex_seq,
            )
        numbers: tuple[Any, ...] = _NO_NUMBERS
        all_flags: list[Flag] = []
        if estimate is not None:
            numbers, all_flags = _window_numbers(estimate), [*estimate.flags, *flags]
        else:
            reflex_seq = None
        i, b, k, i_se, b_se, k_se, vaf, vaf_irf, vaf_fit, lost, i_held, b_held = numbers
        tracked: tuple[Any, ...] = (None,) * 4
        if track is not None:
            tracked = (track.K, track.K_se, track.B, track.B_se)
        k_track, k_track_se, b_track, b_track_se = tracked
        values = (
            robot,
            joint,
            last / fs_hz,
            k_track,
            k_track_se,
            k,
            k_se,
            b,
            b_se,
            b_held,
            i,
            i_se,
            i_held,
            vaf,
            estimate is not None,
            reason,
            all_flags,
            b_track,
            b_track_se,
            vaf_irf,
            vaf_fit,
            lost,
            seq,
            first,
            last,
            first / fs_hz,
            compute_ms,
            latency_ms,
            reflex_seq,
            time.time_ns(),
        )
        return _json_object(values)  # the number fields finite or None: JSON has no NaN

    def as_dict(self) -> dict[str, Any]:
        """The JSON object: non-finite numbers as ``None``, flags as a list."""
        out = _json_object(_estimate_values(self))
        out["flags"] = list(self.flags)
        return out


def _estimate_dict(
    e: WindowEstimate,
    track: Tracked,
    seq: int,
    first: int,
    last: int,
    fs_hz: float,
    robot: str,
    joint: str,
    flags: Sequence[Flag],
    compute_ms: float | None,
    latency_ms: float | None,
    reflex_seq: int | None,
) -> dict[str, Any]:
    """:meth:`EstimateMessage.window_dict` of an estimate and its track: its field values in
    one tuple, made the JSON object by :func:`_json_object` (tests/io/test_messages.py holds it
    to the dataclass's JSON object)."""
    return _json_object(
        (
            robot,
            joint,
            last / fs_hz,
            track.K,
            track.K_se,
            e.K,
            e.K_se,
            e.B,
            e.B_se,
            e.B_held,
            e.I,
            e.I_se,
            e.I_held,
            e.vaf,
            True,
            None,
            [*e.flags, *flags],
            track.B,
            track.B_se,
            e.vaf_irf,
            e.vaf_fit,
            e.lost_samples,
            seq,
            first,
            last,
            first / fs_hz,
            compute_ms,
            latency_ms,
            reflex_seq,
            time.time_ns(),
        )
    )


def _json_object_reference(values: Sequence[Any]) -> dict[str, Any]:
    """An estimate message's field values as its JSON object: non-finite floats (JSON has no
    NaN) as None."""
    isfinite = math.isfinite
    return {
        name: None if isinstance(value, float) and not isfinite(value) else value
        for name, value in zip(_ESTIMATE_NAMES, values, strict=True)
    }


def _json_object(values: Sequence[Any]) -> dict[str, Any]:
    """:func:`_json_object_reference` of a tuple of values, in one compiled call when the
    kernel was built (``finite_dict``: the dict sized once for its 30 keys; a dict display
    that long is built as two dicts merged)."""
    if _FINITE_DICT is not None and type(values) is tuple:
        return _FINITE_DICT(_ESTIMATE_NAMES, values)
    return _json_object_reference(values)


#: The estimate message's field names, in order (the JSON keys, the CSV columns).
_ESTIMATE_NAMES = tuple(f.name for f in dataclasses.fields(EstimateMessage))
_FINITE_DICT = getattr(compiled_kernel(), "finite_dict", None)
#: An estimate message's field values, in that order.
_estimate_values = operator.attrgetter(*_ESTIMATE_NAMES)

#: What an estimate message takes from the window's estimate (None when withheld).
_WINDOW_NUMBERS = (
    "I",
    "B",
    "K",
    "I_se",
    "B_se",
    "K_se",
    "vaf",
    "vaf_irf",
    "vaf_fit",
    "lost_samples",
    "I_held",
    "B_held",
)
_window_numbers = operator.attrgetter(*_WINDOW_NUMBERS)
_NO_NUMBERS = (None,) * len(_WINDOW_NUMBERS)


def _fields_as_json(message: Any) -> dict[str, Any]:
    """A message dataclass's fields as a dict, non-finite top-level numbers as ``None``."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(message):
        value = getattr(message, f.name)
        out[f.name] = None if isinstance(value, float) and not math.isfinite(value) else value
    return out


def _json_type(annotation: Any) -> dict[str, Any]:
    """The JSON-schema type of a field annotation (str, int, float, bool, enums, optional)."""
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        schema = _json_type(inner[0])
        kind = schema.get("type")
        if "enum" in schema:
            return {**schema, "type": [kind, "null"], "enum": [*schema["enum"], None]}
        return {**schema, "type": [kind, "null"]}
    if typing.get_origin(annotation) is tuple:
        return {"type": "array", "items": _json_type(args[0])}
    if isinstance(annotation, type) and issubclass(annotation, Reason | Flag):
        return {"type": "string", "enum": [m.value for m in annotation]}
    if typing.get_origin(annotation) is list:
        return {"type": "array", "items": _json_type(args[0])}
    if typing.get_origin(annotation) is dict:
        return {"type": "object"}
    names = {str: "string", int: "integer", float: "number", bool: "boolean"}
    return {"type": names[annotation]}


def schema_of(
    cls: type,
    schema_id: str,
    *,
    required: Sequence[str] | None = None,
    additional: bool = False,
) -> dict[str, Any]:
    """The JSON schema of a message dataclass (default: every field without a default
    required, no other keys).

    Enum-valued fields list their members, each described in the field's description.
    """
    hints = typing.get_type_hints(cls)
    properties: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        meta = dict(f.metadata)
        description = meta.pop("description")
        vocabulary = _vocabulary(hints[f.name])
        if vocabulary:
            description += ": " + "; ".join(f"{m.value} ({m.description})" for m in vocabulary)
        properties[f.name] = {**_json_type(hints[f.name]), **meta, "description": description}
    return {
        "$schema": DRAFT,
        "$id": schema_id,
        "title": schema_id,
        "description": (cls.__doc__ or "").strip(),
        "type": "object",
        "properties": properties,
        "required": _without_default(cls) if required is None else list(required),
        "additionalProperties": additional,
    }


def _without_default(cls: type) -> list[str]:
    """Fields a message must carry: those without a default (added later ones have one, so
    messages of older recordings stay valid)."""
    return [
        f.name
        for f in dataclasses.fields(cls)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]


def _vocabulary(annotation: Any) -> list[Any]:
    for arg in (annotation, *typing.get_args(annotation)):
        if isinstance(arg, type) and issubclass(arg, Reason | Flag):
            return list(arg)
    return []


#: The estimate message's schema, generated from :class:`EstimateMessage`.
ESTIMATE_SCHEMA: dict[str, Any] = schema_of(EstimateMessage, "rtsid.Estimate")


def _counters(description: str, names: Sequence[str]) -> dict[str, Any]:
    return {
        "description": description,
        "properties": {
            n: {"type": ["integer", "number", "boolean", "string", "null"]} for n in names
        },
        "additionalProperties": True,
    }


#: The acquisition's counters, from the type that holds them (so the schema cannot drift),
#: plus the logger's own count of sample rows the ring overwrote before it read them.
ACQUISITION_COUNTERS = (
    *(f.name for f in dataclasses.fields(LinkCounters)),
    "logger_overwritten",
)
_WORKER = {
    "description": "window worker counters (WorkerCounters)",
    "properties": {
        **{n: {"type": "integer"} for n in ("estimates", "overruns", "deadline_misses")},
        "withheld": {
            "type": "object",
            "description": "withheld windows by reason",
            "additionalProperties": {"type": "integer"},
        },
    },
    "additionalProperties": True,
}
_MCAP = {
    "description": "MCAP logger: McapLogger.stats()",
    "properties": {
        "state": {"type": "string"},
        "file": {"type": ["string", "null"]},
        "bytes": {"type": "integer"},
        "written": {"type": "integer"},
        "dropped": {"type": "integer"},
        "lost": {"type": "integer"},
        "errors": {"type": "integer"},
        "last_error": {"type": ["string", "null"]},
    },
    "additionalProperties": True,
}
_ZENOH = {
    "description": "zenoh publisher: ZenohPublisher.stats()",
    "properties": {
        "state": {"type": "string"},
        "published": {"type": "integer"},
        "errors": {"type": "integer"},
        "last_error": {"type": ["string", "null"]},
    },
    "additionalProperties": True,
}


_SLOW_LANE = {
    "description": "slow lane (reflex model) counters, SlowLaneCounters; null when it is off",
    "properties": {
        "mode": {"type": "string"},
        **{n: {"type": "integer"} for n in ("fits", "applied", "failed", "worker_restarts")},
        "last_seq": {"type": ["integer", "null"]},
        "last_fit_ms": {"type": ["number", "null"]},
        "last_error": {"type": ["string", "null"]},
    },
    "additionalProperties": True,
}


_SESSION = {
    "description": "session and markers (SessionCounters): subject, session, condition, "
    "condition_changes, markers recorded by source, markers refused (inbox full, bad label, "
    "not written) and duplicates (a resent marker_id, acknowledged again, recorded once); "
    "null from daemons before sessions",
    "properties": {
        **{n: {"type": "string"} for n in ("subject", "session", "condition")},
        **{
            n: {"type": "integer"}
            for n in ("condition_changes", "markers", "refused", "duplicates", "wire_dropped")
        },
        "markers_by_source": {"type": "object", "additionalProperties": {"type": "integer"}},
        "refused_by_reason": {"type": "object", "additionalProperties": {"type": "integer"}},
    },
    "additionalProperties": True,
}


@dataclass(frozen=True, slots=True)
class StatusMessage:
    """Health of the daemon, 1–2 Hz. Counters are totals since start."""

    robot: str = field(metadata=_meta("robot name from the config"))
    joint: str = field(metadata=_meta("joint name from the config"))
    host_time_ns: int = field(metadata=_meta("host UNIX time, ns"))
    uptime_s: float = field(metadata=_meta("s since the daemon started"))
    cpu_percent: float | None = field(
        metadata=_meta("daemon CPU over the last status period, % of one core")
    )
    rss_mb: float | None = field(metadata=_meta("resident memory, MiB"))
    # nested objects: their schema (description included) is the field's metadata
    acquisition: dict[str, Any] = field(
        metadata=_counters("link / acquisition counters (LinkCounters)", ACQUISITION_COUNTERS)
    )
    worker: dict[str, Any] = field(metadata=_WORKER)
    mcap: dict[str, Any] = field(metadata=_MCAP)
    zenoh: dict[str, Any] = field(metadata=_ZENOH)
    slow_lane: dict[str, Any] | None = field(default=None, metadata=_SLOW_LANE)
    session: dict[str, Any] | None = field(default=None, metadata=_SESSION)

    def as_dict(self) -> dict[str, Any]:
        """The JSON object (non-finite top-level numbers as ``None``)."""
        return _fields_as_json(self)


#: The status message's schema, generated from :class:`StatusMessage`. Readers of older
#: recordings may meet statuses with fewer parts: only the identity keys are required.
STATUS_SCHEMA: dict[str, Any] = schema_of(
    StatusMessage,
    "rtsid.Status",
    required=("robot", "joint", "host_time_ns", "uptime_s"),
    additional=True,
)


@dataclass(frozen=True, slots=True)
class ReflexMessage:
    """One slow-lane fit: the reflex pathway over the last horizon, and whether the fast lane
    subtracts it."""

    robot: str = field(metadata=_meta("robot name from the config"))
    joint: str = field(metadata=_meta("joint name from the config"))
    seq: int = field(metadata=_meta("fit number on the schedule (data end / update)"))
    start_index: int = field(metadata=_meta("first sample index of the data fitted"))
    end_index: int = field(metadata=_meta("sample index after the last sample fitted"))
    applies_from_index: int = field(
        metadata=_meta("windows ending at or after this sample index use this fit")
    )
    ok: bool = field(metadata=_meta("true: a reflex pathway was fitted"))
    applied: bool = field(
        metadata=_meta(
            "the decision: true when a reflex pathway is present in the data and the fast lane "
            "subtracts it (it adds at least min_vaf_gain_percent over the horizon and "
            "window_vaf_gain >= min_window_vaf_gain_percent); false: absent, nothing subtracted"
        )
    )
    variant: str = field(metadata=_meta("reflex pathway: rect or hammerstein"))
    gain: float | None = field(
        metadata=_meta("reflex gain of the delayed low-pass fitted to the IRF, N·m·s/rad")
    )
    delay_ms: float | None = field(metadata=_meta("reflex delay, ms"))
    corner_hz: float | None = field(metadata=_meta("corner of the reflex low-pass, Hz"))
    damping_ratio: float | None = field(metadata=_meta("damping ratio of the reflex low-pass"))
    dynamics_vaf: float | None = field(
        metadata=_meta("VAF of the IRF by the delayed low-pass, % (low: gain/delay unreliable)")
    )
    irf_gain: float | None = field(metadata=_meta("area of the reflex IRF, N·m·s/rad"))
    rank: int | None = field(metadata=_meta("IRF components kept by the MDL criterion"))
    vaf_total: float | None = field(metadata=_meta("VAF of the cascade, %"))
    vaf_intrinsic_only: float | None = field(
        metadata=_meta("VAF of an intrinsic IRF fitted alone, %")
    )
    vaf_intrinsic_path: float | None = field(metadata=_meta("VAF by the intrinsic pathway, %"))
    vaf_reflex_path: float | None = field(metadata=_meta("VAF by the reflex pathway, %"))
    iterations: int = field(metadata=_meta("alternations of the cascade"))
    window_vaf_gain: float | None = field(
        metadata=_meta(
            "evidence for the decision: median over the horizon's 300 ms windows of the VAF "
            "(percentage points, 40 Hz basis) the reflex model adds to each window's own "
            "least-squares I, B, K"
        )
    )
    windows_improved: float | None = field(
        metadata=_meta("share of those windows whose VAF the reflex model raises, 0-1")
    )
    irf_fs_hz: float | None = field(metadata=_meta("rate of the IRF lags, Hz"))
    irf: list[float] = field(
        metadata=_meta("reflex IRF, lags 0, 1/irf_fs_hz, …, N·m per rad/s per s")
    )
    fit_ms: float | None = field(metadata=_meta("time the fit took, ms (null in a replay)"))
    error: str | None = field(metadata=_meta("why there is no reflex pathway (null when ok)"))
    host_time_ns: int = field(metadata=_meta("host UNIX time at publication, ns"))

    @classmethod
    def of(
        cls,
        update: ReflexUpdate,
        *,
        robot: str,
        joint: str,
        variant: str,
        applies_from_index: int,
        fit_ms: float | None,
    ) -> ReflexMessage:
        """The message of one slow-lane fit."""
        p = update.pathway
        d = p.dynamics if p is not None else None
        return cls(
            robot=robot,
            joint=joint,
            seq=update.seq,
            start_index=update.start_index,
            end_index=update.end_index,
            applies_from_index=applies_from_index,
            ok=p is not None,
            applied=update.applied,
            variant=variant,
            gain=d.gain if d else None,
            delay_ms=d.delay_s * 1e3 if d else None,
            corner_hz=d.corner_hz if d else None,
            damping_ratio=d.damping_ratio if d else None,
            dynamics_vaf=d.vaf if d else None,
            irf_gain=p.irf_gain if p else None,
            rank=p.rank if p else None,
            vaf_total=update.vaf_total,
            vaf_intrinsic_only=update.vaf_intrinsic_only,
            vaf_intrinsic_path=update.vaf_intrinsic_path,
            vaf_reflex_path=update.vaf_reflex_path,
            iterations=update.iterations,
            window_vaf_gain=update.window_vaf_gain,
            windows_improved=update.windows_improved,
            irf_fs_hz=p.fs_hz if p else None,
            irf=[float(v) for v in p.irf] if p else [],
            fit_ms=fit_ms,
            error=update.error,
            host_time_ns=time.time_ns(),
        )

    def as_dict(self) -> dict[str, Any]:
        """The JSON object (non-finite top-level numbers as ``None``)."""
        return _fields_as_json(self)


#: The reflex message's schema, generated from :class:`ReflexMessage`.
REFLEX_SCHEMA: dict[str, Any] = schema_of(ReflexMessage, "rtsid.Reflex")


#: Longest marker label, characters (a trial name, not a note).
MAX_LABEL_CHARS = 200
#: Longest marker id, characters.
MAX_MARKER_ID_CHARS = 64
#: Where a marker came from.
MARKER_SOURCES = ("zenoh", "wire")


@dataclass(frozen=True, slots=True, kw_only=True)
class SessionMessage:
    """Who is measured and under what condition, from a sample on: written at the start of
    every recording part and on every change of condition (``rtsid condition``)."""

    robot: str = field(metadata=_meta("robot name from the config"))
    joint: str = field(metadata=_meta("joint name from the config"))
    t_s: float = field(metadata=_meta("sample time the session state holds from, s"))
    sample_index: int = field(metadata=_meta("sample index it holds from"))
    subject: str = field(metadata=_meta("subject ([session] subject, --subject)", maxLength=64))
    session: str = field(metadata=_meta("session of that subject", maxLength=64))
    condition: str = field(metadata=_meta("condition the subject is in", maxLength=64))
    host_time_ns: int = field(metadata=_meta("host UNIX time, ns"))

    def as_dict(self) -> dict[str, Any]:
        """The JSON object."""
        return _fields_as_json(self)


#: The session message's schema, generated from :class:`SessionMessage`.
SESSION_SCHEMA: dict[str, Any] = schema_of(SessionMessage, "rtsid.Session")


@dataclass(frozen=True, slots=True, kw_only=True)
class MarkerMessage:
    """A trial marker: a label on one sample (``rtsid mark``, a zenoh put, or the wire)."""

    robot: str = field(metadata=_meta("robot name from the config"))
    joint: str = field(metadata=_meta("joint name from the config"))
    t_s: float = field(metadata=_meta("sample time of the marked sample, s (index / fs)"))
    sample_index: int = field(metadata=_meta("the marked sample's index"))
    label: str = field(
        metadata=_meta(
            "what the marker says, e.g. 'trial 3 start' (plain text, never markup)",
            maxLength=MAX_LABEL_CHARS,
        )
    )
    source: str = field(
        metadata=_meta(
            "zenoh (rtsid mark, or a put on .../mark/in) or wire (a marker frame or datagram)",
            enum=list(MARKER_SOURCES),
        )
    )
    marker_id: str = field(
        metadata=_meta(
            "the sender's id for this marker (a resent marker keeps it, so readers drop "
            "duplicates), or one the daemon made",
            maxLength=MAX_MARKER_ID_CHARS,
        )
    )
    host_time_ns: int = field(metadata=_meta("host UNIX time the daemon took the marker, ns"))

    def as_dict(self) -> dict[str, Any]:
        """The JSON object."""
        return _fields_as_json(self)


#: The marker message's schema, generated from :class:`MarkerMessage`.
MARKER_SCHEMA: dict[str, Any] = schema_of(MarkerMessage, "rtsid.Marker")
