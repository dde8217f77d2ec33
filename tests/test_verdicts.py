"""Every declared withheld reason and flag can occur, and nothing else is emitted."""

import time

import numpy as np
import pytest

from rtsid.errors import WindowError
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.stream import sliding_estimates
from rtsid.ident.window import EstimatorOptions, estimate_window
from rtsid.io.messages import ESTIMATE_SCHEMA
from rtsid.link.protocol import STATUS_DISCONTINUITY, STATUS_TORQUE_SATURATED
from rtsid.link.ring import RingBuffer
from rtsid.runtime.worker import WindowEvaluator, WindowWorker, WorkerConfig, assess_window
from rtsid.sim.joint import JointParameters, simulate_impedance
from rtsid.verdicts import Flag, Reason

FS = 2500.0
ANKLE = JointParameters(0.015, 0.8, 150.0)


def joint_window(joint=ANKLE, noise=5.0, seed=0):
    rng = np.random.default_rng(seed)
    theta = filtered_noise(2750, FS, 30.0, peak=0.03, seed=rng)
    tau = simulate_impedance(theta, FS, joint, noise_percent=noise, seed=rng)
    return theta[1000:1750], tau[1000:1750]


def withheld_reason(position, torque, **kwargs):
    with pytest.raises(WindowError) as info:
        estimate_window(position, torque, FS, hold="none", **kwargs)
    return info.value.reason


def ring_snapshot(status_at=None, status=0, age_s=0.0):
    ring = RingBuffer(2000)
    theta, tau = joint_window()
    now = time.monotonic() - age_s
    for k in range(750):
        ring.append(theta[k], tau[k], status if k == status_at else 0, now, k / FS)
    return ring.read_since(0, 750)


def reasons_that_occur():
    p, t = joint_window()
    long_gap = np.ones(750, dtype=bool)
    long_gap[100:130] = False
    return {
        Reason.GAP: withheld_reason(p, t, valid=long_gap),
        Reason.NAN: withheld_reason(np.where(np.arange(750) == 9, np.nan, p), t),
        Reason.NO_EXCITATION: withheld_reason(np.zeros(750), t),
        Reason.TOO_SHORT: withheld_reason(p[:12], t[:12]),
        Reason.UNIDENTIFIABLE: withheld_reason(p, echoes(p, t), lag_s=0.04),
        Reason.NUMERICAL: next(iter(sliding_estimates(p, np.zeros(750), FS, 0.3, 0.1))).reason,
        Reason.SATURATED: assess_window(
            ring_snapshot(10, STATUS_TORQUE_SATURATED), time.monotonic(), 1.0
        ),
        Reason.STALE: assess_window(ring_snapshot(age_s=5.0), time.monotonic(), 1.0),
    } | {
        "discontinuity": assess_window(
            ring_snapshot(10, STATUS_DISCONTINUITY), time.monotonic(), 1.0
        )
    }


def test_every_withheld_reason_occurs_and_is_declared():
    seen = reasons_that_occur()
    assert seen.pop("discontinuity") == Reason.GAP
    assert seen == {reason: reason for reason in Reason}
    assert ESTIMATE_SCHEMA["properties"]["reason"]["enum"] == [*Reason, None]


def flags_of(joint, noise=5.0, torque=None, **options):
    p, t = joint_window(joint, noise)
    t = t if torque is None else torque(p, t)
    return set(estimate_window(p, t, FS, hold="none", **options).flags)


def echoes(p, t):
    """Torque from position 25 ms before minus 25 ms after: a ±40 ms IRF holds it (VAF
    > 99 %), no I/B/K does."""
    shift = round(0.025 * FS)
    late = np.concatenate((np.zeros(shift), p[:-shift]))
    early = np.concatenate((p[shift:], np.zeros(shift)))
    return 150.0 * (late - early)


def echoes_on_a_spring(p, t):
    """The echoes beside a spring: K > 0, the model still mismatched (published, flagged;
    echoes alone read K < 0 and are withheld as unidentifiable)."""
    return echoes(p, t) + 50.0 * p


def unrelated(p, t):
    return t + 3 * np.std(t) * np.sin(2 * np.pi * 7.0 * np.arange(t.size) / FS)


def test_every_flag_occurs_and_is_declared():
    ankle = ANKLE
    seen = {
        Flag.LOW_VAF: flags_of(ankle, torque=unrelated),
        Flag.MODEL_MISMATCH: flags_of(ankle, torque=echoes_on_a_spring, lag_s=0.04),
        Flag.NEGATIVE_STIFFNESS: flags_of(JointParameters(0.015, 0.8, -150.0)),
        Flag.NEGATIVE_DAMPING: flags_of(JointParameters(0.015, -0.8, 150.0)),
        Flag.NEGATIVE_INERTIA: flags_of(JointParameters(-0.015, 0.8, 150.0)),
        Flag.INERTIA_UNCERTAIN: flags_of(JointParameters(1e-6, 0.8, 150.0), noise=20.0),
        Flag.STIFFNESS_UNCERTAIN: flags_of(JointParameters(0.015, 0.8, 0.5), noise=20.0),
    }
    for flag, flags in seen.items():
        assert flag in flags, (flag, flags)
    assert Flag.LOW_VAF not in flags_of(ankle)
    published = []
    theta, tau = joint_window()
    ring = RingBuffer(2000)
    now = time.monotonic()
    for k in range(750):
        ring.append(theta[k], tau[k], 0, now, k / FS)
    config = WorkerConfig(budget_s=1e-9)
    worker = WindowWorker(ring, WindowEvaluator(FS, config, EstimatorOptions(), published.append))
    message = worker.process_window(749)
    assert Flag.OVER_BUDGET in message["flags"]
    assert ESTIMATE_SCHEMA["properties"]["flags"]["items"]["enum"] == list(Flag)
