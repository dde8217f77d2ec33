"""The link benchmark's measuring parts work (its figures come from running it, not from here)."""

import numpy as np

from rtsid.benchmarks.link import LatencyHistogram, measure


def test_histogram_quantiles_match_numpy_within_a_bin(rng):
    samples = rng.exponential(0.002, 50_000)
    hist = LatencyHistogram()
    hist.add(samples[:20_000])
    hist.add(samples[20_000:])
    for q in (0.5, 0.99, 0.999):
        assert abs(hist.quantile_s(q) - np.quantile(samples, q)) <= 5e-6
    assert hist.max_s == samples.max()


def test_a_short_virtual_run_accounts_for_every_sample():
    result = measure("virtual", 2500.0, 0.5, rss_every_s=0.25)
    assert result.received > 500 and result.lost == 0 and result.unexplained == 0
    assert result.received == result.sent
    assert 0 < result.latency.quantile_s(0.5) < 1.0 and result.cpu_percent > 0
