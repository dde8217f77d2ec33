import numpy as np
import pytest

from rtsid.errors import WindowError
from rtsid.ident.excitation import filtered_noise
from rtsid.ident.gaps import clean_rows, contaminated, count_lost
from rtsid.ident.stream import WindowStream
from rtsid.ident.window import EstimatorOptions, estimate_window
from rtsid.sim.joint import JointParameters, simulate_impedance

FS = 2500.0


def window(seed, loss=0.01):
    rng = np.random.default_rng(seed)
    theta = filtered_noise(2750, FS, 30.0, peak=0.03, seed=rng)
    tau = simulate_impedance(
        theta, FS, JointParameters(0.015, 0.8, 150.0), noise_percent=10.0, seed=rng
    )
    valid = rng.random(750) > loss
    return theta[1000:1750].copy(), tau[1000:1750].copy(), valid


def test_lost_samples_are_never_interpolated_their_values_do_not_matter():
    p, t, valid = window(0)
    assert 0 < (~valid).sum() <= 15
    est = estimate_window(p, t, FS, hold="none", valid=valid)
    p[~valid], t[~valid] = np.nan, 1e9  # whatever the lost rows hold
    again = estimate_window(p, t, FS, hold="none", valid=valid)
    assert again.as_dict() == est.as_dict()
    assert est.lost_samples == int((~valid).sum())
    assert est.K == pytest.approx(150.0, rel=0.05)


def test_at_one_percent_loss_nearly_every_window_is_estimated_nearly_as_well():
    errors, lossless, estimated = [], [], 0
    for seed in range(30):
        p, t, valid = window(seed)
        lossless.append(abs(estimate_window(p, t, FS, hold="none").K - 150.0))
        try:
            est = estimate_window(p, t, FS, hold="none", valid=valid)
        except WindowError:
            continue
        estimated += 1
        errors.append(abs(est.K - 150.0))
    assert estimated >= 27  # ≥ 90 %
    assert np.median(errors) <= 1.5 * np.median(lossless)


def test_past_the_limits_the_window_is_withheld_as_gap():
    p, t, _ = window(1)
    long_run = np.ones(p.size, dtype=bool)
    long_run[300:312] = False  # 4.8 ms, 1.6 % of the window
    with pytest.raises(WindowError, match="max_gap_s") as info:
        estimate_window(p, t, FS, valid=long_run)
    assert info.value.reason == "gap"
    many = np.ones(p.size, dtype=bool)
    many[::20] = False  # 5 %
    with pytest.raises(WindowError, match="max_lost_percent"):
        estimate_window(p, t, FS, valid=many)


def test_a_stream_plans_from_the_longest_valid_stretch():
    p, t, valid = window(2)
    stream = WindowStream(FS, EstimatorOptions(), 0.02)
    est = stream.estimate(p, t, valid)
    clean = WindowStream(FS, EstimatorOptions(), 0.02)
    clean.estimate(p, t)
    assert est.lost_samples > 0
    assert stream.plan.lowpass_hz == pytest.approx(clean.plan.lowpass_hz, rel=0.3)


def test_contamination_reaches_as_far_as_the_filter_and_the_stencils():
    valid = np.ones(100, dtype=bool)
    valid[50] = False
    bad = contaminated(valid, taps=11, factor=1)
    assert bad.size == 90 and np.flatnonzero(bad).tolist() == list(range(40, 51))
    rows = clean_rows(bad, 4)
    # row r is analysis sample r + 4, its stencil spans r … r + 8
    assert rows.size == 82 and not rows[32:51].any() and rows[:32].all() and rows[51:].all()
    assert count_lost(valid, FS, 2.0, 0.004).longest_run == 1
