"""``rtsid summary REC… [--by trial|condition|subject] [-o table.csv] [--plot fig.png]``:
one row per trial, condition or subject from the recordings' own estimates (nothing is
estimated again; :mod:`rtsid.summary`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rtsid.commands.common import add_output
from rtsid.summary import BY

TRIALS_HELP = (
    "Trials come from the /marker channel: markers are taken in time order and each ends the "
    "trial that is open; '<name> start' (or 'begin') opens trial <name>, '<name> end' (or "
    "'stop') closes it, any other label opens a trial named by it; the last runs to the "
    "end of the recording. A window belongs to the trial in force at its t_end_s. Trials of "
    "one name in a session are numbered (repeat). A recording without markers is one trial; "
    "one made before sessions existed has empty subject, session and condition (its notes say "
    "so). A trial during which the condition changed gives one row per condition."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (parser.description or "") + ". " + TRIALS_HELP
    parser.add_argument(
        "recording",
        type=Path,
        nargs="+",
        help="rtsid .mcap recordings with /estimate messages (the daemon's, or rtsid replay "
        "-o OUT.mcap), or folders of them (searched recursively); the rotated parts of a "
        "session are read as one recording",
    )
    parser.add_argument(
        "--by",
        choices=BY,
        default="trial",
        help="one row per trial (default), per subject and condition, or per subject",
    )
    add_output(parser, "the table as CSV (default: CSV on standard output)", kind=Path)
    parser.add_argument(
        "--plot", type=Path, metavar="PNG", help="a figure: K_track, K and VAF per row"
    )
    parser.add_argument(
        "--include-between",
        action="store_true",
        help="also report the windows outside every trial, as rows '(between trials)'",
    )


def run(args: argparse.Namespace) -> int:
    from rtsid.io.estimate_csv import open_output
    from rtsid.summary import find_recordings, read_study, summarise, write_summary

    if args.plot:
        from rtsid.plots import require_matplotlib

        require_matplotlib()
    recordings = read_study(find_recordings(args.recording))
    rows = summarise(recordings, args.by, include_between=args.include_between)
    with open_output(args.output) as fh:
        write_summary(rows, fh)
    windows = sum(int(r["windows"]) for r in rows)
    where = f"wrote {args.output}: " if args.output else ""
    print(
        f"rtsid summary: {where}{len(rows)} rows by {args.by} from {len(recordings)} "
        f"recording(s), {windows} windows",
        file=sys.stderr,
    )
    if args.plot:
        from rtsid.plots import plot_summary

        out = plot_summary(rows, args.plot, by=args.by)
        print(f"rtsid summary: wrote {out}", file=sys.stderr)
    return 0
