"""The summary table: columns made from messages, written as npz, read back only when sound."""

from __future__ import annotations

import io
import json
import pickle
import zipfile
from typing import Any

import numpy as np
import pytest

from rtsid.io.summary_table import NO_INT, VERSION, SummaryTable, TableBuilder, TableError


def estimate(t_end_s: float, **extra: Any) -> dict[str, Any]:
    message = {"robot": "rig", "joint": "ankle", "t_start_s": t_end_s - 0.3, "t_end_s": t_end_s}
    message.update(ok=True, reason=None, K_track=101.0, K=100.0, B=0.8, I=0.015, vaf=90.0)
    message.update(B_held=True, I_held=False, reflex_seq=None, host_time_ns=10**18)
    message.update(extra)
    return message


def built() -> SummaryTable:
    builder = TableBuilder()
    builder.add("estimate", estimate(0.3))
    builder.add("estimate", estimate(0.4, ok=False, reason="gap", K=None, B_held=None))
    builder.add("estimate", estimate(0.5, K=True, reflex_seq=3, robot=None, joint=7))
    builder.add_payload("reflex", json.dumps({"seq": 3, "applied": True, "gain": 2.0}).encode())
    builder.add("reflex", {"applied": True})  # no seq: counted, not kept
    builder.add("status", {"host_time_ns": 5, "acquisition": {"lost_samples": 2}})
    builder.add("status", {"host_time_ns": 6, "acquisition": {"lost_samples": "x"}})
    builder.add("marker", {"t_s": 0.35, "label": "trial 1 start", "marker_id": "a"})
    builder.add("samples", {"ignored": True})
    return builder.table()


def test_messages_become_columns_with_their_nulls_said() -> None:
    table = built()
    c = table.columns
    assert table.counts == {"estimate": 3, "reflex": 2, "status": 2, "session": 0, "marker": 1}
    np.testing.assert_array_equal(c["K"], [100.0, np.nan, 1.0])  # a bool is a number, as in JSON
    np.testing.assert_array_equal(c["B_held"], [1, -1, 1])
    np.testing.assert_array_equal(c["ok"], [1, 0, 1])
    assert table.text("reason") == [None, "gap", None]
    assert table.text("robot") == ["rig", "rig", None] and table.text("joint")[2] == "7"
    assert c["reflex_seq"].tolist() == [NO_INT, NO_INT, 3]
    assert (c["reflex_seq_id"].tolist(), c["reflex_gain"].tolist()) == ([3], [2.0])
    assert (c["status_host_time_ns"].tolist(), c["status_lost_samples"].tolist()) == ([5], [2])
    assert table.markers[0]["label"] == "trial 1 start"


def test_npz_round_trip_and_parts_joined() -> None:
    table = built()
    back = SummaryTable.from_npz(table.to_npz())
    assert back.counts == table.counts and back.markers == table.markers
    for key, column in table.columns.items():
        np.testing.assert_array_equal(back.columns[key], column)
    other = TableBuilder()
    other.add("estimate", estimate(0.6, ok=False, reason="saturation"))
    other.add("estimate", estimate(0.7, ok=False, reason="gap"))
    joined = SummaryTable.concatenate([back, other.table()])
    assert joined.text("reason") == [None, "gap", None, "saturation", "gap"]
    assert joined.counts["estimate"] == 5 and len(joined) == 5


def npz(**members: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.savez(out, **members)
    return out.getvalue()


def with_member(data: bytes, name: str, raw: bytes) -> bytes:
    """``data`` (an npz) with member ``name`` replaced by ``raw`` bytes."""
    src = zipfile.ZipFile(io.BytesIO(data))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            dst.writestr(info.filename, raw if info.filename == name else src.read(info))
    return out.getvalue()


class _Boom:
    def __reduce__(self) -> tuple[Any, ...]:
        return (pytest.fail, ("the summary table reader unpickled an object",))


def test_hostile_or_foreign_tables_are_refused_never_unpickled() -> None:
    good = built().to_npz()
    header = b"\x93NUMPY\x01\x00" + b"v\x00"
    huge = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000,), }"
    huge_npy = b"\x93NUMPY\x01\x00" + len(huge.ljust(118) + "\n").to_bytes(2, "little")
    huge_npy += (huge.ljust(118) + "\n").encode() + b"\x00" * 64
    objects = io.BytesIO()
    np.save(objects, np.array([_Boom()], dtype=object), allow_pickle=True)
    cases = {
        "not a zip": b"PK not really",
        "object column": with_member(good, "K.npy", objects.getvalue()),
        "declares 10^12 values": with_member(good, "K.npy", huge_npy),
        "bad npy header": with_member(good, "K.npy", header),
        "another version": with_member(good, "version.npy", npz_member(VERSION + 1)),
        "a column missing": npz(version=np.array([VERSION])),
        "counts of two dimensions": with_member(good, "counts.npy", npz_member_2d()),
        "pickle itself": pickle.dumps(_Boom()),
    }
    for what, data in cases.items():
        try:
            SummaryTable.from_npz(data)
        except TableError:
            continue
        pytest.fail(f"{what}: accepted")


def npz_member_2d() -> bytes:
    out = io.BytesIO()
    np.save(out, np.zeros((5, 2), dtype=np.int64))
    return out.getvalue()


def npz_member(version: int) -> bytes:
    out = io.BytesIO()
    np.save(out, np.array([version], dtype=np.int64))
    return out.getvalue()


def test_rows_of_a_column_must_match_the_counts() -> None:
    table = built()
    short = SummaryTable(
        {**table.counts, "estimate": 4}, table.columns, table.sessions, table.markers
    )
    with pytest.raises(TableError, match="rows for 4 estimate"):
        SummaryTable.from_npz(short.to_npz())


def test_estimates_added_at_once_are_the_rows_added_one_by_one() -> None:
    messages = [
        estimate(0.3),
        estimate(0.4, ok=False, reason="gap", K=None, B_held=None, robot="other"),
        estimate(0.5, K=True, reflex_seq=3, robot=None, joint=7),  # a bool K: a number
        estimate(0.6, K="100", B=np.float64(0.9), I=10**400, vaf=float("nan")),  # odd values
        estimate(0.7, reflex_seq=2**63, host_time_ns=True, reason=3, I_held="yes"),
        {"t_end_s": 0.8},  # keys missing
    ]
    one_by_one, at_once = TableBuilder(), TableBuilder()
    for message in messages:
        one_by_one.add("estimate", message)
    at_once.add_estimates(messages[:2])  # in two calls: the texts' codes carry on
    at_once.add_estimates(messages[2:])
    a, b = one_by_one.table(), at_once.table()
    assert a.counts == b.counts
    assert a.columns.keys() == b.columns.keys()
    for key, column in a.columns.items():
        assert column.dtype == b.columns[key].dtype
        assert column.tobytes() == b.columns[key].tobytes(), key
    for key in ("robot", "joint", "reason"):
        assert a.text(key) == b.text(key)
