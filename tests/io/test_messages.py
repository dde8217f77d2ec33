"""EstimateMessage.window_dict is of_window(...).as_dict(), key for key and in order."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from rtsid.ident.assess import WindowEstimate
from rtsid.ident.stream import Tracked
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


CASES = [
    (estimate(), None, track(), {}),
    (estimate(I_se=math.nan, K=np.float64(math.inf)), None, track(K=math.nan), {}),
    (estimate(vaf=np.float64(math.nan)), None, None, {"flags": (Flag.OVER_BUDGET,)}),
    (None, Reason.GAP, track(), {"flags": (Flag.OVER_BUDGET,), "reflex_seq": 3}),
    (None, Reason.STALE, None, {"compute_ms": 0.0, "latency_ms": None}),
    (estimate(), None, track(B=math.nan, B_se=math.nan), {"reflex_seq": 7, "latency_ms": 1.5}),
]


@pytest.mark.parametrize(("window", "reason", "tracked", "extra"), CASES)
def test_window_dict_is_the_messages_json_object(window, reason, tracked, extra) -> None:
    kwargs = dict(seq=4, first=250, last=999, fs_hz=2500.0, robot="r", joint="j", **extra)
    fast = EstimateMessage.window_dict(window, reason, tracked, **kwargs)
    slow = EstimateMessage.of_window(window, reason, tracked, **kwargs).as_dict()
    assert fast.pop("host_time_ns") > 0 and slow.pop("host_time_ns") > 0
    assert list(fast) == list(slow)  # the same keys, in the same (schema) order
    for key in slow:
        assert type(fast[key]) is type(slow[key]), key
        assert fast[key] == slow[key], key
    assert [*fast, "host_time_ns"] == list(ESTIMATE_SCHEMA["properties"])
