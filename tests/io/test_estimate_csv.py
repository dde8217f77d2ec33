"""One estimate schema: identify's CSV, replay's CSV and the daemon's MCAP name the same fields
in the same order and encode them one way (booleans true/false, enums as values, null empty)."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path

import numpy as np
import pytest

from rtsid.cli import main
from rtsid.ident.excitation import filtered_noise
from rtsid.io.estimate_csv import COLUMNS, ENVELOPE, encode_value, estimate_row, write_estimates
from rtsid.io.messages import EstimateMessage
from rtsid.io.recording import read_estimates
from rtsid.runtime.daemon import Daemon, DaemonConfig
from rtsid.sim.joint import simulate_impedance
from rtsid.verdicts import Flag, Reason

LEAD = (
    "t_end_s",
    "K_track",
    "K_track_se",
    "K",
    "K_se",
    "B",
    "B_se",
    "B_held",
    "I",
    "I_se",
    "I_held",
    "vaf",
    "ok",
    "reason",
    "flags",
)
BOOLEANS = ("ok", "I_held", "B_held")
#: Differ between two runs over the same samples by nature (time spent).
TIMING = ("compute_ms", "latency_ms")


def without_timing(row: dict[str, str]) -> dict[str, str]:
    """A row without what two runs do not share (time spent: also the over_budget flag)."""
    out = {k: v for k, v in row.items() if k not in TIMING}
    out["flags"] = ";".join(f for f in row["flags"].split(";") if f and f != "over_budget")
    return out


def read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or ()), list(reader)


def assert_one_encoding(rows: list[dict[str, str]]) -> None:
    """Every row encodes booleans, verdicts and numbers the one way."""
    for row in rows:
        assert row["ok"] in ("true", "false")
        for key in ("I_held", "B_held"):
            assert row[key] in (("true", "false") if row["ok"] == "true" else ("",)), key
        if row["ok"] == "true":
            assert row["reason"] == "" and row["K"] and math.isfinite(float(row["K"]))
        else:
            assert row["reason"] in {r.value for r in Reason} and row["K"] == ""
        flags = row["flags"].split(";") if row["flags"] else []
        assert set(flags) <= {f.value for f in Flag}
        assert "<" not in "".join(row.values())  # no repr of an enum, None or NaN …
        assert not {"None", "nan", "True", "False"} & set(row.values())


def test_the_columns_are_the_message_fields_led_by_time_and_the_tracked_stiffness():
    fields = [f.name for f in dataclasses.fields(EstimateMessage)]
    assert list(COLUMNS) == [f for f in fields if f not in ENVELOPE]
    assert COLUMNS[: len(LEAD)] == LEAD


def test_values_are_encoded_one_way():
    assert [encode_value(v) for v in (True, False, np.bool_(True), None)] == [
        "true",
        "false",
        "true",
        "",
    ]
    numbers = (math.nan, math.inf, np.float64(0.1), 0.30000000000000004)
    assert [encode_value(v) for v in numbers] == [
        "",
        "",
        "0.1",
        "0.30000000000000004",  # shortest round-trip: the JSON's digits
    ]
    assert encode_value(Reason.GAP) == "gap"
    assert encode_value([Flag.LOW_VAF, Flag.OVER_BUDGET]) == "low_vaf;over_budget"
    assert encode_value(np.int64(3)) == "3"
    withheld = EstimateMessage.window_dict(None, Reason.NAN, None, seq=0, first=0, last=9, fs_hz=10)
    row = estimate_row(withheld)
    assert (row["ok"], row["reason"], row["K"], row["B_held"], row["t_end_s"]) == (
        "false",
        "nan",
        "",
        "",
        "0.9",
    )
    fh = io.StringIO()
    assert write_estimates([withheld], fh) == 1
    assert fh.getvalue().splitlines()[0] == ",".join(COLUMNS)


@pytest.mark.slow  # a real-time daemon run of a second and a half
def test_identify_replay_and_the_daemon_write_one_schema(tmp_path, free_port):
    # the daemon's MCAP, read back through the one recording reader
    config = DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port}"]},
            "mcap": {"directory": str(tmp_path / "rec")},
        }
    )
    Daemon(config).run(duration_s=1.5)
    (recording,) = sorted((tmp_path / "rec").glob("*.mcap"))
    live = read_estimates(recording)
    assert len(live) > 20
    for message in live:
        assert [k for k in message if k not in ENVELOPE] == list(COLUMNS)
        assert type(message["ok"]) is bool
        assert message["ok"] or message["I_held"] is None
        assert message["reason"] is None or message["reason"] in {r.value for r in Reason}
        assert all(f in {f.value for f in Flag} for f in message["flags"])

    # replay's CSV of that recording
    replayed = tmp_path / "replay.csv"
    assert main(["replay", str(recording), "-o", str(replayed)]) == 0
    header, replay_rows = read_csv(replayed)
    assert header == list(COLUMNS)
    assert_one_encoding(replay_rows)
    # ... says in text what replay's MCAP of the same windows says in JSON, field for field
    replayed_mcap = tmp_path / "replay.mcap"
    assert main(["replay", str(recording), "-o", str(replayed_mcap)]) == 0
    messages = read_estimates(replayed_mcap)
    assert [k for k in messages[0] if k not in ENVELOPE] == list(COLUMNS)
    assert [without_timing(estimate_row(m)) for m in messages] == [
        without_timing(row) for row in replay_rows
    ]

    # identify's CSV of a sample file (one window withheld for a gap)
    fs = 1000.0
    theta = filtered_noise(3000, fs, 30.0, peak=0.03, seed=3)
    tau = simulate_impedance(theta, fs)
    tau[1500:1520] = np.nan
    path = tmp_path / "gap.npz"
    np.savez(path, position_rad=theta, torque_nm=tau, fs_hz=fs)
    identified = tmp_path / "identify.csv"
    assert main(["identify", str(path), "--allow-nan", "-o", str(identified)]) == 0
    header, identify_rows = read_csv(identified)
    assert header == list(COLUMNS)
    assert_one_encoding(identify_rows)
    assert {r["ok"] for r in identify_rows} == {"true", "false"}
    assert {r["reason"] for r in identify_rows if r["ok"] == "false"} == {"gap"}
    # the tracker's columns are filled in identify's windows too
    assert all(r["K_track"] and r["K_track_se"] for r in identify_rows if r["ok"] == "true")
    assert {r["I_held"] for r in identify_rows if r["ok"] == "true"} <= {"true", "false"}
