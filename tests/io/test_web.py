"""``rtsid watch --web``: the board, the server (page, package data, SSE stream) and the page in
a real browser — headless Chromium (Debian package) driven over the DevTools protocol on a
pipe, reading the rendered DOM while a daemon runs and saving a screenshot."""

from __future__ import annotations

import base64
import http.client
import json
import os
import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from rtsid.errors import ServiceError
from rtsid.io.schemas import encode_status
from rtsid.io.watch import FeedEvent
from rtsid.io.web.server import WINDOW_S, LabBoard, WebView
from rtsid.runtime.daemon import Daemon, DaemonConfig

PLANT_K = 150.0  # the embedded plant's stiffness, N·m/rad


def estimate(seq: int, t_ns: int, ok: bool = True, joint: str = "ankle") -> dict[str, Any]:
    return {
        "robot": "rig",
        "joint": joint,
        "seq": seq,
        "K": 150.0,
        "K_se": 1.0,
        "B": 0.8,
        "B_se": 0.01,
        "I": 0.015,
        "I_se": 0.001,
        "vaf": 99.0,
        "ok": ok,
        "reason": None if ok else "gap",
        "flags": [],
        "latency_ms": 1.0,
        "host_time_ns": t_ns,
    }


def event(kind: str, message: dict[str, Any] | None, joint: str = "ankle") -> FeedEvent:
    payload = b""
    if message is not None:
        payload = encode_status(message) if kind == "status" else json.dumps(message).encode()
    return FeedEvent(kind, f"rtsid/rig/{joint}/{kind}", payload, time.time_ns())


def test_board_keeps_30_s_per_joint_drops_duplicates_and_removes_a_joint_that_leaves() -> None:
    board = LabBoard()
    t0 = 1_000_000_000_000
    for seq in range(40):  # one per second: only the last 30 s stay
        board.take(event("estimate", estimate(seq, t0 + seq * 10**9)))
    board.take(event("estimate", estimate(39, t0 + 39 * 10**9)))  # the same again (history)
    board.take(event("estimate", estimate(40, t0 + 40 * 10**9, ok=False)))
    board.take(event("estimate", estimate(0, t0, joint="knee"), joint="knee"))
    last_id, snap = board.snapshot()
    points = snap["joints"]["rig/ankle"]["points"]
    assert [p["seq"] for p in points] == list(range(40 - int(WINDOW_S), 41))
    assert points[-1]["ok"] is False and points[-1]["reason"] == "gap"
    assert set(snap["joints"]) == {"rig/ankle", "rig/knee"}
    board.take(event("gone", None, joint="knee"))
    board.take(event("estimate", estimate(1, t0 + 10**9, joint="knee"), joint="knee"))  # late
    _, snap = board.snapshot()
    assert set(snap["joints"]) == {"rig/ankle"}
    assert "rig/knee left" in snap["notes"][0]
    events = board.events_after(last_id, 0.0)
    assert events is not None
    assert [json.loads(e)["type"] for _, e in events] == ["gone"]
    board.take(event("alive", None, joint="knee"))
    board.take(event("estimate", estimate(2, t0 + 2 * 10**9, joint="knee"), joint="knee"))
    assert "rig/knee" in board.snapshot()[1]["joints"]


def test_a_page_that_falls_behind_is_told_to_take_a_snapshot() -> None:
    board = LabBoard()
    for seq in range(5000):
        board.take(event("estimate", estimate(seq, 10**12 + seq * 10**6)))
    assert board.events_after(0, 0.0) is None
    recent = board.events_after(4999, 0.0)
    assert recent is not None and [i for i, _ in recent] == [5000]


def get(port: int, path: str) -> tuple[int, str, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", path)
        response = conn.getresponse()
        return response.status, response.getheader("Content-Type") or "", response.read()
    finally:
        conn.close()


def sse_messages(port: int, count: int) -> list[dict[str, Any]]:
    """The first ``count`` messages of the page's event stream."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    try:
        conn.request("GET", "/events")
        response = conn.getresponse()
        assert response.getheader("Content-Type") == "text/event-stream"
        messages = []
        while len(messages) < count:
            line = response.readline()
            assert line, "the event stream ended"
            if line.startswith(b"data: "):
                messages.append(json.loads(line[6:]))
        return messages
    finally:
        conn.close()


def daemon_config(tmp_path: Path, port: int) -> DaemonConfig:
    return DaemonConfig.from_mapping(
        {
            "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"], "robot": "rig"},
            "mcap": {"directory": str(tmp_path / "rec")},
            "plant": {"perturbation": "filtered_noise", "bandwidth_hz": 30.0},
        }
    )


@pytest.fixture
def running_daemon(tmp_path: Path, free_port: int) -> Iterator[int]:
    """A daemon on the embedded plant in a thread, peer on ``free_port``; yields the port."""
    daemon = Daemon(daemon_config(tmp_path, free_port))
    thread = threading.Thread(target=daemon.run, args=(120.0,), name="test-daemon")
    thread.start()
    try:
        yield free_port
    finally:
        daemon.request_stop()
        thread.join(30)
        assert not thread.is_alive()


def test_a_taken_port_is_one_clear_error(free_port: int) -> None:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(ServiceError, match=f"127.0.0.1:{port}.*--web PORT"):
            WebView("rtsid/*/*", (f"tcp/127.0.0.1:{free_port}",), port=port).start()


@pytest.mark.slow  # a real-time daemon run of seconds
def test_server_serves_the_page_its_library_and_live_events(running_daemon: int) -> None:
    endpoint = (f"tcp/127.0.0.1:{running_daemon}",)
    with WebView("rtsid/*/*", endpoint, port=0) as view:
        assert view.url.startswith("http://127.0.0.1:")
        assert view.port is not None
        status, ctype, body = get(view.port, "/")
        assert status == 200 and ctype.startswith("text/html")
        assert b"/static/uPlot.iife.min.js" in body and b"https://" not in body  # no CDN
        status, ctype, body = get(view.port, "/static/uPlot.iife.min.js")
        assert status == 200 and ctype.startswith("text/javascript") and len(body) > 20_000
        assert get(view.port, "/static/../server.py")[0] == 404
        assert get(view.port, "/nothing")[0] == 404
        messages = sse_messages(view.port, 30)
    assert messages[0]["type"] == "snapshot"
    kinds = {m["type"] for m in messages[1:]}
    assert "estimate" in kinds
    assert {m["joint"] for m in messages[1:]} == {"rig/ankle"}


# ---------------------------------------------------------------------- a real browser


def chromium_binary() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("Chromium is not installed (apt-get install chromium); CI installs it")


class DevTools:
    """Headless Chromium driven over the DevTools protocol on a pipe (fds 3 and 4 of the
    browser; NUL-separated JSON), so no WebSocket client is needed."""

    def __init__(self, binary: str, profile: Path) -> None:
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        args = [
            binary,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--no-first-run",
            "--remote-debugging-pipe",
            "--window-size=1400,1000",
            f"--user-data-dir={profile}",
            "about:blank",
        ]
        # bash moves the pipe ends to fds 3 and 4 (dash accepts only one-digit fds there).
        script = f'exec "$@" 3<&{to_browser_r} 4>&{from_browser_w}'
        self.proc = subprocess.Popen(
            ["bash", "-c", script, "bash", *args],
            pass_fds=(to_browser_r, from_browser_w),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 0
        self.session: str | None = None

    def call(self, method: str, timeout_s: float = 20.0, **params: Any) -> dict[str, Any]:
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params}
        if self.session is not None and not method.startswith(("Target.", "Browser.")):
            message["sessionId"] = self.session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return dict(reply.get("result", {}))

    def _read(self, deadline: float) -> dict[str, Any]:
        import select

        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            assert left > 0, "Chromium did not answer in time"
            ready, _, _ = select.select([self._from_browser], [], [], left)
            if ready:
                chunk = os.read(self._from_browser, 1 << 20)
                assert chunk, "Chromium closed its DevTools pipe"
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return dict(json.loads(message))

    def open(self, url: str) -> None:
        target = self.call("Target.createTarget", url=url)["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)[
            "sessionId"
        ]

    def evaluate(self, expression: str) -> Any:
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return result.get("result", {}).get("value")

    def screenshot(self, path: Path) -> None:
        data = self.call("Page.captureScreenshot", format="png")["data"]
        path.write_bytes(base64.b64decode(data))

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout_s=5.0)
        except (AssertionError, RuntimeError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=10)
        os.close(self._to_browser)
        os.close(self._from_browser)


PAGE_STATE = """(() => {
  const card = document.querySelector('section.joint[data-joint="rig/ankle"]');
  if (!card) return null;
  const text = (f) => card.querySelector(`[data-field="${f}"]`).textContent;
  return {K: text("K"), K_band: text("K_band"), B: text("B"), I: text("I"), vaf: text("vaf"),
          counters: text("counters"), connection: document.getElementById("connection").textContent,
          plots: card.querySelectorAll(".uplot canvas").length};
})()"""


@pytest.mark.slow  # a real-time daemon run and a browser
def test_the_page_shows_live_values_in_chromium(running_daemon: int, tmp_path: Path) -> None:
    binary = chromium_binary()
    endpoint = (f"tcp/127.0.0.1:{running_daemon}",)
    with WebView("rtsid/*/*", endpoint, port=0) as view:
        browser = DevTools(binary, tmp_path / "profile")
        try:
            browser.open(view.url)
            deadline = time.monotonic() + 60
            state = None
            while time.monotonic() < deadline:  # bounded: the page fills within seconds
                state = browser.evaluate(PAGE_STATE)
                if state and state["K"] not in ("", "–") and "deadline misses" in state["counters"]:
                    break
                time.sleep(0.25)
            assert state is not None, "no card for rig/ankle appeared"
            first_k = float(state["K"])
            time.sleep(1.0)
            later = browser.evaluate(PAGE_STATE)
            shot = tmp_path / "rtsid-web.png"
            browser.screenshot(shot)
        finally:
            browser.close()
    artifacts = os.environ.get("RTSID_TEST_ARTIFACTS")
    if artifacts:
        Path(artifacts).mkdir(parents=True, exist_ok=True)
        shutil.copy(shot, Path(artifacts) / shot.name)
    assert state["connection"] == "live"
    assert abs(first_k - PLANT_K) <= 0.05 * PLANT_K, state
    assert float(state["K_band"]) > 0  # the 95 % half-width from K_se
    assert float(state["vaf"]) > 80
    assert "link: samples" in state["counters"] and "deadline misses" in state["counters"]
    assert state["plots"] >= 4  # K, B, I, VAF
    assert later["K"] != "" and later["counters"] != state["counters"]  # live: it moves
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 10_000


def test_any_other_channel_shows_its_latest_message() -> None:
    """A channel the board does not know (a daemon's reflex model, say) is kept as its latest
    message and pushed to the pages, so a new channel needs no change to the web view."""
    board = LabBoard()
    board.take(event("estimate", estimate(0, 10**12)))
    last_id, _ = board.snapshot()
    reflex = {"robot": "rig", "joint": "ankle", "gain": 0.4, "host_time_ns": 10**12}
    board.take(FeedEvent("reflex", "rtsid/rig/ankle/reflex", json.dumps(reflex).encode(), 0))
    _, snap = board.snapshot()
    assert snap["joints"]["rig/ankle"]["channels"] == {"reflex": reflex}
    events = board.events_after(last_id, 0.0)
    assert events is not None
    (pushed,) = [json.loads(e) for _, e in events]
    assert pushed == {
        "type": "channel",
        "joint": "rig/ankle",
        "channel": "reflex",
        "message": reflex,
    }
