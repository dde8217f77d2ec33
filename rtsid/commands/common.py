"""Arguments that mean the same in every command, built in one place.

- ``--fs HZ``: a sampling rate, Hz.
- ``--duration S``: how long to run, s.
- ``-o/--output PATH``: the file the command writes (estimates, a track, a figure, a
  recording); never an input or a by-product.
- ``--connect ENDPOINT`` and ``--mode {peer,client}``: how a zenoh reader reaches the daemons,
  with the same defaults in ``watch`` and ``query``.

An old spelling keeps working for one release: it is accepted, hidden from ``--help``, and
prints one line to stderr, ``rtsid: --fs-hz is deprecated; use --fs (it will be removed in the
next release)`` (:func:`deprecated_alias`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

__all__ = [
    "DEFAULT_CONNECT",
    "DEFAULT_MODE",
    "MODES",
    "add_duration",
    "add_fs",
    "add_output",
    "add_zenoh_reader",
    "connect_endpoints",
    "deprecated_alias",
    "deprecation_note",
]

#: A zenoh reader's modes, and the default of ``watch`` and ``query``. A listener-less *peer*
#: works out of the box in both loopback set-ups (``rtsid run`` alone: the daemon is a peer
#: listening on tcp/127.0.0.1:7447; a lab: ``rtsid router`` listens there), and also when it
#: is started before the daemon (it keeps trying; a client refuses to open when nothing
#: listens yet). A client of a router opens faster (no 0.5 s peer start-up): ``--mode client``.
MODES = ("peer", "client")
DEFAULT_MODE = "peer"
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"


def deprecation_note(old: str, new: str) -> str:
    """The one line an old spelling prints."""
    return f"rtsid: {old} is deprecated; use {new} (it will be removed in the next release)"


class _DeprecatedAlias(argparse.Action):
    """Store like the new option, after printing the deprecation note once per use."""

    def __init__(self, option_strings: Sequence[str], dest: str, *, new: str, **kwargs: Any):
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        print(deprecation_note(option_string or self.option_strings[0], self.new), file=sys.stderr)
        setattr(namespace, self.dest, values)


def deprecated_alias(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    old: str,
    new: str,
    dest: str,
    **kwargs: Any,
) -> None:
    """Accept ``old`` as a hidden spelling of ``new`` (stored in ``dest``) for one release."""
    parser.add_argument(
        old, dest=dest, action=_DeprecatedAlias, new=new, help=argparse.SUPPRESS, **kwargs
    )


def add_fs(parser: argparse.ArgumentParser, help_text: str, default: float | None = None) -> None:
    """``--fs HZ`` (old spelling ``--fs-hz``), stored as ``args.fs``."""
    parser.add_argument("--fs", type=float, default=default, metavar="HZ", help=help_text)
    deprecated_alias(parser, "--fs-hz", "--fs", "fs", type=float, metavar="HZ")


def add_duration(
    parser: argparse.ArgumentParser, help_text: str, default: float | None = None
) -> None:
    """``--duration S`` (old spelling ``--duration-s``), stored as ``args.duration``."""
    parser.add_argument("--duration", type=float, default=default, metavar="S", help=help_text)
    deprecated_alias(parser, "--duration-s", "--duration", "duration", type=float, metavar="S")


def add_output(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    help_text: str,
    *,
    metavar: str = "PATH",
    required: bool = False,
    kind: Any = None,
    old: Sequence[str] = (),
) -> None:
    """``-o/--output PATH``, what the command writes, stored as ``args.output``; ``old``
    spellings (e.g. ``--out``) are accepted with the deprecation note; ``kind`` converts the
    value (argparse's ``type``)."""
    parser.add_argument(
        "-o", "--output", metavar=metavar, required=required, type=kind, help=help_text
    )
    for spelling in old:
        deprecated_alias(parser, spelling, "-o/--output", "output", metavar=metavar, type=kind)


def add_zenoh_reader(parser: argparse.ArgumentParser, connect_help: str) -> None:
    """``--connect ENDPOINT`` (repeatable) and ``--mode {peer,client}`` of a zenoh reader."""
    parser.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"{connect_help} (repeatable; default {DEFAULT_CONNECT})",
    )
    parser.add_argument(
        "--mode",
        choices=MODES,
        default=DEFAULT_MODE,
        help="peer (default): reaches a lone daemon or a router, and waits for a daemon that "
        "starts later; client: of a router (or a daemon) that is up now, opens faster",
    )


def connect_endpoints(args: argparse.Namespace) -> tuple[str, ...]:
    """The endpoints ``--connect`` gave, or the loopback default."""
    return tuple(args.connect or [DEFAULT_CONNECT])
