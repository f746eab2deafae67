"""The AI-deck stream client against the emulator and raw test servers (127.0.0.1 only)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable

import cv2
import numpy as np
import pytest
from helpers import wait_until

from drivers.crazyflie.aideck_stream import AIDeckStream
from drivers.crazyflie.cpx import ImageHeader, encode_image
from drivers.rig.loader import load_rig
from drivers.sim.emulators.aideck import AIDeckEmulator
from drivers.vehicle.types import CameraFrame
from perception.white_balance import preprocess

LOOPBACK = "127.0.0.1"
sitl = pytest.mark.sitl  # the tests that stream over TCP on 127.0.0.1


class Recorder:
    """Collects every frame the client delivers (from its reader thread)."""

    def __init__(self) -> None:
        self.frames: list[CameraFrame] = []
        self.lock = threading.Lock()

    def __call__(self, frame: CameraFrame) -> None:
        with self.lock:
            self.frames.append(frame)

    def __len__(self) -> int:
        return len(self.frames)


def _client(port: int, rec: Recorder | None = None, **kw: object) -> AIDeckStream:
    kw.setdefault("reconnect_initial_s", 0.05)
    return AIDeckStream(LOOPBACK, port, on_frame=rec, **kw)  # type: ignore[arg-type]


@sitl
@pytest.mark.parametrize("fmt", ["raw", "jpeg"])
def test_frames_bit_exact(fmt: str) -> None:
    rec = Recorder()
    started = time.monotonic()
    with AIDeckEmulator(fps=60, fmt=fmt, header="extended") as emu, _client(emu.port, rec) as cam:
        wait_until(lambda: len(rec) >= 20, 10.0, "20 frames")
        sent = {f.payload: f for f in emu.sent}
        for f in list(rec.frames):
            s = sent[f.meta["payload"]]  # KeyError = a frame the emulator never sent
            assert f.meta["width"] == 324 and f.meta["height"] == 244
            assert f.meta["deck_timestamp_ms"] == s.header.timestamp_ms
            if fmt == "raw":
                assert f.image.shape == (244, 324) and f.image.tobytes() == s.payload
            else:
                expect = cv2.imdecode(np.frombuffer(s.payload, np.uint8), cv2.IMREAD_UNCHANGED)
                assert np.array_equal(f.image, expect)
        frame = cam.poll(100.0)
        since_start_s = time.monotonic() - started
        # stamped in the poller's clock: at or before "now" (100 s), and not before the
        # client existed (a bound by causality, not a latency requirement)
        assert frame is not None and 100.0 - since_start_s <= frame.t_s <= 100.0
        assert frame.pose.source == "none"
        st = cam.stats()
        assert st.frames >= 20 and st.dropped == 0 and st.corrupt == 0 and st.connects == 1
        # the emulator counts a frame after sendall returns, the client may count it first
        wait_until(lambda: st.bytes <= emu.bytes_sent, 5.0, "the emulator to count its bytes")
        assert st.garbage_bytes == 0
        assert 0.0 <= st.latency_mean_s <= st.latency_max_s  # speed: bench/aideck_stream.py


@sitl
def test_bgr_output_white_balanced() -> None:
    rec = Recorder()
    wb = (1.2, 0.8, 1.5)
    with AIDeckEmulator(fps=60) as emu, _client(emu.port, rec, output="bgr", white_balance=wb):
        wait_until(lambda: len(rec) >= 3, 10.0, "3 frames")
        f = rec.frames[0]
        raw = np.frombuffer(f.meta["payload"], np.uint8).reshape(244, 324)
        assert f.image.shape == (244, 324, 3)
        assert np.array_equal(f.image, preprocess(raw, wb))


@sitl
def test_rate_and_counters_at_camera_rate() -> None:
    with AIDeckEmulator(fps=15) as emu, _client(emu.port) as cam:
        wait_until(lambda: cam.stats().frames >= 10, 10.0, "10 frames at 15 fps")
        st = cam.stats()
        assert st.fps > 0.0  # the measured rate is reported (its value: bench/aideck_stream.py)
        assert abs(st.frames - emu.frames_sent) <= 1 and st.dropped == 0


@sitl
def test_faults_from_emulator_dropped_and_recovered() -> None:
    rec = Recorder()
    with AIDeckEmulator(fps=60, seed=7) as emu, _client(emu.port, rec) as cam:
        wait_until(lambda: len(rec) >= 3, 10.0, "3 frames")
        for kind in ("garbage", "truncate", "oversize", "bad_route", "bad_jpeg", "disconnect"):
            emu.inject(kind)
        wait_until(
            lambda: emu.frames_faulted == 6 and cam.stats().connects == 2,
            10.0,
            "6 faulted frames and a reconnect",
        )
        n = len(rec)
        wait_until(lambda: len(rec) >= n + 5, 10.0, "5 frames after the reconnect")
        sent = {f.payload for f in emu.sent}
        assert all(f.meta["payload"] in sent for f in list(rec.frames))
        st = cam.stats()
        assert st.drop_reasons["resync"] == 2  # garbage, oversized length
        assert st.drop_reasons["truncated"] == 1 and st.drop_reasons["route"] == 1
        assert st.drop_reasons["disconnect"] == 1 and st.drop_reasons["bad_jpeg"] == 1
        assert st.dropped == 5 and st.corrupt == 1 and st.reconnects == 1
        assert st.resyncs == 2 and st.garbage_bytes > 0


class RawServer:
    """A one-connection-at-a-time TCP server on loopback running ``script(conn, index)``."""

    def __init__(self, script: Callable[[socket.socket, int], None]) -> None:
        self.script = script
        self.accepts: list[float] = []
        self.srv = socket.socket()
        self.srv.bind((LOOPBACK, 0))
        self.srv.listen(1)
        self.srv.settimeout(0.05)
        self.port = self.srv.getsockname()[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.srv.accept()
            except OSError:
                continue
            self.accepts.append(time.monotonic())
            try:
                self.script(conn, len(self.accepts) - 1)
            except OSError:
                pass
            finally:
                conn.close()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2.0)
        self.srv.close()


def _frame(i: int) -> tuple[bytes, bytes]:
    payload = bytes((i * 7 + k) % 251 for k in range(324 * 244))
    return payload, b"".join(encode_image(ImageHeader(324, 244, 1, 0, len(payload)), payload))


@sitl
def test_raw_server_garbage_truncation_oversize_then_reconnect() -> None:
    rng = np.random.default_rng(3)
    p0, f0 = _frame(0)
    p1, f1 = _frame(1)
    p2, f2 = _frame(2)
    p3, f3 = _frame(3)

    def script(conn: socket.socket, index: int) -> None:
        if index == 0:
            conn.sendall(f0)
            conn.sendall(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes())  # garbage
            conn.sendall(f1[: 15 + 1024 * 30])  # truncated frame (at a packet end) ...
            conn.sendall(b"\xff\xff\x40\x05" + bytes(100))  # ... oversized length
            conn.sendall(f2)
            conn.sendall(f3[:5000])  # then the deck vanishes mid-frame
        else:
            conn.sendall(f3)
            time.sleep(0.3)

    srv = RawServer(script)
    rec = Recorder()
    try:
        with _client(srv.port, rec) as cam:
            wait_until(lambda: len(rec) >= 3, 10.0, "3 frames")
            assert [f.meta["payload"] for f in rec.frames[:3]] == [p0, p2, p3]
            st = cam.stats()
            assert st.frames >= 3 and st.corrupt == 0 and st.resyncs >= 1
            assert st.drop_reasons.get("disconnect") == 1 and st.dropped >= 2
    finally:
        srv.close()


@sitl
def test_stall_and_idle_timeout() -> None:
    payload, frame = _frame(5)

    def script(conn: socket.socket, index: int) -> None:
        conn.sendall(frame[:20000])  # a header and some chunks, then silence
        time.sleep(1.0)

    srv = RawServer(script)
    try:
        with _client(srv.port, stall_s=0.2, idle_timeout_s=0.5) as cam:
            wait_until(lambda: cam.stats().drop_reasons.get("stall", 0) >= 1, 5.0, "a stall drop")
            wait_until(lambda: cam.stats().last_error == "idle timeout", 5.0, "an idle time-out")
            assert cam.stats().frames == 0
    finally:
        srv.close()


class RecordingStop(threading.Event):
    """A stream client's stop event that records every back-off its reader thread waits."""

    def __init__(self) -> None:
        super().__init__()
        self.waits: list[float | None] = []

    def wait(self, timeout: float | None = None) -> bool:
        self.waits.append(timeout)
        return super().wait(timeout)


@sitl
def test_reconnect_backoff_doubles() -> None:
    srv = RawServer(lambda conn, i: None)  # accept and hang up at once
    try:
        cam = _client(srv.port, reconnect_initial_s=0.05, reconnect_max_s=0.3, autostart=False)
        cam._stop = stop = RecordingStop()  # the back-offs asked for, not wall-clock gaps
        cam.start()
        with cam:
            wait_until(lambda: len(srv.accepts) >= 6, 10.0, "6 connections")
        # one back-off after each hang-up: doubling from 0.05 s, capped at reconnect_max_s
        assert stop.waits[:5] == pytest.approx([0.05, 0.1, 0.2, 0.3, 0.3])
    finally:
        srv.close()


@sitl
def test_connection_refused_retries() -> None:
    s = socket.socket()
    s.bind((LOOPBACK, 0))
    port = s.getsockname()[1]
    s.close()  # nobody listens here
    with _client(port) as cam:
        wait_until(lambda: cam.stats().last_error.startswith("connect"), 5.0, "a connect error")
        assert cam.stats().connects == 0 and cam.poll(0.0) is None


@sitl
def test_emulator_survives_peers_that_vanish() -> None:
    with AIDeckEmulator(fps=60, send_timeout_s=0.3) as emu:
        for _ in range(3):  # connect and leave at once
            socket.create_connection((LOOPBACK, emu.port), 3.0).close()
        rst = socket.create_connection((LOOPBACK, emu.port), 3.0)  # reset mid-stream
        wait_until(lambda: emu.frames_sent > 0, 10.0, "a frame sent")
        rst.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
        rst.close()
        mute = socket.create_connection((LOOPBACK, emu.port), 3.0)  # never reads
        mute.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        rec = Recorder()
        with _client(emu.port, rec):
            wait_until(lambda: len(rec) >= 3, 10.0, "3 frames beside the mute peer")
        mute.close()
        assert emu.clients >= 5


def test_from_rig() -> None:
    rig = load_rig(
        None,
        {
            "aideck.port": "5123",
            "aideck.output": "bgr",
            "sensors.camera.white_balance": "[1.1, 1.0, 1.3]",
        },
    )
    cam = AIDeckStream.from_rig(rig.data, autostart=False)
    assert (cam.host, cam.port, cam.output) == ("127.0.0.1", 5123, "bgr")
    assert cam.white_balance == (1.1, 1.0, 1.3) and cam.reconnect_max_s == 5.0
