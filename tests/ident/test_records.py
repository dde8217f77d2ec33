"""The per-window path's records built without their ``__init__`` (rtsid.ident.records) are
the records their constructors give."""

import dataclasses

import numpy as np
import pytest

from rtsid.ident import fused
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.fit import Held
from rtsid.ident.records import built
from rtsid.ident.stream import WindowStream
from rtsid.ident.tracker import TrackerOptions
from rtsid.ident.window import EstimatorOptions, analyse_window
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance

FS = 2500.0


def _same_as_constructed(record):
    """``record`` equals its class's constructor given the same fields, field by field."""
    cls = type(record)
    assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen
    values = {f.name: getattr(record, f.name) for f in dataclasses.fields(cls)}
    assert set(vars(record)) == set(values), cls.__name__  # every field set, nothing else
    again = cls(**values)
    for name, value in values.items():
        if isinstance(value, np.ndarray):
            assert getattr(again, name) is value
        else:
            assert getattr(again, name) == value or value != value, (cls.__name__, name)
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(record, next(iter(values)), 0)


def test_built_gives_the_constructors_record():
    @dataclasses.dataclass(frozen=True)
    class Pair:
        a: float
        b: tuple[str, ...] = ()

    assert built(Pair, a=1.0, b=("x",)) == Pair(1.0, ("x",))
    assert hash(built(Pair, a=1.0, b=())) == hash(Pair(1.0))
    assert repr(built(Pair, a=2.0, b=())) == repr(Pair(2.0))


def test_every_record_of_a_streams_window_is_complete_and_frozen():
    theta = filtered_noise(round(2.0 * FS), FS, 30.0, peak=0.03, seed=5)
    profile = StiffnessProfile.sinusoid(150.0, 50.0, 0.5)
    tau = simulate_impedance(theta, FS, JointParameters(), profile, noise_percent=5.0, seed=6)
    stream = WindowStream(FS, EstimatorOptions(), 0.02, window_s=0.3, tracker=TrackerOptions())
    n, hop = 750, 50
    seen = set()
    for end in range(n, theta.size + 1, hop):
        position, torque = theta[end - n : end], tau[end - n : end]
        window = analyse_window(position, torque, FS, stream.options, stream.plan)
        estimate = stream.estimate(position, torque)
        source = stream._split_source
        newest = None if source is None else source.newest(0.02)
        track = stream.track((end - 1) / FS, estimate)
        for record in (window, window.irf, window.score, estimate, track, newest):
            if record is not None:
                _same_as_constructed(record)
                seen.add(type(record).__name__)
        _same_as_constructed(stream.tracker.stiffness._published(True, False))
        if fused.fusable(stream.options, window.score, False):
            held = Held(0.015, 0.8)
            _same_as_constructed(
                fused.fused_back_end(
                    *window.signals, stream.options, stream.plan, held, window.score
                )
            )
            seen.add("FusedWindow")
    assert seen - {"FusedWindow"} == {
        "AnalysedWindow",
        "IRF",
        "ScoredBand",
        "WindowEstimate",
        "Tracked",
        "NewestPart",
    }
    assert ("FusedWindow" in seen) == (fused._eureka is not None)
