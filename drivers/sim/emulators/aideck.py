"""A software AI-deck: the WiFi image streamer served as CPX over TCP on loopback.

It behaves like the ESP32 + GAP8 ``wifi-img-streamer`` example: it listens on
``127.0.0.1:<port>``, serves one TCP client at a time (others wait in the backlog until the
client leaves), and streams frames in real time at the camera rate (15 fps by default): per
frame one image-header packet and the image in APP packets of at most 1020 bytes
(:func:`drivers.crazyflie.cpx.encode_image`). Frames come from a renderer (``pattern``: a fast
deterministic test pattern; ``pallet``: the simulated world through
:mod:`drivers.sim.renderers.pallet`), sent raw (8-bit BayerBG, 324 x 244) or as JPEG.

A client that vanishes, stops reading (2 s send timeout) or resets the connection is dropped
and the next one is accepted. Tests inject faults on the wire with :meth:`AIDeckEmulator.inject`:
``garbage``, ``truncate``, ``oversize``, ``bad_route``, ``bad_jpeg``, ``disconnect``; and
on the deck itself: :meth:`AIDeckEmulator.set_stalled` (connected, no frames: a hung camera)
and :meth:`AIDeckEmulator.set_online` (off: the client is dropped and new connections are
closed at once, like a deck out of WiFi range or rebooting).

In software in the loop (:mod:`drivers.sim.emulators.sitl`) ``pose_fn`` gives the simulated drone's
true pose at each frame, so the stream shows what the drone's camera sees in real time.

Standalone, for bitcraze's viewers (``opencv-viewer.py -n 127.0.0.1 -p 5000``; the newer
viewer expects the 25-byte header: add ``--header extended``)::

    btrun sim serve aideck --port 5000 [--format jpeg] [--renderer pallet]
"""

from __future__ import annotations

import math
import random
import select
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.crazyflie.cpx import Function, ImageHeader, Packet, Target, encode, encode_image
from drivers.vehicle.types import Pose

__all__ = ["AIDeckEmulator", "FAULTS", "SentFrame", "make_frame_source"]

WIDTH, HEIGHT = 324, 244
FAULTS = ("garbage", "truncate", "oversize", "bad_route", "bad_jpeg", "disconnect")

FrameFn = Callable[[Pose, float], Any]


def pattern_renderer(seed: int = 0) -> FrameFn:
    """A cheap deterministic BayerBG test pattern; every frame differs (index in the pixels)."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    base = ((xx * 255) // WIDTH).astype(np.uint8) ^ ((yy * 255) // HEIGHT).astype(np.uint8)
    rng = np.random.default_rng(seed)
    count = [0]

    def render(pose: Pose, t_s: float, previous: Any = None) -> np.ndarray:
        i = count[0]
        count[0] += 1
        img = np.roll(base, i, axis=1) + rng.integers(0, 8, base.shape, dtype=np.uint8)
        img[0, :8] = np.frombuffer(struct.pack("<Q", i), dtype=np.uint8)
        return img

    return render


def make_frame_source(name: str, seed: int = 0, world: Any = None) -> FrameFn:
    """``pattern`` or a renderer named in :data:`drivers.sim.renderers.RENDERERS`."""
    if name == "pattern":
        return pattern_renderer(seed)
    from drivers.sim.renderers import make_renderer

    r = make_renderer(name, world=world, camera=None, rng=random.Random(seed))
    if r is None:
        raise ValueError(f"renderer {name!r} produces no frames")
    return r


@dataclass(frozen=True, slots=True)
class SentFrame:
    """A frame the emulator finished sending (``payload`` as on the wire)."""

    index: int
    header: ImageHeader
    payload: bytes
    sent_monotonic_s: float


class AIDeckEmulator:
    """Serve the AI-deck image stream on ``host:port`` (port 0: pick a free one)."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        fps: float = 15.0,
        fmt: str = "raw",
        header: str = "basic",
        renderer: FrameFn | None = None,
        pose: Pose | None = None,
        jpeg_quality: int = 85,
        chunk_sizes: list[int] | None = None,
        seed: int = 0,
        record: int = 256,
        send_timeout_s: float = 2.0,
        pose_fn: Callable[[], Pose] | None = None,
        warm_up: bool = False,
    ) -> None:
        if fmt not in ("raw", "jpeg") or header not in ("basic", "extended"):
            raise ValueError("fmt is raw|jpeg, header is basic|extended")
        self.fps, self.fmt, self.header_kind = fps, fmt, header
        self.renderer = renderer or pattern_renderer(seed)
        self.pose = pose or Pose(0.0, 0.0, 0.5, 0.0)
        self.jpeg_quality, self.chunk_sizes = jpeg_quality, chunk_sizes
        self.rng = random.Random(seed)
        self.send_timeout_s = send_timeout_s
        self.pose_fn = pose_fn  # pose of each frame (its t_s is the renderer's time), or fixed
        self.warm_up = warm_up  # render one frame (discarded) before serving: first-call costs
        self.stalled = False
        self.online = True
        self.render_s_max = 0.0
        self.slots_skipped = 0  # frame times skipped because rendering/sending fell behind
        self._render_s_sum = 0.0
        self._renders = 0
        self._previous: tuple[float, Pose] | None = None
        self.sent: deque[SentFrame] = deque(maxlen=record)
        self.frames_sent = 0
        self.frames_faulted = 0
        self.bytes_sent = 0
        self.clients = 0
        self.client_connected = threading.Event()
        self._faults: deque[tuple[str, dict]] = deque()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind((host, port))
        self._srv.listen(4)
        self._srv.settimeout(0.1)
        self.host, self.port = self._srv.getsockname()[:2]
        self._client: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._index = 0

    # -- control ------------------------------------------------------------------------

    def start(self) -> AIDeckEmulator:
        """Start serving in a background thread."""
        self._thread = threading.Thread(target=self._run, name="aideck-emulator", daemon=True)
        self._thread.start()
        return self

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop serving and close every socket."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._srv.close()

    def __enter__(self) -> AIDeckEmulator:
        return self if self._thread is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def inject(self, kind: str, **params: Any) -> None:
        """Queue a wire fault for the next frame (see the module doc for the kinds)."""
        if kind not in FAULTS:
            raise ValueError(f"unknown fault {kind!r} (known: {FAULTS})")
        with self._lock:
            self._faults.append((kind, params))

    def set_stalled(self, stalled: bool = True) -> None:
        """Stop (True) or resume sending frames; the connection stays open."""
        self.stalled = stalled

    def set_online(self, online: bool = True) -> None:
        """Offline: drop the client and close new connections at once; online: serve again."""
        self.online = online
        if not online:
            self.drop_client()

    @property
    def render_s_mean(self) -> float:
        """Mean time to render one frame (s)."""
        return self._render_s_sum / self._renders if self._renders else 0.0

    def drop_client(self) -> None:
        """Close the current client's connection (like the deck rebooting its WiFi)."""
        c = self._client
        if c is not None:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    # -- frames -------------------------------------------------------------------------

    def render(self, t_s: float) -> tuple[ImageHeader, bytes]:
        """Render and encode the next frame: (header, payload).

        With ``pose_fn`` the pose (and the renderer's time, its ``t_s``) come from it, and
        the previous frame's (time, pose) is passed on for motion blur."""
        t0 = time.perf_counter()
        if self.pose_fn is not None:
            self.pose = self.pose_fn()
            t_s = self.pose.t_s
        img = np.ascontiguousarray(
            self.renderer(self.pose, t_s, previous=self._previous), dtype=np.uint8
        )
        self._previous = (t_s, self.pose)
        dt = time.perf_counter() - t0
        self._render_s_sum += dt
        self._renders += 1
        self.render_s_max = max(self.render_s_max, dt)
        h, w = img.shape[:2]
        depth = 1 if img.ndim == 2 else img.shape[2]
        if self.fmt == "jpeg":
            import cv2

            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            if not ok:
                raise RuntimeError("JPEG encoding failed")
            payload, fmt = buf.tobytes(), 1
        else:
            payload, fmt = img.tobytes(), 0
        if self.header_kind == "basic":
            return ImageHeader(w, h, depth, fmt, len(payload)), payload
        x, y, z = (int(max(-32768, min(32767, v * 1000.0))) for v in self.pose.position)
        stamp = int(time.monotonic() * 1000.0) & 0xFFFFFFFF  # the deck's ms capture clock
        return ImageHeader(w, h, depth, fmt, len(payload), stamp, (x, y, z), 0), payload

    def _packets(self, hdr: ImageHeader, payload: bytes) -> tuple[list[bytes], bool, str | None]:
        """Wire packets of one frame, with a queued fault applied: (packets, intact, action)."""
        packets = encode_image(hdr, payload, self.chunk_sizes)
        with self._lock:
            fault = self._faults.popleft() if self._faults else None
        if fault is None:
            return packets, True, None
        kind, params = fault
        cut = params.get("after_packets", max(1, len(packets) // 2))
        if kind == "garbage":
            n = int(params.get("nbytes", 300))
            garbage = bytes(self.rng.getrandbits(8) for _ in range(n))
            return packets[:cut] + [garbage] + packets[cut:], False, None
        if kind == "truncate":
            return packets[:cut], False, None
        if kind == "oversize":
            bogus = struct.pack("<HBB", 0xFFF0, 0x40 | (Target.GAP8 << 3) | Target.HOST, 5)
            return packets[:cut] + [bogus + bytes(64)] + packets[cut:], False, None
        if kind == "bad_route":  # a well-formed APP packet from the wrong source
            bad = encode(Packet(Target.HOST, Target.ESP32, Function.APP, bytes(40)))
            return packets[:cut] + [bad] + packets[cut:], False, None
        if kind == "bad_jpeg":
            junk = bytes(self.rng.getrandbits(8) for _ in range(2000))
            bad_hdr = ImageHeader(hdr.width, hdr.height, hdr.depth, 1, len(junk))
            return encode_image(bad_hdr, junk), False, None
        return packets[:cut], False, "disconnect"

    # -- server loop --------------------------------------------------------------------

    def _run(self) -> None:
        if self.warm_up:  # a renderer's first frame can take 0.5 s (caches): not on the wire
            pose = self.pose_fn() if self.pose_fn is not None else self.pose
            self.renderer(pose, pose.t_s)
        while not self._stop.is_set():
            try:
                client, _ = self._srv.accept()
            except (TimeoutError, OSError):
                continue
            if not self.online:
                client.close()  # the deck is away: the connection is refused at once
                continue
            self.clients += 1
            self._client = client
            self.client_connected.set()
            try:
                self._serve(client)
            except OSError:
                pass  # peer vanished: accept the next one
            finally:
                self._client = None
                self.client_connected.clear()
                try:
                    client.close()
                except OSError:
                    pass

    def _peer_gone(self, client: socket.socket) -> bool:
        """Drain whatever the host sent; True if it closed the connection."""
        while True:
            readable, _, _ = select.select([client], [], [], 0)
            if not readable:
                return False
            if not client.recv(4096):
                return True

    def _serve(self, client: socket.socket) -> None:
        client.settimeout(self.send_timeout_s)  # a client that stops reading is dropped
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        period = 1.0 / self.fps
        next_t = time.monotonic()
        t0 = next_t
        while not self._stop.is_set():
            delay = next_t - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
            if self._peer_gone(client) or not self.online:
                return
            if self.stalled:
                self._previous = None
                next_t = time.monotonic() + period
                continue
            now = time.monotonic()
            hdr, payload = self.render(now - t0)
            packets, intact, action = self._packets(hdr, payload)
            for p in packets:
                client.sendall(p)
                self.bytes_sent += len(p)
            if intact:
                self.frames_sent += 1
                self.sent.append(SentFrame(self._index, hdr, payload, time.monotonic()))
            else:
                self.frames_faulted += 1
            self._index += 1
            if action == "disconnect":
                return
            next_t += period
            behind = time.monotonic() - next_t
            if behind > period:  # fell behind: skip, like a camera
                self.slots_skipped += int(behind / period)
                next_t = time.monotonic()


def default_pose(world: Any, distance_m: float = 1.0) -> Pose:
    """A pose ``distance_m`` in front of the world's scan pallet, facing it."""
    if world is None or not world.pallets:
        return Pose(0.0, 0.0, 0.5, 0.0)
    p = world.pallets[0]
    fx, fy, fz = p.face_center_m
    f = p.facing_rad
    yaw = math.remainder(f + math.pi, 2.0 * math.pi)
    return Pose(fx + distance_m * math.cos(f), fy + distance_m * math.sin(f), max(fz, 0.3), yaw)
