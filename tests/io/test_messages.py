"""EstimateMessage.window_dict is the message built field by field, as its JSON object: key for
key and in order."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pytest

from rtsid.ident.assess import WindowEstimate
from rtsid.ident.stream import Tracked
from rtsid.io import messages
from rtsid.io.messages import ESTIMATE_SCHEMA, EstimateMessage
from rtsid.verdicts import Flag, Reason


def estimate(**changes: Any) -> WindowEstimate:
    numbers = dict(I=0.01, B=0.5, K=120.0, I_se=0.001, B_se=0.02, K_se=2.0)
    numbers.update(vaf=91.0, vaf_irf=93.0, vaf_fit=97.0)
    fields = dict(irf=np.zeros(3), lags_s=np.zeros(3), fs_hz=500.0, method="oe")
    fields.update(flags=(Flag.INERTIA_UNCERTAIN,), lost_samples=2, I_held=True, B_held=False)
    return WindowEstimate(**{**numbers, **fields, **changes})


def track(**changes: Any) -> Tracked:
    values = dict(K=118.0, K_se=1.0, B=0.4, B_se=0.05)
    values.update(changes)
    return Tracked(**values)


def message(
    window, reason, tracked, *, seq, first, last, fs_hz, flags=(), **rest
) -> EstimateMessage:
    """The reference: every field of the message by name."""
    reflex_seq = rest.pop("reflex_seq", None)
    numbers = ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit")
    numbers += ("lost_samples", "I_held", "B_held")
    return EstimateMessage(
        seq=seq,
        window_start_index=first,
        window_end_index=last,
        t_start_s=first / fs_hz,
        t_end_s=last / fs_hz,
        **{k: getattr(window, k) if window else None for k in numbers},
        K_track=tracked.K if tracked else None,
        K_track_se=tracked.K_se if tracked else None,
        B_track=tracked.B if tracked else None,
        B_track_se=tracked.B_se if tracked else None,
        compute_ms=rest.pop("compute_ms", None),
        latency_ms=rest.pop("latency_ms", None),
        ok=window is not None,
        reason=reason,
        flags=(*window.flags, *flags) if window else (),
        reflex_seq=reflex_seq if window else None,
        host_time_ns=time.time_ns(),
        **rest,
    )


CASES = [
    (estimate(), None, track(), {}),
    (estimate(I_se=math.nan, K=np.float64(math.inf)), None, track(K=math.nan), {}),
    (estimate(vaf=np.float64(math.nan)), None, None, {"flags": (Flag.OVER_BUDGET,)}),
    (None, Reason.GAP, track(), {"flags": (Flag.OVER_BUDGET,), "reflex_seq": 3}),
    (None, Reason.STALE, None, {"compute_ms": 0.0, "latency_ms": None}),
    (estimate(), None, track(B=math.nan, B_se=math.nan), {"reflex_seq": 7, "latency_ms": 1.5}),
    # every number field of an estimate with its track non-finite (the one-display build)
    (
        estimate(B=-math.inf, B_se=math.nan, I=math.nan, vaf_irf=math.inf, vaf_fit=math.nan),
        None,
        track(K=math.inf, K_se=-math.inf, B=np.float64(math.nan), B_se=math.nan),
        {"compute_ms": math.nan, "latency_ms": math.inf, "reflex_seq": 2},
    ),
    (estimate(K_se=np.float64(-math.inf), vaf=math.nan), None, track(), {"compute_ms": 0.25}),
]


@pytest.mark.parametrize(("window", "reason", "tracked", "extra"), CASES)
def test_window_dict_is_the_messages_json_object(window, reason, tracked, extra) -> None:
    kwargs = dict(seq=4, first=250, last=999, fs_hz=2500.0, robot="r", joint="j", **extra)
    fast = EstimateMessage.window_dict(window, reason, tracked, **kwargs)
    slow = message(window, reason, tracked, **kwargs).as_dict()
    assert fast.pop("host_time_ns") > 0 and slow.pop("host_time_ns") > 0
    assert list(fast) == list(slow)  # the same keys, in the same (schema) order
    for key in slow:
        assert type(fast[key]) is type(slow[key]), key
        assert fast[key] == slow[key], key
    assert [*fast, "host_time_ns"] == list(ESTIMATE_SCHEMA["properties"])


@pytest.mark.skipif(messages._FINITE_DICT is None, reason="compiled kernel not built")
@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_json_object_is_the_comprehensions(seed) -> None:
    # finite_dict (one call, the dict sized once) against the reference: every key in order,
    # every value the same object but a non-finite float (Python's or numpy's) as None
    rng = np.random.default_rng(seed)
    pool: list[Any] = [1.5, -0.0, math.nan, math.inf, -math.inf, np.float64(math.nan)]
    pool += [np.float64(2.5), np.float64(-math.inf), 3, True, None, "r", [Flag.LOW_VAF], 10**20]
    values = tuple(pool[int(k)] for k in rng.integers(0, len(pool), len(messages._ESTIMATE_NAMES)))
    got = messages._json_object(values)
    want = messages._json_object_reference(values)
    assert list(got) == list(want) == list(messages._ESTIMATE_NAMES)
    assert all(got[k] is want[k] for k in want)
    with pytest.raises(TypeError):
        messages._FINITE_DICT(messages._ESTIMATE_NAMES, values[:-1])
