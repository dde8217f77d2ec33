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
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from rtsid.link.acquisition import LinkCounters
from rtsid.verdicts import Flag, Reason

__all__ = ["ESTIMATE_SCHEMA", "STATUS_SCHEMA", "EstimateMessage", "StatusMessage", "schema_of"]

DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _meta(text: str, **schema: Any) -> dict[str, Any]:
    """A field's description (and any extra schema keywords), its dataclass metadata."""
    return {"description": text, **schema}


@dataclass(frozen=True, slots=True)
class EstimateMessage:
    """One identification window: I, B, K of tau = I*ddq + B*dq + K*q, or why not."""

    robot: str = field(metadata=_meta("robot name from the config"))
    joint: str = field(metadata=_meta("joint name from the config"))
    seq: int = field(metadata=_meta("estimate counter (0, 1, …)", minimum=0))
    window_start_index: int = field(metadata=_meta("first sample index"))
    window_end_index: int = field(metadata=_meta("last sample index (inclusive)"))
    t_start_s: float = field(metadata=_meta("sample time of the first sample, s (index / fs)"))
    t_end_s: float = field(metadata=_meta("sample time of the last sample, s"))
    I: float | None = field(metadata=_meta("inertia, kg·m² (N·m·s²/rad)"))  # noqa: E741 - the physical symbol
    B: float | None = field(metadata=_meta("damping, N·m·s/rad"))
    K: float | None = field(metadata=_meta("stiffness, N·m/rad"))
    I_se: float | None = field(
        metadata=_meta("standard error of I, kg·m² (null when held or not computed)")
    )
    B_se: float | None = field(metadata=_meta("standard error of B, N·m·s/rad (null when held)"))
    K_se: float | None = field(metadata=_meta("standard error of K, N·m/rad"))
    K_track: float | None = field(
        metadata=_meta(
            "tracked stiffness now (causal Kalman filter over the windows, rtsid.ident.tracker;"
            " a withheld window advances the prediction), N·m/rad; null before the first "
            "estimate or with the tracker off"
        )
    )
    K_track_se: float | None = field(metadata=_meta("standard error of K_track, N·m/rad"))
    B_track: float | None = field(
        metadata=_meta("tracked damping, N·m·s/rad; null while B is held (hold = inertia_damping)")
    )
    B_track_se: float | None = field(metadata=_meta("standard error of B_track, N·m·s/rad"))
    vaf: float | None = field(
        metadata=_meta(
            "variance of the measured torque (analysed band) accounted for by the I, B, K model, %"
        )
    )
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
    compute_ms: float | None = field(metadata=_meta("time spent identifying the window, ms"))
    latency_ms: float | None = field(
        metadata=_meta("time from the window's last sample to publication, ms")
    )
    ok: bool = field(metadata=_meta("true: I, B, K are usable"))
    reason: Reason | None = field(metadata=_meta("why the estimate is withheld (null when ok)"))
    flags: tuple[Flag, ...] = field(metadata=_meta("warnings on a published estimate"))
    host_time_ns: int = field(metadata=_meta("host UNIX time at publication, ns"))

    def as_dict(self) -> dict[str, Any]:
        """The JSON object: non-finite numbers as ``None``, flags as a list."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                value = None
            out[f.name] = list(value) if f.name == "flags" else value
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
    """The JSON schema of a message dataclass (default: every field required, no other keys).

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
        "required": list(properties) if required is None else list(required),
        "additionalProperties": additional,
    }


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
        "properties": {n: {"type": ["integer", "number", "boolean", "null"]} for n in names},
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

    def as_dict(self) -> dict[str, Any]:
        """The JSON object (non-finite top-level numbers as ``None``)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = None if isinstance(value, float) and not math.isfinite(value) else value
        return out


#: The status message's schema, generated from :class:`StatusMessage`. Readers of older
#: recordings may meet statuses with fewer parts: only the identity keys are required.
STATUS_SCHEMA: dict[str, Any] = schema_of(
    StatusMessage,
    "rtsid.Status",
    required=("robot", "joint", "host_time_ns", "uptime_s"),
    additional=True,
)
