"""The slow lane's fit-to-fit store: what a fit takes from the previous one is the same numbers
bit for bit, on the compiled and the numpy path, and is checked rather than assumed."""

import numpy as np
import pytest

from rtsid.ident import reflex_lane, yardstick
from rtsid.ident.reflex_lane import SlowLaneSettings, fit_reflex_update
from rtsid.ident.yardstick import BasisStore, WindowVafBasis
from tests.ident.test_cascade import FS, joint_with_reflex

COMPILED = yardstick._eureka is not None


def _path(compiled, monkeypatch):
    if compiled and not COMPILED:
        pytest.skip("the compiled kernel is not built")
    if not compiled:
        monkeypatch.setattr(yardstick, "_eureka", None)
        monkeypatch.setattr(reflex_lane, "_eureka", None)


def _assert_same_basis(got, want):
    assert got.torque.tobytes() == want.torque.tobytes()
    assert got.regressors.tobytes() == want.regressors.tobytes()


@pytest.mark.parametrize("compiled", [True, False])
def test_the_store_forms_the_basis_of_a_record_formed_afresh_bit_for_bit(compiled, monkeypatch):
    _path(compiled, monkeypatch)
    rng = np.random.default_rng(7)
    x = rng.standard_normal(20_000).cumsum() * 1e-3
    y = rng.standard_normal(20_000)
    store = BasisStore()
    # forwards, the same record again, forwards past the buffers' end (moved, carrying),
    # backwards before their start (moved, carrying), a jump back with no overlap, a record
    # inside the last one, a jump forwards
    spans = [(0, 4_000), (1_000, 4_000), (1_000, 4_000), (2_000, 4_000), (5_000, 4_000)]
    spans += [(8_500, 4_000), (7_500, 4_000), (0, 4_000), (500, 2_000), (16_000, 3_000)]
    carried = []
    for first, n in spans:
        got = store.basis(x[first : first + n], y[first : first + n], FS, first)
        _assert_same_basis(got, WindowVafBasis(x[first : first + n], y[first : first + n], FS))
        carried.append(store.carried)
    # a record sharing s samples with the last carries the interior of both: s − 10
    assert carried == [0, 2_990, 3_990, 2_990, 990, 490, 2_990, 0, 1_990, 0]


@pytest.mark.parametrize("compiled", [True, False])
def test_the_store_carries_nothing_where_the_samples_differ(compiled, monkeypatch):
    _path(compiled, monkeypatch)
    rng = np.random.default_rng(8)
    x = rng.standard_normal(6_000).cumsum() * 1e-3
    y = rng.standard_normal(6_000)
    store = BasisStore()
    store.basis(x[:4_000], y[:4_000], FS, 0)
    changed = x[1_000:5_000].copy()
    changed[1_500] = np.nextafter(changed[1_500], np.inf)  # one sample, one ulp
    got = store.basis(changed, y[1_000:5_000], FS, 1_000)
    assert store.carried == 0
    _assert_same_basis(got, WindowVafBasis(changed, y[1_000:5_000], FS))
    # other data at the same indices, and another rate, carry nothing either
    other = rng.standard_normal(4_000).cumsum()
    _assert_same_basis(
        store.basis(other, y[:4_000], FS, 1_000), WindowVafBasis(other, y[:4_000], FS)
    )
    assert store.carried == 0
    store.basis(x[:4_000], y[:4_000], FS, 0)
    got = store.basis(x[1_000:5_000], y[1_000:5_000], 2 * FS, 1_000)
    assert store.carried == 0
    _assert_same_basis(got, WindowVafBasis(x[1_000:5_000], y[1_000:5_000], 2 * FS))
    # a record too short to hold an interior is formed alone and forgets the kept one
    short = store.basis(x[:20], y[:20], FS, 0)
    _assert_same_basis(short, WindowVafBasis(x[:20], y[:20], FS))
    store.basis(x[:4_000], y[:4_000], FS, 0)
    assert store.carried == 0


def test_the_compiled_range_is_the_convolutions_interior_and_writes_nothing_else():
    if not COMPILED:
        pytest.skip("the compiled kernel is not built")
    kernel = yardstick._eureka
    x = np.random.default_rng(9).standard_normal(500).cumsum()
    taps = yardstick._savgol_taps(FS)
    d1, d2 = np.empty(x.size), np.empty(x.size)
    kernel.savgol_pair(x, taps[0], taps[1], d1, d2)
    for lo, hi in ((5, 495), (5, 6), (17, 18), (100, 103), (250, 250), (30, 495)):
        r1, r2 = np.full(x.size, 7.0), np.full(x.size, 7.0)
        kernel.savgol_range(x, taps[0], taps[1], lo, hi, r1, r2)
        np.testing.assert_array_equal(r1[lo:hi], d1[lo:hi])
        np.testing.assert_array_equal(r2[lo:hi], d2[lo:hi])
        assert np.all(np.delete(r1, np.arange(lo, hi)) == 7.0)
        assert np.all(np.delete(r2, np.arange(lo, hi)) == 7.0)
    for lo, hi in ((4, 10), (10, 496), (20, 19)):
        with pytest.raises(ValueError, match="savgol_range"):
            kernel.savgol_range(x, taps[0], taps[1], lo, hi, r1, r2)


def test_the_compiled_finiteness_check_is_numpys():
    if not COMPILED:
        pytest.skip("the compiled kernel is not built")
    kernel = yardstick._eureka
    for n in (0, 1, 3, 4, 5, 9, 1_001):
        for bad in (np.nan, np.inf, -np.inf):
            for at in sorted({0, n // 2, n - 1}) if n else []:
                x = np.ones(n) * 1e308
                x[at] = bad
                assert not kernel.all_finite(x, np.ones(3)) and not kernel.all_finite(np.ones(3), x)
        assert kernel.all_finite(-np.full(n, 1e308), np.zeros(n))


def _fields(update):
    p = update.pathway
    return (
        update.applied,
        update.iterations,
        update.error,
        np.array(
            [
                update.vaf_total,
                update.vaf_intrinsic_only,
                update.window_vaf_gain,
                update.windows_improved,
            ]
        ).tobytes(),
        None if p is None else (p.irf.tobytes(), p.rank, p.dynamics),
    )


@pytest.mark.parametrize("compiled", [True, False])
def test_consecutive_fits_equal_fits_formed_afresh_and_lost_samples_reset_the_store(
    compiled, monkeypatch
):
    _path(compiled, monkeypatch)
    store = BasisStore()
    monkeypatch.setattr(reflex_lane, "EVIDENCE_BASES", store)
    theta, torque = joint_with_reflex(seconds=16.0, seed=5)
    settings = SlowLaneSettings(horizon_s=12.0, update_s=2.0)
    horizon, update = round(12.0 * FS), round(2.0 * FS)
    valid = np.ones(horizon, bool)
    valid[horizon - 1_500] = False  # one lost sample, bridged
    runs = [(0, None), (update, None), (2 * update, valid), (2 * update, None)]

    def fit(start, lost):
        span = slice(start, start + horizon)
        return fit_reflex_update(0, start, theta[span], torque[span], lost, FS, settings)

    afresh = []
    for start, lost in runs:
        store.clear()
        afresh.append(_fields(fit(start, lost)))
    store.clear()
    carried = []
    for (start, lost), want in zip(runs, afresh, strict=True):
        assert _fields(fit(start, lost)) == want
        carried.append(store.carried)
    # the second fit carries what it shares with the first; the bridged one neither uses nor
    # leaves anything, so the one after it starts afresh
    assert carried[0] == 0 and carried[1] == 27_500 - update - 10 and carried[2:] == [0, 0]
    assert afresh[0][2] is None and afresh[2][2] is None


def test_a_fit_of_strided_rows_is_the_fit_of_their_copies(monkeypatch):
    monkeypatch.setattr(reflex_lane, "EVIDENCE_BASES", BasisStore())
    theta, torque = joint_with_reflex(seconds=8.0, seed=6)
    rows = np.stack((theta, torque), axis=1)  # columns: strided views
    settings = SlowLaneSettings(horizon_s=8.0)
    strided = fit_reflex_update(0, 0, rows[:, 0], rows[:, 1], None, FS, settings)
    reflex_lane.EVIDENCE_BASES.clear()
    assert _fields(strided) == _fields(fit_reflex_update(0, 0, theta, torque, None, FS, settings))
    assert strided.error is None
