"""``rtsid certs DIR``: the secure lab profile (zenoh mTLS, access control) and certificates.

Who gets which file: each daemon's machine its ``daemon-ROBOT-JOINT`` files; the experimenter's
desk (marks trials, changes the condition) its ``operator-NAME`` files; a display, a student's
laptop or a controller that only reads its ``viewer-NAME`` files.
"""

from __future__ import annotations

import argparse

from rtsid.errors import ConfigError
from rtsid.runtime.lab_security import LabProfile, participants, write_lab_profile


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write a lab CA, certificates and zenoh json5 files (mutual TLS, access control, "
        "default deny). Hand out: each daemon's machine its daemon-ROBOT-JOINT files; the "
        "experimenter's desk its operator-NAME files (reads, and may mark trials and change "
        "the condition); a display or a student its viewer-NAME files (reads only)."
    )
    parser.add_argument("directory", metavar="DIR", help="a new (or empty) directory to write")
    parser.add_argument(
        "--daemon",
        action="append",
        default=[],
        metavar="ROBOT/JOINT",
        help="a daemon allowed to publish on rtsid/ROBOT/JOINT/** (repeatable)",
    )
    parser.add_argument(
        "--viewer",
        action="append",
        default=[],
        metavar="NAME",
        help="a viewer (a display, a student): subscribes and queries the daemons' read-only "
        "queryables (config, estimate, status, history, session); cannot mark or change the "
        "condition; gets viewer-NAME.json5 (repeatable)",
    )
    parser.add_argument(
        "--operator",
        action="append",
        default=[],
        metavar="NAME",
        help="an operator (the experimenter's desk): a viewer's rights plus `rtsid mark` and "
        "`rtsid condition` (queries on rtsid/**/mark and rtsid/**/condition); gets "
        "operator-NAME.json5 (repeatable)",
    )
    parser.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="the router's TLS endpoint, repeatable (default tls/127.0.0.1:7447, loopback only; "
        "a lab names its interface, e.g. tls/192.168.10.2:7447)",
    )
    parser.add_argument(
        "--connect",
        default="",
        metavar="ENDPOINT",
        help="the endpoint daemons, operators and viewers connect to (default: the first "
        "--listen); its host is written into the router's certificate",
    )
    parser.add_argument("--key-prefix", default="rtsid", help="first key chunk (default rtsid)")
    parser.add_argument("--days", type=int, default=825, help="certificate validity (825 days)")


def _daemon(text: str) -> tuple[str, str]:
    robot, sep, joint = text.partition("/")
    if not sep or not robot or not joint or "/" in joint:
        raise ConfigError(
            f"--daemon {text!r} is not accepted; expected ROBOT/JOINT, e.g. rig1/ankle"
        )
    return robot, joint


def run(args: argparse.Namespace) -> int:
    profile = LabProfile(
        daemons=tuple(_daemon(d) for d in args.daemon),
        viewers=tuple(args.viewer),
        operators=tuple(args.operator),
        listen=tuple(args.listen or LabProfile.listen),
        connect=args.connect,
        key_prefix=args.key_prefix,
        days=args.days,
    )
    files = write_lab_profile(args.directory, profile)
    where = files[0].parent
    print(f"rtsid certs: wrote {len(files)} files to {where} (keys mode 0600)")
    print(f"  router:  rtsid router --config {where / 'router.toml'}")
    for stem, common_name in participants(profile):
        print(f"  {common_name}: zenoh config {where / (stem + '.json5')}")
    return 0
