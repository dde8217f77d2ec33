"""rtsid — real-time system identification of human joint impedance."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = ["__version__", "estimate_window"]

if TYPE_CHECKING:
    from rtsid.ident.window import estimate_window


def __getattr__(name: str) -> Any:
    # Lazy so that `import rtsid` (e.g. for the CLI) does not pay for scipy until needed.
    if name == "estimate_window":
        from rtsid.ident.window import estimate_window

        return estimate_window
    raise AttributeError(f"module 'rtsid' has no attribute {name!r}")
