"""``rtsid router``: a zenoh router for a lab, from eclipse-zenoh's own router mode.

Daemons connect to it as clients (``[zenoh] mode = "client"``, ``connect = [its endpoint]``),
and so do ``rtsid watch``, the web view and controllers; zenoh routes every estimate, status,
liveliness token and query between them. Nothing here is home-made networking: the session is
``zenoh.open`` of a router-mode configuration (:func:`rtsid.io.zenoh_link.router_config`), which
a lab may replace with a standalone ``zenohd`` given the same json5 (``hw/zenohd.json5``).

The router also watches the daemons' liveliness tokens, so its console says which
``robot/joint`` joined and left.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from rtsid.config import load_toml
from rtsid.errors import ConfigError, ServiceError
from rtsid.io.access_token import is_loopback
from rtsid.io.zenoh_link import RouterConfig, router_config, zenoh_error_text

__all__ = ["RouterConfig", "load_router_config", "open_to_anyone", "run_router"]

log = logging.getLogger(__name__)


def load_router_config(path: str | Path | None, listen: tuple[str, ...] = ()) -> RouterConfig:
    """The ``[router]`` section of a TOML file (defaults without one); ``listen`` overrides.

    Raises
    ------
    ConfigError
        Another section in the file, an unknown key or a bad endpoint.
    """
    document: dict[str, Any] = {} if path is None else load_toml(path)
    unknown = sorted(set(document) - {"router"})
    if unknown:
        raise ConfigError(f"unknown config section [{unknown[0]}]; accepted sections: [router]")
    section = document.get("router") or {}
    if not isinstance(section, Mapping):
        raise ConfigError("config key 'router' must be a table [router]")
    section = dict(section)
    if listen:
        section["listen"] = list(listen)
    if path is not None and isinstance(section.get("config_file"), str) and section["config_file"]:
        file = Path(section["config_file"]).expanduser()
        section["config_file"] = str(file if file.is_absolute() else Path(path).parent / file)
    return RouterConfig.from_mapping(section)


def open_to_anyone(conf: Any) -> list[str]:
    """The router's endpoints beyond loopback when its access control is off (else none).

    ``conf`` is the router's ``zenoh.Config``. Such a router lets anyone who reaches it publish
    on and read every daemon's keys; the secure lab profile (``rtsid certs``) closes it.
    """
    if json.loads(conf.get_json("access_control/enabled")):
        return []
    listen = json.loads(conf.get_json("listen/endpoints"))
    if isinstance(listen, dict):  # zenoh's per-mode form: {"router": [...], ...}
        listen = listen.get("router") or []
    beyond = []
    for endpoint in listen:
        address = str(endpoint).split("#", 1)[0].split("?", 1)[0].partition("/")[2]
        host = address.rsplit(":", 1)[0] if ":" in address else address
        if not is_loopback(host):
            beyond.append(str(endpoint))
    return beyond


def _token_name(key: str) -> str:
    """``rtsid/rig/ankle/alive`` → ``rig/ankle``."""
    return "/".join(key.rstrip("/").split("/")[-3:-1])


def run_router(
    cfg: RouterConfig,
    stop: threading.Event,
    *,
    key_prefix: str = "rtsid",
    on_event: Callable[[str], None] | None = None,
    duration_s: float | None = None,
) -> int:
    """Run the router until ``stop`` is set (or ``duration_s`` passes).

    Parameters
    ----------
    cfg : RouterConfig
    stop : threading.Event
        Set it (e.g. from a signal handler) to close the router.
    key_prefix : str
        Daemons' key prefix, for the joined/left lines.
    on_event : callable, optional
        Called with one line per event (listening, a daemon joined or left).
    duration_s : float, optional
        Close after this long, s.

    Returns
    -------
    int
        Daemons seen alive over the run.

    Raises
    ------
    ServiceError
        The router could not open (endpoint taken or invalid), naming the endpoint and the fix.
    """
    import zenoh

    say = on_event or (lambda line: log.info("%s", line))
    conf = router_config(cfg)
    exposed = open_to_anyone(conf)
    if exposed:
        say(
            f"warning: listening beyond loopback ({', '.join(exposed)}) without access control: "
            f"anyone who reaches it can publish on and read {key_prefix}/**; use the secure "
            "lab profile (rtsid certs, docs/lab.md)"
        )
    where = ", ".join(cfg.listen) if not cfg.config_file else cfg.config_file
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ServiceError(
            f"zenoh router on {where} could not open: {zenoh_error_text(exc)}; is another "
            "router or daemon listening there? choose a free endpoint with --listen or "
            "[router] listen"
        ) from None
    seen: set[str] = set()
    end = None if duration_s is None else time.monotonic() + duration_s
    with session:
        tokens = session.liveliness().declare_subscriber(
            f"{key_prefix}/**/alive", zenoh.handlers.RingChannel(256), history=True
        )
        say(f"zenoh router {session.zid()} listening on {where}")
        while not stop.is_set() and (end is None or time.monotonic() < end):
            token = tokens.try_recv()
            if token is None:
                stop.wait(0.05)
                continue
            name = _token_name(str(token.key_expr))
            if token.kind == zenoh.SampleKind.PUT:
                seen.add(name)
                say(f"{name} joined")
            else:
                say(f"{name} left (liveliness token gone)")
        tokens.undeclare()
    return len(seen)
