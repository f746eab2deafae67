"""Port 4 (memory): the emulated Crazyflie has no memories (no EEPROM, no decks' 1-wire).

cflib asks ``[1]`` (number of memories) on ch 0 during connection and gets ``[1, 0]``. Any
other request is answered with the firmware's "no such memory" so that nothing waits forever.
"""

from __future__ import annotations

from drivers.sim.emulators.crtp.crtp import ENOENT, MEM, Packet

CMD_INFO_NBR = 1
CMD_INFO_DETAILS = 2


class MemPort:
    """Port 4 handler."""

    port = MEM

    def handle(self, pk: Packet) -> list[Packet]:
        if pk.channel != 0 or not pk.data:
            if pk.channel in (1, 2) and len(pk.data) >= 5:  # read/write: [id, addr u32, ...]
                return [Packet(MEM, pk.channel, pk.data[:5] + bytes((ENOENT,)))]
            return []
        if pk.data[0] == CMD_INFO_NBR:
            return [Packet(MEM, 0, bytes((CMD_INFO_NBR, 0)))]
        if pk.data[0] == CMD_INFO_DETAILS and len(pk.data) >= 2:
            return [Packet(MEM, 0, bytes((CMD_INFO_DETAILS, pk.data[1])))]
        return []
