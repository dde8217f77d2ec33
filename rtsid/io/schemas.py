"""The JSON payloads rtsid publishes over zenoh and logs to MCAP, with their JSON schemas.

One place for every message layout (documented with examples in ``docs/io.md``):

========== ====================================== ========================================
payload    zenoh key / MCAP topic                 rate
========== ====================================== ========================================
estimate   ``rtsid/<robot>/<joint>/estimate``     one per window (every hop, 50 Hz default)
           ``/estimate``
samples    ``rtsid/<robot>/<joint>/samples``      batches of raw samples (≈ 10 Hz)
           ``/samples``
status     ``rtsid/<robot>/<joint>/status``       1–2 Hz
           ``/status``
can_frames ``/can_frames`` (MCAP only, optional)  batches of raw CAN frames
session    ``rtsid/<robot>/<joint>/session``      at the start of each part, on a condition
           ``/session``                           change (and the zenoh queryable)
marker     ``rtsid/<robot>/<joint>/marker``       one per trial marker
           ``/marker``
========== ====================================== ========================================

All values are SI (rad, N·m, s, kg·m², N·m·s/rad, N·m/rad); JSON has no NaN, so a missing or
non-finite number is ``null``. Foxglove reads the MCAP channels with schema encoding
``jsonschema`` and message encoding ``json`` (one estimate per message, so its Plot panel can
plot ``/estimate.K`` against time).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtsid.errors import InputDataError
from rtsid.ident.levinson import compiled_kernel
from rtsid.io.messages import (
    ESTIMATE_SCHEMA,
    MARKER_SCHEMA,
    REFLEX_SCHEMA,
    SESSION_SCHEMA,
    STATUS_SCHEMA,
)
from rtsid.verdicts import Reason

__all__ = [
    "CAN_FRAMES_SCHEMA",
    "ESTIMATE_FIELDS",
    "ESTIMATE_SCHEMA",
    "MARKER_SCHEMA",
    "REFLEX_SCHEMA",
    "SAMPLES_SCHEMA",
    "SCHEMAS",
    "SESSION_SCHEMA",
    "STATUS_SCHEMA",
    "WITHHELD_REASONS",
    "SampleBatch",
    "compact_sample_rows",
    "decode_samples",
    "decode_samples_into",
    "decode_samples_json",
    "encode_can_frames",
    "encode_estimate",
    "encode_estimate_reference",
    "encode_json",
    "encode_samples",
    "encode_status",
    "estimate_payload",
    "json_safe",
]

DRAFT = "https://json-schema.org/draft/2020-12/schema"

#: Short machine-readable reasons for a withheld (``ok: false``) estimate.
WITHHELD_REASONS: tuple[str, ...] = tuple(Reason)

_NUMBER_OR_NULL = {"type": ["number", "null"]}


def _num(description: str) -> dict[str, Any]:
    return {**_NUMBER_OR_NULL, "description": description}


#: Keys of an estimate message, in schema order.
ESTIMATE_FIELDS: tuple[str, ...] = tuple(ESTIMATE_SCHEMA["properties"])
#: Keys an estimate message must have (later additions default to null).
_REQUIRED: tuple[str, ...] = tuple(ESTIMATE_SCHEMA["required"])

SAMPLES_SCHEMA: dict[str, Any] = {
    "$schema": DRAFT,
    "$id": "rtsid.Samples",
    "title": "rtsid.Samples",
    "description": "Consecutive raw samples; index i of each array is sample first_index + i. "
    "Rows of lost samples are kept with valid = false and null values.",
    "type": "object",
    "properties": {
        "first_index": {"type": "integer", "description": "sample index of the first row"},
        "fs_hz": {"type": "number", "exclusiveMinimum": 0, "description": "sample rate, Hz"},
        "t_first_s": {"type": "number", "description": "sample time of the first row, s"},
        "position_rad": {"type": "array", "items": _NUMBER_OR_NULL, "description": "rad"},
        "torque_nm": {"type": "array", "items": _NUMBER_OR_NULL, "description": "N·m"},
        "valid": {"type": "array", "items": {"type": "boolean"}},
        "status": {
            "type": "array",
            "items": {"type": "integer"},
            "description": "per-sample status bits from the link (0 = nominal)",
        },
    },
    "additionalProperties": False,
}
SAMPLES_SCHEMA["required"] = list(SAMPLES_SCHEMA["properties"])


CAN_FRAMES_SCHEMA: dict[str, Any] = {
    "$schema": DRAFT,
    "$id": "rtsid.CanFrames",
    "title": "rtsid.CanFrames",
    "description": "A batch of raw CAN frames as received (before decoding).",
    "type": "object",
    "properties": {
        "frames": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "timestamp_s": {"type": "number", "description": "receive time, s"},
                    "arbitration_id": {"type": "integer"},
                    "is_extended_id": {"type": "boolean"},
                    "is_error_frame": {"type": "boolean"},
                    "data_hex": {"type": "string", "description": "payload bytes as hex"},
                },
                "required": [
                    "timestamp_s",
                    "arbitration_id",
                    "is_extended_id",
                    "is_error_frame",
                    "data_hex",
                ],
            },
        }
    },
    "required": ["frames"],
    "additionalProperties": False,
}

#: name -> (schema, MCAP topic); the zenoh key is ``<prefix>/<robot>/<joint>/<name>``.
SCHEMAS: dict[str, tuple[dict[str, Any], str]] = {
    "samples": (SAMPLES_SCHEMA, "/samples"),
    "estimate": (ESTIMATE_SCHEMA, "/estimate"),
    "status": (STATUS_SCHEMA, "/status"),
    "reflex": (REFLEX_SCHEMA, "/reflex"),
    "can_frames": (CAN_FRAMES_SCHEMA, "/can_frames"),
    "session": (SESSION_SCHEMA, "/session"),
    "marker": (MARKER_SCHEMA, "/marker"),
}


def json_safe(value: Any) -> Any:
    """Recursively convert ``value`` to plain JSON types: NaN/±inf → None, numpy → Python.

    Parameters
    ----------
    value : Any
        Scalars, numpy scalars/arrays, mappings, sequences.

    Returns
    -------
    Any
        Something :func:`json.dumps` accepts with ``allow_nan=False``.
    """
    if isinstance(value, bool) or value is None or isinstance(value, str | int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, np.ndarray):
        return _array_to_list(value)
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, Iterable):
        return [json_safe(v) for v in value]
    raise InputDataError(
        f"cannot encode {type(value).__name__} {value!r} as JSON; pass numbers, strings, "
        "lists or dicts"
    )


def _array_to_list(array: np.ndarray) -> list[Any]:
    """1-D float array → list with None where the value is not finite (no per-element Python
    checks unless there is something to replace)."""
    if array.dtype.kind == "f":
        out = array.tolist()
        bad = np.flatnonzero(~np.isfinite(array.reshape(-1)))
        if bad.size and array.ndim == 1:
            for i in bad.tolist():
                out[i] = None
        elif bad.size:
            return json_safe(out)  # nested lists: slow path, rare
        return out
    return array.tolist()


def encode_json(message: Any) -> bytes:
    """Compact UTF-8 JSON of ``message`` after :func:`json_safe` (no NaN ever reaches JSON)."""
    return json.dumps(json_safe(message), separators=(",", ":"), allow_nan=False).encode()


def encode_estimate(message: Mapping[str, Any]) -> bytes:
    """Encode one estimate message (keys of :data:`ESTIMATE_FIELDS`; the optional ones, added
    after the first release, may be missing and are written as null).

    The bytes are :func:`encode_estimate_reference`'s, byte for byte, by a shorter way for
    the usual message (plain Python values, every number finite): see
    :func:`estimate_payload`.

    Parameters
    ----------
    message : Mapping
        The estimate; numbers may be numpy scalars and may be NaN (encoded as null).

    Returns
    -------
    bytes
        UTF-8 JSON in schema order.

    Raises
    ------
    InputDataError
        A missing or unknown key (names it), or a value that cannot be JSON.
    """
    return estimate_payload(message)[0]


def estimate_payload(message: Mapping[str, Any]) -> tuple[bytes, bool]:
    """:func:`encode_estimate`'s bytes, and whether they decode to ``message``'s own values.

    The usual message (a dict with every key of :data:`ESTIMATE_FIELDS` in schema order,
    plain Python values, every number finite, as the window worker builds it) is written by
    the compiled kernel's ``estimate_json`` in one call (a float by its own repr, texts as
    json's ASCII encoder writes them: the reference's bytes; 89 k instructions a message
    against 146 k), which declines anything else (a non-finite number, numpy integers,
    mappings, another key order). Without it (the numpy path) or when it declines, the
    message goes to one compact ``json`` C encoder made once: two thirds of the reference's
    cost, which goes on every value's type check and, in ``json.dumps``, on building an
    encoder per call. The bytes are the reference's: that encoder refuses what is not plain
    (numpy values: a TypeError) and writes a non-finite number as ``NaN``/``Infinity`` and a
    mapping as ``{…}`` (whose keys :func:`json_safe` would have made texts), so a text holding
    either word or a second brace is encoded again by :func:`encode_estimate_reference` — as
    is a message in another key order or without the optional keys.

    Returns
    -------
    payload : bytes
        UTF-8 JSON in schema order.
    plain : bool
        ``json.loads(payload)`` holds ``message``'s values (equal as JSON values): a reader of
        the payload (the summary table) may take ``message`` instead of decoding it.

    Raises
    ------
    InputDataError
        As :func:`encode_estimate`.
    """
    if _ESTIMATE_JSON is not None and type(message) is dict:
        reason = message.get("reason")
        if reason is None or isinstance(reason, str):  # another reason: refused below
            compiled = _ESTIMATE_JSON(message, ESTIMATE_FIELDS, _ESTIMATE_PREFIXES)
            if compiled is not None:
                return compiled, True
    if type(message) is dict and tuple(message) == ESTIMATE_FIELDS:
        reason = message["reason"]
        if reason is not None and not isinstance(reason, str):
            _check_estimate_keys(message)  # raises
        try:
            text = _encode_plain(message)
        except (TypeError, ValueError, RecursionError):  # numpy values: the reference
            text = ""
        if text.count("{") == 1 and "NaN" not in text and "Infinity" not in text:
            return text.encode(), True
    return encode_estimate_reference(message), False


#: The compiled estimate encoder (``_eureka.estimate_json``; None on the numpy path): the
#: message's values written as ``json.dumps`` writes them, each key's ``{"key":`` or
#: ``,"key":`` from :data:`_ESTIMATE_PREFIXES`; it declines (None) what it does not write
#: exactly so (non-finite numbers, escaped texts, numpy integers, another key order).
_ESTIMATE_JSON = getattr(compiled_kernel(), "estimate_json", None)
_ESTIMATE_PREFIXES = tuple(
    ("{" if k == 0 else ",").encode() + json.dumps(name).encode() + b":"
    for k, name in enumerate(ESTIMATE_FIELDS)
)
#: Keys of :data:`ESTIMATE_FIELDS` as a set.
_ESTIMATE_KEYS = frozenset(ESTIMATE_FIELDS)
#: A compact encoder; non-finite numbers it writes as ``NaN``/``Infinity``, which
#: :func:`estimate_payload` looks for.
_PLAIN_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=True)


def _compact_encoder() -> Callable[[Any], str]:
    """:data:`_PLAIN_ENCODER`'s ``encode``, made once: ``JSONEncoder.encode`` builds its
    C encoder (``json.encoder.c_make_encoder``) on every call; without the C encoder
    (another Python), ``encode`` itself."""
    make = getattr(json.encoder, "c_make_encoder", None)
    if make is None:  # pragma: no cover - CPython has it
        return _PLAIN_ENCODER.encode
    e = _PLAIN_ENCODER
    chunks = make(
        None,  # no markers: a circular value recurses until RecursionError (the reference)
        e.default,
        json.encoder.encode_basestring_ascii,
        None,
        e.key_separator,
        e.item_separator,
        e.sort_keys,
        e.skipkeys,
        e.allow_nan,
    )
    return lambda value: "".join(chunks(value, 0))


_encode_plain = _compact_encoder()


def _check_estimate_keys(message: Mapping[str, Any]) -> None:
    """Refuse a message with a missing required key, an unknown key or a non-text reason."""
    if message.keys() != _ESTIMATE_KEYS:
        keys = set(message)
        if not set(_REQUIRED) <= keys <= _ESTIMATE_KEYS:
            missing = sorted(set(_REQUIRED) - keys)
            unknown = sorted(keys - _ESTIMATE_KEYS)
            raise InputDataError(
                f"estimate message has missing keys {missing} and unknown keys {unknown}; "
                f"it must have exactly {list(ESTIMATE_FIELDS)} (see docs/io.md)"
            )
    reason = message["reason"]
    if reason is not None and not isinstance(reason, str):
        raise InputDataError(f"estimate 'reason' = {reason!r}; expected null or a short string")


def encode_estimate_reference(message: Mapping[str, Any]) -> bytes:
    """:func:`encode_estimate` value by value: each number made plain (NaN → null, numpy →
    Python) by :func:`json_safe`, then one ``json.dumps``; the reference its fast path is
    tested against, and the encoder of any message that path does not take.

    Raises
    ------
    InputDataError
        As :func:`encode_estimate`.
    """
    _check_estimate_keys(message)
    out: dict[str, Any] = {}
    for k in ESTIMATE_FIELDS:  # fast path for plain floats; numpy scalars, lists: json_safe
        v = message.get(k)
        if type(v) is float:
            out[k] = v if math.isfinite(v) else None
        elif v is None or type(v) in (int, bool, str):
            out[k] = v
        else:
            out[k] = json_safe(v)
    return json.dumps(out, separators=(",", ":"), allow_nan=False).encode()


def encode_status(message: Mapping[str, Any]) -> bytes:
    """Encode one status message (must have the schema's required keys).

    Raises
    ------
    InputDataError
        A required key is missing (named) or a value cannot be JSON.
    """
    missing = [k for k in STATUS_SCHEMA["required"] if k not in message]
    if missing:
        raise InputDataError(
            f"status message lacks required keys {missing}; see STATUS_SCHEMA (docs/io.md)"
        )
    return encode_json(message)


@dataclass(frozen=True)
class SampleBatch:
    """Consecutive raw samples as logged (rows of lost samples kept, invalid, NaN).

    Attributes
    ----------
    first_index : int
        Sample index of row 0 (sample time = index / fs_hz).
    fs_hz : float
        Sample rate, Hz.
    position_rad, torque_nm : numpy.ndarray, shape (n,), float64
        NaN where a sample was lost or not finite.
    valid : numpy.ndarray, shape (n,), bool
    status : numpy.ndarray, shape (n,), int64
        Per-sample status bits from the link.
    log_time_ns : int
        Host UNIX time the batch was logged, ns (0 when unknown).
    """

    first_index: int
    fs_hz: float
    position_rad: np.ndarray
    torque_nm: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    log_time_ns: int = 0

    def __len__(self) -> int:
        return int(self.position_rad.shape[0])

    @property
    def end_index(self) -> int:
        """Index one past the last row."""
        return self.first_index + len(self)


def _as_1d(name: str, values: Any, dtype: Any) -> np.ndarray:
    array = np.asarray(values, dtype=dtype)
    if array.ndim != 1:
        raise InputDataError(f"samples '{name}' must be 1-D, got shape {array.shape}")
    return array


def encode_samples(
    first_index: int,
    fs_hz: float,
    position_rad: Any,
    torque_nm: Any,
    valid: Any,
    status: Any,
) -> bytes:
    """Encode a batch of consecutive samples.

    Parameters
    ----------
    first_index : int
        Sample index of row 0.
    fs_hz : float
        Sample rate, Hz (> 0).
    position_rad, torque_nm : array_like, shape (n,)
        Values; non-finite become null.
    valid : array_like of bool, shape (n,)
        False for lost/invalid rows; their values are written as null.
    status : array_like of int, shape (n,)
        Per-sample status bits.

    Returns
    -------
    bytes
        UTF-8 JSON following :data:`SAMPLES_SCHEMA`.

    Raises
    ------
    InputDataError
        Arrays of different lengths or not 1-D, or ``fs_hz <= 0``.
    """
    pos = _as_1d("position_rad", position_rad, np.float64)
    tq = _as_1d("torque_nm", torque_nm, np.float64)
    ok = _as_1d("valid", valid, bool)
    st = _as_1d("status", status, np.int64)
    n = pos.shape[0]
    if not (tq.shape[0] == ok.shape[0] == st.shape[0] == n):
        raise InputDataError(
            f"samples arrays differ in length (position {n}, torque {tq.shape[0]}, "
            f"valid {ok.shape[0]}, status {st.shape[0]}); pass one row per sample"
        )
    if not fs_hz > 0:
        raise InputDataError(f"samples fs_hz = {fs_hz!r}; expected a rate > 0 Hz")
    pos_list = _array_to_list(pos)
    tq_list = _array_to_list(tq)
    if not ok.all():
        for i in np.flatnonzero(~ok).tolist():
            pos_list[i] = None
            tq_list[i] = None
    message = {
        "first_index": int(first_index),
        "fs_hz": float(fs_hz),
        "t_first_s": int(first_index) / float(fs_hz),
        "position_rad": pos_list,
        "torque_nm": tq_list,
        "valid": ok.tolist(),
        "status": st.tolist(),
    }
    return json.dumps(message, separators=(",", ":"), allow_nan=False).encode()


def decode_samples(data: bytes | str, log_time_ns: int = 0) -> SampleBatch:
    """Decode a samples payload into numpy arrays (null → NaN).

    A payload in the logger's own compact layout (:func:`encode_samples`) is read by the
    compiled kernel's ``json_array`` (the same doubles as ``json.loads``, bit for bit, about
    ten times faster: what replay spends reading a recording); any other payload, or every
    payload with ``RTSID_NUMPY_ONLY=1``, by ``json.loads``, the reference.

    Raises
    ------
    InputDataError
        Not JSON or not a samples message.
    """
    fast = _decode_compact_samples(data, log_time_ns)
    if fast is not None:
        return fast
    return decode_samples_json(data, log_time_ns)


#: What separates the columns of a compact samples payload, in :func:`encode_samples`'s order.
_COLUMN_SEPARATORS = (b',"position_rad":[', b'],"torque_nm":[', b'],"valid":[', b'],"status":[')
#: Each column's dtype, in :func:`encode_samples`'s order.
_COLUMN_DTYPES = (np.float64, np.float64, np.bool_, np.int64)


def _decode_compact_samples(data: bytes | str, log_time_ns: int) -> SampleBatch | None:
    """A payload in :func:`encode_samples`'s exact layout, read by the compiled kernel into
    columns of its own (:func:`decode_samples_into`); None (the caller reads it with
    ``json.loads``) for anything else, or without the kernel."""
    if _SAMPLES_INTO is None or type(data) is not bytes:
        return None
    rows = compact_sample_rows(data)
    if rows is None:
        return None
    columns = tuple(np.empty(rows, dtype) for dtype in _COLUMN_DTYPES)
    position, torque, valid, status = columns
    done = decode_samples_into(data, position, torque, valid, status, 0)
    if done is None or done[2] != rows:
        return None
    first_index, fs_hz, _ = done
    return SampleBatch(first_index, fs_hz, position, torque, valid, status, int(log_time_ns))


#: The compiled reader of a whole compact payload into preallocated columns
#: (``_eureka.samples_into``; None on the numpy path).
_SAMPLES_INTO = getattr(compiled_kernel(), "samples_into", None)


def decode_samples_into(
    data: bytes,
    position_rad: np.ndarray,
    torque_nm: np.ndarray,
    valid: np.ndarray,
    status: np.ndarray,
    offset: int,
) -> tuple[int, float, int] | None:
    """Decode a payload in :func:`encode_samples`'s compact layout straight into rows
    ``offset …`` of preallocated columns (a reader joining many batches into one block).

    The values are :func:`decode_samples`'s, bit for bit (the compiled kernel's
    ``samples_into``: the conversions of ``json_array``, one call for the whole payload).

    Parameters
    ----------
    data : bytes
        One ``/samples`` payload.
    position_rad, torque_nm : numpy.ndarray, shape (capacity,), float64
    valid : numpy.ndarray, shape (capacity,), bool
    status : numpy.ndarray, shape (capacity,), int64
        The columns, written from row ``offset`` on (rows after it may be written even when
        the payload is declined).
    offset : int
        First row to write.

    Returns
    -------
    (first_index, fs_hz, rows) or None
        None: another layout, more rows than fit after ``offset``, or no compiled kernel
        (numpy path): read the payload with :func:`decode_samples`, which also says what is
        wrong with a damaged one.
    """
    if _SAMPLES_INTO is None or type(data) is not bytes:
        return None
    done: tuple[int, float, int] | None = _SAMPLES_INTO(
        data, position_rad, torque_nm, valid, status, offset
    )
    return done


def compact_sample_rows(data: bytes) -> int | None:
    """Rows of a payload in :func:`encode_samples`'s compact layout, counted by the items of
    its last column (``status``: integers, one a row) without reading its numbers; None for
    any other payload (decode it to count it)."""
    if type(data) is not bytes or not data.endswith(b"]}"):
        return None
    start = data.rfind(_COLUMN_SEPARATORS[-1])
    if start < 0:
        return None
    items = data[start + len(_COLUMN_SEPARATORS[-1]) : len(data) - 2]
    if items.strip(b"0123456789,-"):
        return None  # not a bare list of integers
    return items.count(b",") + 1 if items else 0


def decode_samples_json(data: bytes | str, log_time_ns: int = 0) -> SampleBatch:
    """:func:`decode_samples` by ``json.loads`` alone: the reference (and the reader of any
    payload not in the compact layout).

    Raises
    ------
    InputDataError
        Not JSON or not a samples message.
    """
    try:
        msg = json.loads(data)
        n = len(msg["position_rad"])
        batch = SampleBatch(
            first_index=int(msg["first_index"]),
            fs_hz=float(msg["fs_hz"]),
            position_rad=np.array(msg["position_rad"], dtype=np.float64),
            torque_nm=np.array(msg["torque_nm"], dtype=np.float64),
            valid=np.array(msg["valid"], dtype=bool),
            status=np.array(msg["status"], dtype=np.int64),
            log_time_ns=int(log_time_ns),
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise InputDataError(f"not an rtsid samples message ({exc}); see SAMPLES_SCHEMA") from exc
    columns = (batch.position_rad, batch.torque_nm, batch.valid, batch.status)
    if any(c.shape != (n,) for c in columns):
        raise InputDataError("samples message arrays differ in length; the payload is corrupt")
    return batch


_CAN_ATTRS = ("timestamp", "arbitration_id", "is_extended_id", "is_error_frame", "data")


def encode_can_frames(frames: Iterable[Any]) -> bytes:
    """Encode CAN frames (objects with python-can ``Message`` attributes, or dicts).

    Parameters
    ----------
    frames : iterable
        Each has ``timestamp``, ``arbitration_id``, ``is_extended_id``, ``is_error_frame`` and
        ``data`` (bytes-like), as :class:`can.Message` does.
    """
    out = []
    for f in frames:
        fields = f if isinstance(f, Mapping) else {k: getattr(f, k) for k in _CAN_ATTRS}
        out.append(
            {
                "timestamp_s": float(fields["timestamp"]),
                "arbitration_id": int(fields["arbitration_id"]),
                "is_extended_id": bool(fields["is_extended_id"]),
                "is_error_frame": bool(fields["is_error_frame"]),
                "data_hex": bytes(fields["data"]).hex(),
            }
        )
    return json.dumps({"frames": out}, separators=(",", ":")).encode()
