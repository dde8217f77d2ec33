"""The live views beyond loopback: the web page takes a token, the Foxglove server stays home.

Every server here binds 127.0.0.1 (the token is required there too once ``RTSID_WEB_TOKEN`` is
set, which is how the check is exercised without opening a port beyond loopback); the refusals
of a non-loopback host happen before anything binds.
"""

from __future__ import annotations

import http.client
from collections.abc import Iterator

import pytest

from rtsid.cli import main
from rtsid.errors import ConfigError
from rtsid.io.access_token import TOKEN_ENV, is_loopback, token_matches, web_token
from rtsid.io.foxglove_live import FoxgloveLive
from rtsid.io.web.server import WebView

TOKEN = "lab-token-0123456789abcdef"


def request(
    port: int, path: str, headers: dict[str, str] | None = None
) -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", path, headers=headers or {})
        response = conn.getresponse()
        if path.startswith("/events") and response.status == 200:
            body = response.readline()  # the first snapshot line; the stream goes on
        else:
            body = response.read()
        return response.status, dict(response.getheaders()), body
    finally:
        conn.close()


@pytest.fixture
def page(monkeypatch: pytest.MonkeyPatch, free_port: int) -> Iterator[int]:
    """A web view on 127.0.0.1 with ``RTSID_WEB_TOKEN`` set (no daemon: an empty board)."""
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    with WebView("rtsid/*/*", (f"tcp/127.0.0.1:{free_port}",), port=0, history_s=0) as view:
        assert view.port is not None
        yield view.port


def test_loopback_is_told_from_every_other_address() -> None:
    for host in ("127.0.0.1", "127.1.2.3", "::1", "[::1]", "localhost"):
        assert is_loopback(host), host
    for host in ("0.0.0.0", "::", "192.168.10.2", "10.0.0.1", "lab-pc", ""):
        assert not is_loopback(host), host
    assert token_matches(TOKEN, TOKEN) and not token_matches(TOKEN[:-1], TOKEN)
    assert not token_matches(None, TOKEN)


def test_the_page_refuses_to_bind_beyond_loopback_without_a_token(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    assert web_token("127.0.0.1") is None
    with pytest.raises(ConfigError, match=f"beyond loopback.*{TOKEN_ENV}"):
        web_token("0.0.0.0")
    assert main(["watch", "--web", "0", "--host", "0.0.0.0", "--timeout", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and TOKEN_ENV in err and "127.0.0.1" in err, err
    monkeypatch.setenv(TOKEN_ENV, "short")
    with pytest.raises(ConfigError, match="at least 16"):
        web_token("0.0.0.0")
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    assert web_token("0.0.0.0") == TOKEN


def test_every_request_needs_the_token_once_it_is_set(page: int) -> None:
    for path in ("/", "/static/app.js", "/state.json", "/events", "/nothing"):
        status, _, body = request(page, path)
        assert status == 401 and b"token" in body, (path, status)
        assert request(page, path + "?token=wrong-token-0123456789")[0] == 401
        assert request(page, path, {"Authorization": "Bearer " + TOKEN[:-1]})[0] == 401
        assert request(page, path, {"Cookie": "rtsid_token=nope"})[0] == 401
    status, headers, body = request(page, f"/?token={TOKEN}")
    assert status == 200 and b"<html" in body.lower()
    cookie = headers["Set-Cookie"]
    assert cookie.startswith(f"rtsid_token={TOKEN}") and "HttpOnly" in cookie
    cookie_header = {"Cookie": cookie.split(";", 1)[0]}
    assert request(page, "/state.json", cookie_header)[0] == 200
    status, _, first = request(page, "/events", cookie_header)
    assert status == 200 and first.startswith(b"data: ")
    assert request(page, "/state.json", {"Authorization": f"Bearer {TOKEN}"})[0] == 200


def test_the_foxglove_server_stays_on_loopback(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match="no authentication.*ssh -L"):
        FoxgloveLive(["estimate"], host="0.0.0.0")
    FoxgloveLive(["estimate"], host="::1")  # loopback: accepted (not started)
    pytest.importorskip("foxglove", reason="the CLI checks the 'live' extra first")
    assert main(["run", "--foxglove", "0", "--foxglove-host", "192.168.10.2"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "stays on loopback" in err, err
