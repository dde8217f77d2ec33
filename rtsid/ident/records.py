"""Building the per-window path's frozen records without their generated ``__init__``.

A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__`` (frozen
classes forbid ``self.x = …``): about four times a plain attribute's cost, 1 µs for six
fields. The window path builds some 50 such fields per hop (the estimate, its IRF, the
tracker's answers); :func:`built` fills an instance's ``__dict__`` in one update instead.
The instance is the same as the constructor's (equal, hashed alike, still frozen);
``tests/ident/test_records.py`` holds every record built this way to its constructor's.
"""

from __future__ import annotations

from typing import Any, TypeVar

__all__ = ["built"]

T = TypeVar("T")


def built(cls: type[T], /, **fields: Any) -> T:
    """An instance of the frozen dataclass ``cls`` with ``fields`` — every field, by name,
    defaults included (none is filled in) — as ``cls(**fields)`` gives it, without running
    its ``__init__``; for records that have no ``__post_init__``."""
    record = object.__new__(cls)
    record.__dict__.update(fields)
    return record
