"""``btrun run --foxglove [PORT]``: the run.mcap channels served live over Foxglove's
WebSocket protocol (foxglove-sdk); a client subscribes and receives messages."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from helpers import REPO

from nodes.foxglove_live import FoxgloveError, FoxgloveTee
from nodes.mcap_schemas import CHANNELS

ws_client = pytest.importorskip("websockets.sync.client")
PROTOCOL = "foxglove.sdk.v1"


def _advertised(ws, deadline_s: float = 10.0) -> dict[str, int]:
    """Topic -> channel id, from the server's advertise messages."""
    channels: dict[str, int] = {}
    end = time.monotonic() + deadline_s
    while len(channels) < len(CHANNELS) and time.monotonic() < end:
        msg = ws.recv(timeout=max(0.1, end - time.monotonic()))
        if isinstance(msg, str):
            doc = json.loads(msg)
            if doc.get("op") == "advertise":
                channels.update({c["topic"]: c["id"] for c in doc["channels"]})
    return channels


def _first_message(ws, deadline_s: float = 20.0) -> tuple[int, int, bytes] | None:
    """(subscription id, log time ns, payload) of the first binary message data frame; None
    if none came within ``deadline_s``."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        try:
            msg = ws.recv(timeout=max(0.05, end - time.monotonic()))
        except TimeoutError:
            return None
        if isinstance(msg, bytes) and msg[:1] == b"\x01":
            sub = int.from_bytes(msg[1:5], "little")
            return sub, int.from_bytes(msg[5:13], "little"), msg[13:]
    return None


def test_the_tee_serves_run_mcap_channels():
    tee = FoxgloveTee(0)
    try:
        with ws_client.connect(f"ws://127.0.0.1:{tee.port}", subprotocols=[PROTOCOL]) as ws:
            channels = _advertised(ws)
            assert set(channels) == set(CHANNELS)
            sub = {"op": "subscribe", "subscriptions": [{"id": 3, "channelId": channels["/tf"]}]}
            ws.send(json.dumps(sub))
            deadline = time.monotonic() + 10
            got = None
            while got is None and time.monotonic() < deadline:  # the subscription lands
                tee.log("/tf", 2_000_000_000, b'{"transforms": []}')
                got = _first_message(ws, 0.2)
            assert got == (3, 2_000_000_000, b'{"transforms": []}')
    finally:
        tee.close()


def test_a_port_in_use_is_refused():
    tee = FoxgloveTee(0)
    try:
        with pytest.raises(FoxgloveError, match="cannot serve Foxglove"):
            FoxgloveTee(tee.port)
    finally:
        tee.close()


@pytest.mark.slow
def test_btrun_run_streams_the_run_live(tmp_path):
    """A real-time flight with --foxglove 0: a client subscribed to /vehicle/pose receives
    the drone's pose while it flies."""
    cmd = [sys.executable, "-m", "btrun_launcher", os.path.join(REPO, "missions", "square.xml")]
    cmd += ["--foxglove", "0", "--realtime", "--max-time", "20", "--out", str(tmp_path / "r")]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        port = None
        end = time.monotonic() + 120
        while port is None and time.monotonic() < end:
            line = proc.stdout.readline().decode()
            if not line:
                break
            if "Foxglove live on ws://" in line:
                port = int(line.rsplit(":", 1)[1])
        assert port, "btrun did not print the Foxglove address"
        with ws_client.connect(f"ws://127.0.0.1:{port}", subprotocols=[PROTOCOL]) as ws:
            channels = _advertised(ws)
            pose = channels["/vehicle/pose"]
            ws.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": pose}]})
            )
            got = _first_message(ws)
        assert got is not None, "no pose within 20 s"
        sub, _, payload = got
        msg = json.loads(payload)
        assert sub == 1 and msg["frame_id"] == "world" and "position" in msg["pose"]
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()


def test_the_shipped_layout_is_the_generated_one():
    """docs/foxglove-layout.json is what nodes.foxglove_live.layout_json builds (regenerate:
    python -c "from nodes.foxglove_live import layout_json; print(layout_json())" >
    docs/foxglove-layout.json); its panels read channels that run.mcap has."""
    from nodes.foxglove_live import layout_json

    with open(os.path.join(REPO, "docs", "foxglove-layout.json")) as f:
        shipped = f.read()
    assert shipped == layout_json() + "\n"
    text = json.dumps(json.loads(shipped))
    for topic in ("/camera/image", "/camera/annotations", "/scene", "/log", "/result"):
        assert f'"{topic}' in text and topic in CHANNELS
