"""``rtsid bench tv``: its metrics on known tracks, and a quick run end to end (slow)."""

from __future__ import annotations

import numpy as np
import pytest

from rtsid.benchmarks import tv
from rtsid.cli import main


def test_rise_time_is_the_10_to_90_percent_time_of_each_step():
    t = np.arange(0, 6, tv.HOP_S)
    truth = np.where((t % 4.0) < 2.0, 150.0, 300.0)
    lagged = np.interp(t - 0.1, t, truth)  # a 100 ms linear ramp after each step (20 ms grid)
    ramp = np.convolve(truth, np.ones(10) / 10, mode="full")[: t.size]  # 200 ms ramp
    assert tv._rise_time(t, lagged, truth) == pytest.approx(0.0, abs=tv.HOP_S)
    assert tv._rise_time(t, ramp, truth) == pytest.approx(0.16, abs=1e-9)


def test_bias_random_and_total_error_separate_a_shared_offset_from_scatter():
    t = np.linspace(0, 10, 501)
    truth = np.full(t.size, 150.0)
    rng = np.random.default_rng(0)
    runs = [truth + 2.0 + rng.standard_normal(t.size) for _ in range(50)]
    bias, random, total = tv._metrics(t, runs, truth)
    assert bias == pytest.approx(2.0, abs=0.2)
    assert random == pytest.approx(1.0, abs=0.05)
    assert total == pytest.approx(np.hypot(2.0, 1.0), abs=0.1)


@pytest.mark.slow  # a minute of window estimates
def test_bench_tv_quick_prints_the_table_floors_and_cost(capsys, tmp_path):
    assert main(["bench", "tv", "--quick", "--figures", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    expected = ("tracker", "window 300 ms", "oracle 300 ms", "skirt legendre", "floors", "cost")
    for text in (*expected, "real record"):
        assert text in out
    assert len(list(tmp_path.glob("tv_*.png"))) == len(tv.profiles(8.0))


def test_the_step_oracle_reads_the_step_off_noiseless_ramping_windows():
    t = np.arange(0, 10, tv.HOP_S)
    truth = np.where((t % 4.0) < 2.0, tv.K0, 2 * tv.K0)
    boxcar = np.array([truth[max(0, k - 14) : k + 1].mean() for k in range(t.size)])
    tracks = [{"_t": t, "_truth": truth, "window 300 ms": boxcar} for _ in range(2)]
    tv._add_step_oracle(tracks)
    oracle = tracks[0]["oracle step read-out"]
    steps = np.flatnonzero(np.abs(np.diff(truth)) > 0.5 * tv.K0) + 1
    for k0 in steps:
        assert oracle[k0] == pytest.approx(truth[k0 - 1])  # no sample after the step yet
        # from the next window on, the fitted read-out of a noiseless ramp is exact
        np.testing.assert_allclose(oracle[k0 + 1 : k0 + 40], truth[k0 + 1 : k0 + 40], atol=1e-6)
    assert np.abs(boxcar - truth)[steps + 5].min() > 40.0  # while the windows still ramp
