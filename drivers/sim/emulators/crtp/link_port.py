"""Port 15 (link control): protocol query, echo (cflib's latency ping), sink, scan probe.

* ch 0 echo: the packet comes back unchanged (``LinkStatistics`` pings at 10 Hz).
* ch 1 source: the reply starts with ``Bitcraze Crazyflie`` (30 bytes, zero padded); cflib then
  asks the platform port for the protocol version.
* ch 2 sink: swallowed.
* ch 3 (header ``0xFF``, cflib's scan probe / null packet): answered with a null packet.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from drivers.sim.emulators.crtp.crtp import LINKCTRL, MAX_PAYLOAD, Packet

MAGIC = b"Bitcraze Crazyflie"


@dataclass
class LinkStats:
    """Counters of the emulated radio link (what link statistics would report)."""

    rx: int = 0
    tx: int = 0
    malformed: int = 0
    errors: int = 0
    dropped_rx: int = 0
    dropped_tx: int = 0
    echoes: int = 0
    unsupported: dict[int, int] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-friendly copy."""
        return {
            "rx": self.rx,
            "tx": self.tx,
            "malformed": self.malformed,
            "errors": self.errors,
            "dropped_rx": self.dropped_rx,
            "dropped_tx": self.dropped_tx,
            "echoes": self.echoes,
            "unsupported": dict(self.unsupported),
        }


class LinkPort:
    """Port 15 handler."""

    port = LINKCTRL

    def __init__(self, stats: LinkStats) -> None:
        self.stats = stats

    def handle(self, pk: Packet) -> list[Packet]:
        if pk.channel == 0:
            self.stats.echoes += 1
            return [pk]
        if pk.channel == 1:
            return [Packet(LINKCTRL, 1, MAGIC.ljust(MAX_PAYLOAD, b"\0"))]
        if pk.channel == 3:
            return [Packet(LINKCTRL, 3, b"")]
        return []
