"""CPX packet coding, the stream parser (fuzzed) and the image-frame assembler."""

from __future__ import annotations

import itertools
import random
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.crazyflie.cpx import (
    MAX_DATA,
    CPXError,
    FrameAssembler,
    Function,
    ImageHeader,
    Packet,
    Resync,
    StreamParser,
    Target,
    decode,
    encode,
    encode_image,
)


def test_encode_known_bytes_and_bit_layout() -> None:
    raw = encode(Packet(Target.HOST, Target.GAP8, Function.APP, b"ab"))
    # length = len(data) + 2; route = last(0x40) | src 4 << 3 | dst 3; function 5, version 0
    assert raw == b"\x04\x00" + bytes([0x40 | 0x20 | 0x03, 0x05]) + b"ab"
    p = decode(encode(Packet(Target.ESP32, Target.STM32, Function.WIFI_CTRL, b"", last=False)))
    assert (p.destination, p.source, p.function, p.data, p.last) == (2, 1, 4, b"", False)


@given(
    st.sampled_from(list(Target)),
    st.sampled_from(list(Target)),
    st.sampled_from(list(Function)),
    st.binary(max_size=MAX_DATA),
    st.booleans(),
)
def test_roundtrip(dst: int, src: int, fn: int, data: bytes, last: bool) -> None:
    p = Packet(dst, src, fn, data, last)
    assert decode(encode(p)) == p


def test_wire_format_is_cflibs() -> None:
    """Every route (each target to each target, last or not) and function is coded byte for
    byte as Bitcraze's ``cflib.cpx.CPXPacket`` codes it (with the socket transport's length
    prefix), and decodes back (the module docstring says why cflib's codec is not used)."""
    cpx = pytest.importorskip("cflib.cpx")
    for dst, src, fn, last in itertools.product(
        cpx.CPXTarget, cpx.CPXTarget, cpx.CPXFunction, (False, True)
    ):
        theirs = cpx.CPXPacket(function=fn, destination=dst, source=src, data=bytearray(b"xyz"))
        theirs.lastPacket = last
        wire = struct.pack("<H", theirs.length + 2) + bytes(theirs.wireData)
        ours = Packet(dst.value, src.value, fn.value, b"xyz", last)
        assert encode(ours) == wire, (dst, src, fn, last)
        assert decode(wire) == ours
    assert {t.name: t.value for t in cpx.CPXTarget} == {t.name: t.value for t in Target}
    assert {f.name: f.value for f in cpx.CPXFunction} == {f.name: f.value for f in Function}


def test_invalid_packets_rejected() -> None:
    with pytest.raises(CPXError):
        encode(Packet(Target.HOST, Target.GAP8, Function.APP, bytes(MAX_DATA + 1)))
    good = encode(Packet(Target.HOST, Target.GAP8, Function.APP, b"xyz"))
    for bad in (
        good[:-1],  # truncated
        good + b"!",  # too long
        struct.pack("<HBB", 0xFFFF, good[2], good[3]) + good[4:],  # oversized length
        good[:2] + bytes([good[2] | 0x80]) + good[3:],  # reserved route bit
        good[:2] + bytes([(good[2] & 0xF8) | 7]) + good[3:],  # unknown destination
        good[:3] + bytes([0x45]) + good[4:],  # version 1
        good[:3] + bytes([0x09]) + good[4:],  # unknown function
    ):
        with pytest.raises(CPXError):
            decode(bad)


def test_image_header_pack_parse() -> None:
    basic = ImageHeader(324, 244, 1, 0, 324 * 244)
    assert len(basic.pack()) == 11 and ImageHeader.parse(basic.pack()) == basic
    ext = ImageHeader(324, 244, 1, 1, 5000, 123456, (10, -20, 300), 0xDEADBEEF)
    assert len(ext.pack()) == 25 and ImageHeader.parse(ext.pack()) == ext
    assert ImageHeader.parse(b"\xbd" + basic.pack()[1:]) is None  # magic
    assert ImageHeader.parse(ImageHeader(324, 244, 1, 0, 1000).pack()) is None  # raw size
    assert ImageHeader.parse(ImageHeader(324, 244, 1, 2, 1000).pack()) is None  # format
    assert ImageHeader.parse(basic.pack()[:10]) is None


def _frames(n: int, seed: int = 0, fmt: int = 0) -> list[tuple[ImageHeader, bytes]]:
    rng = random.Random(seed)
    out = []
    for _ in range(n):
        w, h = rng.randint(1, 64), rng.randint(1, 40)
        size = w * h if fmt == 0 else rng.randint(1, 3000)
        out.append((ImageHeader(w, h, 1, fmt, size), rng.randbytes(size)))
    return out


def _assemble(stream: bytes, cuts: list[int], stall_s: float = 1e9) -> tuple[list, FrameAssembler]:
    parser, asm = StreamParser(destinations=(Target.HOST,)), FrameAssembler(stall_s=stall_s)
    images, pos = [], 0
    for cut in [*sorted(cuts), len(stream)]:
        for item in parser.feed(stream[pos:cut]):
            img = asm.feed(item, 0.0)
            if img is not None:
                images.append(img)
        pos = cut
    return images, asm


def test_assembler_bit_exact_any_chunking() -> None:
    frames = _frames(6) + _frames(3, seed=1, fmt=1)
    stream = b"".join(b"".join(encode_image(h, p, [300, 1020, 7])) for h, p in frames)
    images, asm = _assemble(stream, list(range(0, len(stream), 97)))
    assert [(i.header, i.payload) for i in images] == frames
    assert asm.counters.frames == 9 and asm.counters.dropped == 0


def test_assembler_drops_truncated_overflow_route_and_resync() -> None:
    (h1, p1), (h2, p2), (h3, p3), (h4, p4) = _frames(4, seed=3)
    f1 = encode_image(h1, p1, [5])
    assert len(f1) >= 3
    truncated = b"".join(f1[:-1])  # frame 1 loses its last chunk; frame 2 follows
    wrong_route = encode(Packet(Target.HOST, Target.ESP32, Function.APP, b"zz"))
    f3 = encode_image(h3, p3, [5])
    stream = (
        truncated
        + b"".join(encode_image(h2, p2))
        + f3[0] + f3[1] + wrong_route + b"".join(f3[2:])  # dropped: wrong source
        + b"\xff\xff\x00\x00garbage"  # oversized length -> resync
        + b"".join(encode_image(h4, p4))
    )  # fmt: skip
    images, asm = _assemble(stream, [])
    assert [i.payload for i in images] == [p2, p4]
    assert asm.counters.reasons["truncated"] == 1 and asm.counters.reasons["route"] == 1
    assert asm.counters.dropped == 2


def test_resync_mid_frame_drops_it_and_stall() -> None:
    (h1, p1), (h2, p2) = _frames(2, seed=4)
    f1 = encode_image(h1, p1, [3])
    stream = f1[0] + f1[1] + b"\x00\x00\x00" + b"".join(f1[2:]) + b"".join(encode_image(h2, p2))
    images, asm = _assemble(stream, [])
    assert [i.payload for i in images] == [p2] and asm.counters.reasons == {"resync": 1}
    asm = FrameAssembler(stall_s=0.5)
    for raw in f1[:2]:
        asm.feed(decode(raw), 1.0)
    asm.check_stall(1.4)
    assert asm.in_progress
    asm.check_stall(1.6)
    assert not asm.in_progress and asm.counters.reasons == {"stall": 1}


def test_a_frame_on_the_wire_when_the_reader_stops_is_not_a_drop() -> None:
    """abort (the link broke) counts the frame in progress as dropped; discard (we are
    closing the stream at the end of a run) forgets it without counting."""
    ((h1, p1),) = _frames(1, seed=5)
    f1 = encode_image(h1, p1, [3])
    for end, dropped in (("abort", 1), ("discard", 0)):
        asm = FrameAssembler()
        for raw in f1[:2]:
            asm.feed(decode(raw), 1.0)
        assert asm.in_progress
        getattr(asm, end)()
        assert not asm.in_progress and asm.counters.dropped == dropped, end


def test_non_app_packets_ignored_mid_frame() -> None:
    (h1, p1), = _frames(1, seed=5)  # fmt: skip
    f1 = encode_image(h1, p1, [4])
    console = encode(Packet(Target.HOST, Target.GAP8, Function.CONSOLE, b"hello"))
    images, _ = _assemble(f1[0] + console + b"".join(f1[1:]), [])
    assert [i.payload for i in images] == [p1]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=4000), st.lists(st.integers(0, 4000), max_size=30))
def test_parser_fuzz_random_bytes(data: bytes, cuts: list[int]) -> None:
    """Random bytes never crash the parser; every packet it yields is well-formed."""
    parser = StreamParser()
    pos, total = 0, 0
    for cut in [*sorted(c for c in cuts if c <= len(data)), len(data)]:
        for item in parser.feed(data[pos:cut]):
            if isinstance(item, Packet):
                assert len(item.data) <= MAX_DATA
                assert decode(encode(item)) == item
                total += 4 + len(item.data)
        pos = cut
    assert total + parser.garbage_bytes + parser.buffered == len(data)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(0, 2**32 - 1),
    st.lists(st.tuples(st.integers(0, 60), st.binary(min_size=1, max_size=1500)), max_size=6),
    st.lists(st.integers(0, 200_000), max_size=40),
    st.booleans(),
)
def test_assembler_fuzz_garbage_never_corrupts(
    seed: int, garbage: list[tuple[int, bytes]], cuts: list[int], high: bool
) -> None:
    """Garbage at packet boundaries, any TCP chunking: every image out is one that was sent,
    in order. Garbage of bytes >= 0x80 can hold no valid header (bit 7 of a route byte is
    reserved), so then only the frame it interrupts is lost."""
    frames = _frames(12, seed=seed % 1000, fmt=seed % 2)
    packets = [pkt for h, p in frames for pkt in encode_image(h, p, [400])]
    if high:
        garbage = [(i, bytes(b | 0x80 for b in g)) for i, g in garbage]
    where = {min(i, len(packets)): b"\xff\xff" + g for i, g in garbage}  # bad length: detected
    stream = b"".join(where.get(i, b"") + pkt for i, pkt in enumerate(packets))
    stream += where.get(len(packets), b"")
    images, _ = _assemble(stream, [c for c in cuts if c <= len(stream)])
    sent = [p for _, p in frames]
    it = iter(sent)
    assert all(any(img.payload == p for p in it) for img in images)  # ordered subsequence
    if not garbage:
        assert [i.payload for i in images] == sent
    if high:
        assert len(images) >= len(sent) - len(where)


def test_parser_reports_resync_offset_and_recovers() -> None:
    pkt = encode(Packet(Target.HOST, Target.GAP8, Function.APP, b"payload"))
    parser = StreamParser()
    items = parser.feed(pkt + b"\x00\x00junk" + pkt[:3])
    assert items == [decode(pkt), Resync(len(pkt))]
    assert parser.feed(pkt[3:]) == [decode(pkt)]
    assert parser.garbage_bytes == 6 and parser.resyncs == 1 and parser.packets == 2
