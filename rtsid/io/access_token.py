"""Who may open the live views: loopback freely, anything beyond it only with a token.

The web page (``rtsid watch --web``) bound beyond loopback requires the token in
``RTSID_WEB_TOKEN`` on every request (``Authorization: Bearer …``, a ``?token=…`` query on the
first page load, then an HttpOnly cookie), compared in constant time. The Foxglove server has
no authentication in its protocol, so it stays on loopback (an SSH tunnel reaches it).
"""

from __future__ import annotations

import hmac
import ipaddress
import os

from rtsid.errors import ConfigError

__all__ = ["MIN_TOKEN_CHARS", "TOKEN_ENV", "is_loopback", "token_matches", "web_token"]

#: Environment variable holding the web page's token (kept out of ``ps`` and shell history).
TOKEN_ENV = "RTSID_WEB_TOKEN"
#: Shortest token accepted (e.g. ``python -c "import secrets; print(secrets.token_urlsafe())"``).
MIN_TOKEN_CHARS = 16


def is_loopback(host: str) -> bool:
    """True for ``localhost``, ``127.0.0.0/8`` and ``::1``; False for any other address."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def web_token(host: str) -> str | None:
    """The token the page at ``host`` requires (None on loopback without one).

    Raises
    ------
    ConfigError
        ``host`` is beyond loopback and ``RTSID_WEB_TOKEN`` is unset or shorter than
        :data:`MIN_TOKEN_CHARS`.
    """
    token = os.environ.get(TOKEN_ENV, "")
    if token and len(token) < MIN_TOKEN_CHARS:
        raise ConfigError(
            f"{TOKEN_ENV} is {len(token)} characters; use at least {MIN_TOKEN_CHARS}, e.g. "
            "python -c 'import secrets; print(secrets.token_urlsafe())'"
        )
    if not token and not is_loopback(host):
        raise ConfigError(
            f"the web page would bind to {host}, beyond loopback, without a token; set "
            f"{TOKEN_ENV} (at least {MIN_TOKEN_CHARS} characters) or keep --host 127.0.0.1"
        )
    return token or None


def token_matches(given: str | None, expected: str) -> bool:
    """Constant-time comparison of a presented token with the expected one."""
    if given is None:
        return False
    return hmac.compare_digest(given.encode(), expected.encode())
