"""The evaluator's check of a window's rows in one compiled pass (``window_scan``) against its
numpy reference: the status bits raised, every row valid, the valid rows finite."""

from __future__ import annotations

import numpy as np
import pytest

from rtsid.ident import check

compiled = pytest.mark.skipif(check._eureka is None, reason="compiled kernel not built")


def columns(rng: np.random.Generator, n: int, *, lost: int, nan_in_lost: bool, nan: bool):
    """Position, torque, valid and status columns of ``n`` rows: ``lost`` lost rows (NaN
    there when ``nan_in_lost``), a NaN in a valid row when ``nan``, a few status bits."""
    position = 0.03 * rng.standard_normal(n)
    torque = 40.0 * rng.standard_normal(n)
    valid = np.ones(n, dtype=bool)
    valid[rng.choice(n, size=lost, replace=False)] = False
    if nan_in_lost:
        position[~valid], torque[~valid] = np.nan, np.nan
    if nan:
        torque[int(np.flatnonzero(valid)[n // 3])] = np.inf
    status = np.zeros(n, dtype=np.uint8)
    status[rng.choice(n, size=3, replace=False)] = rng.choice([1, 2, 4, 8, 16], size=3)
    return position, torque, valid, status


@compiled
@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_scan_is_numpys_reference(seed):
    rng = np.random.default_rng(seed)
    n = 1200
    pos, tor, val, sta = columns(
        rng, n, lost=int(rng.integers(0, 4)), nan_in_lost=bool(seed % 2), nan=seed % 3 == 0
    )
    cuts = [(0, n), (n - 750, n), (100, 850), (5, 6), (n, n)]  # windows within longer columns
    for start, stop in cuts:
        got = check.window_scan(pos, tor, val, sta, start, stop)
        want = check.window_scan_reference(pos, tor, val, sta, start, stop)
        assert got == want, (start, stop)
        assert [type(v) for v in got] == [int, bool, bool]
    # an eight-byte status column (a sample batch's) reads alike
    wide = sta.astype(np.int64)
    assert check.window_scan(pos, tor, val, wide, 0, n) == check.window_scan_reference(
        pos, tor, val, wide, 0, n
    )


@compiled
def test_the_scan_reads_only_the_rows_asked_for():
    rng = np.random.default_rng(7)
    pos, tor, val, sta = columns(rng, 100, lost=0, nan_in_lost=False, nan=False)
    sta[:] = 0
    sta[10], val[20], tor[30] = 4, False, np.nan
    assert check.window_scan(pos, tor, val, sta, 31, 100) == (0, True, True)
    assert check.window_scan(pos, tor, val, sta, 0, 100) == (4, False, False)
    assert check.window_scan(pos, tor, val, sta, 25, 35) == (0, True, False)
    val[30] = False  # a lost row's value is never read
    assert check.window_scan(pos, tor, val, sta, 25, 35) == (0, False, True)


def test_columns_of_other_types_take_the_reference(monkeypatch):
    rng = np.random.default_rng(8)
    pos, tor, val, sta = columns(rng, 300, lost=2, nan_in_lost=True, nan=False)
    want = check.window_scan_reference(pos, tor, val, sta, 0, 300)
    as_float32 = pos.astype(np.float32)
    assert check.window_scan(as_float32, tor, val, sta, 0, 300) == want
    assert check.window_scan(pos, tor, val, sta.astype(np.int32), 0, 300) == want
    if check._eureka is not None:  # the kernel declines what it does not read
        assert check._eureka.window_scan(as_float32, tor, val, sta, 0, 300) is None
        assert check._eureka.window_scan(pos, tor, val, sta.astype(np.int32), 0, 300) is None
        with pytest.raises(ValueError, match="rows outside"):
            check._eureka.window_scan(pos, tor, val, sta, 0, 301)
    monkeypatch.setattr(check, "_eureka", None)  # the numpy path (RTSID_NUMPY_ONLY=1)
    assert check.window_scan(pos, tor, val, sta, 0, 300) == want
