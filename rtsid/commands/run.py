"""``rtsid run``: the daemon. With no config it runs on the embedded virtual plant."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from typing import Any

from rtsid.commands.common import add_duration
from rtsid.config import to_toml
from rtsid.errors import ConfigError
from rtsid.runtime.daemon import Daemon, DaemonConfig
from rtsid.verdicts import format_counts


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="TOML", help="daemon config (default: virtual plant)")
    add_duration(parser, "stop after S seconds")
    parser.add_argument("--quiet", action="store_true", help="no console line per status")
    parser.add_argument(
        "--foxglove",
        nargs="?",
        const=8765,
        type=int,
        metavar="PORT",
        help="also serve the recording's channels live to Foxglove (WebSocket, default port "
        "8765; needs pip install 'rtsid[live]')",
    )
    parser.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        help="address the Foxglove server binds to: loopback only (127.0.0.1 or ::1), as its "
        "protocol has no authentication; reach it from elsewhere through an SSH tunnel",
    )
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="print the configuration in effect (every section and key) as TOML and exit",
    )


def _fmt(value: Any, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def status_line(status: dict[str, Any], estimate: dict[str, Any] | None) -> str:
    """One console line: the newest estimate and the health counters."""
    acq, worker = status.get("acquisition", {}), status.get("worker", {})
    withheld = sum(worker.get("withheld", {}).values())
    head = f"t={status.get('uptime_s', 0):6.1f}s"
    if estimate is None:
        est = "waiting for the first window"
    elif estimate["ok"]:
        est = (
            f"K={_fmt(estimate['K'], '7.1f')}±{_fmt(estimate['K_se'], '.1f')} N·m/rad  "
            f"B={_fmt(estimate['B'], '.3f')}  I={_fmt(estimate['I'], '.4f')}  "
            f"VAF={_fmt(estimate['vaf'], '5.1f')}%  latency={estimate['latency_ms']:.1f} ms"
        )
    else:
        est = f"withheld: {estimate['reason']}"
    health = (
        f"[{worker.get('estimates', 0)} estimates, {withheld} withheld, "
        f"{worker.get('deadline_misses', 0)} misses, {acq.get('lost_samples', 0)} lost, "
        f"cpu {status.get('cpu_percent', 0):.0f}%]"
    )
    return f"{head}  {est}  {health}"


def _zenoh_where(config: DaemonConfig) -> str:
    z = config.zenoh
    if not z.enabled:
        return "off"
    if z.config_file:
        return f"from {z.config_file}"
    if z.mode == "client":
        return f"client of {', '.join(z.connect)}"
    return ", ".join(z.listen + z.connect) or "peer without endpoints"


def _foxglove_server(args: argparse.Namespace, config: DaemonConfig) -> Any:
    """The Foxglove live server ``--foxglove`` asks for (not started), or None."""
    if args.foxglove is None:
        return None
    from rtsid.io.foxglove_live import FoxgloveLive, require_foxglove
    from rtsid.io.mcap_log import channel_kinds

    require_foxglove()  # before anything starts: a missing extra is a one-line error
    if not config.mcap.enabled:
        raise ConfigError(
            "--foxglove serves the recording's channels live and needs mcap.enabled = true; "
            "enable [mcap] or drop --foxglove"
        )
    kinds = channel_kinds(can_frames=config.mcap.log_can_frames)
    return FoxgloveLive(kinds, host=args.foxglove_host, port=args.foxglove)


def run(args: argparse.Namespace) -> int:
    config = DaemonConfig.load(args.config)
    if args.print_config:
        print(to_toml(config.as_dict()), end="")
        return 0

    def show(status: dict[str, Any], estimate: dict[str, Any] | None) -> None:
        print(status_line(status, estimate), flush=True)

    if not args.quiet:  # the worker says once which analysis it chose, and so on
        logging.basicConfig(level=logging.INFO, format="rtsid run: %(message)s")
    foxglove = _foxglove_server(args, config)
    daemon = Daemon(
        config,
        on_status=None if args.quiet else show,
        message_tap=None if foxglove is None else foxglove.tap,
    )
    previous = {
        sig: signal.signal(sig, lambda *_: daemon.request_stop())
        for sig in (signal.SIGINT, signal.SIGTERM)
    }
    source = config.link.interface
    if source == "embedded":
        source = f"embedded virtual plant ({config.plant.mode})"
    print(
        f"rtsid run: {source}, {config.worker.window_s * 1e3:.0f} ms windows every "
        f"{config.worker.hop_s * 1e3:.0f} ms; zenoh {_zenoh_where(config)}; "
        f"MCAP in {config.mcap.directory}. Ctrl-C stops.",
        flush=True,
    )
    try:
        if foxglove is not None:
            foxglove.start()
            print(f"rtsid run: Foxglove live on {foxglove.url}", flush=True)
        summary = daemon.run(duration_s=args.duration)
    finally:
        if foxglove is not None:
            foxglove.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    withheld = format_counts(summary.withheld)
    print(
        f"rtsid run: stopped — {summary.estimates} estimates, withheld {withheld}, "
        f"{summary.deadline_misses} deadline misses, {summary.samples} samples "
        f"({summary.lost_samples} lost), MCAP: {', '.join(summary.mcap_files) or 'none'}"
        f"{'' if summary.clean_shutdown else ' (shutdown was not clean)'}",
        file=sys.stderr,
    )
    if summary.failure is not None:
        print(f"rtsid run: error: {summary.failure}", file=sys.stderr)
    return 0 if summary.clean_shutdown else 1
