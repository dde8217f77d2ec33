"""docs/getting-started.md stays true: its configs load, its commands parse, its tables match.

A new lab user copies the guide's ``toml`` blocks into files and types its commands. These tests
do the same, cheaply (no daemon runs): every block, saved under the name its first comment
gives, loads with rtsid's own loader beside the DBC the guide tells the user to copy; the
baseline's calibration fits the experiment's rate; every ``rtsid …`` command shown parses with
the options it uses; the columns a ``cut`` shows are the summary's.
"""

from __future__ import annotations

import argparse
import re
import shlex
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rtsid.calibrate import Calibration, save_calibration
from rtsid.cli import COMMANDS, build_parser
from rtsid.ident.robot import identify_robot
from rtsid.io.calibration import robot_calibration
from rtsid.link.signals import SimSource
from rtsid.runtime.daemon import DaemonConfig
from rtsid.summary import COLUMNS

REPO = Path(__file__).resolve().parents[1]
GUIDE = REPO / "docs" / "getting-started.md"
DBC = REPO / "hw" / "protocols" / "twoframe.dbc"  # "your robot's" DBC in the guide
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.MULTILINE | re.DOTALL)
FILE_NAME = re.compile(r"^# ([\w.-]+\.toml)\b")
INLINE_COMMAND = re.compile(r"`(rtsid [^`]+)`")
BASELINE_SECONDS = 2.0  # enough for the robot's IRF; the guide records 10 s


def guide_text() -> str:
    """The guide as a new user reads it."""
    return GUIDE.read_text(encoding="utf-8")


def blocks(language: str) -> list[str]:
    """The bodies of the guide's fenced blocks of ``language`` (``toml``, ``console``, …)."""
    return [body for lang, body in FENCE.findall(guide_text()) if lang == language]


def config_files() -> dict[str, str]:
    """The files the guide tells the user to write: name (its first comment) → text."""
    files: dict[str, str] = {}
    for body in blocks("toml"):
        match = FILE_NAME.match(body)
        assert match, f"a toml block of {GUIDE.name} does not start with '# NAME.toml':\n{body}"
        assert match.group(1) not in files, f"{match.group(1)} is written twice in the guide"
        files[match.group(1)] = body
    return files


def typed_commands() -> list[list[str]]:
    """Every ``rtsid …`` command line of the guide's console and sh blocks, as argv."""
    typed = [
        line[2:] for body in blocks("console") for line in body.splitlines() if line[:2] == "$ "
    ]
    typed += [line for body in blocks("sh") for line in body.splitlines()]
    return [
        shlex.split(line.split(" | ")[0], comments=True)[1:]
        for line in typed
        if line.startswith("rtsid ")
    ]


def subcommand_parser(name: str) -> argparse.ArgumentParser:
    """The parser of ``rtsid NAME`` (its options, as ``rtsid NAME --help`` lists them)."""
    parser = build_parser([name])
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


def calibrate_from(baseline: DaemonConfig, path: Path) -> None:
    """``rtsid calibrate``'s result for a short run of the baseline's plant, saved to ``path``."""
    source = SimSource(baseline.plant)
    runs = [source.next_block() for _ in range(round(BASELINE_SECONDS / baseline.plant.block_s))]
    position = np.concatenate([b.position_rad for b in runs])
    torque = np.concatenate([b.torque_nm for b in runs])
    robot = identify_robot([(position, torque)], baseline.link.fs_hz)
    save_calibration(Calibration(robot, source="baseline"), path)


@pytest.fixture
def user_folder(tmp_path, monkeypatch):
    """The user's own folder as the cwd: the guide's files, their robot's DBC, and the
    ``robot.json`` that step 3 calibrates from ``baseline.toml``."""
    shutil.copy(DBC, tmp_path / DBC.name)
    for name, text in config_files().items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    calibrate_from(DaemonConfig.load(tmp_path / "baseline.toml"), tmp_path / "robot.json")
    return tmp_path


def test_the_guide_names_the_files_a_user_writes():
    assert {"myrig.toml", "baseline.toml", "experiment.toml"} <= set(config_files())


def test_every_config_of_the_guide_loads_with_the_robots_dbc(user_folder):
    """Each block, as its own file, passes the daemon's validation (the DBC mapping too)."""
    for name in config_files():
        cfg = DaemonConfig.load(user_folder / name)
        if cfg.link.interface == "embedded" or cfg.link.udp.embedded_plant:
            assert cfg.plant.fs_hz == cfg.link.fs_hz, f"{name}: the virtual plant's rate"


def test_baseline_and_experiment_are_copies_of_myrig_for_the_link(user_folder):
    """The guide says so: one robot, one mapping; a calibration is only valid on that link."""
    myrig = DaemonConfig.load(user_folder / "myrig.toml")
    assert myrig.link.protocol.dbc == str(user_folder / DBC.name)
    for name in ("baseline.toml", "experiment.toml"):
        assert DaemonConfig.load(user_folder / name).link == myrig.link, name


def test_the_baseline_calibrates_the_experiments_rate_and_detaches_the_ankle(user_folder):
    baseline = DaemonConfig.load(user_folder / "baseline.toml")
    assert (baseline.plant.inertia, baseline.plant.damping, baseline.plant.stiffness) == (0, 0, 0)
    experiment = DaemonConfig.load(user_folder / "experiment.toml")
    assert experiment.worker.calibration_file == str(user_folder / "robot.json")
    assert experiment.plant.stiffness > 0  # the virtual ankle is back on
    robot_calibration(experiment.worker.calibration_file, experiment.link.fs_hz)


def test_a_calibration_at_another_rate_is_refused_with_the_fix(user_folder):
    """What a user who calibrated without myrig.toml's link meets (the guide quotes it)."""
    baseline = DaemonConfig.load(user_folder / "baseline.toml")
    other = replace(baseline, link=replace(baseline.link, fs_hz=2500.0))
    calibrate_from(replace(other, plant=replace(baseline.plant, fs_hz=2500.0)), Path("c.json"))
    with pytest.raises(Exception, match="calibrate from a baseline recorded at 2000 Hz") as err:
        robot_calibration(str(user_folder / "c.json"), baseline.link.fs_hz)
    assert str(err.value) in guide_text().replace("\n", " ")


def test_every_typed_command_exists_with_its_options(user_folder, capsys):
    commands = typed_commands()
    assert len(commands) >= 10
    for argv in commands:
        assert argv[0] in COMMANDS, f"rtsid {argv[0]}: no such command"
        try:
            args = build_parser([argv[0]]).parse_args(argv)
        except SystemExit:
            pytest.fail(f"rtsid {shlex.join(argv)}: {capsys.readouterr().err.strip()}")
        config = getattr(args, "config", None)
        if config is not None:
            assert config in config_files(), f"--config {config}: a file the guide never shows"


def test_every_inline_command_exists_with_its_options():
    """Commands named in the text (``rtsid replay REC.mcap -o OUT.mcap``): command and flags."""
    for line in INLINE_COMMAND.findall(guide_text()):
        argv = shlex.split(line)[1:]
        assert argv[0] in COMMANDS, f"`{line}`: no command rtsid {argv[0]}"
        parser = subcommand_parser(argv[0])
        flags = {s for action in parser._actions for s in action.option_strings}
        for token in argv[1:]:
            if token.startswith("-"):
                assert token.split("=")[0] in flags, f"`{line}`: rtsid {argv[0]} has no {token}"


def test_the_columns_a_cut_shows_are_the_summarys():
    """``cut -d, -fLIST`` over the summary's CSV: the header shown is COLUMNS at LIST."""
    checked = 0
    for body in blocks("console"):
        lines = body.splitlines()
        for n, line in enumerate(lines):
            match = re.search(r"cut -d, -f([\d,-]+)", line)
            if not match or ("rtsid summary" not in line and "trials.csv" not in line):
                continue
            fields: list[int] = []
            for part in match.group(1).split(","):
                low, _, high = part.partition("-")
                fields += range(int(low), int(high or low) + 1)
            assert lines[n + 1] == ",".join(COLUMNS[f - 1] for f in fields), line
            checked += 1
    assert checked >= 3


def test_every_link_of_the_guide_reaches_a_file_and_heading():
    """``[text](file.md#anchor)``: the file exists and has that heading (GitHub's anchors)."""
    links = re.findall(r"\]\(([^)#\s]+)(?:#([\w-]+))?\)", guide_text())
    assert len(links) >= 5
    for target, anchor in links:
        path = (GUIDE.parent / target).resolve()
        assert path.exists(), f"({target}): no such file"
        if anchor:
            headings = re.findall(r"^#+ (.+)$", path.read_text(encoding="utf-8"), re.MULTILINE)
            anchors = {
                re.sub(r"[^\w -]", "", h).strip().lower().replace(" ", "-") for h in headings
            }
            assert anchor in anchors, f"({target}#{anchor}): no such heading"
