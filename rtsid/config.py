"""Configuration: frozen dataclasses loaded from TOML and validated on load.

Every part of rtsid owns the dataclass of its own section (``[link]``, ``[plant]``,
``[worker]``, ``[zenoh]``, ``[mcap]``, …) and builds it with :func:`section_from_mapping`,
which rejects unknown keys and wrong types with a :class:`~rtsid.errors.ConfigError` that
names the key, the value and what is accepted. Range checks live in each dataclass's
``__post_init__`` and raise through :func:`invalid`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from rtsid.errors import ConfigError, invalid, require_choice, require_range

__all__ = [
    "invalid",
    "load_toml",
    "require_choice",
    "require_finite",
    "require_range",
    "section_from_mapping",
]

T = TypeVar("T")


def require_finite(key: str, value: object) -> None:
    """Raise if ``value`` is, or (in a list/tuple) holds, a NaN or infinite float.

    TOML accepts ``nan`` and ``inf``; no rtsid setting means anything with them (NaN even
    passes every range check, e.g. ``max_sample_age_s = nan`` would turn staleness off).
    """
    values = value if isinstance(value, list | tuple) else (value,)
    for v in values:
        if isinstance(v, float) and not math.isfinite(v):
            raise invalid(key, value, "a finite number")


#: Largest config file read, bytes: a config is a page of settings; anything larger is a
#: wrong path (a recording, a log), refused before it is read.
MAX_CONFIG_BYTES = 1 << 20


def from_config_folder(value: Any, base_dir: str | Path | None) -> Any:
    """A path key's value as read from a config file: a relative path (``~`` expanded) taken
    from ``base_dir``, the file's folder; anything else (absolute, empty, not a string, no
    file) unchanged, for the section's own check to judge."""
    if base_dir is None or not isinstance(value, str) or not value:
        return value
    return str(Path(base_dir) / Path(value).expanduser())


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; a missing, unreadable, binary, oversized or malformed file is a
    ConfigError naming the file and the fix."""
    p = Path(path)
    where = f"config file {str(p)!r}"
    try:
        with p.open("rb") as fh:
            data = fh.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{where} does not exist; check the path") from None
    except IsADirectoryError:
        raise ConfigError(f"{where} is a directory; pass the path of a .toml file") from None
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ConfigError(f"{where} cannot be read ({reason}); check the path") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{where} is larger than {MAX_CONFIG_BYTES // 1024} KiB, the most a config may be; "
            "is it the right file?"
        )
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{where} is not UTF-8 text (byte {exc.start} is 0x{data[exc.start]:02x}); "
            "pass a TOML text file"
        ) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where} is not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{where} nests arrays or tables too deeply; flatten it") from None


def _type_matches(value: object, annotation: Any) -> bool:
    origin = typing.get_origin(annotation)
    if annotation is Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_type_matches(value, arg) for arg in typing.get_args(annotation))
    if annotation is type(None):
        return value is None
    if annotation is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if annotation is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if origin in (tuple, list):
        args = typing.get_args(annotation)
        if not isinstance(value, list | tuple):
            return False
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            return all(_type_matches(v, args[0]) for v in value)
        if origin is tuple and args:
            return len(value) == len(args) and all(map(_type_matches, value, args))
        return not args or all(_type_matches(v, args[0]) for v in value)
    if origin in (dict, Mapping) or annotation in (dict, Mapping):
        return isinstance(value, Mapping)
    if isinstance(annotation, type):
        return isinstance(value, annotation)
    return True


def _type_name(annotation: Any) -> str:
    if typing.get_origin(annotation) in (dict, Mapping) or annotation in (dict, Mapping):
        return "table (e.g. {fd = true})"
    return getattr(annotation, "__name__", None) or str(annotation).replace("typing.", "")


@functools.cache
def _field_types(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints(cls)``, once per class: the annotations are strings (``from
    __future__ import annotations``) that it compiles and evaluates on every call — a
    replay process loaded its recording's configuration (a few dozen sections) in ≈ 10 ms."""
    return typing.get_type_hints(cls)


def section_from_mapping(cls: type[T], mapping: Mapping[str, Any] | None, section: str) -> T:
    """Build the frozen dataclass ``cls`` from one TOML section, validating keys and types.

    Parameters
    ----------
    cls : type
        A dataclass whose fields are the section's keys (defaults for absent keys).
    mapping : Mapping or None
        The section's table (``None`` or empty: all defaults).
    section : str
        Section name used in messages, e.g. ``"worker"`` gives ``worker.hop_s``.

    Returns
    -------
    cls
        The validated instance.

    Raises
    ------
    ConfigError
        Not a table, an unknown key (with the accepted keys), a value of the wrong type, a NaN or
        infinite number, or a value the dataclass's own ``__post_init__`` rejects.
    """
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    if mapping is not None and not isinstance(mapping, Mapping):
        raise invalid(section, mapping, f"a table [{section}]")
    mapping = dict(mapping or {})
    hints = _field_types(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(mapping) - set(fields))
    if unknown:
        raise ConfigError(
            f"unknown config key {section}.{unknown[0]}; accepted keys in [{section}]: "
            + ", ".join(sorted(fields))
        )
    values: dict[str, Any] = {}
    for name, value in mapping.items():
        annotation = hints[name]
        if not _type_matches(value, annotation):
            raise invalid(f"{section}.{name}", value, f"a value of type {_type_name(annotation)}")
        require_finite(f"{section}.{name}", value)
        if isinstance(value, list) and typing.get_origin(annotation) is tuple:
            value = tuple(value)
        if annotation is float and isinstance(value, int):
            if abs(value) > 2**1023:  # beyond a float: no setting means that
                raise invalid(f"{section}.{name}", value, "a finite number")
            value = float(value)
        values[name] = value
    try:
        return cls(**values)
    except ConfigError as exc:
        msg = str(exc)
        if f"'{section}." not in msg and msg.startswith("config key '"):
            msg = msg.replace("config key '", f"config key '{section}.", 1)
        raise ConfigError(msg) from None


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def to_toml(document: Mapping[str, Any], prefix: str = "") -> str:
    """Write nested tables of plain values as TOML (keys first, then sub-tables).

    ``None`` values are written as comments (TOML has no null). The result reads back with
    :func:`load_toml` to the same document, minus the ``None`` keys.
    """
    lines: list[str] = []
    tables = []
    for key, value in document.items():
        if isinstance(value, Mapping):
            tables.append((key, value))
        elif value is None:
            lines.append(f"# {key} = (not set)")
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    out = []
    if prefix and (lines or not tables):
        out.append(f"[{prefix}]")
    out.extend(lines)
    for key, value in tables:
        name = f"{prefix}.{key}" if prefix else key
        out.append("")
        out.append(to_toml(value, name).rstrip("\n"))
    return "\n".join(out).strip("\n") + "\n"
