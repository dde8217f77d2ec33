"""``rtsid run --foxglove``: the recording's channels served live over the Foxglove WebSocket
protocol, checked with an independent client (@foxglove/ws-protocol on node)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from rtsid.errors import ConfigError, ServiceError
from rtsid.io.mcap_log import channel_kinds
from rtsid.io.messages import ESTIMATE_SCHEMA
from rtsid.io.schemas import SCHEMAS, encode_json

foxglove = pytest.importorskip("foxglove", reason="foxglove-sdk not installed (rtsid[live])")

from rtsid.io.foxglove_live import FoxgloveLive  # noqa: E402
from rtsid.runtime.daemon import Daemon, DaemonConfig  # noqa: E402

SCRIPT = Path(__file__).with_name("foxglove_check.js")


def node_path() -> str:
    """node_modules with @foxglove/ws-protocol and ws (CI: .ci/js), or skip with the reason."""
    path = os.environ.get("RTSID_JS_NODE_PATH") or os.environ.get("RTSID_MCAP_JS_NODE_PATH")
    if not path or shutil.which("node") is None:
        pytest.skip(
            "set RTSID_JS_NODE_PATH to a node_modules with @foxglove/ws-protocol and ws "
            "(npm install --prefix .ci/js) to run the independent Foxglove client"
        )
    if not (Path(path) / "@foxglove" / "ws-protocol").is_dir():
        pytest.skip(f"{path} has no @foxglove/ws-protocol (npm install --prefix .ci/js)")
    return path


def daemon_config(tmp_path: Path) -> DaemonConfig:
    return DaemonConfig.from_mapping(
        {
            "zenoh": {"enabled": False},
            "mcap": {"directory": str(tmp_path / "rec")},
            "plant": {"perturbation": "filtered_noise", "bandwidth_hz": 30.0},
        }
    )


def test_without_the_extra_the_error_names_it(monkeypatch: pytest.MonkeyPatch) -> None:
    from rtsid.cli import main

    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove -> ImportError
    with pytest.raises(ConfigError, match=r"pip install 'rtsid\[live\]'"):
        FoxgloveLive(["estimate"]).start()
    assert main(["run", "--foxglove", "--duration", "0.1"]) == 2


def test_a_taken_port_is_one_clear_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(ServiceError, match=f"127.0.0.1:{port}.*--foxglove PORT"):
            FoxgloveLive(["estimate"], port=port).start()


def test_channels_are_the_recordings_and_bind_to_loopback() -> None:
    kinds = channel_kinds(can_frames=True)
    with FoxgloveLive(kinds, port=0) as live:
        assert live.url.startswith("ws://127.0.0.1:") and live.port
        channels = live._channels
        assert set(channels) == set(kinds)
        for kind, channel in channels.items():
            schema, topic = SCHEMAS[kind]
            assert channel.topic() == topic
            assert channel.schema().data == encode_json(schema)
            assert channel.schema().encoding == "jsonschema"
            assert channel.message_encoding == "json"


def test_a_channel_added_to_the_recording_is_served_too(monkeypatch: pytest.MonkeyPatch) -> None:
    """Channels come from the recording's list and SCHEMAS: a new one (a reflex model, say)
    is created the first time the logger hands one of its messages over."""
    import rtsid.io.foxglove_live as live_module

    schema = {"title": "rtsid.Reflex", "type": "object"}
    monkeypatch.setitem(live_module.SCHEMAS, "reflex", (schema, "/reflex"))
    with FoxgloveLive(["estimate"], port=0) as live:
        live.tap("reflex", 1, b'{"gain": 1}')
        live.tap("not_a_channel", 1, b"{}")  # unknown to SCHEMAS: ignored
        assert set(live._channels) == {"estimate", "reflex"}
        assert live._channels["reflex"].topic() == "/reflex"
        assert live.sent == 1 and live.errors == 0


@pytest.mark.slow  # a real-time daemon run of seconds
def test_an_independent_client_receives_estimates_with_the_declared_schema(
    tmp_path: Path,
) -> None:
    modules = node_path()
    config = daemon_config(tmp_path)
    kinds = channel_kinds(can_frames=config.mcap.log_can_frames)
    with FoxgloveLive(kinds, port=0) as live:
        client = subprocess.Popen(
            ["node", str(SCRIPT), live.url, "/estimate", "5"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "NODE_PATH": modules},
        )
        try:
            summary = Daemon(config, message_tap=live.tap).run(duration_s=6.0)
            out, err = client.communicate(timeout=30)
        finally:
            if client.poll() is None:
                client.kill()
                client.communicate(timeout=10)
    assert summary.clean_shutdown
    assert client.returncode == 0, err
    report: dict[str, Any] = json.loads(out)
    advertised = {c["topic"]: c for c in report["channels"]}
    assert set(advertised) == {SCHEMAS[k][1] for k in kinds}
    for kind in kinds:
        schema, topic = SCHEMAS[kind]
        channel = advertised[topic]
        assert (channel["encoding"], channel["schemaEncoding"]) == ("json", "jsonschema")
        assert channel["schemaName"] == schema["title"]
        assert json.loads(channel["schema"]) == json.loads(encode_json(schema))
    assert len(report["messages"]) == 5
    for message in report["messages"]:
        jsonschema.validate(message, ESTIMATE_SCHEMA)
    assert any(m["ok"] and abs(m["K"] - 150.0) < 15.0 for m in report["messages"])
