"""What an estimate message may say about its window: why it was withheld, what to beware of.

Two closed vocabularies, one place: the numerics raise them, the worker publishes them, the
JSON schema lists them (:mod:`rtsid.io.messages`), and a test makes each one happen. Both are
``StrEnum``: a member *is* its string (``Reason.GAP == "gap"``), so JSON, CSV, ``str()``,
f-strings and comparisons with plain strings give the value. Only a container's ``repr`` shows
``<Reason.GAP: 'gap'>``: a tally for people goes through :func:`format_counts`.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum

__all__ = ["Flag", "Reason", "format_counts", "plain_counts"]


class Reason(StrEnum):
    """Why a window was withheld (``ok: false``); its numbers are then ``null``."""

    GAP = "gap"
    NAN = "nan"
    SATURATED = "saturated"
    STALE = "stale"
    NO_EXCITATION = "no_excitation"
    NUMERICAL = "numerical"
    TOO_SHORT = "too_short"
    UNIDENTIFIABLE = "unidentifiable"

    @property
    def description(self) -> str:
        """One line for the schema and the docs."""
        return _REASONS[self]


class Flag(StrEnum):
    """A warning on a published estimate (the numbers are given, with this caveat)."""

    LOW_VAF = "low_vaf"
    MODEL_MISMATCH = "model_mismatch"
    NEGATIVE_STIFFNESS = "negative_stiffness"
    NEGATIVE_DAMPING = "negative_damping"
    NEGATIVE_INERTIA = "negative_inertia"
    INERTIA_UNCERTAIN = "inertia_uncertain"
    STIFFNESS_UNCERTAIN = "stiffness_uncertain"
    OVER_BUDGET = "over_budget"
    REFLEX_ABSENT = "reflex_absent"
    REFLEX_STALE = "reflex_stale"

    @property
    def description(self) -> str:
        """One line for the schema and the docs."""
        return _FLAGS[self]


def plain_counts(counts: Mapping[str, int]) -> dict[str, int]:
    """A tally keyed by reasons or flags with plain-string keys (their values), sorted."""
    return {str(k): int(v) for k, v in sorted(counts.items(), key=lambda kv: str(kv[0]))}


def format_counts(counts: Mapping[str, int], empty: str = "0") -> str:
    """A tally of reasons or flags for people: ``gap: 1, nan: 2`` (``empty`` when none)."""
    return ", ".join(f"{k}: {v}" for k, v in plain_counts(counts).items() if v) or empty


_REASONS = {
    Reason.GAP: "a discontinuity in the signal, or more lost samples than the estimator "
    "bridges (max_lost_percent, max_gap_s)",
    Reason.NAN: "a valid sample is NaN or infinite",
    Reason.SATURATED: "a sample carries a position or torque saturation bit",
    Reason.STALE: "no sample arrived for longer than max_sample_age_s",
    Reason.NO_EXCITATION: "the position carries no usable perturbation",
    Reason.NUMERICAL: "the numerics cannot give a trustworthy answer (e.g. not positive "
    "definite, inseparable inertia and stiffness)",
    Reason.TOO_SHORT: "the window is too short for the analysis (filter, lags, stencils)",
    Reason.UNIDENTIFIABLE: "the fit reads K <= 0 and the second-order model does not match the "
    "window's own IRF (model_mismatch): no joint's impedance, so no estimate",
}
_FLAGS = {
    Flag.LOW_VAF: "the I/B/K model explains less of the torque than low_vaf_percent",
    Flag.MODEL_MISMATCH: "the I/B/K model explains < 50 % of the IRF's prediction: the joint "
    "or rig is not second-order in the analysed band",
    Flag.NEGATIVE_STIFFNESS: "K <= 0",
    Flag.NEGATIVE_DAMPING: "B <= 0",
    Flag.NEGATIVE_INERTIA: "I <= 0",
    Flag.INERTIA_UNCERTAIN: "the standard error of I exceeds 25 % of |I|",
    Flag.STIFFNESS_UNCERTAIN: "the standard error of K exceeds 10 % of |K|",
    Flag.OVER_BUDGET: "computing the window took longer than the worker's budget",
    Flag.REFLEX_ABSENT: "the slow lane is on but no reflex model could be used: the intrinsic "
    "estimate includes any reflex torque",
    Flag.REFLEX_STALE: "the reflex model used is not the one due (the slow lane was late or "
    "failed) or older than stale_after_s",
}
