"""``rtsid condition C``: change the condition of running daemons without a restart.

A zenoh query to each daemon's ``<prefix>/<robot>/<joint>/condition`` queryable; the daemon
records a ``/session`` message holding from its next sample, publishes it on
``…/session`` and answers with that sample, printed here one line per daemon.
"""

from __future__ import annotations

import argparse
import sys

from rtsid.commands.mark import add_daemon_target, ask_daemons
from rtsid.io.session import check_session_name
from rtsid.io.validate import printable


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("condition", help="the new condition, e.g. fatigue")
    add_daemon_target(parser)


def run(args: argparse.Namespace) -> int:
    condition = check_session_name("condition", args.condition)
    acks, errors = ask_daemons(args, "condition", {"condition": condition})
    for ack in acks:
        print(
            f"rtsid condition: {printable(ack['robot'], 64)}/{printable(ack['joint'], 64)} "
            f"{printable(condition, 64)!r} from sample {ack['sample_index']} "
            f"(t = {ack['t_s']:.4f} s)",
            flush=True,
        )
    for error in errors:
        print(f"rtsid condition: error reply: {error}", file=sys.stderr)
    return 1 if errors else 0
