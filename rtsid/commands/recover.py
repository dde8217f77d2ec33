"""``rtsid recover REC.mcap [-o OUT.mcap]``: rewrite a recording that lost its footer."""

from __future__ import annotations

import argparse
from pathlib import Path

from rtsid.commands.common import add_output


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, help="an MCAP recording (e.g. after kill -9)")
    add_output(parser, "output file (default: REC-recovered.mcap beside the input)", kind=Path)
    parser.add_argument("--overwrite", action="store_true", help="replace OUTPUT if it exists")


def run(args: argparse.Namespace) -> int:
    from rtsid.io.mcap_read import recover

    src: Path = args.recording
    dst: Path = args.output or src.with_name(src.stem + "-recovered.mcap")
    report = recover(src, dst, overwrite=args.overwrite)
    state = "complete (had its footer)" if report.complete else f"incomplete: {report.error}"
    print(f"{src}: {state}")
    topics = ", ".join(f"{t} {n}" for t, n in sorted(report.by_topic.items())) or "none"
    print(f"wrote {dst}: {report.messages} messages saved ({topics})")
    return 0
