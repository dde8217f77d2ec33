"""The ``rtsid`` command line: one subcommand per module, imported only when used.

Each command module defines ``add_arguments(parser)`` and ``run(args) -> int``. Errors that
rtsid raises on purpose (:class:`rtsid.errors.RtsidError`) print as one line naming the
problem and the fix, and exit with status 2; nothing partial is left behind by the command.
Warnings rtsid issues on purpose (:class:`rtsid.errors.RtsidWarning`) print as one line each.

Exit status: 0 done; 2 an error (nothing written); 3 done, but a recording it read ended
early (:class:`rtsid.errors.IncompleteRecordingWarning`): the outputs are complete and correct
for the part that could be read, and the warning says how much that was — a script must not
take them for the whole recording without looking; 70 an internal error (a bug, or out of
memory: one line says which; ``RTSID_TRACEBACK=1`` shows the traceback); 130 interrupted.
"""

from __future__ import annotations

# BLAS is pinned to one thread by the package's __init__ (it runs before this module).
import argparse
import atexit
import contextlib
import importlib
import os
import sys
import threading
import warnings
from collections.abc import Iterator, Sequence
from typing import NoReturn

from rtsid import __version__
from rtsid.errors import IncompleteRecordingWarning, RtsidError, RtsidWarning

# name -> (module, one-line help). Add a command by adding a line here.
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("rtsid.commands.run", "the daemon: acquire, identify every hop, publish and log"),
    "replay": ("rtsid.commands.replay", "run the window worker over MCAP recordings"),
    "identify": (
        "rtsid.commands.identify",
        "estimate I, B, K and VAF window by window from a file",
    ),
    "demo": ("rtsid.commands.demo", "identify a simulated ankle and print estimates against truth"),
    "bench": ("rtsid.commands.bench", "run a benchmark and print its table"),
    "plant": ("rtsid.commands.plant", "run the virtual ankle robot behind a socketcand server"),
    "recover": ("rtsid.commands.recover", "rewrite an MCAP recording that lost its footer"),
    "watch": ("rtsid.commands.watch", "show live K, B, I, VAF and status from a daemon (zenoh)"),
    "tv": ("rtsid.commands.tv", "time-varying G(jω,t), K(t), f_n(t) from a multisine record"),
    "calibrate": ("rtsid.commands.calibrate", "identify the robot's own dynamics (no person)"),
    "convert": ("rtsid.commands.convert", "CAN captures and .npz/.csv files as rtsid recordings"),
    "plot": ("rtsid.commands.plot", "figure of K, B, I (95 % bands) and VAF from a recording"),
    "summary": (
        "rtsid.commands.summary",
        "per-trial, condition or subject results from recordings' estimates (CSV, figure)",
    ),
    "router": ("rtsid.commands.router", "a zenoh router for a lab of daemons (loopback default)"),
    "query": ("rtsid.commands.query", "latest estimates and recent history from running daemons"),
    "mark": ("rtsid.commands.mark", "a trial marker on the next sample of running daemons"),
    "condition": ("rtsid.commands.condition", "change the condition of running daemons"),
    "certs": (
        "rtsid.commands.certs",
        "certificates and zenoh configs of a secure lab (mTLS, access control)",
    ),
}


def build_parser(commands: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """Parser with every registered subcommand (or only ``commands``)."""
    parser = argparse.ArgumentParser(
        prog="rtsid", description="Real-time system identification of joint impedance."
    )
    parser.add_argument("--version", action="version", version=f"rtsid {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        if commands is not None and name not in commands:
            continue
        module = importlib.import_module(module_name)
        # argparse %-formats help strings ("95 % bands" would crash it); descriptions are not.
        cmd = sub.add_parser(name, help=help_text.replace("%", "%%"), description=help_text)
        module.add_arguments(cmd)
        cmd.set_defaults(_module=module)
    return parser


EXIT_INCOMPLETE = 3
EXIT_BUG = 70  # sysexits EX_SOFTWARE: an exception rtsid did not raise on purpose


@contextlib.contextmanager
def _one_line_warnings(command: str) -> Iterator[list[str]]:
    """Print rtsid's own warnings as ``rtsid CMD: warning: …`` lines (others as Python does);
    yields the list of incomplete-recording warnings seen."""
    incomplete: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RtsidWarning)
        try:
            yield incomplete
        finally:
            for w in caught:
                if not issubclass(w.category, RtsidWarning):
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)
                    continue
                print(f"rtsid {command}: warning: {w.message}", file=sys.stderr)
                if issubclass(w.category, IncompleteRecordingWarning):
                    incomplete.append(str(w.message))


def _forget_the_interrupt() -> None:
    """Let a handled Ctrl-C end ``python -m rtsid.cli`` with status 130, not by SIGINT.

    CPython (3.8 on) marks an interrupt "unhandled" whenever a KeyboardInterrupt leaves an
    ``exec``/``eval`` of a string (``dataclasses`` and ``namedtuple`` build their methods so,
    e.g. at an import the interrupt lands in), even when a caller catches it later; under
    ``python -m`` the interpreter then kills itself with SIGINT after ``main`` returned 130
    (status −2, no traceback: a replay interrupted mid-import did so). Each run of a string
    clears that mark as it starts, so one empty run here does.
    """
    exec("")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line ``argv`` (default: this process's); its exit status."""
    return _main(argv)[0]


def console() -> NoReturn:
    """The ``rtsid`` console script and ``python -m rtsid.cli``: :func:`main` as a process,
    its exit status the process's. A command that leaves nothing behind to tear down (it
    sets ``skip_teardown`` on its arguments: ``replay``) ends without the interpreter's
    teardown (:func:`_exit_without_teardown`)."""
    code, args = _main(None)
    if getattr(args, "skip_teardown", False):
        _exit_without_teardown(code)
    sys.exit(code)


def _exit_without_teardown(code: int) -> None:
    """End the process with status ``code`` once its output is flushed and its exit handlers
    have run, skipping the interpreter's teardown of its modules, arrays and caches (0.04 s
    after a replay of a directory: on the command's path to its exit, and the wall time of
    ``--jobs N``). Returns, for the interpreter's usual exit, while another thread runs (the
    interpreter would wait for it), when the output cannot be flushed (a reader gone: the
    interpreter says so) or on an interpreter without CPython's ``atexit._run_exitfuncs``."""
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)  # CPython's, not a promise
    if threading.active_count() > 1 or run_exit_handlers is None:
        return
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except Exception:
        return
    run_exit_handlers()  # those of multiprocessing, logging, a coverage tool…
    try:  # what the handlers wrote; the interpreter's status when it cannot
        sys.stdout.flush()
        sys.stderr.flush()
    except Exception:
        code = 120
    os._exit(code)


def _main(argv: Sequence[str] | None) -> tuple[int, argparse.Namespace | None]:
    """:func:`main`'s exit status, and the command's arguments (None: no command)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    wanted = [a for a in argv[:1] if a in COMMANDS] or None
    parser = build_parser(wanted)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0, None
    return _run(args), args


def _run(args: argparse.Namespace) -> int:
    """Run the parsed command; its exit status (errors printed as one line)."""
    try:
        with _one_line_warnings(args.command) as incomplete:
            code = int(args._module.run(args) or 0)
        return EXIT_INCOMPLETE if code == 0 and incomplete else code
    except RtsidError as exc:
        print(f"rtsid {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rtsid {args.command}: interrupted", file=sys.stderr)
        _forget_the_interrupt()
        return 130
    except BrokenPipeError:
        # The reader went away (e.g. `rtsid identify … | head`): stop quietly.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except MemoryError:
        print(
            f"rtsid {args.command}: error: out of memory; give it a smaller input (the caps "
            "are in docs/io.md) or more memory",
            file=sys.stderr,
        )
        return EXIT_BUG
    except Exception as exc:  # last resort: every loader raises RtsidError on purpose
        if os.environ.get("RTSID_TRACEBACK"):
            raise
        where = f"{type(exc).__name__}: {str(exc)[:200]}"
        print(
            f"rtsid {args.command}: internal error ({where}); this is a bug in rtsid: please "
            "report it with the command line (RTSID_TRACEBACK=1 shows the traceback)",
            file=sys.stderr,
        )
        return EXIT_BUG


if __name__ == "__main__":
    console()
