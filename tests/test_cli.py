"""The command line itself: help works for the top level and for every command."""

from __future__ import annotations

import pytest

from rtsid.cli import COMMANDS, main


@pytest.mark.parametrize("argv", [["-h"], ["--help"]])
def test_top_level_help_lists_every_command(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert all(name in out for name in COMMANDS)


def test_no_command_prints_help_and_succeeds(capsys):
    assert main([]) == 0
    assert "usage: rtsid" in capsys.readouterr().out


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_has_working_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert f"usage: rtsid {command}" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("error", "says"),
    [
        (
            TypeError("'int' object is not iterable"),
            "internal error (TypeError: 'int' object is not "
            "iterable); this is a bug in rtsid: please report it",
        ),
        (MemoryError(), "error: out of memory; give it a smaller input"),
    ],
)
def test_an_unexpected_exception_is_one_line_and_exit_70(monkeypatch, capsys, error, says):
    """The last resort, in addition to each loader's own checks: no traceback, a pointer."""
    import rtsid.commands.recover as command

    def run(_args):
        raise error

    monkeypatch.setattr(command, "run", run)
    assert main(["recover", "x.mcap"]) == 70
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rtsid recover: ") and says in lines[0]
    assert "Traceback" not in captured.err
    monkeypatch.setenv("RTSID_TRACEBACK", "1")
    if isinstance(error, TypeError):
        with pytest.raises(TypeError):
            main(["recover", "x.mcap"])


def test_the_desk_commands_start_without_the_numerics():
    # `rtsid mark` took 2–6 s on a busy machine, most of it importing scipy through
    # rtsid.io.messages and rtsid.link: the experimenter waits on it at every trial
    import subprocess
    import sys

    code = (
        "import sys, rtsid.cli, rtsid.commands.mark, rtsid.commands.condition, "
        "rtsid.commands.summary, rtsid.summary, rtsid.commands.query; "
        "print(sorted(m for m in ('scipy', 'rtsid.sim', 'rtsid.ident.stream') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert out.stdout.strip() == "[]", out.stdout


def test_an_interrupt_caught_inside_a_string_run_still_exits_130(tmp_path):
    """A Ctrl-C whose KeyboardInterrupt left an ``exec`` of a string (a dataclass being
    built at an import, when the signal lands) ends ``python -m`` with 130 and one line, not
    by SIGINT (the interpreter marks such an interrupt unhandled, caught or not)."""
    import subprocess
    import sys

    (tmp_path / "interrupted_command.py").write_text(
        "def add_arguments(parser):\n    pass\n\n\n"
        "def run(args):\n    exec('raise KeyboardInterrupt')\n"
    )
    (tmp_path / "entry.py").write_text(
        "from rtsid import cli\n"
        "cli.COMMANDS['interrupted'] = ('interrupted_command', 'raises Ctrl-C in a string run')\n"
        "raise SystemExit(cli.main(['interrupted']))\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "entry"], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert (done.returncode, done.stderr) == (130, "rtsid interrupted: interrupted\n")


_ENTRY = """\
import atexit, sys
from rtsid import cli

class Teardown:
    def __del__(self):
        sys.stderr.write("torn down\\n")

kept = Teardown()  # freed only by the interpreter's teardown
atexit.register(lambda: sys.stderr.write("exit handler ran\\n"))
cli.COMMANDS["ends"] = ("ending_command", "ends with the status it is given")
sys.argv[1:] = ["ends", *sys.argv[1:]]
cli.console()
"""

_COMMAND = """\
import sys
from rtsid.errors import InputDataError

def add_arguments(parser):
    parser.add_argument("outcome")
    parser.add_argument("--keep-teardown", action="store_true")

def run(args):
    args.skip_teardown = not args.keep_teardown
    sys.stdout.write("unflushed table")  # no newline: still in the buffer
    if args.outcome == "error":
        raise InputDataError("no such recording")
    if args.outcome == "thread":  # still running at the end: the interpreter waits for it
        import threading, time
        late = lambda: (time.sleep(0.2), sys.stdout.write(", then the thread's line"))
        threading.Thread(target=late).start()
        return 0
    if args.outcome == "no_hook":  # an interpreter without CPython's atexit._run_exitfuncs
        import atexit
        del atexit._run_exitfuncs
        return 0
    return int(args.outcome)
"""


def _ends(tmp_path, *argv: str):
    """The test command ``ends`` (``_COMMAND``) run through ``cli.console`` in a fresh process."""
    import subprocess
    import sys

    (tmp_path / "ending_command.py").write_text(_COMMAND)
    (tmp_path / "entry.py").write_text(_ENTRY)
    command = [sys.executable, "-m", "entry", *argv]
    return subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize(
    ("outcome", "status"), [("0", 0), ("3", 3), ("error", 2)], ids=["done", "incomplete", "error"]
)
def test_a_command_may_end_without_the_interpreters_teardown(tmp_path, outcome, status):
    # `rtsid replay DIR` ends so (its teardown was 0.04 s of the command's wall time): the
    # status is the command's, its output flushed and the exit handlers run; the teardown's
    # work (here an object's finalizer) is not done
    done = _ends(tmp_path, outcome)
    assert (done.returncode, done.stdout) == (status, "unflushed table")
    assert "exit handler ran" in done.stderr and "torn down" not in done.stderr
    assert ("no such recording" in done.stderr) == (outcome == "error")
    kept = _ends(tmp_path, outcome, "--keep-teardown")  # the interpreter's usual exit
    assert (kept.returncode, kept.stdout) == (status, "unflushed table")
    assert "exit handler ran" in kept.stderr and "torn down" in kept.stderr


def test_a_command_that_leaves_a_thread_running_ends_as_python_does(tmp_path):
    # skipping the teardown would kill the thread: the interpreter's exit waits for it
    done = _ends(tmp_path, "thread")
    assert (done.returncode, done.stdout) == (0, "unflushed table, then the thread's line")
    assert "exit handler ran" in done.stderr and "torn down" in done.stderr


def test_without_cpythons_exit_hook_a_command_ends_as_python_does(tmp_path):
    done = _ends(tmp_path, "no_hook")
    assert (done.returncode, done.stdout) == (0, "unflushed table")
    assert "exit handler ran" in done.stderr and "torn down" in done.stderr
