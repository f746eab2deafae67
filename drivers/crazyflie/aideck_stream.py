"""The AI-deck camera stream as a :class:`~drivers.vehicle.interfaces.CameraSource` (CPX over TCP).

:class:`AIDeckStream` connects to the AI-deck's ESP32 (default ``192.168.4.1:5000`` on the
deck's own access point; the rig default is the loopback emulator,
:mod:`drivers.sim.emulators.aideck`), reads CPX packets in a background thread, reassembles
the image stream bit-exact (:class:`drivers.crazyflie.cpx.FrameAssembler`), decodes raw Bayer or JPEG
frames with OpenCV and hands the newest frame to :meth:`AIDeckStream.poll`.

Robustness: garbage, oversized length fields and unknown routes make the parser resynchronise
and drop the frame in progress; a raw frame whose size is not ``width * height * depth`` and a
JPEG that does not decode are dropped; a silent or garbage-only connection is closed and
re-opened with exponential back-off. Nothing a peer sends can crash the reader or produce a
corrupt frame as far as the protocol can tell (CPX has no checksum: TCP's must do).

Frames: with ``output="bayer"`` (default, like the simulated camera) ``CameraFrame.image`` is
the 244 x 324 uint8 Bayer mosaic as sent (a JPEG from the deck is the same mosaic, lossy);
with ``output="bgr"`` it is demosaiced (``COLOR_BayerBG2BGR``) and white-balanced with the
rig's per-channel factors (B, G, R). ``meta["format"]`` says which (``bayer_bg`` or ``bgr``,
as :class:`drivers.sim.camera.SimCamera` marks its frames); ``meta`` also carries the exact
``payload`` bytes, ``wire_format`` (``raw`` or ``jpeg``), the header fields, ``latency_s``
(header arrival -> last chunk) and the deck timestamp if the firmware sends the extended
header.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.crazyflie.cpx import AssembledImage, FrameAssembler, StreamParser, Target
from drivers.vehicle.health import RateWindow
from drivers.vehicle.types import CameraFrame, Pose
from perception.white_balance import apply_white_balance, preprocess

log = logging.getLogger(__name__)

_NO_POSE = Pose(0.0, 0.0, 0.0, 0.0, source="none")


_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's start-of-frame segment, without decoding; None if the
    markers before it are malformed or there is none (linear in the header length)."""
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a length
            i += 2
            continue
        if marker == 0xDA or marker == 0xD9:  # scan data or end before any frame header
            return None
        length = (data[i + 2] << 8) | data[i + 3]
        if length < 2:
            return None
        if marker in _SOF_MARKERS:
            if i + 9 > n:
                return None
            height = (data[i + 5] << 8) | data[i + 6]
            width = (data[i + 7] << 8) | data[i + 8]
            return width, height
        i += 2 + length
    return None


def decode_image(img: AssembledImage) -> np.ndarray | None:
    """The image array of an assembled frame, or None if it does not decode.

    Raw depth 1 -> (h, w) uint8 mosaic; raw depth d > 1 -> (h, w, d). JPEG -> whatever
    OpenCV decodes (grey mosaic for the AI-deck), or None for a broken JPEG.
    """
    h = img.header
    if h.format == 0:
        if len(img.payload) != h.width * h.height * h.depth:
            return None
        arr = np.frombuffer(img.payload, dtype=np.uint8)
        return (
            arr.reshape(h.height, h.width)
            if h.depth == 1
            else arr.reshape(h.height, h.width, h.depth)
        )
    p = img.payload
    if len(p) < 4 or p[:2] != b"\xff\xd8" or b"\xff\xd9" not in p[-16:]:
        return None
    # Decode only what the header announced: a tiny JPEG may declare 30000 x 30000 pixels
    # (gigabytes once decoded); its frame size must be the header's (itself bounded by CPX).
    if jpeg_size(p) != (h.width, h.height):
        return None
    import cv2

    out = cv2.imdecode(np.frombuffer(p, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    return out if out is not None and out.size > 0 else None


@dataclass(frozen=True, slots=True)
class StreamStats:
    """Counters of an :class:`AIDeckStream` (times in seconds, rates over the last second)."""

    connected: bool
    frames: int
    fps: float
    dropped: int  # frames started and not delivered (resync, truncation, overflow, stall...)
    corrupt: int  # frames complete but undecodable (raw size mismatch, bad JPEG)
    drop_reasons: dict[str, int]
    skipped: int  # decoded frames replaced by a newer one before poll() took them
    bytes: int
    garbage_bytes: int
    resyncs: int
    connects: int
    reconnects: int
    latency_mean_s: float
    latency_max_s: float
    last_error: str


class AIDeckStream:
    """A :class:`~drivers.vehicle.interfaces.CameraSource` reading the AI-deck CPX image stream over TCP."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 5000,
        output: str = "bayer",
        white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0),
        reconnect_initial_s: float = 0.25,
        reconnect_max_s: float = 5.0,
        connect_timeout_s: float = 2.0,
        idle_timeout_s: float = 3.0,
        max_garbage_bytes: int = 256 * 1024,
        stall_s: float = 2.0,
        pose_fn: Callable[[float], Pose] | None = None,
        on_frame: Callable[[CameraFrame], None] | None = None,
        autostart: bool = True,
    ) -> None:
        if output not in ("bayer", "bgr"):
            raise ValueError(f"output must be 'bayer' or 'bgr', not {output!r}")
        self.host, self.port, self.output = host, int(port), output
        b, g, r = (float(f) for f in white_balance)
        self.white_balance = (b, g, r)
        self.reconnect_initial_s, self.reconnect_max_s = reconnect_initial_s, reconnect_max_s
        self.connect_timeout_s, self.idle_timeout_s = connect_timeout_s, idle_timeout_s
        self.max_garbage_bytes = max_garbage_bytes
        self.pose_fn, self.on_frame = pose_fn, on_frame
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._sock: socket.socket | None = None
        self._latest: tuple[float, CameraFrame] | None = None  # (monotonic header time, frame)
        self._parser = StreamParser(destinations=(Target.HOST,))
        self._asm = FrameAssembler(stall_s=stall_s)
        self._frames = 0
        self._corrupt = 0
        self._skipped = 0
        self._connects = 0
        self._connected = False
        self._last_error = ""
        self._rate = RateWindow(1.0)
        self._lat_sum, self._lat_max = 0.0, 0.0
        self._thread: threading.Thread | None = None
        if autostart:
            self.start()

    @classmethod
    def from_rig(cls, data: dict, **kwargs: Any) -> AIDeckStream:
        """Build from validated rig data (its ``aideck:`` section); ``kwargs`` override.

        ``aideck.white_balance: null`` takes ``sensors.camera.white_balance`` (the factors
        ``python -m perception.white_balance calibrate`` writes), else (1, 1, 1).
        """
        a = data["aideck"]
        wb = a.get("white_balance")
        if wb is None:
            wb = data.get("sensors", {}).get("camera", {}).get("white_balance") or (1.0, 1.0, 1.0)
        args: dict[str, Any] = dict(
            host=a["host"],
            port=a["port"],
            output=a["output"],
            white_balance=tuple(wb),
            reconnect_initial_s=a["reconnect_initial_s"],
            reconnect_max_s=a["reconnect_max_s"],
            connect_timeout_s=a["connect_timeout_s"],
            idle_timeout_s=a["idle_timeout_s"],
        )
        args.update(kwargs)
        return cls(**args)

    # -- CameraSource -------------------------------------------------------------------

    def poll(self, now_s: float) -> CameraFrame | None:
        """The newest frame completed since the last poll, or None.

        ``t_s`` is the mission time at which its header arrived (now_s minus the wall time
        elapsed since then); ``pose`` comes from ``pose_fn(t_s)`` if one was given.
        """
        with self._lock:
            item, self._latest = self._latest, None
        if item is None:
            return None
        t_header, frame = item
        t_s = now_s - max(0.0, time.monotonic() - t_header)
        pose = self.pose_fn(t_s) if self.pose_fn is not None else _NO_POSE
        return CameraFrame(frame.image, t_s, pose, frame.index, frame.meta)

    # -- lifecycle ------------------------------------------------------------------------

    def start(self) -> None:
        """Start the reader thread (idempotent)."""
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="aideck-stream", daemon=True)
            self._thread.start()

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the reader thread and close the socket."""
        self._stop.set()
        sock = self._sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        if self._thread is not None:
            self._thread.join(timeout_s)

    def __enter__(self) -> AIDeckStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def connected(self) -> bool:
        """True while a TCP connection to the deck is open."""
        return self._connected

    def stats(self) -> StreamStats:
        """A snapshot of the counters."""
        with self._lock:
            now = time.monotonic()
            rate = self._rate.rate_hz(now)
            c = self._asm.counters
            return StreamStats(
                connected=self._connected,
                frames=self._frames,
                fps=rate,
                dropped=c.dropped,
                corrupt=self._corrupt,
                drop_reasons=dict(c.reasons),
                skipped=self._skipped,
                bytes=self._parser.bytes_in,
                garbage_bytes=self._parser.garbage_bytes,
                resyncs=self._parser.resyncs,
                connects=self._connects,
                reconnects=max(0, self._connects - 1),
                latency_mean_s=self._lat_sum / self._frames if self._frames else math.nan,
                latency_max_s=self._lat_max,
                last_error=self._last_error,
            )

    # -- reader thread --------------------------------------------------------------------

    def _run(self) -> None:
        backoff = self.reconnect_initial_s
        while not self._stop.is_set():
            try:
                sock = socket.create_connection((self.host, self.port), self.connect_timeout_s)
            except OSError as e:
                self._last_error = f"connect: {e}"
                self._stop.wait(backoff)
                backoff = min(self.reconnect_max_s, backoff * 2.0)
                continue
            self._sock = sock
            self._connects += 1
            self._connected = True
            try:
                if self._serve(sock):
                    backoff = self.reconnect_initial_s
            except OSError as e:
                self._last_error = f"recv: {e}"
            except Exception as e:  # never let a bad peer kill the reader
                log.exception("AI-deck stream reader error")
                self._last_error = f"{type(e).__name__}: {e}"
            finally:
                self._connected = False
                self._sock = None
                with self._lock:
                    if self._stop.is_set():  # we are closing: a frame on the wire is not a drop
                        self._asm.discard()
                    else:
                        self._asm.abort("disconnect")
                self._parser.reset()
                try:
                    sock.close()
                except OSError:
                    pass
            if not self._stop.is_set():
                self._stop.wait(backoff)
                backoff = min(self.reconnect_max_s, backoff * 2.0)

    def _serve(self, sock: socket.socket) -> bool:
        """Read one connection until it closes, stalls or spews garbage; True if it gave frames."""
        sock.settimeout(0.2)
        got_frames = False
        last_rx = time.monotonic()
        garbage_at_good = self._parser.garbage_bytes
        while not self._stop.is_set():
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                chunk = None
            now = time.monotonic()
            if chunk is None:
                with self._lock:
                    self._asm.check_stall(now)
                if now - last_rx > self.idle_timeout_s:
                    self._last_error = "idle timeout"
                    return got_frames
                continue
            if not chunk:
                self._last_error = "closed by peer"
                return got_frames
            last_rx = now
            for item in self._parser.feed(chunk):
                with self._lock:
                    img = self._asm.feed(item, now)
                if img is not None and self._deliver(img):
                    got_frames = True
                    garbage_at_good = self._parser.garbage_bytes
            if self._parser.garbage_bytes - garbage_at_good > self.max_garbage_bytes:
                self._last_error = "too much garbage"
                return got_frames
        return got_frames

    def _deliver(self, img: AssembledImage) -> bool:
        image = decode_image(img)
        h = img.header
        with self._lock:
            if image is None:
                self._corrupt += 1
                c = self._asm.counters
                reason = "bad_jpeg" if h.format == 1 else "bad_size"
                c.reasons[reason] = c.reasons.get(reason, 0) + 1
                return False
        if self.output == "bgr":
            if image.ndim == 2:
                image = preprocess(image, self.white_balance)
            elif image.ndim == 3 and image.shape[2] == 3:
                image = apply_white_balance(image, self.white_balance)
        latency = img.complete_time - img.header_time
        meta: dict[str, Any] = {
            "payload": img.payload,
            "format": "bgr" if image.ndim == 3 else "bayer_bg",  # as the simulated camera's
            "wire_format": "jpeg" if h.format == 1 else "raw",
            "width": h.width,
            "height": h.height,
            "depth": h.depth,
            "size": h.size,
            "chunks": img.chunks,
            "latency_s": latency,
            "received_monotonic_s": img.complete_time,
        }
        if h.timestamp_ms is not None:
            meta["deck_timestamp_ms"] = h.timestamp_ms
            meta["deck_position_mm"] = h.position_mm
            meta["deck_quat_compressed"] = h.quat_compressed
        with self._lock:
            self._frames += 1
            self._rate.add(img.complete_time)
            self._lat_sum += latency
            self._lat_max = max(self._lat_max, latency)
            if self._latest is not None:
                self._skipped += 1
            frame = CameraFrame(image, 0.0, _NO_POSE, self._frames, meta)
            self._latest = (img.header_time, frame)
        if self.on_frame is not None:
            self.on_frame(frame)  # reader thread; t_s is 0 (no mission time here)
        return True
