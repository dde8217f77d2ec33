"""What a view or client takes from a peer: checked against the generated schemas, or refused.

Every payload ``rtsid watch``, ``rtsid watch --web`` and ``rtsid query`` read from zenoh (live
samples, the latest-value queryables, history replies) goes through :func:`decode_message`
(or :func:`decode_history_part`) before anything shows it. One bad peer, or a spoofer on the
network, must cost one counted rejection, never a traceback, a crashed view, script in a page
or escape codes in a terminal. The checks, all documented bounds:

- the payload is at most :data:`MAX_MESSAGE_BYTES` (a history part: :data:`MAX_PART_BYTES`),
  UTF-8 JSON without ``NaN``/``Infinity`` and nested at most :data:`MAX_DEPTH` deep;
- it follows the channel's JSON schema generated in :mod:`rtsid.io.messages` (types, required
  keys, no unknown keys where the schema says so, the closed vocabularies of reasons and
  flags, minimums); a channel without a schema is an object with ``robot`` and ``joint``;
- every number is finite with ``|x| <=`` :data:`MAX_ABS_NUMBER` (integers: within int64);
  every string is at most :data:`MAX_STRING_CHARS` characters with no control characters but
  tab, CR and LF (an error text may span lines; what is printed goes through :func:`printable`);
  every array at most :data:`MAX_ITEMS` items;
- ``robot`` and ``joint`` are names (:data:`NAME_PATTERN`) and equal the key the message came
  on (``<prefix>/<robot>/<joint>/<channel>``): a daemon's channel cannot speak for another.

The validator is a small interpreter of the JSON-schema keywords those schemas use (``type``,
``enum``, ``minimum``, ``maxItems``, ``maxLength``, ``properties``, ``required``,
``additionalProperties``, ``items``); ``jsonschema`` is only a test dependency (the tests check
both agree).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from rtsid.errors import InputDataError
from rtsid.io.history import HISTORY_PART_SCHEMA
from rtsid.io.messages import (
    ESTIMATE_SCHEMA,
    MARKER_SCHEMA,
    REFLEX_SCHEMA,
    SESSION_SCHEMA,
    STATUS_SCHEMA,
)

__all__ = [
    "MAX_ABS_NUMBER",
    "MAX_DEPTH",
    "MAX_ITEMS",
    "MAX_MESSAGE_BYTES",
    "MAX_PART_BYTES",
    "MAX_STRING_CHARS",
    "NAME_PATTERN",
    "CheckedReplies",
    "MalformedMessage",
    "check_replies",
    "check_value",
    "decode_json",
    "decode_message",
    "error_reply_text",
    "joint_of_key",
    "printable",
]

#: Bytes of one message (an estimate is ≈ 0.8 KiB, a reflex model a few KiB).
MAX_MESSAGE_BYTES = 256 * 1024
#: Bytes of one history reply (500 estimates ≈ 0.4 MB).
MAX_PART_BYTES = 4 * 1024 * 1024
#: Largest magnitude of a non-integer number; integers must fit in int64.
MAX_ABS_NUMBER = 1e15
MAX_STRING_CHARS = 1000
MAX_ITEMS = 10_000
MAX_DEPTH = 8
#: robot and joint names: as ``[zenoh] robot/joint`` accept them.
NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")

_INT64 = (-(2**63), 2**63 - 1)
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")  # replaced by printable()
_FORBIDDEN = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f]")  # in a string: not tab, CR, LF
_SCHEMAS: dict[str, Mapping[str, Any]] = {
    "estimate": ESTIMATE_SCHEMA,
    "status": STATUS_SCHEMA,
    "reflex": REFLEX_SCHEMA,
    "session": SESSION_SCHEMA,
    "marker": MARKER_SCHEMA,
}
_ANY_CHANNEL: Mapping[str, Any] = {
    "type": "object",
    "properties": {"robot": {"type": "string"}, "joint": {"type": "string"}},
    "required": ["robot", "joint"],
}


class MalformedMessage(InputDataError):
    """A peer's payload that does not follow its schema or the bounds (the message says
    where and why). The message names the peer's own keys and values, so it is made
    printable here, once for every reason: a key holding a terminal escape came through
    the path of a rejected number to `rtsid watch`'s screen (hypothesis, 27 Nov)."""

    def __init__(self, why: str) -> None:
        super().__init__(printable(why))


def printable(text: str, limit: int = 300) -> str:
    """``text`` with control characters (terminal escapes, newlines) replaced by ``?`` and
    cut to ``limit`` characters: safe to print on one line."""
    text = _CONTROL.sub("?", text)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _refuse_constant(name: str) -> Any:
    raise MalformedMessage(f"{name} is not a JSON number")


def decode_json(payload: bytes, limit_bytes: int = MAX_MESSAGE_BYTES) -> Any:
    """UTF-8 JSON of at most ``limit_bytes``, without NaN or Infinity.

    Raises
    ------
    MalformedMessage
        Too large, not UTF-8, not JSON, or nested too deep to decode.
    """
    if len(payload) > limit_bytes:
        raise MalformedMessage(f"{len(payload)} bytes, more than the {limit_bytes} accepted")
    try:
        return json.loads(payload.decode("utf-8"), parse_constant=_refuse_constant)
    except UnicodeDecodeError:
        raise MalformedMessage("not UTF-8") from None
    except RecursionError:
        raise MalformedMessage("nested too deep") from None
    except ValueError as exc:  # json.JSONDecodeError
        raise MalformedMessage(f"not JSON ({exc})") from None


def _type_of(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "number"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "object"
    return type(value).__name__


def _matches(actual: str, value: Any, wanted: str) -> bool:
    if actual == wanted:
        return True
    if wanted == "number" and actual == "integer":
        return True
    # JSON schema: an integer is any number with a zero fractional part (2.0 is one)
    return wanted == "integer" and actual == "number" and float(value).is_integer()


def check_value(value: Any, schema: Mapping[str, Any], where: str = "", depth: int = 0) -> None:
    """Check ``value`` against ``schema`` (the keywords in the module docstring) and the
    bounds every value obeys.

    Raises
    ------
    MalformedMessage
        Names the path of the first offending value and why.
    """
    if depth > MAX_DEPTH:
        raise MalformedMessage(f"{where or 'message'} is nested more than {MAX_DEPTH} deep")
    actual = _type_of(value)
    wanted = schema.get("type")
    if wanted is not None:
        choices = [wanted] if isinstance(wanted, str) else list(wanted)
        if not any(_matches(actual, value, w) for w in choices):
            raise MalformedMessage(
                f"{where or 'message'} is {actual}; expected {'/'.join(choices)}"
            )
    _check_bounds(actual, value, where)
    if "enum" in schema and value not in schema["enum"]:
        raise MalformedMessage(
            f"{where} = {printable(repr(value), 80)} is not one of the known values"
        )
    if actual == "string" and len(value) > schema.get("maxLength", MAX_STRING_CHARS):
        raise MalformedMessage(
            f"{where} is a string of {len(value)} characters, more than accepted"
        )
    if "minimum" in schema and actual in ("integer", "number") and value < schema["minimum"]:
        raise MalformedMessage(f"{where} = {value!r} is below {schema['minimum']}")
    if actual == "array":
        if len(value) > schema.get("maxItems", MAX_ITEMS):
            raise MalformedMessage(f"{where} has {len(value)} items, more than accepted")
        items = schema.get("items", {})
        for i, item in enumerate(value):
            check_value(item, items, f"{where}[{i}]", depth + 1)
    elif actual == "object":
        _check_object(value, schema, where, depth)


def _check_bounds(actual: str, value: Any, where: str) -> None:
    if actual == "number" and not (math.isfinite(value) and abs(value) <= MAX_ABS_NUMBER):
        raise MalformedMessage(
            f"{where} = {value!r} is not a finite number within ±{MAX_ABS_NUMBER:g}"
        )
    if actual == "integer" and not _INT64[0] <= value <= _INT64[1]:
        raise MalformedMessage(f"{where} is an integer outside int64")
    if actual == "string":
        if len(value) > MAX_STRING_CHARS:
            raise MalformedMessage(f"{where} is a string of {len(value)} characters")
        if _FORBIDDEN.search(value):
            raise MalformedMessage(f"{where} holds control characters")
    if actual not in ("null", "boolean", "integer", "number", "string", "array", "object"):
        raise MalformedMessage(f"{where} is a {actual}")


def _check_object(value: dict[str, Any], schema: Mapping[str, Any], where: str, depth: int) -> None:
    if len(value) > MAX_ITEMS:
        raise MalformedMessage(f"{where or 'message'} has {len(value)} keys")
    missing = [k for k in schema.get("required", ()) if k not in value]
    if missing:
        raise MalformedMessage(f"{where or 'message'} lacks {', '.join(missing)}")
    properties = schema.get("properties", {})
    extra = schema.get("additionalProperties", True)
    for key, item in value.items():
        path = f"{where}.{key}" if where else key
        if key in properties:
            check_value(item, properties[key], path, depth + 1)
        elif extra is False:
            raise MalformedMessage(f"unknown key {printable(repr(key), 80)}")
        else:
            check_value(item, extra if isinstance(extra, Mapping) else {}, path, depth + 1)


def check_names(message: Mapping[str, Any], key: str | None) -> str:
    """``robot/joint`` of a message, both names valid and equal to the key's.

    Raises
    ------
    MalformedMessage
    """
    robot, joint = message.get("robot"), message.get("joint")
    for what, name in (("robot", robot), ("joint", joint)):
        if not isinstance(name, str) or not NAME_PATTERN.match(name):
            raise MalformedMessage(
                f"{what} {printable(repr(name), 80)} is not a name (letters, digits, _ . -)"
            )
    name = f"{robot}/{joint}"
    if key is not None:
        chunks = key.rstrip("/").split("/")
        if len(chunks) < 3 or "/".join(chunks[-3:-1]) != name:
            raise MalformedMessage(f"names {name} but came on {printable(key, 120)}")
    return name


def joint_of_key(key: str) -> str:
    """``robot/joint`` of ``<prefix>/<robot>/<joint>/<channel>`` (a liveliness token's key),
    both valid names.

    Raises
    ------
    MalformedMessage
    """
    chunks = key.rstrip("/").split("/")
    names = chunks[-3:-1] if len(chunks) >= 3 else []
    if len(names) != 2 or not all(NAME_PATTERN.match(n) for n in names):
        raise MalformedMessage(f"key {printable(key, 120)} does not name a robot and a joint")
    return "/".join(names)


def decode_message(
    kind: str, payload: bytes, key: str | None = None, limit_bytes: int = MAX_MESSAGE_BYTES
) -> dict[str, Any]:
    """Decode and check one message of channel ``kind`` that arrived on ``key``.

    Returns
    -------
    dict
        The message, every value within the bounds of the module docstring.

    Raises
    ------
    MalformedMessage
        Says why (one line, safe to print).
    """
    message = decode_json(payload, limit_bytes)
    check_message(kind, message, key)
    return dict(message)


def check_message(kind: str, message: Any, key: str | None = None) -> None:
    """:func:`decode_message` for an already decoded value."""
    check_value(message, _SCHEMAS.get(kind, _ANY_CHANNEL))
    check_names(message, key)


def error_reply_text(text: str) -> str:
    """What a queryable's error reply says, on one printable line (``{"error": …}`` or the
    text itself)."""
    try:
        decoded = json.loads(text)
    except (ValueError, RecursionError):
        decoded = None
    if isinstance(decoded, dict) and isinstance(decoded.get("error"), str):
        text = decoded["error"]
    return printable(text)


@dataclass
class CheckedReplies:
    """The replies of a query that passed the checks.

    Attributes
    ----------
    messages : list of (str, str, dict)
        ``(channel, key, message)`` oldest first (by ``host_time_ns``): each message of a
        history part, or a latest-value reply.
    parts : list of dict
        The history parts' headers (everything but ``messages``), in arrival order.
    rejected : list of str
        Why each rejected reply or message was refused (one printable line each).
    """

    messages: list[tuple[str, str, dict[str, Any]]] = field(default_factory=list)
    parts: list[dict[str, Any]] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)


def check_replies(replies: Iterable[tuple[str, bytes]]) -> CheckedReplies:
    """Check every reply of a query (``(key, payload)`` pairs): history parts on
    ``…/history`` (:data:`~rtsid.io.history.HISTORY_PART_SCHEMA`, each message against its
    channel's schema), any other key a single message of the channel its last chunk names."""
    out = CheckedReplies()
    for key, payload in replies:
        base, _, kind = key.rstrip("/").rpartition("/")
        try:
            if kind != "history":
                out.messages.append((kind, key, decode_message(kind, payload, key)))
                continue
            part = decode_json(payload, MAX_PART_BYTES)
            check_value(part, HISTORY_PART_SCHEMA)
            check_names(part, key)
        except MalformedMessage as exc:
            out.rejected.append(f"{printable(key, 120)}: {exc}")
            continue
        out.parts.append({k: v for k, v in part.items() if k != "messages"})
        channel_key = f"{base}/{part['kind']}"
        for message in part["messages"]:
            try:
                check_message(part["kind"], message, channel_key)
            except MalformedMessage as exc:
                out.rejected.append(f"{printable(key, 120)}: {exc}")
                continue
            out.messages.append((part["kind"], channel_key, message))
    out.messages.sort(key=lambda item: _time_ns(item[2]))
    return out


def _time_ns(message: Mapping[str, Any]) -> int:
    stamp = message.get("host_time_ns")
    return int(stamp) if isinstance(stamp, int | float) and not isinstance(stamp, bool) else 0
