"""The compiled reader of compact samples payloads equals json.loads, bit for bit.

``decode_samples`` reads the logger's own layout with the kernel's ``json_array`` and
everything else (and everything with ``RTSID_NUMPY_ONLY=1``) with ``json.loads``, the
reference (``decode_samples_json``): whichever path a payload takes, the batch is the same.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rtsid.errors import InputDataError
from rtsid.ident.levinson import HAVE_COMPILED_KERNEL
from rtsid.io.schemas import (
    SampleBatch,
    _decode_compact_samples,
    decode_samples,
    decode_samples_into,
    decode_samples_json,
    encode_samples,
)

compiled_only = pytest.mark.skipif(not HAVE_COMPILED_KERNEL, reason="no compiled kernel")


def assert_same(a: SampleBatch, b: SampleBatch) -> None:
    assert (a.first_index, a.fs_hz, a.log_time_ns) == (b.first_index, b.fs_hz, b.log_time_ns)
    for x, y in zip(
        (a.position_rad, a.torque_nm, a.valid, a.status),
        (b.position_rad, b.torque_nm, b.valid, b.status),
        strict=True,
    ):
        assert x.dtype == y.dtype
        assert x.tobytes() == y.tobytes()  # bit for bit: NaN, -0.0 and all


def both(data: bytes) -> SampleBatch:
    """The batch by decode_samples, checked equal to the reference's (and to what
    decode_samples_into writes into a block, after other rows)."""
    batch = decode_samples(data, 7)
    assert_same(batch, decode_samples_json(data, 7))
    into = decoded_into(data, offset=3)
    if HAVE_COMPILED_KERNEL:  # the compiled path reads every compact payload into a block
        assert into is not None
    if into is not None:
        assert_same(into, batch)
    return batch


def decoded_into(data: bytes, offset: int, spare: int = 5) -> SampleBatch | None:
    """decode_samples_into's rows of ``data`` at ``offset`` of columns with room for them and
    ``spare`` more rows (None when it declines); the rows around them are left as they were."""
    capacity = offset + data.count(b",") + spare  # at least the rows a payload can hold
    columns = (
        np.full(capacity, 1.25),
        np.full(capacity, 2.5),
        np.ones(capacity, bool),
        np.full(capacity, 9, np.int64),
    )
    done = decode_samples_into(data, *columns, offset)
    if done is None:
        return None
    first_index, fs_hz, rows = done
    for column, fill in zip(columns, (1.25, 2.5, True, 9), strict=True):
        assert (column[:offset] == fill).all() and (column[offset + rows :] == fill).all()
    position, torque, valid, status = (c[offset : offset + rows] for c in columns)
    return SampleBatch(first_index, fs_hz, position, torque, valid, status, 7)


def payload(values: list[str], *, valid: str = "", status: str = "") -> bytes:
    """A compact samples payload whose position and torque columns are ``values``."""
    n = len(values)
    column = ",".join(values)
    return (
        '{"first_index":10,"fs_hz":2500.0,"t_first_s":0.004,'
        f'"position_rad":[{column}],"torque_nm":[{column}],'
        f'"valid":[{valid or ",".join(["true"] * n)}],"status":[{status or ",".join(["0"] * n)}]}}'
    ).encode()


finite = st.floats(allow_nan=False, allow_infinity=False)
wide = st.one_of(finite, st.floats(min_value=-1e6, max_value=1e6), st.just(0.0), st.just(-0.0))


@given(
    st.lists(st.tuples(wide, wide, st.booleans(), st.integers(0, 2**62)), max_size=300),
    st.integers(0, 2**40),
)
def test_compact_payloads_decode_as_json_loads_does(rows, first_index) -> None:
    n = len(rows)
    columns = [np.array([r[k] for r in rows]) for k in range(4)] if rows else [[]] * 4
    data = encode_samples(first_index, 2500.0, *columns)
    batch = both(data)
    assert len(batch) == n
    if HAVE_COMPILED_KERNEL:  # the compiled path read it (the numpy-only pass: json)
        assert _decode_compact_samples(data, 7) is not None


@compiled_only
def test_hundreds_of_thousands_of_random_doubles_are_exact() -> None:
    """Every magnitude a recording holds (and beyond): the decimal fast path, its halfway
    fallback and Python's conversion all give json.loads's double."""
    rng = np.random.default_rng(5)
    x = np.concatenate(
        [
            rng.standard_normal(60_000) * 10.0 ** rng.uniform(-15, 15, 60_000),
            rng.integers(0, 2**63, 60_000, dtype=np.uint64).view(np.float64),
        ]
    )
    x = x[np.isfinite(x)]
    n = x.size
    data = encode_samples(0, 2500.0, x, -x, np.ones(n, bool), np.zeros(n))
    assert _decode_compact_samples(data, 0) is not None
    assert_same(decode_samples(data), decode_samples_json(data))


@compiled_only
@pytest.mark.parametrize(
    "token",
    [
        "9007199254740993.0",  # halfway between two doubles: the extended result is a tie
        "9007199254740995.0",
        "4503599627370496.5",
        # the extended result falls exactly halfway though the decimal is not: rounding it
        # again would differ from rounding the decimal once (found with fractions.Fraction)
        "945.8860201190776138",
        "1.1179182577791514364",
        "0.05736767927757018340",
        "0.005646045117947716841",
        "1337664928726.4984131",
        "0.1",
        "-0.0",
        "0.0",
        "1e-320",  # subnormal
        "2.2250738585072014e-308",
        "1.7976931348623157e308",
        "1e400",  # json.loads reads inf
        "-1e400",
        "1.00000000000000011102230246251565404236316680908203125",  # more than 19 digits
        "123456789012345678901234.5",
        "1.5e27",
        "1.5e-28",
        "0.000000000000000000000000000012345",
        "1E5",
        "1e+5",
        "null",
    ],
)
def test_edge_tokens_read_as_json_loads_reads_them(token: str) -> None:
    data = payload([token, "0.5", token])
    assert _decode_compact_samples(data, 7) is not None
    both(data)


@pytest.mark.parametrize(
    "data",
    [
        payload(["1", "-0", "2.5"]),  # integers in a float column: json makes ints (-0 → +0.0)
        payload(["1.5", "2.5"], valid="1,0"),  # valid as numbers
        payload(["1.5", "2.5"]).replace(b",", b", "),  # whitespace
        payload(["1.5", "NaN"]),  # json.loads reads NaN; the kernel does not
        b'{"fs_hz":2500.0,"first_index":3,"position_rad":[1.5],"torque_nm":[2.0],'
        b'"valid":[true],"status":[0]}',
        b'{"first_index":3,"fs_hz":2500,"status":[0],"position_rad":[1.5],"torque_nm":[2.0],'
        b'"valid":[true]}',
        payload(["1.5", "2.5"], status=f"{2**63},1"),  # beyond int64: json → numpy overflow
    ],
)
def test_other_layouts_are_read_by_the_reference(data: bytes) -> None:
    assert decoded_into(data, offset=0) is None  # the block reader leaves them to it
    try:
        expected = decode_samples_json(data, 7)
    except (InputDataError, OverflowError) as exc:
        with pytest.raises(type(exc)):
            decode_samples(data, 7)
        return
    assert_same(decode_samples(data, 7), expected)


@pytest.mark.parametrize(
    "data",
    [
        payload(["1.5", "2.5"], valid="true"),  # columns of different lengths
        payload(["1.5", "2.5"], status="0,0,0"),
        payload(["1.5", "abc"]),
        payload(["1.5", ""]),
        payload(["1.5", "2.5"])[:-1],  # cut short
        payload(["1.5", "2.5"]) + b" x",
        payload(["1.5", "1.5.5"]),
        payload(["1.5", "--1.5"]),
        b'{"position_rad":[1.5],"torque_nm":[2.0],"valid":[true],"status":[0]}',
    ],
)
def test_corrupt_payloads_are_refused_as_the_reference_refuses_them(data: bytes) -> None:
    assert decoded_into(data, offset=2) is None
    with pytest.raises(InputDataError):
        decode_samples_json(data)
    with pytest.raises(InputDataError):
        decode_samples(data)


def test_the_reference_reads_the_compact_layout_with_json_loads() -> None:
    data = payload(["0.011359948532765084", "null"], valid="true,false", status="3,0")
    batch = decode_samples_json(data, 1)
    parsed = json.loads(data)
    assert batch.position_rad[0] == parsed["position_rad"][0]
    assert np.isnan(batch.position_rad[1])
    assert batch.valid.tolist() == [True, False]
    assert batch.status.tolist() == [3, 0]
    assert_same(decode_samples(data, 1), batch)


@compiled_only
def test_a_payload_with_more_rows_than_the_block_holds_is_declined() -> None:
    data = payload(["0.5", "1.5", "2.5"])
    block = (np.zeros(4), np.zeros(4), np.zeros(4, bool), np.zeros(4, np.int64))
    assert decode_samples_into(data, *block, 1) == (10, 2500.0, 3)  # rows 1..3 of 4
    assert block[0].tolist() == [0.0, 0.5, 1.5, 2.5]
    assert decode_samples_into(data, *block, 2) is None  # rows 2..4: one too many
    odd = (np.zeros(4), np.zeros(3), np.zeros(4, bool), np.zeros(4, np.int64))
    assert decode_samples_into(data, *odd, 0) is None  # columns of different lengths


@compiled_only
def test_every_digit_run_length_reads_as_json_loads_reads_it() -> None:
    """Runs of 1-30 digits before and after the point (the kernel reads eight, then four,
    then one at a time, and leaves digits past 2^64 to Python's conversion): json.loads's
    doubles, bit for bit."""
    digits = "987654321098765432109876543210"
    tokens = [
        f"{sign}{whole}.{fraction}"
        for sign in ("", "-")
        for whole in ("0", *(digits[:n] for n in range(1, 31)))
        for fraction in ("0" * 3 + digits[:5], *(digits[:n] for n in range(1, 31)))
    ]
    data = payload(tokens)
    assert _decode_compact_samples(data, 7) is not None
    both(data)


@compiled_only
@pytest.mark.parametrize(
    ("valid", "status"),
    [
        ("true,false,true", "0,9,7"),  # the one-item fast paths
        ("false,true,false", "10,-0,-3"),  # the general reader: several digits, signs
        ("true,true,true", f"{2**63 - 1},0,123456789012"),
    ],
)
def test_valid_and_status_items_read_as_json_loads_reads_them(valid: str, status: str) -> None:
    data = payload(["0.5", "1.5", "2.5"], valid=valid, status=status)
    assert _decode_compact_samples(data, 7) is not None
    both(data)


@pytest.mark.parametrize(
    "data",
    [
        payload(["0.5", "1.5"], status="01,0"),  # a leading zero: not JSON
        payload(["0.5", "1.5"], valid="true,True"),
        payload(["0.5", "1.5"], valid="truex,true"),
        payload(["0.5", "1.5"], status="0,0x"),
    ],
)
def test_items_near_the_fast_paths_are_refused_as_the_reference_refuses_them(
    data: bytes,
) -> None:
    assert decoded_into(data, offset=1) is None
    with pytest.raises((InputDataError, OverflowError)):
        decode_samples_json(data)
