"""The stream's per-window bookkeeping in C (section stream8 of ``_eureka.c``) against its
Python reference (rtsid.ident.stream): the running medians, and a whole stream whose held
parameters, typical excitation, flags and estimates are kept by the compiled
``stream_window``, bit for bit, state included."""

import dataclasses
import math

import numpy as np
import pytest

from rtsid.ident import onecall, stream, tracker
from rtsid.ident.split import NewestPart
from rtsid.ident.stream import RunningMedian, WindowStream, running_median, sliding_estimates
from rtsid.ident.tracker import TrackerOptions
from rtsid.ident.window import EstimatorOptions
from rtsid.verdicts import Reason
from tests.ident.test_onecall import assert_same_windows, hostile_recording, same

FS = 2500.0
pytestmark = pytest.mark.skipif(stream._eureka is None, reason="compiled kernel not built")


def _values(rng, count: int) -> list[float]:
    """Values a median meets: repeats, signed zeros, NaN runs, a wide and a narrow spread."""
    pool = [0.0, -0.0, 1.0, 1.0, 2.5, -3.0, 1e-300, 1e300, -1e300]
    out: list[float] = []
    for i in range(count):
        pick = i % 11
        if pick == 0:
            out.append(math.nan)
        elif pick in (1, 2):
            out.append(pool[int(rng.integers(len(pool)))])
        elif pick == 3 and 40 <= i % 300 < 60:  # a NaN run longer than some horizons
            out.append(math.nan)
        else:
            out.append(float(rng.normal(0.0, 10.0 if i % 2 else 1e-3)))
    return out


@pytest.mark.parametrize(
    ("horizon", "min_count"), [(1, 1), (1, 5), (2, 5), (5, 5), (7, 3), (50, 5), (501, 5), (0, 0)]
)
def test_the_compiled_running_median_is_the_reference(horizon, min_count):
    rng = np.random.default_rng(horizon * 31 + min_count)
    got, want = running_median(horizon, min_count), RunningMedian(horizon, min_count)
    assert not isinstance(got, RunningMedian)  # the compiled one
    assert got.min_count == want.min_count
    assert got.median() is None and want.median() is None
    values = _values(rng, 3000)
    values.append(np.float64(4.25))  # a numpy float, as a window's level may be
    for value in values:
        got.add(value)
        want.add(value)
        g, w = got.median(), want.median()
        assert (g is None) == (w is None)
        if w is not None:
            assert same(g, float(w))


def test_the_compiled_running_median_refuses_what_float_refuses():
    median = running_median(5, 1)
    with pytest.raises(TypeError):
        median.add("1.0")
    assert median.median() is None  # nothing was added


def _stream(theta, tau, options, *, compiled: bool, monkeypatch, calls: list | None = None):
    """The stream's results: compiled (the one call with its bookkeeping) or every Python
    reference (the step-by-step path, the Python medians and tracker)."""
    with monkeypatch.context() as patch:
        if not compiled:
            patch.setattr(stream, "_eureka", None)
            patch.setattr(stream, "one_call_possible", lambda _: False)
            patch.setattr(tracker, "_eureka", None)
        elif calls is not None:
            bookkept = onecall.WindowCall.stream_window

            def counted(self, *args):
                result = bookkept(self, *args)
                calls.append(result is not None)
                return result

            patch.setattr(onecall.WindowCall, "stream_window", counted)
        s = WindowStream(FS, options, 0.02, window_s=0.3, tracker=TrackerOptions())
        results = list(sliding_estimates(theta, tau, FS, 0.3, 0.02, stream=s))
    return results, s


@pytest.mark.parametrize(
    "options",
    [
        EstimatorOptions(hold="inertia_damping"),
        EstimatorOptions(hold="inertia"),
        EstimatorOptions(hold="inertia_damping", hold_inertia=0.012),
        EstimatorOptions(hold="inertia_damping", low_vaf_percent=97.0),  # learns from few
    ],
    ids=["inertia_damping", "inertia", "given_inertia", "strict_vaf"],
)
def test_the_bookkept_stream_is_the_python_reference_bit_for_bit(options, monkeypatch):
    theta, tau, _ = hostile_recording(14.0, 11, sign_flip=True)
    calls: list[bool] = []
    got, got_stream = _stream(
        theta, tau, options, compiled=True, monkeypatch=monkeypatch, calls=calls
    )
    want, want_stream = _stream(theta, tau, options, compiled=False, monkeypatch=monkeypatch)
    assert isinstance(want_stream.excitation, RunningMedian)  # the reference's medians
    assert not isinstance(got_stream.excitation, RunningMedian)
    assert len(got) == len(want) > 600
    assert sum(calls) >= sum(w.estimate is not None for w in want) > 300
    assert not all(calls)  # some windows were declined (and taken by the step-by-step path)
    reasons = {w.reason for w in want}
    assert {None, Reason.NAN, Reason.NO_EXCITATION} <= reasons
    flagged = sum(bool(w.estimate.flags) for w in want if w.estimate is not None)
    assert flagged > 0  # flags were raised
    assert_same_windows(got, want)
    assert got_stream.held.current() == want_stream.held.current()
    assert got_stream.held.current() is got_stream.held.current()  # one object until learned
    assert same(got_stream.excitation.median(), want_stream.excitation.median())
    for mine, theirs in zip(got_stream.held.medians, want_stream.held.medians, strict=True):
        assert same(mine.median(), theirs.median())


def _same_as_constructed(record) -> None:
    """``record`` (built in C) equals its class's constructor given the same fields."""
    cls = type(record)
    assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen
    values = {f.name: getattr(record, f.name) for f in dataclasses.fields(cls)}
    assert list(vars(record)) == list(values), cls.__name__  # every field, in order
    again = cls(**values)
    for name, value in values.items():
        assert getattr(again, name) is value or same(getattr(again, name), value), name
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(record, next(iter(values)), 0)


def test_the_records_built_in_c_are_their_constructors(monkeypatch):
    theta, tau, _ = hostile_recording(4.0, 12, sign_flip=True)
    got, s = _stream(theta, tau, EstimatorOptions(), compiled=True, monkeypatch=monkeypatch)
    estimates = [w.estimate for w in got if w.estimate is not None]
    assert len(estimates) > 100
    for estimate in estimates[::10]:
        _same_as_constructed(estimate)
    for w in got[::10]:
        _same_as_constructed(w)  # the WindowResult
    # the tracker's calm step answers a TrackEstimate record, the stream's call a NewestPart
    k = s.tracker.stiffness
    steps = []
    for i, w in enumerate(got[-20:]):
        steps.append(k.step(w.t_end_s + 1.0 + 0.02 * i, 150.0 + i % 3, 2.0))
    calm = [step for step in steps if step.mode in ("quiet", "trend", "fast")]
    assert calm
    for step in calm:
        _same_as_constructed(step)
    estimate = s.estimate(theta[-750:], tau[-750:])  # one window more, its source kept
    source = s._split_source
    assert source is not None and source.estimate is estimate
    part = source.newest(0.02)
    assert type(part) is NewestPart  # as stream_window built it
    _same_as_constructed(part)


def test_held_values_give_the_learned_record_when_they_hold_its_values():
    from rtsid.ident.fit import NOT_HELD, Held, held_values

    learned = Held(0.012, 0.9)
    both = EstimatorOptions(hold="inertia_damping")
    assert held_values(both, learned) is learned  # what a stream reads every window
    assert held_values(both, NOT_HELD) is NOT_HELD
    inertia_only = held_values(EstimatorOptions(hold="inertia"), learned)
    assert inertia_only == Held(0.012, None) and inertia_only is not learned
    given = held_values(EstimatorOptions(hold="inertia_damping", hold_inertia=0.02), learned)
    assert given == Held(0.02, 0.9)


def test_the_compiled_flags_are_window_flags_on_any_numbers():
    from rtsid.ident import assess

    kernel = stream._eureka
    rng = np.random.default_rng(8)
    options = EstimatorOptions()
    low = float(options.low_vaf_percent)
    edges = [0.0, -0.0, math.nan, math.inf, -math.inf, 1e-300, -1e-300]
    for _ in range(4000):
        params = tuple(
            float(rng.choice(edges)) if rng.random() < 0.15 else float(rng.normal(0, 100))
            for _ in range(3)
        )
        # standard errors near each threshold (SE 25 % of |I|, 10 % of |K|), NaN when held
        se = [abs(params[i]) * float(rng.choice([0.1, 0.25, 0.26, 0.24])) for i in range(3)]
        se = tuple(math.nan if rng.random() < 0.2 else v for v in se)
        vafs = tuple(
            float(rng.choice([low, 50.0, math.nan, low - 1e-12, 49.9, 100.0]))
            if rng.random() < 0.3
            else float(rng.uniform(-50.0, 100.0))
            for _ in range(3)
        )
        want = assess.window_flags(params, se, vafs, options)  # type: ignore[arg-type]
        got = kernel.window_flags(params, se, vafs, low, assess.FLAG_ORDER)
        assert got == want and all(g is w for g, w in zip(got, want, strict=True))
