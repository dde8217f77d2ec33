"""The same flag means the same thing in every command; old spellings work for one release and
say so in one line."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import pytest

from rtsid.benchmarks import BENCHMARKS
from rtsid.cli import COMMANDS, build_parser, main
from rtsid.commands.bench import benchmark_parser
from rtsid.commands.common import deprecation_note
from rtsid.ident.excitation import filtered_noise
from rtsid.io.estimate_csv import COLUMNS
from rtsid.sim.joint import simulate_impedance

REFERENCE = Path(__file__).resolve().parents[2] / "replay" / "reference" / "sim_3s.mcap"


def _parsers() -> dict[str, argparse.ArgumentParser]:
    """Every command's parser and every benchmark's."""
    root = build_parser()
    sub = next(a for a in root._actions if isinstance(a, argparse._SubParsersAction))
    parsers = {name: sub.choices[name] for name in COMMANDS}
    parsers.update({f"bench {name}": benchmark_parser(name)[0] for name in BENCHMARKS})
    return parsers


def _visible_options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {
        option: action
        for action in parser._actions
        if action.help != argparse.SUPPRESS
        for option in action.option_strings
    }


def test_a_flag_means_the_same_thing_in_every_command():
    seen = {"-o": 0, "--fs": 0, "--duration": 0, "--mode": 0}
    for name, parser in _parsers().items():
        options = _visible_options(parser)
        assert not {"--fs-hz", "--duration-s", "--out", "--csv"} & set(options), name
        if "-o" in options:  # the file the command writes
            assert options["-o"].dest == "output" and "--output" in options["-o"].option_strings
            seen["-o"] += 1
        if "--fs" in options:  # a rate, Hz
            assert options["--fs"].dest == "fs" and options["--fs"].type is float, name
            seen["--fs"] += 1
        if "--duration" in options:  # how long, s
            action = options["--duration"]
            assert action.dest == "duration" and action.type is float, name
            seen["--duration"] += 1
        if "--mode" in options:  # the zenoh reader's session
            action = options["--mode"]
            assert tuple(action.choices or ()) == ("peer", "client"), name
            assert action.default == "peer", name
            seen["--mode"] += 1
    assert seen["-o"] >= 7 and seen["--fs"] >= 5 and seen["--duration"] >= 6
    assert seen["--mode"] == 4  # watch, query, mark and condition, with one default


@pytest.fixture
def csv_without_time(tmp_path: Path) -> Path:
    fs = 1000.0
    theta = filtered_noise(1000, fs, 30.0, peak=0.03, seed=2)
    tau = simulate_impedance(theta, fs)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([theta, tau]), delimiter=",", header="position_rad,torque_nm")
    path.write_text(path.read_text().removeprefix("# "))
    return path


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_fs_hz_still_works_and_says_it_is_deprecated(csv_without_time, tmp_path, capsys):
    new, old = tmp_path / "new.csv", tmp_path / "old.csv"
    assert main(["identify", str(csv_without_time), "--fs", "1000", "-o", str(new)]) == 0
    assert "deprecated" not in capsys.readouterr().err
    assert main(["identify", str(csv_without_time), "--fs-hz", "1000", "-o", str(old)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err.count(deprecation_note("--fs-hz", "--fs")) == 1
    note = "rtsid: --fs-hz is deprecated; use --fs (it will be removed in the next release)"
    assert err[0] == note
    assert _rows(old) and [r["K"] for r in _rows(old)] == [r["K"] for r in _rows(new)]


def test_identify_out_still_works_and_says_it_is_deprecated(csv_without_time, tmp_path, capsys):
    out = tmp_path / "est.csv"
    assert main(["identify", str(csv_without_time), "--fs", "1000", "--out", str(out)]) == 0
    assert deprecation_note("--out", "-o/--output") in capsys.readouterr().err.splitlines()
    assert list(_rows(out)[0]) == list(COLUMNS)


def test_replay_out_still_works_and_says_it_is_deprecated(tmp_path, capsys):
    out = tmp_path / "est.csv"
    assert main(["replay", str(REFERENCE), "--out", str(out)]) == 0
    assert deprecation_note("--out", "-o/--output") in capsys.readouterr().err.splitlines()
    assert len(_rows(out)) > 100


def test_duration_s_still_works_and_says_it_is_deprecated(capsys):
    argv = ["demo", "--fs", "1000", "--hop", "0.5"]
    assert main([*argv, "--duration", "1.3"]) == 0
    new = capsys.readouterr().out
    assert main([*argv, "--duration-s", "1.3"]) == 0
    captured = capsys.readouterr()
    assert deprecation_note("--duration-s", "--duration") in captured.err.splitlines()
    assert captured.out == new  # the same run


def test_plant_old_flags_set_what_the_new_ones_do(capsys):
    parser = build_parser(["plant"])
    new = parser.parse_args(["plant", "--plant-mode", "player", "--fs", "500", "--duration", "2"])
    assert capsys.readouterr().err == ""
    old = parser.parse_args(["plant", "--mode", "player", "--fs-hz", "500", "--duration-s", "2"])
    assert vars(old) == vars(new)
    assert capsys.readouterr().err.splitlines() == [
        deprecation_note("--mode", "--plant-mode"),
        deprecation_note("--fs-hz", "--fs"),
        deprecation_note("--duration-s", "--duration"),
    ]


def test_bench_link_duration_s_still_parses(capsys):
    parser, _ = benchmark_parser("link")
    assert parser.parse_args(["--duration-s", "30"]).duration == 30.0
    assert capsys.readouterr().err.strip() == deprecation_note("--duration-s", "--duration")


def test_tv_old_csv_and_old_simulation_output_still_work(tmp_path, capsys):
    exp = tmp_path / "cs1.npz"
    argv = ["tv", "--simulate", "CS1", "--spacing", "1.4"]
    assert main([*argv, "-o", str(exp)]) == 0  # -o FILE.npz meant the simulation
    assert (
        deprecation_note("-o FILE.npz with --simulate", "--save-simulation")
        in capsys.readouterr().err.splitlines()
    )
    assert exp.exists()
    track = tmp_path / "track.csv"
    assert main(["tv", str(exp), "-p", "4", "--times", "3", "--csv", str(track)]) == 0
    assert deprecation_note("--csv", "-o/--output") in capsys.readouterr().err.splitlines()
    assert track.read_text().splitlines()[0] == "t_s,K,B,I,f_n_hz,f_peak_hz,fit_error,K_true"
