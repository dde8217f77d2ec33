"""Who is being measured and under what condition: the ``[session]`` section and the names
it gives recordings.

A run records one subject's session under a condition (``rtsid run --subject S01 --session 2
--condition baseline``, or the ``[session]`` section). The names go into every recording (the
``rtsid.session`` MCAP metadata record, the ``/session`` channel) and, through
``recording_pattern``, into the recording's file name, so nobody renames files after a run.

The pattern's fields (:data:`PATTERN_FIELDS`)::

    subject, session, condition   the [session] names (condition: the one at the start)
    robot, joint                  the [zenoh] names
    start                         the run's start, UTC, YYYYmmddTHHMMSSZ

A rotated part adds ``-001``, ``-002``, … before ``.mcap``; characters other than letters,
digits, ``_``, ``.`` and ``-`` in a field's value become ``_``. Without a subject the name is the
old ``rtsid-<robot>-<joint>-<start>`` whatever the pattern says.
"""

from __future__ import annotations

import re
import string
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from rtsid.config import invalid, section_from_mapping
from rtsid.errors import ConfigError

__all__ = [
    "DEFAULT_PATTERN",
    "MAX_NAME_CHARS",
    "PATTERN_FIELDS",
    "SessionConfig",
    "check_session_name",
    "recording_stem",
]

#: The recording name of a run with a subject.
DEFAULT_PATTERN = "{subject}_{session}_{robot}-{joint}_{start}"
#: Fields a ``recording_pattern`` may use.
PATTERN_FIELDS = ("subject", "session", "condition", "robot", "joint", "start")
#: Longest subject, session or condition, characters.
MAX_NAME_CHARS = 64

_UNSAFE = re.compile(r"[^A-Za-z0-9_.\-]")
_LITERAL = re.compile(r"^[A-Za-z0-9_.\-]*$")


def check_session_name(key: str, value: object) -> str:
    """``value`` if it is a subject, session or condition name: a string of at most
    :data:`MAX_NAME_CHARS` printable characters without ``/`` or ``\\``.

    Raises
    ------
    ConfigError
        Names ``key`` and what is accepted.
    """
    accepted = (
        f"printable text of at most {MAX_NAME_CHARS} characters without '/' or '\\' "
        "(e.g. S01, 2, baseline)"
    )
    if not isinstance(value, str):
        raise invalid(key, value, accepted)
    if len(value) > MAX_NAME_CHARS or not value.isprintable() or "/" in value or "\\" in value:
        shown = value if len(value) <= 80 else value[:77] + "..."
        if key.startswith("--"):
            raise ConfigError(f"{key} {shown!r} is not accepted; expected {accepted}")
        raise invalid(key, shown, accepted)
    return value


def _pattern_fields(pattern: str) -> list[str]:
    """The fields ``pattern`` uses; a field outside :data:`PATTERN_FIELDS`, a format spec or
    a literal character that is not safe in a file name is a ConfigError."""
    accepted = ", ".join("{" + f + "}" for f in PATTERN_FIELDS)
    try:
        parsed = list(string.Formatter().parse(pattern))
    except ValueError as exc:
        raise invalid(
            "session.recording_pattern", pattern, f"fields in braces ({exc}); accepted: {accepted}"
        ) from None
    used = []
    for literal, name, spec, conversion in parsed:
        if not _LITERAL.match(literal):
            raise invalid(
                "session.recording_pattern",
                pattern,
                f"fields ({accepted}) joined by letters, digits, '_', '.' or '-' (no path "
                "separators or spaces)",
            )
        if name is None:
            continue
        if name not in PATTERN_FIELDS or spec or conversion:
            raise ConfigError(
                f"config key 'session.recording_pattern' = {pattern!r} uses the field "
                f"{{{name}{'!' + conversion if conversion else ''}{':' + spec if spec else ''}}}; "
                f"accepted fields: {accepted}"
            )
        used.append(name)
    return used


@dataclass(frozen=True)
class SessionConfig:
    """The ``[session]`` config section (``rtsid run --subject/--session/--condition``
    override it).

    Attributes
    ----------
    subject : str
        Who is measured, e.g. ``"S01"`` (empty: none; the recording keeps the
        ``rtsid-<robot>-<joint>-<start>`` name).
    session : str
        Which session of that subject, e.g. ``"2"``.
    condition : str
        What the subject is asked to do at the start (``rtsid condition C`` changes it while
        the daemon runs).
    recording_pattern : str
        The recording's file name without ``.mcap`` when a subject is given; fields in braces
        from :data:`PATTERN_FIELDS`, and it must hold ``{start}`` (two runs never share a name,
        and a run's rotated parts are found by it).
    """

    subject: str = ""
    session: str = ""
    condition: str = ""
    recording_pattern: str = DEFAULT_PATTERN

    def __post_init__(self) -> None:
        for name in ("subject", "session", "condition"):
            check_session_name(name, getattr(self, name))
        if "start" not in _pattern_fields(self.recording_pattern):
            raise invalid(
                "recording_pattern",
                self.recording_pattern,
                "a pattern holding {start} (the run's UTC start), e.g. " + repr(DEFAULT_PATTERN),
            )

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any] | None) -> SessionConfig:
        """Build from the ``[session]`` TOML table (unknown keys and bad values rejected)."""
        return section_from_mapping(cls, mapping, "session")

    def with_overrides(
        self,
        *,
        subject: str | None = None,
        session: str | None = None,
        condition: str | None = None,
    ) -> SessionConfig:
        """This section with the command line's names in place of its own (None: keep)."""
        changes = {
            k: v
            for k, v in (("subject", subject), ("session", session), ("condition", condition))
            if v is not None
        }
        for key, value in changes.items():
            check_session_name(f"--{key}", value)
        return SessionConfig(**{**self.__dict__, **changes})


def utc_stamp(start: datetime) -> str:
    """``YYYYmmddTHHMMSSZ`` of ``start`` in UTC (the ``{start}`` field)."""
    return start.astimezone(UTC).strftime("%Y%m%dT%H%M%SZ")


def recording_stem(
    robot: str, joint: str, start: datetime, session: SessionConfig | None = None
) -> str:
    """A recording's file name without part suffix and ``.mcap``.

    With a subject: ``session.recording_pattern`` filled in (each field's unsafe characters
    become ``_``); without: ``rtsid-<robot>-<joint>-<start>`` (robot and joint's characters
    other than letters, digits, ``_`` and ``.`` become ``_``, as always).
    """
    stamp = utc_stamp(start)
    if session is None or not session.subject:
        return f"rtsid-{_old_safe(robot)}-{_old_safe(joint)}-{stamp}"
    values = {
        "subject": session.subject,
        "session": session.session,
        "condition": session.condition,
        "robot": robot,
        "joint": joint,
        "start": stamp,
    }
    safe = {k: _UNSAFE.sub("_", v) for k, v in values.items()}
    return session.recording_pattern.format(**safe)


def _old_safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.]+", "_", name)
