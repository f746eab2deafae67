"""Port 13 (platform): protocol/firmware version (ch 1) and legacy arming requests (ch 0).

``[0]`` on ch 1 -> ``[0, int32 protocol version]`` (12 here: cflib then uses TOC v2, velocity
world set-points and the supervisor port for arming). ``[1]`` -> ``[1, "btrun-sim"]``.
ch 0 ``[1, arm]`` is the pre-supervisor arming request, ``[2]`` crash recovery.
"""

from __future__ import annotations

import struct

from drivers.sim.emulators.crtp.crtp import PLATFORM, Packet
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie

FIRMWARE_NAME = b"btrun-sim"


class PlatformPort:
    """Port 13 handler."""

    port = PLATFORM

    def __init__(self, cf: EmulatedCrazyflie) -> None:
        self.cf = cf

    def handle(self, pk: Packet) -> list[Packet]:
        if not pk.data:
            return []
        cmd = pk.data[0]
        if pk.channel == 1:
            if cmd == 0:
                return [Packet(PLATFORM, 1, struct.pack("<Bi", 0, self.cf.protocol_version))]
            if cmd == 1:
                return [Packet(PLATFORM, 1, bytes((1,)) + FIRMWARE_NAME)]
            return []
        if pk.channel == 0:
            fw = self.cf.drone.firmware
            if cmd == 1 and len(pk.data) >= 2:
                fw.arm(bool(pk.data[1]))
            elif cmd == 2:
                recover(self.cf)
        return []


def recover(cf: EmulatedCrazyflie) -> bool:
    """Crash recovery: allowed on the ground and upright (as the firmware's supervisor)."""
    d = cf.drone
    if (d.crashed or d.firmware.crashed) and d.body.on_ground and not cf.tumbled():
        d.crashed = d.firmware.crashed = False
        return True
    return False
