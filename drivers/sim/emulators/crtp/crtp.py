"""CRTP framing as the cflib UDP driver sends it: one packet per datagram.

Byte 0 is the header ``port << 4 | 0b1100 | channel`` (the two "link" bits are set, as in
``cflib.crtp.crtpstack.CRTPPacket``), then 0 to 30 payload bytes. No checksum, no handshake.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

MAX_PAYLOAD = 30

# Ports (cflib.crtp.crtpstack.CRTPPort)
CONSOLE, PARAM, COMMANDER, MEM, LOGGING = 0x0, 0x2, 0x3, 0x4, 0x5
LOCALIZATION, COMMANDER_GENERIC, SETPOINT_HL, SUPERVISOR = 0x6, 0x7, 0x8, 0x9
PLATFORM, LINKCTRL = 0xD, 0xF

# errno values the firmware answers with
ENOENT, E2BIG, ENOMEM, EEXIST, EINVAL = 2, 7, 12, 17, 22


@dataclass(frozen=True, slots=True)
class Packet:
    """One CRTP packet (``data`` at most :data:`MAX_PAYLOAD` bytes)."""

    port: int
    channel: int
    data: bytes = b""

    @property
    def header(self) -> int:
        """The header byte."""
        return ((self.port & 0x0F) << 4) | 0x0C | (self.channel & 0x03)

    def encode(self) -> bytes:
        """The datagram (header + payload, truncated to 30 payload bytes)."""
        return bytes((self.header,)) + bytes(self.data[:MAX_PAYLOAD])


def decode(datagram: bytes) -> Packet | None:
    """Parse a datagram; None if it cannot be a CRTP packet (empty or over 31 bytes)."""
    if not datagram or len(datagram) > MAX_PAYLOAD + 1:
        return None
    h = datagram[0]
    return Packet((h >> 4) & 0x0F, h & 0x03, bytes(datagram[1:]))


class PortHandler(Protocol):
    """One CRTP port of the emulated firmware."""

    port: int

    def handle(self, pk: Packet) -> list[Packet]:
        """Answer one packet (may raise on malformed input; the server counts it)."""
