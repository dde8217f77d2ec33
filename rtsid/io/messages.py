"""Typed messages: one dataclass per channel, its JSON schema generated from the type.

The estimate message is built as an :class:`EstimateMessage` (the worker, replay) and goes out
as its :meth:`EstimateMessage.as_dict` — the JSON object described by
:data:`ESTIMATE_SCHEMA`, which is generated here from the fields, their types and
descriptions, and the closed vocabularies of :mod:`rtsid.verdicts` (a reason outside
:class:`~rtsid.verdicts.Reason` or a flag outside :class:`~rtsid.verdicts.Flag` cannot be
declared without being emitted, or emitted without being declared).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any

from rtsid.verdicts import Flag, Reason

__all__ = ["ESTIMATE_SCHEMA", "EstimateMessage", "schema_of"]

DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _doc(text: str, **schema: Any) -> Any:
    """A field's description (and any extra schema keywords) as dataclass metadata."""
    return field(metadata={"description": text, **schema})


@dataclass(frozen=True, slots=True)
class EstimateMessage:
    """One identification window: I, B, K of tau = I*ddq + B*dq + K*q, or why not."""

    robot: str = _doc("robot name from the config")
    joint: str = _doc("joint name from the config")
    seq: int = _doc("estimate counter (0, 1, …)", minimum=0)
    window_start_index: int = _doc("first sample index")
    window_end_index: int = _doc("last sample index (inclusive)")
    t_start_s: float = _doc("sample time of the first sample, s (index / fs)")
    t_end_s: float = _doc("sample time of the last sample, s")
    I: float | None = _doc("inertia, kg·m² (N·m·s²/rad)")  # noqa: E741 - the physical symbol
    B: float | None = _doc("damping, N·m·s/rad")
    K: float | None = _doc("stiffness, N·m/rad")
    I_se: float | None = _doc("standard error of I, kg·m² (null when held or not computed)")
    B_se: float | None = _doc("standard error of B, N·m·s/rad (null when held)")
    K_se: float | None = _doc("standard error of K, N·m/rad")
    vaf: float | None = _doc(
        "variance of the measured torque (analysed band) accounted for by the I, B, K model, %"
    )
    vaf_irf: float | None = _doc("variance accounted for by the IRF's torque, %")
    vaf_fit: float | None = _doc(
        "variance of the IRF's torque accounted for by the I, B, K model, %"
    )
    lost_samples: int | None = _doc(
        "lost samples in the window, bridged by sums over valid samples only (never "
        "interpolated); null when withheld",
        minimum=0,
    )
    compute_ms: float | None = _doc("time spent identifying the window, ms")
    latency_ms: float | None = _doc("time from the window's last sample to publication, ms")
    ok: bool = _doc("true: I, B, K are usable")
    reason: Reason | None = _doc("why the estimate is withheld (null when ok)")  # noqa: RUF009
    flags: tuple[Flag, ...] = _doc("warnings on a published estimate")
    host_time_ns: int = _doc("host UNIX time at publication, ns")

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
    names = {str: "string", int: "integer", float: "number", bool: "boolean"}
    return {"type": names[annotation]}


def schema_of(cls: type, schema_id: str) -> dict[str, Any]:
    """The JSON schema of a message dataclass: every field required, no other keys.

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
        "required": list(properties),
        "additionalProperties": False,
    }


def _vocabulary(annotation: Any) -> list[Any]:
    for arg in (annotation, *typing.get_args(annotation)):
        if isinstance(arg, type) and issubclass(arg, Reason | Flag):
            return list(arg)
    return []


#: The estimate message's schema, generated from :class:`EstimateMessage`.
ESTIMATE_SCHEMA: dict[str, Any] = schema_of(EstimateMessage, "rtsid.Estimate")
