"""rtsid — real-time system identification of human joint impedance."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = ["Identifier", "__version__", "errors", "estimate_window", "identify"]

if TYPE_CHECKING:
    from rtsid import errors
    from rtsid.ident.window import estimate_window
    from rtsid.identifier import Identifier, identify


def __getattr__(name: str) -> Any:
    # Lazy so that `import rtsid` (e.g. for the CLI) does not pay for scipy until needed.
    if name == "estimate_window":
        from rtsid.ident.window import estimate_window

        return estimate_window
    if name in ("Identifier", "identify"):
        from rtsid import identifier

        return getattr(identifier, name)
    if name == "errors":
        from rtsid import errors

        return errors
    raise AttributeError(f"module 'rtsid' has no attribute {name!r}")
