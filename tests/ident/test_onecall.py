"""A stream's window in one compiled call (rtsid.ident.onecall) and the tracker's calm step
(``tracker_step``) against the step-by-step path they replace: bit for bit, state included."""

import math

import numpy as np
import pytest

from rtsid.errors import WindowError
from rtsid.ident import onecall, stream, tracker
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.split import NewestPart, SplitScan
from rtsid.ident.stream import WindowStream, sliding_estimates
from rtsid.ident.tracker import ParameterTracker, TrackerOptions
from rtsid.ident.window import EstimatorOptions
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance
from rtsid.verdicts import Reason

FS = 2500.0
FIELDS = ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit", "flags")
FIELDS += ("lost_samples", "I_held", "B_held", "method", "fs_hz")

pytestmark = pytest.mark.skipif(onecall._eureka is None, reason="compiled kernel not built")


def same(got, want) -> bool:
    """Equal, NaN included (bit for bit for floats: -0.0 is not 0.0)."""
    if isinstance(want, float):
        if math.isnan(want):
            return isinstance(got, float) and math.isnan(got)
        return (
            isinstance(got, float)
            and math.copysign(1.0, got) == math.copysign(1.0, want)
            and got == want
        )
    return type(got) is type(want) and got == want


def assert_same_windows(got, want) -> None:
    """Two runs' window results equal bit for bit: reason, estimate (its record's fields, IRF
    and lags) and track."""
    for g, w in zip(got, want, strict=True):
        assert g.reason == w.reason
        assert (g.estimate is None) == (w.estimate is None)
        if w.estimate is not None:
            assert type(g.estimate) is type(w.estimate)
            assert vars(g.estimate).keys() == vars(w.estimate).keys()
            for name in FIELDS:
                assert same(getattr(g.estimate, name), getattr(w.estimate, name)), name
            assert np.array_equal(g.estimate.irf, w.estimate.irf)
            assert np.array_equal(g.estimate.lags_s, w.estimate.lags_s)
        for name in ("K", "K_se", "B", "B_se"):
            assert same(getattr(g.track, name), getattr(w.track, name)), name


def hostile_recording(seconds: float, seed: int, *, sign_flip: bool = False):
    """A stiffness step and a sinusoid, a paused perturbation, NaN samples, lost samples and
    a torque burst: every way a window is declined, withheld or flagged (``sign_flip``: also
    the torque's sign flipped over 600 samples from 85 % of the record on, a rejected fit)."""
    n = round(seconds * FS)
    theta = filtered_noise(n, FS, 30.0, peak=0.03, seed=seed)
    profile = StiffnessProfile.ramp(120.0, 320.0, 0.4 * seconds, 0.4 * seconds + 0.004)
    tau = simulate_impedance(theta, FS, JointParameters(), profile, noise_percent=5.0, seed=seed)
    tau[round(0.15 * n) : round(0.15 * n) + 8] = np.nan
    theta[round(0.25 * n) : round(0.3 * n)] *= 1e-4  # the perturbation pauses
    tau[round(0.7 * n) : round(0.7 * n) + 150] += 400.0  # a burst
    if sign_flip:
        tau[round(0.85 * n) : round(0.85 * n) + 600] *= -1.0
    valid = np.ones(n, dtype=bool)
    valid[round(0.55 * n) : round(0.55 * n) + 3] = False
    return theta, tau, valid


def _results(theta, tau, valid, options, *, compiled: bool, monkeypatch, done=None):
    """The stream's results; ``done`` (a list) collects whether each one call fitted its window."""
    with monkeypatch.context() as patch:
        if not compiled:
            patch.setattr(stream, "one_call_possible", lambda _: False)
            patch.setattr(tracker, "_eureka", None)
        elif done is not None:
            one_window = onecall.WindowCall.__call__
            bookkept = onecall.WindowCall.stream_window  # the call with the stream's bookkeeping

            def counted(self, *args):
                result = one_window(self, *args)
                done.append(result is not None)
                return result

            def counted_bookkept(self, *args):
                result = bookkept(self, *args)
                done.append(result is not None)
                return result

            patch.setattr(onecall.WindowCall, "__call__", counted)
            patch.setattr(onecall.WindowCall, "stream_window", counted_bookkept)
        s = WindowStream(FS, options, 0.02, window_s=0.3, tracker=TrackerOptions())
        results = list(sliding_estimates(theta, tau, FS, 0.3, 0.02, stream=s, valid=valid))
    return results, s


@pytest.mark.parametrize("lost", [False, True])
@pytest.mark.parametrize("hold", ["inertia", "inertia_damping"])
def test_the_streams_windows_in_one_call_are_the_step_by_step_ones_bit_for_bit(
    hold, lost, monkeypatch
):
    theta, tau, valid = hostile_recording(12.0, 5)
    if not lost:
        valid = None  # a stream told of no lost samples: every planned window tries the one call
    options = EstimatorOptions(hold=hold)
    done: list[bool] = []
    got, got_stream = _results(
        theta, tau, valid, options, compiled=True, monkeypatch=monkeypatch, done=done
    )
    want, want_stream = _results(
        theta, tau, valid, options, compiled=False, monkeypatch=monkeypatch
    )
    assert len(got) == len(want) > 500
    # without lost samples the one call fitted at least every estimate the reference gives (it
    # declines only windows the reference fails or withholds; a fitted window may still be
    # withheld by its flags); with a mask of lost samples every window takes the step-by-step path
    fitted = sum(w.estimate is not None for w in want)
    assert sum(done) >= fitted if not lost else sum(done) == 0
    reasons = {w.reason for w in want}
    assert {None, Reason.NAN, Reason.NO_EXCITATION} <= reasons  # the hostile parts came
    assert_same_windows(got, want)
    # the state carried on: held parameters, typical excitation, the trackers' every value
    assert got_stream.held.current() == want_stream.held.current()
    assert got_stream.excitation.median() == want_stream.excitation.median()
    for which in ("stiffness", "damping"):
        _assert_same_state(getattr(got_stream.tracker, which), getattr(want_stream.tracker, which))


def test_a_declined_window_leaves_the_stream_as_the_step_by_step_path_does():
    theta = filtered_noise(1500, FS, 30.0, peak=0.03, seed=6)
    tau = simulate_impedance(theta, FS, JointParameters(), noise_percent=5.0, seed=6)
    s = WindowStream(FS, EstimatorOptions(), 0.02, window_s=0.3)
    s.estimate(theta[:750], tau[:750])  # plans the stream
    state = (s.held.current(), s.excitation.median())
    quiet = theta[750:1500] * 1e-6
    with pytest.raises(WindowError, match="no perturbation"):
        s.estimate(quiet, tau[750:1500])
    assert (s.held.current(), s.excitation.median()) == state


def _assert_same_state(got: ParameterTracker, want: ParameterTracker) -> None:
    for name, value in vars(want).items():
        if name in ("_steps", "_by_dt", "_last"):
            continue  # caches of the transition, filled on demand
        other = getattr(got, name)
        if name in ("quiet", "trend", "fast"):
            if value is None:
                assert other is None
                continue
            for field in ("x0", "x1", "p00", "p01", "p11", "lag"):
                assert same(getattr(other, field), getattr(value, field)), (name, field)
        elif name == "_history":
            assert list(other) == list(value)
        elif name != "_all":
            assert same(other, value) or other == value, name


def _steps(seed: int):
    """A stream of (t, z, se, newest) with calm stretches, a step, a reversal, outliers,
    withheld windows (None, NaN, se <= 0) and irregular intervals."""
    rng = np.random.default_rng(seed)
    t, out = 0.3, []
    for k in range(900):
        t += 0.02 if k % 97 else 0.06  # a skipped window now and then
        level = 150.0 + (120.0 if 300 <= k < 600 else 0.0) + 20.0 * math.sin(0.01 * k)
        z: float | None = level + rng.normal(0.0, 1.5)
        se: float | None = abs(rng.normal(1.2, 0.1))
        if k % 53 == 7:
            z = z + 60.0  # an outlier # type: ignore[operator]
        if k % 41 == 5:
            z, se = None, None
        elif k % 43 == 9:
            se = math.nan
        elif k % 47 == 3:
            se = 0.0
        newest = NewestPart(level + rng.normal(0.0, 6.0), abs(rng.normal(8.0, 1.0)), 0.01)
        out.append((t, z, se, newest if k % 5 else None, _split_of(rng, k, level)))
    return out


def _split_of(rng, k: int, level: float):
    """The window's splits, as the stream hands them to the tracker: none (no samples), a
    scan finding nothing, nothing significant or a step (one in four scans)."""
    if k % 7 == 0:
        return None
    if k % 7 == 1:
        return lambda: None
    n = 40
    z_ratio = rng.normal(0.0, 1.0, n)
    k_after = level + rng.normal(0.0, 3.0, n)
    if k % 4 == 0:
        z_ratio[25], k_after[25:] = 400.0, level + 90.0  # a step at row 25
    offsets = np.linspace(0.29, 0.0, n)
    scan = SplitScan(offsets, k_after, np.full(n, level), z_ratio, np.full(n, 2.0), offsets > 0)
    return lambda: scan


@pytest.mark.parametrize("fast", [True, False])
def test_the_compiled_calm_step_is_the_trackers_python_step(fast, monkeypatch):
    options = TrackerOptions(stiffness_acceleration_noise=1000.0 if fast else 0.0)

    def run() -> tuple[list, ParameterTracker]:
        p = ParameterTracker(0.3, 0.02, 0.3, 100.0, options, options.stiffness_acceleration_noise)
        steps = _steps(7)
        return [p.step(t, z, se, split, newest) for t, z, se, newest, split in steps], p

    got, got_tracker = run()
    monkeypatch.setattr(tracker, "_eureka", None)
    want, want_tracker = run()
    modes = {w.mode for w in want}
    assert {"quiet", "change"} <= modes  # calm stretches and the change modes came
    for g, w in zip(got, want, strict=True):
        for name in ("value", "se", "rate", "updated", "change", "mode"):
            assert same(getattr(g, name), getattr(w, name)), name
    _assert_same_state(got_tracker, want_tracker)
