"""One exception tree for rtsid; every message says what went wrong and how to fix it.

::

    RtsidError
    ├── ConfigError(ValueError)          a config key or value is not accepted
    │   └── TorqueSignError              most windows read K, B, I < 0: the sign is inverted
    ├── InputDataError(ValueError)       samples or files that cannot be used as they are
    │   └── WindowError                  a window that must not be estimated (gap, NaN, too short…)
    ├── NumericalError(ArithmeticError)  the numerics cannot give a trustworthy answer
    │   └── NotPositiveDefiniteError     Toeplitz matrix not positive definite
    ├── LinkError(OSError)               the hardware link (CAN bus, socketcand, protocol)
    ├── RecordingError(OSError)          reading or writing recordings (MCAP, CSV, npz)
    └── ServiceError(RuntimeError)       the daemon's threads, zenoh, deadlines

Each class also subclasses the built-in it resembles, so callers that catch ``ValueError``
or ``OSError`` keep working.

Warnings (work went on, but the user must hear of it; the CLI prints each as one line)::

    RtsidWarning(UserWarning)
    ├── IncompleteRecordingWarning       a recording ended early; says how much was read
    └── JointAttachedWarning             a calibration forced from a baseline with a joint on
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from rtsid.verdicts import Reason


class RtsidError(Exception):
    """Base class of every error rtsid raises on purpose."""


class ConfigError(RtsidError, ValueError):
    """A configuration key or value is not accepted; the message names key, value and choices."""


class TorqueSignError(ConfigError):
    """Most windows of a stream read K, B, I < 0: the configured torque sign is inverted.

    Attributes
    ----------
    inverted, estimable : int
        Windows that read inverted, of the estimable ones.
    torque_sign : float
        The sign that was configured (the fix is its opposite).
    """

    def __init__(self, message: str, inverted: int, estimable: int, torque_sign: float) -> None:
        super().__init__(message)
        self.inverted = inverted
        self.estimable = estimable
        self.torque_sign = torque_sign


class InputDataError(RtsidError, ValueError):
    """Input samples or files cannot be used as they are."""


class WindowError(InputDataError):
    """A window must not be estimated; ``reason`` is a short machine-readable flag.

    Parameters
    ----------
    message : str
        Human-readable explanation, with the fix where there is one.
    reason : Reason
        Why, from the closed vocabulary :class:`rtsid.verdicts.Reason`.
    """

    def __init__(self, message: str, reason: Reason) -> None:
        super().__init__(message)
        self.reason = reason


class NumericalError(RtsidError, ArithmeticError):
    """The numerics cannot give a trustworthy answer for this input."""


class NotPositiveDefiniteError(NumericalError):
    """A Toeplitz matrix is not positive definite (prediction-error variance <= 0).

    Parameters
    ----------
    message : str
        Explanation with the fix.
    step : int
        Recursion step at which the prediction-error variance stopped being positive.
    """

    def __init__(self, message: str, step: int) -> None:
        super().__init__(message)
        self.step = step


class LinkError(RtsidError, OSError):
    """The hardware link failed: bus, socketcand connection or protocol."""


class RecordingError(RtsidError, OSError):
    """A recording could not be read or written."""


class ServiceError(RtsidError, RuntimeError):
    """The daemon's threads, zenoh session or scheduling failed."""


class RtsidWarning(UserWarning):
    """Base class of the warnings rtsid issues on purpose."""


class IncompleteRecordingWarning(RtsidWarning):
    """A recording ended before its footer; the message says how much of it was read."""


class JointAttachedWarning(RtsidWarning):
    """``rtsid calibrate --force`` calibrated from a baseline with a joint attached."""


# The checks every frozen settings class runs in ``__post_init__``; here, at the bottom of the
# package, so that the pure numerics (``rtsid.ident``) validate their options without
# importing the config loader. ``rtsid.config`` re-exports them.


def invalid(key: str, value: object, accepted: str) -> ConfigError:
    """Error for ``key = value`` naming what is accepted instead."""
    return ConfigError(f"config key {key!r} = {value!r} is not accepted; expected {accepted}")


def require_choice(key: str, value: object, choices: Iterable[object]) -> None:
    """Raise unless ``value`` is one of ``choices``."""
    options = tuple(choices)
    if value not in options:
        raise invalid(key, value, "one of " + ", ".join(repr(c) for c in options))


def require_range(
    key: str,
    value: float,
    low: float | None = None,
    high: float | None = None,
    *,
    low_inclusive: bool = True,
) -> None:
    """Raise unless ``value`` is finite and ``low <= value <= high`` (``low < value`` when
    not ``low_inclusive``). NaN compares false with everything, so it is refused first."""
    too_low = low is not None and (value < low if low_inclusive else value <= low)
    too_high = high is not None and value > high
    if too_low or too_high or not math.isfinite(value):
        lo = "" if low is None else f"{'>=' if low_inclusive else '>'} {low}"
        hi = "" if high is None else f"<= {high}"
        raise invalid(key, value, "a finite number " + " and ".join(p for p in (lo, hi) if p))
