"""The link benchmark's measuring parts work (its figures come from running it, not from here)."""

import numpy as np
import pytest

from rtsid.benchmarks.link import LatencyHistogram, fault_mismatches, measure


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


@pytest.mark.parametrize(("transport", "rate_hz"), [("twoframe", 2000.0), ("udp", 2500.0)])
def test_a_short_run_of_a_new_path_counts_injected_faults_exactly(transport, rate_hz):
    result = measure(transport, rate_hz, 1.5, rss_every_s=1.0, faults_percent=2.0)
    assert result.plant is not None and result.plant.duplicated > 0 and result.lost > 0
    assert fault_mismatches(result) == []
    assert result.received > 0.8 * rate_hz
