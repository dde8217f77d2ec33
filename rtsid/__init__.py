"""rtsid — real-time system identification of human joint impedance."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

# Before numpy loads (any ``import rtsid...`` runs this first: the CLI, replay or the Python
# API): BLAS worker threads spin against the acquisition thread and make a 1 ms window cost
# 10 ms under load (measured with `rtsid bench window`); and a multi-threaded BLAS sums in
# another order, so a replay through the Python API gave other numbers than the live run (5691
# of 6030 windows of a daemon recording with a reflex, whose slow-lane fits use BLAS; its fits
# also took 0.9 s each instead of 17 ms on the loaded 2-core VM). Windows are small; one thread
# is fastest. A user can still override these from the environment.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

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
