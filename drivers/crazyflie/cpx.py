"""CPX (Crazyflie Packet eXchange) over TCP, and the AI-deck image-stream protocol on top.

Wire format of one CPX packet on the AI-deck's WiFi TCP socket (little endian)::

    [u16 length = len(data) + 2][route][function][data ...]

* ``route``: bit 7 reserved (0), bit 6 = last packet of a message, bits 5-3 = source,
  bits 2-0 = destination (:class:`Target`).
* ``function``: bits 7-6 = version (0), bits 5-0 = function (:class:`Function`).
* ``data`` is at most :data:`MAX_DATA` (1020) bytes, so ``length`` is 2..1022.

The image streamer (GAP8 -> host, function ``APP``) sends one header packet per frame,
``<BHHBBI`` = magic 0xBC, width, height, depth, format (0 raw, 1 JPEG), size; newer firmware
appends ``<IhhhI`` = GAP8 capture time (ms), drone x, y, z (mm) and a compressed quaternion
(25 bytes in all). The image follows in APP packets of at most 1020 bytes whose lengths sum
to ``size``.

Everything here is pure (no sockets): :func:`encode` / :func:`decode` for single packets,
:class:`StreamParser` to cut packets out of arbitrary TCP byte chunks and resynchronise on
garbage, and :class:`FrameAssembler` to turn packets into complete images - it drops a frame
rather than ever returning one that is not bit-exact what the deck sent, as far as the
protocol can tell (a resynchronisation, a wrong route, an overflowing or missing chunk, a
new header mid-frame or a stall all drop the frame in progress).

Why not cflib's own ``cflib.cpx`` (checked against cflib 0.1.34): its ``CPXPacket`` writes the
same route and function bytes (``tests/test_cpx.py`` compares every target, function and
last flag byte for byte), but it is not a codec this parser can use. The packet has no
length field: ``SocketTransport.writePacket`` prepends it in native byte order from
``packet.length``, which only the constructor sets. Decoding (the ``wireData`` setter) ignores
the reserved route bit 7 and any length over 1020 bytes, raises ``ValueError`` for an unknown
target or function and logs an error and raises ``RuntimeError`` for another version: the
header checks :class:`StreamParser` resynchronises on must run before it anyway, and each
garbage byte would log. Targets and functions are plain ``enum.Enum`` members, so a
3-bit value it does not list cannot be represented, and each packet costs about 40 % more
to decode. Its transport cannot take the stream parser's place: ``readPacket`` trusts the
length it reads (one corrupt byte desynchronises the stream for good) and ``_readData``
spins forever once the peer closes (``recv`` returns ``b""``). So the two struct lines of
:func:`encode` / :func:`decode` stay here, checked against cflib by the test.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field

__all__ = [
    "AssembledImage",
    "CPXError",
    "FrameAssembler",
    "Function",
    "ImageHeader",
    "MAX_DATA",
    "Packet",
    "Resync",
    "StreamParser",
    "Target",
    "decode",
    "encode",
    "encode_image",
]

HEADER_SIZE = 4  # u16 length + route + function
MAX_DATA = 1020  # largest data field of one packet
MAX_LENGTH = MAX_DATA + 2  # largest value of the length field
IMAGE_MAGIC = 0xBC
IMAGE_HEADER = struct.Struct("<BHHBBI")  # 11 bytes
IMAGE_HEADER_EXT = struct.Struct("<BHHBBIIhhhI")  # 25 bytes
MAX_IMAGE_SIDE = 2048
MAX_IMAGE_BYTES = 8 * 1024 * 1024


class Target(enum.IntEnum):
    """CPX endpoints (3 bits)."""

    STM32 = 1
    ESP32 = 2
    HOST = 3
    GAP8 = 4


class Function(enum.IntEnum):
    """CPX functions (6 bits)."""

    SYSTEM = 1
    CONSOLE = 2
    CRTP = 3
    WIFI_CTRL = 4
    APP = 5
    TEST = 14
    BOOTLOADER = 15


_TARGETS = frozenset(int(t) for t in Target)
_FUNCTIONS = frozenset(int(f) for f in Function)


class CPXError(ValueError):
    """A byte string is not a valid CPX packet."""


@dataclass(frozen=True, slots=True)
class Packet:
    """One CPX packet."""

    destination: int
    source: int
    function: int
    data: bytes
    last: bool = True
    version: int = 0


@dataclass(frozen=True, slots=True)
class Resync:
    """Stream event: bytes that are not a valid packet header were skipped from here on."""

    offset: int  # stream offset of the first skipped byte


def route_byte(destination: int, source: int, last: bool = True) -> int:
    """The route byte: bit 6 last, bits 5-3 source, bits 2-0 destination."""
    return (0x40 if last else 0) | ((source & 7) << 3) | (destination & 7)


def encode(packet: Packet) -> bytes:
    """Serialise one packet for the TCP transport (raises :class:`CPXError` if invalid)."""
    if len(packet.data) > MAX_DATA:
        raise CPXError(f"data of {len(packet.data)} bytes exceeds {MAX_DATA}")
    if not (0 <= packet.destination < 8 and 0 <= packet.source < 8):
        raise CPXError("source and destination are 3-bit fields")
    if not (0 <= packet.function < 64 and 0 <= packet.version < 4):
        raise CPXError("function is 6 bits, version 2 bits")
    route = route_byte(packet.destination, packet.source, packet.last)
    func = (packet.version << 6) | packet.function
    return struct.pack("<HBB", len(packet.data) + 2, route, func) + bytes(packet.data)


def _header_ok(length: int, route: int, func: int, destinations: frozenset[int]) -> bool:
    return (
        2 <= length <= MAX_LENGTH
        and route & 0x80 == 0
        and (route >> 3) & 7 in _TARGETS
        and route & 7 in destinations
        and func >> 6 == 0
        and func & 0x3F in _FUNCTIONS
    )


def decode(buf: bytes) -> Packet:
    """Parse exactly one packet (raises :class:`CPXError` unless valid and complete)."""
    if len(buf) < HEADER_SIZE:
        raise CPXError("shorter than a packet header")
    length, route, func = struct.unpack_from("<HBB", buf)
    if not _header_ok(length, route, func, _TARGETS):
        raise CPXError(f"invalid header length={length} route=0x{route:02x} func=0x{func:02x}")
    if len(buf) != length + 2:
        raise CPXError(f"length field says {length + 2} bytes, got {len(buf)}")
    return Packet(route & 7, (route >> 3) & 7, func & 0x3F, bytes(buf[4:]), bool(route & 0x40))


class StreamParser:
    """Cut CPX packets out of a TCP byte stream fed in arbitrary chunks.

    A header is accepted only if its length is 2..1022, the reserved route bit is clear, the
    source is a known target, the destination is one of ``destinations``, the version is 0 and
    the function is known. Otherwise one byte is skipped and the next offset is tried; the
    first skipped byte of each garbage run is reported as a :class:`Resync` event, in stream
    order with the packets, so a consumer can drop whatever it was assembling.
    """

    def __init__(self, destinations: Iterable[int] | None = None) -> None:
        self.destinations = frozenset(destinations) if destinations is not None else _TARGETS
        self._buf = bytearray()
        self._offset = 0  # stream offset of _buf[0]
        self._in_garbage = False
        self.packets = 0
        self.resyncs = 0
        self.garbage_bytes = 0
        self.bytes_in = 0

    def reset(self) -> None:
        """Forget buffered bytes (call on a new connection)."""
        self._buf.clear()
        self._in_garbage = False

    @property
    def buffered(self) -> int:
        """Bytes held back waiting for the rest of a packet."""
        return len(self._buf)

    def feed(self, chunk: bytes) -> list[Packet | Resync]:
        """Add received bytes; return the packets and resync events they complete."""
        self.bytes_in += len(chunk)
        buf = self._buf
        buf += chunk
        out: list[Packet | Resync] = []
        pos, n = 0, len(buf)
        dests = self.destinations
        while n - pos >= HEADER_SIZE:
            length, route, func = struct.unpack_from("<HBB", buf, pos)
            if not _header_ok(length, route, func, dests):
                if not self._in_garbage:
                    self._in_garbage = True
                    self.resyncs += 1
                    out.append(Resync(self._offset + pos))
                self.garbage_bytes += 1
                pos += 1
                continue
            end = pos + 2 + length
            if end > n:
                break
            self._in_garbage = False
            data = bytes(buf[pos + 4 : end])
            out.append(Packet(route & 7, (route >> 3) & 7, func & 0x3F, data, bool(route & 0x40)))
            self.packets += 1
            pos = end
        del buf[:pos]
        self._offset += pos
        return out


@dataclass(frozen=True, slots=True)
class ImageHeader:
    """The image-stream header packet (basic 11 bytes, or 25 with the extended fields)."""

    width: int
    height: int
    depth: int
    format: int  # 0 raw, 1 JPEG
    size: int
    timestamp_ms: int | None = None  # GAP8 capture clock (extended header only)
    position_mm: tuple[int, int, int] | None = None
    quat_compressed: int | None = None

    def pack(self) -> bytes:
        """Serialise (extended form if ``timestamp_ms`` is set)."""
        if self.timestamp_ms is None:
            return IMAGE_HEADER.pack(
                IMAGE_MAGIC, self.width, self.height, self.depth, self.format, self.size
            )
        x, y, z = self.position_mm or (0, 0, 0)
        return IMAGE_HEADER_EXT.pack(
            IMAGE_MAGIC, self.width, self.height, self.depth, self.format, self.size,
            self.timestamp_ms & 0xFFFFFFFF, x, y, z, (self.quat_compressed or 0) & 0xFFFFFFFF,
        )  # fmt: skip

    @classmethod
    def parse(cls, data: bytes) -> ImageHeader | None:
        """Parse a header packet's data; None unless it is a plausible image header.

        Plausible: 11 or 25 bytes, magic 0xBC, 1..2048 pixels per side, depth 1..4, format 0
        or 1, and a size that matches ``width * height * depth`` for raw frames or lies in
        1..min(8 MiB, 4 * w * h * depth + 4096) for JPEG.
        """
        if len(data) == IMAGE_HEADER.size:
            magic, w, h, d, f, size = IMAGE_HEADER.unpack(data)
            ext: tuple[int, ...] | None = None
        elif len(data) == IMAGE_HEADER_EXT.size:
            magic, w, h, d, f, size, *ext = IMAGE_HEADER_EXT.unpack(data)
        else:
            return None
        if magic != IMAGE_MAGIC or not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
            return None
        if not 1 <= d <= 4 or f not in (0, 1):
            return None
        if f == 0 and size != w * h * d:
            return None
        if f == 1 and not 0 < size <= min(MAX_IMAGE_BYTES, 4 * w * h * d + 4096):
            return None
        if ext is None:
            return cls(w, h, d, f, size)
        ts, x, y, z, q = ext
        return cls(w, h, d, f, size, ts, (x, y, z), q)


def encode_image(
    header: ImageHeader,
    payload: bytes,
    chunk_sizes: Iterable[int] | None = None,
    source: int = Target.GAP8,
    destination: int = Target.HOST,
) -> list[bytes]:
    """The TCP byte strings (one per CPX packet) that stream one image.

    Chunks are :data:`MAX_DATA` bytes except the last, unless ``chunk_sizes`` (cycled) says
    otherwise, e.g. to mimic the JPEG streamer's separate JPEG-header and footer chunks.
    """
    if len(payload) != header.size:
        raise CPXError(f"payload of {len(payload)} bytes, header says {header.size}")
    out = [encode(Packet(destination, source, Function.APP, header.pack()))]
    sizes = list(chunk_sizes) if chunk_sizes else [MAX_DATA]
    if any(not 0 < s <= MAX_DATA for s in sizes):
        raise CPXError("chunk sizes must be 1..1020")
    pos, i = 0, 0
    while pos < len(payload):
        step = sizes[i % len(sizes)]
        out.append(encode(Packet(destination, source, Function.APP, payload[pos : pos + step])))
        pos += step
        i += 1
    return out


@dataclass(slots=True)
class AssembledImage:
    """One complete image as the deck sent it (``payload`` is bit-exact)."""

    header: ImageHeader
    payload: bytes
    header_time: float  # receive time of the header packet (caller's clock)
    complete_time: float  # receive time of the last chunk
    chunks: int


@dataclass(slots=True)
class AssemblerCounters:
    """What the :class:`FrameAssembler` has seen."""

    frames: int = 0
    dropped: int = 0
    reasons: dict[str, int] = field(default_factory=dict)
    stray_chunks: int = 0  # APP packets outside any frame (ignored)
    other_packets: int = 0  # non-APP packets (ignored)


class FrameAssembler:
    """Reassemble images from CPX packets; drop every frame that cannot be proven whole.

    Feed packets and :class:`Resync` events in stream order with :meth:`feed`, and call
    :meth:`abort` on a disconnect. A frame in progress is dropped on a resync, on an APP packet
    from an unexpected route, on a chunk that overflows the announced size, on a packet that
    looks like a new image header while chunks are still owed (unless it exactly completes the
    frame), or when :meth:`check_stall` finds it idle too long.
    """

    def __init__(
        self, source: int = Target.GAP8, destination: int = Target.HOST, stall_s: float = 2.0
    ) -> None:
        self.source, self.destination, self.stall_s = source, destination, stall_s
        self.counters = AssemblerCounters()
        self._hdr: ImageHeader | None = None
        self._parts: list[bytes] = []
        self._got = 0
        self._t0 = 0.0
        self._last_t = 0.0

    @property
    def in_progress(self) -> bool:
        """True while a frame's chunks are still owed."""
        return self._hdr is not None

    def _drop(self, reason: str) -> None:
        if self._hdr is not None:
            c = self.counters
            c.dropped += 1
            c.reasons[reason] = c.reasons.get(reason, 0) + 1
        self._hdr, self._parts, self._got = None, [], 0

    def discard(self) -> None:
        """Forget the frame in progress without counting it: the reader is stopping, so
        the frame was not lost, the run ended while it was on the wire."""
        self._hdr, self._parts, self._got = None, [], 0

    def abort(self, reason: str = "disconnect") -> None:
        """Drop the frame in progress (e.g. the connection closed)."""
        self._drop(reason)

    def check_stall(self, now: float) -> None:
        """Drop the frame in progress if no chunk came for ``stall_s``."""
        if self._hdr is not None and now - self._last_t > self.stall_s:
            self._drop("stall")

    def _start(self, hdr: ImageHeader, now: float) -> None:
        self._hdr, self._parts, self._got = hdr, [], 0
        self._t0 = self._last_t = now

    def feed(self, item: Packet | Resync, now: float) -> AssembledImage | None:
        """Consume one packet or event received at ``now``; return a completed image."""
        if isinstance(item, Resync):
            self._drop("resync")
            return None
        if item.function != Function.APP:
            self.counters.other_packets += 1
            return None
        if item.source != self.source or item.destination != self.destination:
            self._drop("route")
            return None
        hdr = self._hdr
        if hdr is None:
            new = ImageHeader.parse(item.data)
            if new is None:
                self.counters.stray_chunks += 1
            else:
                self._start(new, now)
            return None
        remaining = hdr.size - self._got
        n = len(item.data)
        if n != remaining:
            new = ImageHeader.parse(item.data)
            if new is not None:  # a header while chunks are owed: the frame was truncated
                self._drop("truncated")
                self._start(new, now)
                return None
            if n > remaining:
                self._drop("overflow")
                return None
        if n == 0:  # the firmware's chunk loop ends with an empty packet on exact multiples
            return None
        self._parts.append(item.data)
        self._got += n
        self._last_t = now
        if self._got < hdr.size:
            return None
        img = AssembledImage(hdr, b"".join(self._parts), self._t0, now, len(self._parts))
        self._hdr, self._parts, self._got = None, [], 0
        self.counters.frames += 1
        return img
