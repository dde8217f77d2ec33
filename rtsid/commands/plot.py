"""``rtsid plot REC.mcap -o FIG.png``: the tracked stiffness K_track with its 95 % band (each
window's K beside it), B and I (fitted with their bands, held values as held), and VAF."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.commands.common import add_output
from rtsid.errors import InputDataError, RtsidWarning
from rtsid.plots import estimate_series


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording",
        type=Path,
        nargs="+",
        help="an .mcap with /estimate messages (any part of a rotated session reads them all)",
    )
    add_output(parser, "the PNG to write", required=True, kind=Path)
    parser.add_argument("--hist", type=Path, metavar="PNG", help="also histograms of K, B, I, VAF")
    parser.add_argument("--title", help="figure title (default: the file name)")
    parser.add_argument(
        "--every",
        type=int,
        default=1,
        metavar="N",
        help="plot every N-th window only (long recordings at a 20 ms hop get dense)",
    )


def _window_s(message: dict[str, Any]) -> float:
    """The window's length, s, from its first and last sample's index and time."""
    gaps = message["window_end_index"] - message["window_start_index"]
    span_s = message["t_end_s"] - message["t_start_s"]
    return float(span_s * (gaps + 1) / gaps) if gaps > 0 and span_s > 0 else 0.3


def run(args: argparse.Namespace) -> int:
    from rtsid.io.recording import read_estimates, read_session, session_parts
    from rtsid.plots import plot_distributions, plot_impedance_track, require_matplotlib

    require_matplotlib()
    messages = []
    for path in session_parts(args.recording):
        found = read_estimates(path)
        if not found:
            raise InputDataError(
                f"{path} has no /estimate messages (raw samples only?); estimate them first "
                f"with: rtsid replay {path} -o OUT.mcap, then rtsid plot OUT.mcap"
            )
        messages.extend(found)
    messages.sort(key=lambda m: m["window_end_index"])
    name = args.recording[0].name + (
        f" (+{len(args.recording) - 1} more)" if len(args.recording) > 1 else ""
    )
    if args.every < 1:
        raise InputDataError(f"--every {args.every}: give a whole number >= 1")
    t, series, flagged = estimate_series(messages[:: args.every])
    ok = np.isfinite(series["K"])
    if not ok.any():
        reasons = sorted({str(m.get("reason")) for m in messages})
        raise InputDataError(
            f"{name}: all {len(t)} windows plotted were withheld ({', '.join(reasons)}); "
            "nothing to plot"
        )
    title = args.title or f"{name}: {int(ok.sum())} of {len(t)} windows"
    window_s = _window_s(messages[0])
    with warnings.catch_warnings():  # what the parts lack was said once already
        warnings.simplefilter("ignore", RtsidWarning)
        markers = read_session(args.recording).markers
    out = plot_impedance_track(
        t,
        series,
        args.output,
        title=title,
        flagged=flagged,
        window_s=window_s,
        markers=[(m["t_s"], str(m["label"])) for m in markers],
    )
    track = series["K_track"]
    tracked = (
        f"median K_track {np.nanmedian(track):.1f} N·m/rad, " if np.isfinite(track).any() else ""
    )
    print(
        f"wrote {out}: {tracked}median K {np.nanmedian(series['K']):.1f} N·m/rad, "
        f"B {np.nanmedian(series['B']):.3f} N·m·s/rad, I {np.nanmedian(series['I']):.4f} kg·m², "
        f"VAF {np.nanmedian(series['vaf']):.1f} % over {int(ok.sum())} windows "
        f"({len(t) - int(ok.sum())} withheld, {int(flagged.sum())} flagged), "
        f"{len(markers)} markers"
    )
    if args.hist:
        print(f"wrote {plot_distributions(series, args.hist, title=title)}")
    return 0
