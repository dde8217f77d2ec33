"""The one atomic writer and the one .npz reader, and the commands' errors that rest on them."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rtsid.cli import main
from rtsid.errors import InputDataError, RecordingError
from rtsid.io.files import atomic_write, read_npz


def test_atomic_write_replaces_the_file_whole_after_fsync(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    out = tmp_path / "cal.json"
    out.write_text("old")
    with atomic_write(out) as fh:
        fh.write("new\n")
        assert out.read_text() == "old"  # nothing visible under the name before the rename
    assert out.read_text() == "new\n" and len(synced) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    out = tmp_path / "rec.mcap"
    out.write_bytes(b"old")
    with pytest.raises(ZeroDivisionError), atomic_write(out, "wb") as fh:
        fh.write(b"half")
        raise ZeroDivisionError
    assert out.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["rec.mcap"]


def test_an_unwritable_place_names_the_file(tmp_path):
    out = tmp_path / "missing" / "x.csv"
    with pytest.raises(RecordingError, match=r"cannot write estimates .*missing/x\.csv"):
        with atomic_write(out, what="estimates") as fh:
            fh.write("x")
    with atomic_write(out, make_folder=True) as fh:
        fh.write("x")
    assert out.read_text() == "x"


@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 torn", b"plain text"])
def test_empty_torn_or_foreign_npz_is_one_clear_error(tmp_path, content):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(content)
    with pytest.raises(InputDataError, match="not a readable .npz"):
        read_npz(bad, ["a"], hint="")


def test_a_single_array_file_and_missing_arrays_are_named(tmp_path):
    single = tmp_path / "single.npz"
    with single.open("wb") as fh:
        np.save(fh, np.zeros(3))
    with pytest.raises(InputDataError, match="single array"):
        read_npz(single, ["a"], hint="")
    some = tmp_path / "some.npz"
    np.savez(some, a=np.zeros(2))
    with pytest.raises(InputDataError, match="lacks b .arrays found: a.; make it so"):
        read_npz(some, ["a", "b"], hint="make it so")
    assert read_npz(some, ["a"], hint="")["a"].shape == (2,)


@pytest.mark.parametrize("make", ["empty", "no_arrays", "no_samples"])
def test_tv_of_an_empty_npz_is_a_one_line_error(tmp_path, capsys, make):
    path = tmp_path / "empty.npz"
    if make == "empty":
        path.write_bytes(b"")
    elif make == "no_arrays":
        np.savez(path)
    else:
        np.savez(
            path,
            torque_nm=np.zeros(0),
            position_rad=np.zeros(0),
            fs_hz=100.0,
            excited_bins=np.array([1, 2]),
            period_samples=100,
        )
    assert main(["tv", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "empty.npz" in err


def test_recover_blames_the_input_when_the_input_is_bad(tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"junk\n")
    nowhere = tmp_path / "no-folder" / "out.mcap"
    for src, problem in ((junk, "not an MCAP file"), (tmp_path / "gone.mcap", "does not exist")):
        assert main(["recover", str(src), "-o", str(nowhere)]) == 2
        err = capsys.readouterr().err
        assert problem in err and "cannot write" not in err
    assert not nowhere.parent.exists()
