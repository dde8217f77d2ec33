"""The secure lab profile: zenoh's own mutual TLS and access control, and its certificates.

``rtsid certs DIR --daemon ROBOT/JOINT … --operator NAME … --viewer NAME …`` writes, into a
new directory,

- a lab certificate authority (``ca.pem``, ``ca-key.pem``) made with the ``openssl`` CLI;
- one certificate per participant, signed by it, whose common name says who it is:
  ``router``, ``daemon:<robot>:<joint>``, ``operator:<name>``, ``viewer:<name>`` (``:``
  cannot appear in a name, so no two participants can share a common name);
- the zenoh json5 files that use them: ``router.json5`` (router mode, ``tls/`` listener with
  ``enable_mtls``, and the ``access_control`` rules below), ``daemon-<robot>-<joint>.json5``,
  ``operator-<name>.json5`` and ``viewer-<name>.json5`` (client mode, ``tls/`` connect
  endpoint, the participant's certificate), and ``router.toml`` for ``rtsid router --config``.

Nothing is home-made: authentication is zenoh's mutual TLS (a client without a certificate
signed by the lab's CA cannot complete the handshake), and authorisation is zenoh's
``access_control`` with subjects matched by certificate common name (``cert_common_names``),
default ``deny``:

==============  =====================================================================
who             allowed (everything else is denied)
==============  =====================================================================
daemon R/J      ingress ``put``, ``delete``, ``declare_queryable``, ``reply``,
                ``liveliness_token`` on ``<prefix>/R/J/**`` only; egress ``query`` and
                ``declare_subscriber`` on ``<prefix>/**`` (the router may ask it)
viewer          ingress ``declare_subscriber``, ``declare_liveliness_subscriber``,
                ``liveliness_query`` on ``<prefix>/**``; ingress ``query`` on the daemons'
                read-only queryables only (``<prefix>/**/config``, ``…/estimate``,
                ``…/status``, ``…/history``, ``…/session``); egress ``put``, ``delete``,
                ``reply``, ``declare_queryable``, ``liveliness_token`` on ``<prefix>/**``
operator        a viewer's rights, plus ingress ``query`` on ``<prefix>/**/mark`` and
                ``<prefix>/**/condition`` (``rtsid mark``, ``rtsid condition``)
anyone else     nothing (a certificate of the lab's CA with another common name connects
                and is refused every message)
==============  =====================================================================

zenoh allows a message only when an allow rule's key expression *includes* the message's
(``nodes_including`` in zenoh's policy decision point; a rule cannot negate), so the
queries a viewer may send are listed one queryable name at a time; a viewer's query on a
wider key (``<prefix>/**``, ``<prefix>/*/*/*``) is refused whole. No one but a daemon may put:
``…/mark/in`` (a marker put with no acknowledgement) stays closed, so in the secure lab every
marker is an acknowledged one.

Certificates rather than user/password: a certificate both encrypts the link and names the
peer, the private keys never cross the network, and zenoh's user/password dictionary would
keep every password in one clear-text file on the router.
"""

from __future__ import annotations

import ipaddress
import json
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rtsid.errors import ConfigError, ServiceError

__all__ = [
    "LabProfile",
    "access_control",
    "daemon_common_name",
    "operator_common_name",
    "profile_texts",
    "viewer_common_name",
    "write_lab_profile",
]

_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")
_TLS_ENDPOINT = re.compile(r"^tls/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+):[0-9]{1,5}$")

#: What a daemon sends on its own keys, and what it may be sent.
DAEMON_SENDS = ("put", "delete", "declare_queryable", "reply", "liveliness_token")
DAEMON_RECEIVES = ("query", "declare_subscriber")
#: What a viewer (and an operator) follows, and what it may be sent.
VIEWER_FOLLOWS = ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query")
VIEWER_RECEIVES = ("put", "delete", "reply", "declare_queryable", "liveliness_token")
#: The daemons' read-only queryables (rtsid.io.zenoh_link): a viewer may query these only.
READ_ONLY_QUERYABLES = ("config", "estimate", "status", "history", "session")
#: The queryables that change a recording (a marker, the condition): operators only.
OPERATOR_QUERYABLES = ("mark", "condition")


def daemon_common_name(robot: str, joint: str) -> str:
    """The certificate common name of the daemon of ``robot``/``joint``."""
    return f"daemon:{robot}:{joint}"


def viewer_common_name(name: str) -> str:
    """The certificate common name of viewer ``name``."""
    return f"viewer:{name}"


def operator_common_name(name: str) -> str:
    """The certificate common name of operator ``name``."""
    return f"operator:{name}"


@dataclass(frozen=True)
class LabProfile:
    """Who is in the lab and where the router listens.

    Attributes
    ----------
    daemons : tuple of (robot, joint)
    viewers : tuple of str
        Names of the viewers (``rtsid watch``, ``rtsid query``, the web page, a display, a
        student's laptop): they read, and cannot mark or change the condition.
    operators : tuple of str
        Names of the operators (the experimenter's desk): a viewer's rights plus ``rtsid
        mark`` and ``rtsid condition``.
    listen : tuple of str
        The router's ``tls/`` endpoints (default loopback only).
    connect : str
        The ``tls/`` endpoint clients connect to (default: the first of ``listen``); its host
        goes into the router certificate's names, as clients check it.
    key_prefix : str
        First key chunk of every daemon's keys.
    days : int
        Validity of every certificate.
    """

    daemons: tuple[tuple[str, str], ...]
    viewers: tuple[str, ...]
    operators: tuple[str, ...] = ()
    listen: tuple[str, ...] = ("tls/127.0.0.1:7447",)
    connect: str = ""
    key_prefix: str = "rtsid"
    days: int = 825

    def __post_init__(self) -> None:
        if not self.daemons and not self.viewers and not self.operators:
            raise ConfigError(
                "name at least one --daemon ROBOT/JOINT, --operator NAME or --viewer NAME"
            )
        for robot, joint in self.daemons:
            for what, value in (("robot", robot), ("joint", joint)):
                _check_name(what, value)
        for role, names in (("viewer", self.viewers), ("operator", self.operators)):
            for name in names:
                _check_name(role, name)
        if len(set(self.daemons)) != len(self.daemons):
            raise ConfigError("a daemon is named twice; name each once")
        people = [*self.viewers, *self.operators]
        if len(set(people)) != len(people):
            raise ConfigError(
                "a viewer or operator is named twice (or is both); name each once, in one role"
            )
        for endpoint in (*self.listen, self.connect_endpoint):
            if not _TLS_ENDPOINT.match(endpoint):
                raise ConfigError(
                    f"endpoint {endpoint!r} is not accepted; expected tls/HOST:PORT, e.g. "
                    "tls/127.0.0.1:7447 (the secure profile listens on TLS only)"
                )
        if not 1 <= self.days <= 3650:
            raise ConfigError(f"--days {self.days} is not accepted; expected 1 to 3650")

    @property
    def connect_endpoint(self) -> str:
        return self.connect or (self.listen[0] if self.listen else "")

    def router_names(self) -> list[str]:
        """subjectAltName entries of the router certificate (``IP:…``/``DNS:…``)."""
        hosts = ["127.0.0.1", "localhost"]
        for endpoint in (*self.listen, self.connect_endpoint):
            host = endpoint[len("tls/") :].rsplit(":", 1)[0].strip("[]")
            if host not in hosts and host not in ("0.0.0.0", "::"):
                hosts.append(host)
        return [f"IP:{h}" if _is_ip(h) else f"DNS:{h}" for h in hosts]


def _check_name(what: str, value: str) -> None:
    if not _NAME.match(value):
        raise ConfigError(
            f"{what} {value!r} is not accepted; expected letters, digits, '_', '.', '-'"
        )


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def access_control(profile: LabProfile) -> dict[str, Any]:
    """zenoh's ``access_control`` section for ``profile`` (default deny; see the module doc)."""
    everything = f"{profile.key_prefix}/**"
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    if profile.daemons:
        rules.append(_rule("daemons-are-asked", "egress", DAEMON_RECEIVES, [everything]))
    for robot, joint in profile.daemons:
        ident = f"daemon-{robot}-{joint}"
        own = f"{profile.key_prefix}/{robot}/{joint}/**"
        rules.append(_rule(f"{ident}-sends", "ingress", DAEMON_SENDS, [own]))
        subjects.append({"id": ident, "cert_common_names": [daemon_common_name(robot, joint)]})
        policies.append(
            {"id": ident, "rules": [f"{ident}-sends", "daemons-are-asked"], "subjects": [ident]}
        )
    if profile.viewers or profile.operators:
        rules.append(_rule("viewers-follow", "ingress", VIEWER_FOLLOWS, [everything]))
        rules.append(
            _rule("viewers-read", "ingress", ("query",), _queryables(profile, READ_ONLY_QUERYABLES))
        )
        rules.append(_rule("viewers-are-sent", "egress", VIEWER_RECEIVES, [everything]))
    reads = ["viewers-follow", "viewers-read", "viewers-are-sent"]
    if profile.viewers:
        subjects.append(
            {"id": "viewers", "cert_common_names": [viewer_common_name(v) for v in profile.viewers]}
        )
        policies.append({"id": "viewers", "rules": reads, "subjects": ["viewers"]})
    if profile.operators:
        rules.append(
            _rule(
                "operators-command",
                "ingress",
                ("query",),
                _queryables(profile, OPERATOR_QUERYABLES),
            )
        )
        subjects.append(
            {
                "id": "operators",
                "cert_common_names": [operator_common_name(o) for o in profile.operators],
            }
        )
        policies.append(
            {"id": "operators", "rules": [*reads, "operators-command"], "subjects": ["operators"]}
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _queryables(profile: LabProfile, names: Sequence[str]) -> list[str]:
    """``<prefix>/**/<name>`` for each queryable name: any daemon's, and a wider query such as
    ``<prefix>/rig1/**/history`` too, since the last chunk alone says what is asked."""
    return [f"{profile.key_prefix}/**/{name}" for name in names]


def _rule(ident: str, flow: str, messages: Sequence[str], keys: Sequence[str]) -> dict[str, Any]:
    return {
        "id": ident,
        "permission": "allow",
        "flows": [flow],
        "messages": list(messages),
        "key_exprs": list(keys),
    }


def _scouting_off() -> dict[str, Any]:
    return {"multicast": {"enabled": False}, "gossip": {"enabled": False}}


def router_json5(profile: LabProfile, certs: Path) -> dict[str, Any]:
    """The router's zenoh configuration (TLS listener with mTLS, access control)."""
    return {
        "mode": "router",
        "listen": {"endpoints": list(profile.listen)},
        "connect": {"endpoints": []},
        "scouting": _scouting_off(),
        "transport": {
            "link": {
                "protocols": ["tls"],
                "tls": {
                    "root_ca_certificate": str(certs / "ca.pem"),
                    "listen_certificate": str(certs / "router.pem"),
                    "listen_private_key": str(certs / "router-key.pem"),
                    "enable_mtls": True,
                },
            }
        },
        "access_control": access_control(profile),
    }


def client_json5(profile: LabProfile, certs: Path, stem: str) -> dict[str, Any]:
    """A daemon's, an operator's or a viewer's zenoh configuration: a client of the router
    over mutual TLS."""
    return {
        "mode": "client",
        "connect": {"endpoints": [profile.connect_endpoint]},
        "listen": {"endpoints": []},
        "scouting": _scouting_off(),
        "transport": {
            "link": {
                "protocols": ["tls"],
                "tls": {
                    "root_ca_certificate": str(certs / "ca.pem"),
                    "connect_certificate": str(certs / f"{stem}.pem"),
                    "connect_private_key": str(certs / f"{stem}-key.pem"),
                    "enable_mtls": True,
                },
            }
        },
    }


def _json5_text(document: dict[str, Any], what: str) -> str:
    header = f"// {what}\n// Written by `rtsid certs`; see docs/lab.md (the secure lab profile).\n"
    return header + json.dumps(document, indent=2) + "\n"


def _openssl(args: Sequence[str], cwd: Path) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise ServiceError("openssl not found on PATH; install it (e.g. apt install openssl)")
    done = subprocess.run(
        [exe, *args], cwd=cwd, capture_output=True, text=True, timeout=60, check=False
    )
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise ServiceError(f"openssl {args[0]} failed: {last}")


def _new_key(name: str) -> list[str]:
    return ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes", "-keyout", name]


def _make_ca(cwd: Path, days: int) -> None:
    _openssl(
        [
            "req",
            "-x509",
            *_new_key("ca-key.pem"),
            "-out",
            "ca.pem",
            "-days",
            str(days),
            "-subj",
            "/CN=rtsid-lab-ca",
            "-addext",
            "basicConstraints=critical,CA:TRUE",
            "-addext",
            "keyUsage=critical,keyCertSign,cRLSign",
        ],
        cwd,
    )


def _make_leaf(cwd: Path, stem: str, common_name: str, names: Sequence[str], days: int) -> None:
    _openssl(
        ["req", *_new_key(f"{stem}-key.pem"), "-out", f"{stem}.csr", "-subj", f"/CN={common_name}"],
        cwd,
    )
    ext = cwd / f"{stem}.ext"
    ext.write_text(
        "basicConstraints=critical,CA:FALSE\n"
        "keyUsage=critical,digitalSignature\n"
        "extendedKeyUsage=serverAuth,clientAuth\n"
        f"subjectAltName={','.join(names)}\n"
    )
    _openssl(
        [
            "x509",
            "-req",
            "-in",
            f"{stem}.csr",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca-key.pem",
            "-CAcreateserial",
            "-out",
            f"{stem}.pem",
            "-days",
            str(days),
            "-extfile",
            ext.name,
        ],
        cwd,
    )
    (cwd / f"{stem}.csr").unlink()
    ext.unlink()


def participants(profile: LabProfile) -> list[tuple[str, str]]:
    """``(file stem, certificate common name)`` of every daemon, operator and viewer."""
    out = [(f"daemon-{r}-{j}", daemon_common_name(r, j)) for r, j in profile.daemons]
    out += [(f"operator-{o}", operator_common_name(o)) for o in profile.operators]
    return out + [(f"viewer-{v}", viewer_common_name(v)) for v in profile.viewers]


def profile_texts(profile: LabProfile, certs: Path) -> dict[str, str]:
    """The configuration files of ``profile`` (name → text) for certificates in ``certs``:
    ``router.json5``, ``router.toml`` and one ``<participant>.json5`` each."""
    texts = {
        "router.json5": _json5_text(
            router_json5(profile, certs), "The lab's zenoh router: mutual TLS + access control."
        ),
        "router.toml": "# rtsid router --config THIS_FILE: the secure lab's router "
        '(router.json5 beside it).\n[router]\nconfig_file = "router.json5"\n',
    }
    for stem, common_name in participants(profile):
        texts[f"{stem}.json5"] = _json5_text(
            client_json5(profile, certs, stem), f"The zenoh client {common_name} of the lab."
        )
    return texts


def write_lab_profile(directory: str | Path, profile: LabProfile) -> list[Path]:
    """Write the lab's CA, certificates and zenoh json5 files into the new ``directory``.

    Everything is made in a private temporary directory beside it and moved into place at the
    end, so a failure leaves nothing half-written. Private keys are mode 0600, the directory
    0700.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    ConfigError
        ``directory`` exists and is not empty.
    ServiceError
        ``openssl`` missing or failing.
    """
    target = Path(directory).expanduser().absolute()
    if target.exists() and (not target.is_dir() or any(target.iterdir())):
        raise ConfigError(
            f"{target} already exists and is not an empty directory; name a new directory "
            "(certificates are never overwritten)"
        )
    if not target.parent.is_dir():
        raise ConfigError(f"{target.parent} is not a directory; create it first")
    work = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=target.parent))
    try:
        _make_ca(work, profile.days)
        _make_leaf(work, "router", "router", profile.router_names(), profile.days)
        for stem, common_name in participants(profile):
            _make_leaf(work, stem, common_name, [f"DNS:{stem}"], profile.days)
        (work / "ca.srl").unlink(missing_ok=True)
        for key in work.glob("*-key.pem"):
            key.chmod(0o600)
        for name, text in profile_texts(profile, target).items():
            (work / name).write_text(text)
        if target.exists():
            target.rmdir()
        os.replace(work, target)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return sorted(target.iterdir())
