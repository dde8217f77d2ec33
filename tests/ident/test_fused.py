"""The window's back end in one compiled call (rtsid.ident.fused) against its numpy reference."""

import numpy as np
import pytest

from rtsid.errors import NumericalError
from rtsid.ident import fused, second_order, split, stream
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.fit import Held
from rtsid.ident.stream import WindowStream, sliding_estimates
from rtsid.ident.tracker import TrackerOptions
from rtsid.ident.window import EstimatorOptions, analyse_window, resolve_plan
from rtsid.sim.joint import JointParameters, StiffnessProfile, simulate_impedance

FS = 2500.0
FIELDS = ("I", "B", "K", "I_se", "B_se", "K_se", "vaf", "vaf_irf", "vaf_fit")

pytestmark = pytest.mark.skipif(fused._eureka is None, reason="compiled kernel not built")


def _recording(seconds, seed, profile=None):
    theta = filtered_noise(round(seconds * FS), FS, 30.0, peak=0.03, seed=seed)
    tau = simulate_impedance(
        theta, FS, JointParameters(), profile, noise_percent=5.0, seed=seed + 1
    )
    return theta, tau


def _stream_results(theta, tau, options):
    stream = WindowStream(FS, options, 0.02, window_s=0.3, tracker=TrackerOptions())
    return list(sliding_estimates(theta, tau, FS, 0.3, 0.02, stream=stream))


def _close(got, want, what):
    if np.isnan(want):
        assert np.isnan(got), what
    else:
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12), what


@pytest.mark.parametrize("hold", ["inertia_damping", "inertia", "none"])
def test_the_streams_compiled_windows_and_track_equal_the_numpy_path(hold, monkeypatch):
    # a stiffness that moves: the held parameters learn, the tracker reads newest hops and
    # scans splits; every estimate and tracked value must be the numpy path's
    theta, tau = _recording(8.0, 3, StiffnessProfile.sinusoid(150.0, 50.0, 0.25))
    options = EstimatorOptions(hold=hold)
    compiled = _stream_results(theta, tau, options)
    monkeypatch.setattr(fused, "_eureka", None)
    monkeypatch.setattr(stream, "one_call_possible", lambda _: False)  # nor in one call
    monkeypatch.setattr(split, "_eureka", None)  # the split scans in numpy too
    reference = _stream_results(theta, tau, options)
    assert len(compiled) == len(reference) > 300
    estimated = 0
    for got, want in zip(compiled, reference, strict=True):
        assert got.reason == want.reason
        if want.estimate is not None:
            estimated += 1
            for name in FIELDS:
                _close(getattr(got.estimate, name), getattr(want.estimate, name), name)
            assert got.estimate.flags == want.estimate.flags
            assert (got.estimate.I_held, got.estimate.B_held) == (
                want.estimate.I_held,
                want.estimate.B_held,
            )
        for name in ("K", "K_se", "B", "B_se"):
            _close(getattr(got.track, name), getattr(want.track, name), f"track {name}")
    assert estimated > 300


@pytest.mark.parametrize("held", [Held(), Held(0.015), Held(0.015, 0.8)])
def test_the_newest_hops_k_is_the_split_problems(held, monkeypatch):
    theta, tau = _recording(0.3, 11)
    options = EstimatorOptions()
    plan = resolve_plan(theta, FS, options)
    window = analyse_window(theta, tau, FS, options, plan)
    irf, u, y = window.signals
    rows = round(0.02 * plan.analysis_fs_hz)
    got = fused.fused_back_end(
        irf, u, y, options, plan, held, window.score, learn=True, newest_rows=rows
    )
    monkeypatch.setattr(second_order, "_eureka", None)
    design = second_order.OutputErrorDesign(u, y, irf.fs_hz)
    want = split.SplitProblem.of(design, held.inertia, held.damping, plan, theta.size)
    assert want is not None and got.newest is not None
    newest = want.newest(0.02)
    assert newest is not None
    k, var, row = got.newest
    assert k == pytest.approx(newest.k, rel=1e-9)
    assert var == pytest.approx(newest.var, rel=1e-9)
    assert split.row_offsets_s(row, plan, theta.size) == pytest.approx(newest.centre_s, rel=1e-12)
    whole = design.fit()
    assert (got.whole_inertia, got.whole_damping) == pytest.approx(
        (whole.params[0], whole.params[1]), rel=1e-9
    )
    assert got.estimate.I_held == (held.inertia is not None)
    assert got.estimate.B_held == (held.damping is not None)


def test_a_window_without_torque_raises_as_the_numpy_fit():
    theta, _ = _recording(0.3, 12)
    options = EstimatorOptions()
    plan = resolve_plan(theta, FS, options)
    window = analyse_window(theta, np.zeros_like(theta), FS, options, plan)
    irf, u, y = window.signals
    with pytest.raises(NumericalError, match="torque does not follow position"):
        fused.fused_back_end(irf, u, y, options, plan, Held(), window.score, learn=True)


@pytest.mark.parametrize("sign", [1, -1])
def test_the_explained_torque_is_band_limited_as_in_numpy(sign, monkeypatch):
    from rtsid.ident import front

    theta, tau = _recording(0.3, 13)
    options = EstimatorOptions(torque_sign=sign)
    plan = resolve_plan(theta, FS, options)
    reflex = 0.3 * np.sin(np.arange(theta.size) / 40.0) + 0.1
    got = front.scored_band(theta, tau, options, plan, reflex)
    monkeypatch.setattr(front, "_eureka", None)
    want = front.scored_band(theta, tau, options, plan, reflex)
    assert got.explained is not None and want.explained is not None
    scale = np.abs(want.explained).max()
    np.testing.assert_allclose(got.explained, want.explained, rtol=1e-9, atol=1e-12 * scale)
    assert (got.position_slope, got.torque_slope) == (want.position_slope, want.torque_slope)


def test_the_compiled_front_ends_level_and_slopes_are_numpys(monkeypatch):
    # window_irf also returns std(u) (the excitation level) and the trends' slopes
    from rtsid.ident import front

    theta, tau = _recording(0.3, 14)
    theta = theta + np.linspace(0.0, 0.01, theta.size)  # a trend to score
    options = EstimatorOptions(torque_sign=-1)
    plan = resolve_plan(theta, FS, options)
    got = analyse_window(theta, -tau, FS, options, plan)
    monkeypatch.setattr(front, "_eureka", None)
    want = analyse_window(theta, -tau, FS, options, plan)
    assert got.excitation_rad == pytest.approx(want.excitation_rad, rel=1e-12)
    assert got.score.position_slope == pytest.approx(want.score.position_slope, rel=1e-9)
    assert got.score.torque_slope == pytest.approx(want.score.torque_slope, rel=1e-9)
    assert abs(want.score.position_slope) > 0
