import numpy as np
import pytest

from rtsid.errors import InputDataError
from rtsid.io.sample_files import load_samples, nonfinite_report


def write_npz(path, **arrays):
    np.savez(path, **arrays)
    return path


def test_npz_round_trip(tmp_path):
    p = write_npz(
        tmp_path / "r.npz", position_rad=np.arange(5.0), torque_nm=np.ones(5), fs_hz=100.0
    )
    rec = load_samples(p)
    assert rec.fs_hz == 100.0 and rec.duration_s == pytest.approx(0.05)
    np.testing.assert_array_equal(rec.position_rad, np.arange(5.0))


def test_npz_missing_array_names_what_is_needed(tmp_path):
    p = write_npz(tmp_path / "r.npz", position=np.arange(5.0), torque_nm=np.ones(5), fs_hz=100.0)
    with pytest.raises(InputDataError, match=r"lacks position_rad.*found: "):
        load_samples(p)


def test_truncated_npz_is_a_clear_error(tmp_path):
    p = write_npz(
        tmp_path / "r.npz", position_rad=np.arange(500.0), torque_nm=np.ones(500), fs_hz=1.0
    )
    p.write_bytes(p.read_bytes()[:300])
    with pytest.raises(InputDataError, match="truncated"):
        load_samples(p)


def test_csv_with_time_column_and_comments(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("# rig 3\nt_s,position_rad,torque_nm\n0.000,0.1,1\n0.002,0.2,2\n0.004,0.3,3\n")
    rec = load_samples(p)
    assert rec.fs_hz == pytest.approx(500.0)
    np.testing.assert_allclose(rec.torque_nm, [1, 2, 3])


def test_csv_errors(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("position_rad,torque\n0.1,1\n")
    with pytest.raises(InputDataError, match=r"missing column\(s\) torque_nm"):
        load_samples(p)
    p.write_text("position_rad,torque_nm\n0.1,1\n0.2,2\n")
    with pytest.raises(InputDataError, match="no time column.*--fs"):
        load_samples(p)
    assert load_samples(p, fs_hz=10.0).fs_hz == 10.0
    p.write_text("t_s,position_rad,torque_nm\n0,0.1,1\n0.1,0.2,2\n0.5,0.2,2\n")
    with pytest.raises(InputDataError, match="not uniformly spaced"):
        load_samples(p)
    p.write_text("position_rad,torque_nm\n0.1,abc\n")
    with pytest.raises(InputDataError, match="not a number"):
        load_samples(p, fs_hz=1.0)


def test_unknown_type_and_missing_file(tmp_path):
    txt = tmp_path / "x.txt"
    txt.write_text("1,2\n")
    with pytest.raises(InputDataError, match="unknown sample file type '.txt'"):
        load_samples(txt)
    with pytest.raises(InputDataError, match="no such file"):
        load_samples(tmp_path / "nothing.npz")


def test_nonfinite_report_locates_the_first_bad_sample(tmp_path):
    p = write_npz(
        tmp_path / "r.npz",
        position_rad=np.r_[0.0, 1.0, np.nan, 2.0],
        torque_nm=np.r_[0.0, np.inf, 0.0, 0.0],
        fs_hz=10.0,
    )
    assert (
        nonfinite_report(load_samples(p))
        == "2 sample(s) are NaN or inf, the first at index 1 (t = 0.1000 s)"
    )
