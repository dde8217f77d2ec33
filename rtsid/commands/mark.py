"""``rtsid mark LABEL``: a trial marker on the next sample of every daemon matched.

A zenoh query to each daemon's ``<prefix>/<robot>/<joint>/mark`` queryable: the daemon stamps
the next sample, writes the marker to its recording (``/marker``, flushed) and only then
answers with the sample index and time, printed here one line per daemon. No answer within
``--timeout``: one error line, exit status 2 — the marker was NOT recorded. A resent marker
keeps its ``--id`` and is recorded once.
"""

from __future__ import annotations

import argparse
import os
import sys
import uuid
from typing import Any

from rtsid.commands.common import add_zenoh_reader, connect_endpoints
from rtsid.errors import ConfigError, ServiceError
from rtsid.io.schemas import encode_json
from rtsid.io.validate import (
    NAME_PATTERN,
    MalformedMessage,
    check_value,
    decode_json,
    error_reply_text,
    printable,
)

_ACK_SCHEMA = {
    "type": "object",
    "properties": {
        "ok": {"type": "boolean"},
        "robot": {"type": "string"},
        "joint": {"type": "string"},
        "sample_index": {"type": "integer"},
        "t_s": {"type": "number"},
    },
    "required": ["ok", "robot", "joint", "sample_index", "t_s"],
}


def add_daemon_target(parser: argparse.ArgumentParser) -> None:
    """``--robot``, ``--joint``, ``--prefix``, the zenoh reader's options and ``--timeout``."""
    parser.add_argument("--robot", default="*", help="robot name (default: every robot)")
    parser.add_argument("--joint", default="*", help="joint name (default: every joint)")
    parser.add_argument("--prefix", default="rtsid", help="key prefix of the daemons (rtsid)")
    add_zenoh_reader(parser, "a router's or a daemon's endpoint")
    parser.add_argument(
        "--timeout", type=float, default=5.0, help="wait at most S s for the answers (5)"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("label", help='what the marker says, e.g. "trial 3 start"')
    parser.add_argument(
        "--id",
        dest="marker_id",
        metavar="ID",
        help="the marker's id (default: a new random one); resend with the same id and the "
        "marker is recorded once",
    )
    add_daemon_target(parser)


def ask_daemons(
    args: argparse.Namespace, channel: str, body: dict[str, Any]
) -> tuple[list[dict[str, Any]], list[str]]:
    """Send ``body`` as a query to ``<prefix>/<robot>/<joint>/<channel>`` of every daemon
    matched; their checked acknowledgements and error replies (printable).

    Raises
    ------
    ConfigError
        A bad name, key or timeout.
    ServiceError
        No zenoh session, or no daemon answered (the request was NOT recorded).
    """
    import zenoh

    from rtsid.io.zenoh_link import query, subscriber_config, user_key_expr

    if not args.timeout > 0:
        raise ConfigError(f"--timeout {args.timeout} is not accepted; expected seconds > 0")
    for what in ("robot", "joint"):
        name = getattr(args, what)
        if name != "*" and not NAME_PATTERN.match(name):
            raise ConfigError(
                f"--{what} {printable(name, 80)!r} is not a name; expected letters, digits, "
                "'_', '.', '-' (or * for every one)"
            )
    key = user_key_expr(f"{args.prefix}/{args.robot}/{args.joint}/{channel}")
    connect = connect_endpoints(args)
    try:
        session = zenoh.open(subscriber_config(connect, args.mode))
    except zenoh.ZError as exc:
        raise ServiceError(
            f"cannot reach {', '.join(connect)}: {exc}; is the router (or daemon) running "
            f"there? the {channel} was NOT recorded"
        ) from None
    with session:
        answer = query(session, key, timeout_s=args.timeout, payload=encode_json(body))
    acks, rejected = [], []
    for reply_key, payload in answer.replies:
        try:
            ack = decode_json(payload)
            check_value(ack, _ACK_SCHEMA)
        except MalformedMessage as exc:
            rejected.append(f"{printable(reply_key, 120)}: malformed answer ({exc})")
            continue
        acks.append(ack)
    errors = [error_reply_text(e) for e in answer.errors] + rejected
    if not acks and not errors:
        raise ServiceError(_no_answer(channel, key, args.timeout, connect))
    return acks, errors


def _no_answer(channel: str, key: str, timeout_s: float, connect: tuple[str, ...]) -> str:
    """The one line of a request no daemon answered: through the lab's secure router (a zenoh
    file in ``RTSID_ZENOH_CONFIG``) a viewer's certificate is the likely cause."""
    from rtsid.io.zenoh_link import VIEWER_CONFIG_ENV

    what = "marker" if channel == "mark" else "condition"
    config_file = os.environ.get(VIEWER_CONFIG_ENV, "")
    if config_file:
        return (
            f"no daemon answered on {key} within {timeout_s:g} s via {VIEWER_CONFIG_ENV}="
            f"{printable(config_file, 200)}; the {what} was NOT recorded (is the daemon "
            "running? in the secure lab only an operator's certificate may mark or change the "
            "condition: use your operator-NAME.json5, see docs/lab.md)"
        )
    return (
        f"no daemon answered on {key} within {timeout_s:g} s via {', '.join(connect)}; "
        f"the {what} was NOT recorded (is the daemon running, and --connect its endpoint "
        "or the lab's router?)"
    )


def run(args: argparse.Namespace) -> int:
    from rtsid.runtime.session import RefusedRequest, check_label

    try:
        check_label(args.label)
    except RefusedRequest as exc:
        raise ConfigError(f"label not accepted: {exc}") from None
    marker_id = args.marker_id or uuid.uuid4().hex
    acks, errors = ask_daemons(args, "mark", {"label": args.label, "marker_id": marker_id})
    for ack in acks:
        again = " (already recorded: same id)" if ack.get("duplicate") else ""
        print(
            f"rtsid mark: {printable(ack['robot'], 64)}/{printable(ack['joint'], 64)} "
            f"{printable(args.label, 80)!r} at sample {ack['sample_index']} "
            f"(t = {ack['t_s']:.4f} s), id {marker_id}{again}",
            flush=True,
        )
    for error in errors:
        print(f"rtsid mark: error reply: {error}", file=sys.stderr)
    return 1 if errors else 0
