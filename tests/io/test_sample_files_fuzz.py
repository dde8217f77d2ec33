"""Sample files (.npz, .csv) under hostile input: arbitrary bytes, truncations and bit flips of
valid files, arrays of every dtype and shape, headers declaring huge arrays, oversized files.
Only rtsid's own errors escape the loader (or it loads), and nothing is allocated beyond the
documented caps. Issue 20."""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from rtsid.cli import main
from rtsid.errors import InputDataError, RtsidError
from rtsid.io.files import MAX_ROWS, MAX_SAMPLE_FILE_BYTES
from rtsid.io.sample_files import MAX_CSV_LINE_CHARS, load_samples

FUZZ = settings(suppress_health_check=[HealthCheck.function_scoped_fixture])


def loads_or_refuses(path: Path, fs_hz: float | None = None) -> None:
    try:
        load_samples(path, fs_hz)
    except RtsidError:
        pass


def valid_npz() -> bytes:
    out = io.BytesIO()
    n = 64
    np.savez(out, position_rad=np.sin(np.arange(n) / 5), torque_nm=np.arange(n) * 0.1, fs_hz=2500.0)
    return out.getvalue()


VALID_CSV = b"t_s,position_rad,torque_nm\n" + b"".join(
    f"{k / 2500:.6f},{k * 1e-3:.6f},{-k * 1e-2:.6f}\n".encode() for k in range(64)
)


def mutated(data: bytes, draw: Any) -> bytes:
    """``data`` cut at a drawn length, with a few drawn bits flipped."""
    out = bytearray(data[: draw(st.integers(0, len(data)))])
    for _ in range(draw(st.integers(0, 6))):
        if out:
            out[draw(st.integers(0, len(out) - 1))] ^= 1 << draw(st.integers(0, 7))
    return bytes(out)


@FUZZ
@given(data=st.binary(max_size=600), suffix=st.sampled_from([".npz", ".csv"]))
@example(data=b"PK\x03\x04" + b"\x00" * 40, suffix=".npz")
@example(data=b"\x93NUMPY\x01\x00", suffix=".npz")
@example(data=b"position_rad,torque_nm\n\x00\xff,1\n", suffix=".csv")
@example(data=b'position_rad,torque_nm\n"1\n2,3', suffix=".csv")
def test_fuzz_arbitrary_bytes(tmp_path: Path, data: bytes, suffix: str) -> None:
    path = tmp_path / f"x{suffix}"
    path.write_bytes(data)
    loads_or_refuses(path, fs_hz=100.0)
    loads_or_refuses(path)


@FUZZ
@given(draw=st.data(), suffix=st.sampled_from([".npz", ".csv"]))
def test_fuzz_mutated_valid_files(tmp_path: Path, draw: st.DataObject, suffix: str) -> None:
    original = valid_npz() if suffix == ".npz" else VALID_CSV
    path = tmp_path / f"x{suffix}"
    path.write_bytes(mutated(original, draw.draw))
    loads_or_refuses(path)


_DTYPES = st.sampled_from(
    ["f8", "f4", "i1", "u8", "?", "c16", "U3", "S2", "M8[s]", "m8[s]", "V4", "i4,f4"]
)


@FUZZ
@given(
    dtype=_DTYPES,
    shape=st.sampled_from([(), (0,), (1,), (5,), (2, 3), (5, 1)]),
    which=st.sampled_from(["position_rad", "torque_nm", "fs_hz"]),
)
@example(dtype="U3", shape=(5,), which="position_rad")
def test_fuzz_npz_arrays_of_any_dtype_and_shape(
    tmp_path: Path, dtype: str, shape: tuple[int, ...], which: str
) -> None:
    arrays: dict[str, Any] = {"position_rad": np.zeros(5), "torque_nm": np.zeros(5), "fs_hz": 10.0}
    arrays[which] = np.zeros(shape, dtype=dtype)
    path = tmp_path / "x.npz"
    np.savez(path, **arrays)
    loads_or_refuses(path)


def test_an_npz_of_strings_is_one_error_naming_the_array(tmp_path: Path) -> None:
    """Issue 20: an .npz of strings gave a ValueError traceback."""
    path = tmp_path / "strings.npz"
    np.savez(path, position_rad=np.array(["a", "b"]), torque_nm=np.array(["c", "d"]), fs_hz="x")
    with pytest.raises(InputDataError, match=r"fs_hz holds <U1 values, not real numbers"):
        load_samples(path)
    np.savez(path, position_rad=np.array(["a", "b"]), torque_nm=np.zeros(2), fs_hz=10.0)
    with pytest.raises(InputDataError, match=r"position_rad holds <U1 values"):
        load_samples(path)


def _npy_declaring(shape: tuple[int, ...]) -> bytes:
    """An .npy member whose header declares ``shape`` but holds 8 bytes of data."""
    header = np.lib.format.header_data_from_array_1_0(np.zeros(1))
    header["shape"] = shape
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, header)
    return out.getvalue() + b"\x00" * 8


def test_an_npz_declaring_a_huge_array_is_refused_before_it_is_allocated(tmp_path: Path) -> None:
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("position_rad.npy", _npy_declaring((10**12,)))
        zf.writestr("torque_nm.npy", _npy_declaring((1,)))
        zf.writestr("fs_hz.npy", _npy_declaring(()))
    with pytest.raises(InputDataError, match=r"arrays of 7450\.6 GiB exceed the 1\.0 GiB"):
        load_samples(path)


def test_a_2_gb_sparse_csv_is_refused_at_once_by_its_size(tmp_path: Path) -> None:
    """Issue 20: a 2 GB sparse CSV gave a _csv.Error after 20 s at 4.3 GB RSS."""
    path = tmp_path / "sparse.csv"
    with path.open("wb") as fh:
        fh.write(b"position_rad,torque_nm\n")
        fh.truncate(2 * 10**9)  # a hole: no disk used
    with pytest.raises(InputDataError, match=r"a CSV file of 1\.9 GiB exceed the 1\.0 GiB"):
        load_samples(path, fs_hz=100.0)
    assert MAX_SAMPLE_FILE_BYTES == 1 << 30


def test_a_csv_line_without_end_is_refused_at_the_line_cap(tmp_path: Path) -> None:
    path = tmp_path / "one_line.csv"
    path.write_bytes(b"position_rad,torque_nm\n" + b"0" * (MAX_CSV_LINE_CHARS + 10))
    with pytest.raises(InputDataError, match=r"line 2 is longer than 65536 characters"):
        load_samples(path, fs_hz=100.0)


def test_csv_rows_beyond_the_cap_are_refused_while_reading(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("rtsid.io.files.MAX_ROWS", 10)
    path = tmp_path / "long.csv"
    path.write_bytes(b"position_rad,torque_nm\n" + b"1,2\n" * 11)
    with pytest.raises(InputDataError, match=r"long\.csv: 11 rows exceed the 10 rows"):
        load_samples(path, fs_hz=100.0)
    assert MAX_ROWS == 20_000_000


def test_csv_with_a_text_value_names_the_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "x.csv"
    path.write_text("position_rad,torque_nm,note\n0.1,1,ok\n0.2,abc,ok\n")
    with pytest.raises(InputDataError, match=r"line 3, column torque_nm: 'abc' is not a number"):
        load_samples(path, fs_hz=100.0)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("strings.npz", "strings", "holds <U1 values"),
        ("sparse.csv", "sparse", "exceed the 1.0 GiB"),
        ("garbage.npz", b"\x00garbage", "not a readable .npz file"),
        ("latin.csv", "position_rad,torque_nm\n\xe9,1\n".encode("latin-1"), "not a UTF-8 text"),
    ],
)
@pytest.mark.parametrize("command", ["identify", "convert"])
def test_commands_refuse_bad_sample_files_in_one_line(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    name: str,
    content: Any,
    message: str,
) -> None:
    path = tmp_path / name
    if content == "strings":
        np.savez(path, position_rad=np.array(["a"]), torque_nm=np.array(["b"]), fs_hz=10.0)
    elif content == "sparse":
        with path.open("wb") as fh:
            fh.truncate(2 * 10**9)
    else:
        path.write_bytes(content)
    out = tmp_path / "out.mcap"
    argv = [command, str(path)] + (["-o", str(out)] if command == "convert" else [])
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert "Traceback" not in captured.err and len(lines) == 1, captured.err
    assert lines[0].startswith(f"rtsid {command}: error: ") and message in lines[0]
    assert not out.exists() and not [p for p in os.listdir(tmp_path) if p.endswith(".part")]
