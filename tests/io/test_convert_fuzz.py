"""CAN captures (candump .log, .asc, .blf, .trc) under hostile input: arbitrary bytes,
truncations and bit flips of valid captures, absurd rates and timestamps. Only rtsid's own
errors escape the reader (or it reads), rows are capped before they are allocated, and
``rtsid convert`` writes nothing half-way. Issue 20."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from rtsid.cli import main
from rtsid.errors import InputDataError, RtsidError
from rtsid.io.convert import MAX_FS_HZ, read_can_log, read_source
from rtsid.link.protocol import COUNTER_MODULO, STATE_ID, encode_state_block

FUZZ = settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
SUFFIXES = [".log", ".asc", ".blf", ".trc"]
FS = 2500.0
T0 = 1_763_000_000.0
ROOT = Path(__file__).resolve().parents[2]


def write_capture(path: Path, n: int = 200, step_s: float = 1 / FS, t0: float = T0) -> None:
    k = np.arange(n)
    payload = encode_state_block(k * 3, -k * 2, k % COUNTER_MODULO, np.zeros(n, dtype=np.int64))
    with can.Logger(str(path)) as writer:
        for i in range(n):
            writer.on_message_received(
                can.Message(
                    timestamp=t0 + i * step_s,
                    arbitration_id=STATE_ID,
                    data=payload[i].tobytes(),
                    is_extended_id=False,
                    channel="can0",
                )
            )


_VALID: dict[str, bytes] = {}


def valid_capture(suffix: str, tmp_path: Path) -> bytes:
    if suffix not in _VALID:
        path = tmp_path / f"valid{suffix}"
        write_capture(path)
        _VALID[suffix] = path.read_bytes()
    return _VALID[suffix]


def reads_or_refuses(path: Path) -> None:
    for fs in (FS, None):
        try:
            read_source(path, fs)
        except RtsidError:
            pass


@FUZZ
@given(data=st.binary(max_size=700), suffix=st.sampled_from(SUFFIXES))
@example(data=b"LOGG" + b"\xff" * 140, suffix=".blf")
@example(data=b"(1.0) can0 123#" + b"F" * 300 + b"\n", suffix=".log")
@example(data=b"(nan) can0 0A0#0011223344556677\n(inf) can0 0A0#0011223344556677\n", suffix=".log")
def test_fuzz_arbitrary_bytes(tmp_path: Path, data: bytes, suffix: str) -> None:
    path = tmp_path / f"x{suffix}"
    path.write_bytes(data)
    reads_or_refuses(path)


@FUZZ
@given(draw=st.data(), suffix=st.sampled_from(SUFFIXES))
def test_fuzz_mutated_valid_captures(tmp_path: Path, draw: st.DataObject, suffix: str) -> None:
    original = valid_capture(suffix, tmp_path)
    out = bytearray(original[: draw.draw(st.integers(0, len(original)), label="cut")])
    for _ in range(draw.draw(st.integers(0, 6), label="flips")):
        if out:
            out[draw.draw(st.integers(0, len(out) - 1))] ^= 1 << draw.draw(st.integers(0, 7))
    path = tmp_path / f"x{suffix}"
    path.write_bytes(bytes(out))
    reads_or_refuses(path)


@FUZZ
@given(
    fs=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e7, 1e9])),
    step_s=st.sampled_from([1 / FS, 1.0, 3600.0, 1e9]),
)
@example(fs=1e9, step_s=1 / FS)
def test_fuzz_absurd_rates_and_timestamps(tmp_path: Path, fs: float, step_s: float) -> None:
    path = tmp_path / "c.log"
    write_capture(path, n=50, step_s=step_s, t0=1.0)
    try:
        samples = read_can_log(path, fs)
    except InputDataError:
        return
    assert len(samples) <= 20_000_000


def test_a_garbage_blf_is_one_error_naming_the_format(tmp_path: Path) -> None:
    """Issue 20: a garbage .blf gave a BLFParseError traceback."""
    path = tmp_path / "garbage.blf"
    path.write_bytes(b"not a blf file at all " * 20)
    with pytest.raises(InputDataError, match=r"garbage\.blf: cannot read it as a blf CAN capture"):
        read_source(path, FS)
    with pytest.raises(InputDataError, match=r"cannot read it as a blf CAN capture"):
        read_source(path)  # deriving the rate reads it first


def test_a_rate_above_the_cap_is_refused_before_reading(tmp_path: Path) -> None:
    path = tmp_path / "good.log"
    write_capture(path)
    with pytest.raises(InputDataError, match=r"--fs 10000000\.0: .* more than 100000 Hz"):
        read_can_log(path, 1e7)
    assert MAX_FS_HZ == 100_000.0


def test_a_silence_longer_than_the_row_cap_is_refused_before_allocating(tmp_path: Path) -> None:
    path = tmp_path / "silence.log"
    write_capture(path, n=20, step_s=3600.0)  # an hour between frames at 2500 Hz: 9 M rows each
    with pytest.raises(InputDataError, match=r"rows at 2500 Hz .* exceed the 20000000 rows"):
        read_can_log(path, FS)


_CAPPED = """
import resource, sys
cap = 1536 * 2**20  # 1.5 GiB of address space: the old reader needed 24 GB
resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
from rtsid.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("fs", ["1e9", "1e7"])
def test_convert_at_an_absurd_rate_is_refused_within_a_memory_cap(tmp_path: Path, fs: str) -> None:
    """Issue 20: `rtsid convert good.log --fs 1e9` (5000 frames) was OOM-killed at 24 GB; --fs
    1e7 was refused only after 1.25 GB. Run under a 1.5 GiB address-space cap: refused in one
    line, nothing written."""
    good = tmp_path / "good.log"
    write_capture(good, n=5000)
    out = tmp_path / "out.mcap"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-c", _CAPPED, "convert", str(good), "-o", str(out), "--fs", fs]
    run = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300, check=False)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    assert lines[0].startswith("rtsid convert: error: ")
    assert "more than 100000 Hz, the highest state-frame rate rtsid takes" in lines[0]
    assert not out.exists() and not list(tmp_path.glob(".*.part"))


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_convert_of_a_garbage_capture_is_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], suffix: str
) -> None:
    path = tmp_path / f"garbage{suffix}"
    path.write_bytes(bytes(range(256)) * 4)
    out = tmp_path / "out.mcap"
    assert main(["convert", str(path), "-o", str(out), "--fs", "2500"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    assert lines[0].startswith(f"rtsid convert: error: {path}")
    assert not out.exists()


def _blf_container(compressed: bytes, uncompressed_size: int) -> bytes:
    from can.io import blf

    body = blf.LOG_CONTAINER_STRUCT.pack(blf.ZLIB_DEFLATE, uncompressed_size) + compressed
    size = blf.OBJ_HEADER_BASE_STRUCT.size + len(body)
    head = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, blf.LOG_CONTAINER)
    return head + body + b"\x00" * (size % 4)


def test_a_blf_decompression_bomb_is_refused_before_python_can_inflates_it(
    tmp_path: Path,
) -> None:
    import zlib

    from rtsid.io.convert import MAX_BLF_OBJECT_BYTES

    path = tmp_path / "bomb.blf"
    write_capture(path, n=10)
    data = path.read_bytes()
    squeeze = zlib.compressobj(9)
    zeros = bytes(1 << 20)
    bomb = b"".join(squeeze.compress(zeros) for _ in range(80)) + squeeze.flush()  # 80 MiB
    assert len(bomb) < 200_000
    path.write_bytes(data + _blf_container(bomb, 80 << 20))
    with pytest.raises(InputDataError, match=r"a BLF container, inflated, of \d+ bytes is larger"):
        read_can_log(path, FS)
    from can.io import blf

    header = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, 2**32 - 1, blf.LOG_CONTAINER)
    path.write_bytes(data + header)
    with pytest.raises(InputDataError, match=r"a BLF object of 4294967295 bytes is larger than"):
        read_can_log(path, FS)
    assert MAX_BLF_OBJECT_BYTES == 64 << 20


@pytest.mark.parametrize("suffix", [".log", ".asc", ".trc"])
def test_a_text_capture_without_line_breaks_is_refused_at_the_line_cap(
    tmp_path: Path, suffix: str
) -> None:
    path = tmp_path / f"one_line{suffix}"
    path.write_bytes(b"(1.0) can0 0A0#" + b"0" * 100_000)
    with pytest.raises(InputDataError, match=r"line 1 is longer than 65536 characters"):
        read_can_log(path, FS)
