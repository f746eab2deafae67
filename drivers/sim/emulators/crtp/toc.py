"""Table-of-contents v2 (``[3]`` info, ``[2, lo, hi]`` item) shared by the log and param ports."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence

from drivers.sim.emulators.crtp.crtp import ENOENT, Packet

CMD_TOC_ITEM_V2, CMD_TOC_INFO_V2 = 2, 3


def toc_crc(entries: Sequence[tuple[str, int]]) -> int:
    """A CRC over names and type bytes (cflib caches TOCs by it)."""
    blob = b"".join(f"{n}:{t};".encode() for n, t in entries)
    return zlib.crc32(blob) & 0xFFFFFFFF


def toc_reply(
    port: int, entries: Sequence[tuple[str, int]], data: bytes, info_extra: bytes
) -> list[Packet]:
    """Answer a TOC request on channel 0. ``entries`` are ``(group.name, type byte)``.

    ``info_extra`` follows count and CRC in the info reply (log: max blocks and variables).
    """
    if not data:
        return []
    cmd = data[0]
    if cmd == CMD_TOC_INFO_V2:
        return [
            Packet(port, 0, struct.pack("<BHI", cmd, len(entries), toc_crc(entries)) + info_extra)
        ]
    if cmd == CMD_TOC_ITEM_V2 and len(data) >= 3:
        ident = data[1] | data[2] << 8
        if ident >= len(entries):
            return [Packet(port, 0, bytes((cmd, data[1], data[2], ENOENT)))]
        name, type_byte = entries[ident]
        group, _, var = name.partition(".")
        body = bytes((cmd, data[1], data[2], type_byte)) + group.encode() + b"\0"
        return [Packet(port, 0, body + var.encode() + b"\0")]
    return []
