"""``rtsid run``: the daemon. With no config it runs on the embedded virtual plant."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import signal
import sys
from typing import Any

from rtsid.commands.common import add_duration
from rtsid.config import to_toml
from rtsid.errors import ConfigError
from rtsid.link.acquisition import explain_link_state
from rtsid.link.config import LinkConfig
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
    for name, example in (("subject", "S01"), ("session", "2"), ("condition", "baseline")):
        parser.add_argument(
            f"--{name}",
            metavar=name.upper(),
            help=f"the {name} (e.g. {example}; overrides [session] {name}); names the "
            "recording with [session] recording_pattern",
        )
    parser.add_argument(
        "--print-config",
        action="store_true",
        help="print the configuration in effect (every section and key) as TOML and exit",
    )


def _fmt(value: Any, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def status_line(
    status: dict[str, Any], estimate: dict[str, Any] | None, where: str = "the bus"
) -> str:
    """One console line: the newest estimate (or why none comes) and the health counters.

    ``where`` names the link's far end (:func:`link_where`) in the reason for waiting.
    """
    acq, worker = status.get("acquisition", {}), status.get("worker", {})
    withheld = sum(worker.get("withheld", {}).values())
    head = f"t={status.get('uptime_s', 0):6.1f}s"
    why = explain_link_state(acq, where)
    if estimate is None:
        est = "waiting for the first window" if why is None else f"waiting: {why}"
    elif estimate["ok"]:
        est = (
            f"K_track={_band(estimate.get('K_track'), estimate.get('K_track_se'))} N·m/rad  "
            f"K(300ms)={_fmt(estimate['K'], '.1f')}  "
            f"B={_held(estimate, 'B', '.3f')}  I={_held(estimate, 'I', '.4f')}  "
            f"VAF={_fmt(estimate['vaf'], '5.1f')}%  latency={estimate['latency_ms']:.1f} ms"
        )
    else:
        est = f"withheld: {estimate['reason']}"
    if estimate is not None and why is not None:
        est = f"{est}; link: {why}"
    health = (
        f"[{worker.get('estimates', 0)} estimates, {withheld} withheld, "
        f"{worker.get('deadline_misses', 0)} misses, {acq.get('lost_samples', 0)} lost, "
        f"cpu {status.get('cpu_percent', 0):.0f}%]"
    )
    return f"{head}  {est}  {health}"


def _band(value: float | None, se: float | None) -> str:
    """``149.8±0.4``: a value and its 95 % half-width (1.96 SE), or ``—``."""
    if value is None:
        return "—"
    return f"{value:.1f}" + ("" if se is None else f"±{1.96 * se:.1f}")


def _held(estimate: dict[str, Any], key: str, spec: str) -> str:
    """A parameter as a held value (``0.800 (held)``) or with its standard error."""
    if estimate.get(f"{key}_held"):
        return f"{_fmt(estimate[key], spec)} (held)"
    return f"{_fmt(estimate[key], spec)}±{_fmt(estimate[f'{key}_se'], spec)}"


def link_where(link: LinkConfig) -> str:
    """The link's far end as a user names it: ``host:port``, the adapter and channel."""
    if link.interface == "socketcand":
        return f"{link.host}:{link.port}"
    if link.interface == "embedded":
        return "the embedded plant"
    if link.interface == "udp":
        return f"UDP {link.udp.bind_host}:{link.udp.port}"
    return f"{link.interface} channel {link.channel}"


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


def _who(config: DaemonConfig) -> str:
    """``; subject S01, session 2, condition baseline`` (empty without a subject)."""
    s = config.session
    if not s.subject:
        return ""
    return f"; subject {s.subject}, session {s.session or '-'}, condition {s.condition or '-'}"


class _ConsoleFormat(logging.Formatter):
    """``rtsid run: …`` lines, with ``warning:`` or ``error:`` said as the CLI says them."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        if record.levelno >= logging.ERROR:
            return f"rtsid run: error: {text}"
        if record.levelno >= logging.WARNING:
            return f"rtsid run: warning: {text}"
        return f"rtsid run: {text}"


def _log_to_console(level: int) -> None:
    """The daemon's log records on standard error as one prefixed line each."""
    handler = logging.StreamHandler()
    handler.setFormatter(_ConsoleFormat("%(message)s"))
    logging.basicConfig(level=level, handlers=[handler])


def run(args: argparse.Namespace) -> int:
    config = DaemonConfig.load(args.config)
    session = config.session.with_overrides(
        subject=args.subject, session=args.session, condition=args.condition
    )
    config = dataclasses.replace(config, session=session)
    if args.print_config:
        print(to_toml(config.as_dict()), end="")
        return 0

    def show(status: dict[str, Any], estimate: dict[str, Any] | None) -> None:
        print(status_line(status, estimate, link_where(config.link)), flush=True)

    # the worker says once which analysis it chose, and so on; --quiet keeps the warnings
    _log_to_console(logging.WARNING if args.quiet else logging.INFO)
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
        f"MCAP in {config.mcap.directory}{_who(config)}. Ctrl-C stops.",
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
