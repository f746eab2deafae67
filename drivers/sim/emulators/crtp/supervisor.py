"""Port 9 (supervisor, protocol >= 12): arming, crash recovery, emergency stop, state bits.

ch 0 ``[0x0C]`` -> ``[0x8C, u16 bitfield]``. ch 1 ``[1, arm]`` -> ``[0x81, success, armed]``;
``[2]`` -> ``[0x82, success, recovered]``; ``[3]`` emergency stop and ``[4]`` emergency-stop
watchdog (no reply). Replies set the high bit of the command, as the firmware does.
"""

from __future__ import annotations

import struct

from drivers.sim.emulators.crtp.crtp import SUPERVISOR, Packet
from drivers.sim.emulators.crtp.platform_port import recover
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie

CMD_ARM, CMD_RECOVER, CMD_ESTOP, CMD_ESTOP_WATCHDOG, CMD_GET_STATE = 0x01, 0x02, 0x03, 0x04, 0x0C


class SupervisorPort:
    """Port 9 handler."""

    port = SUPERVISOR

    def __init__(self, cf: EmulatedCrazyflie) -> None:
        self.cf = cf
        self.arm_requests = 0

    def handle(self, pk: Packet) -> list[Packet]:
        if not pk.data:
            return []
        cmd, fw = pk.data[0], self.cf.drone.firmware
        if pk.channel == 0 and cmd == CMD_GET_STATE:
            return [
                Packet(SUPERVISOR, 0, struct.pack("<BH", 0x80 | cmd, self.cf.supervisor_bits()))
            ]
        if pk.channel != 1:
            return []
        if cmd == CMD_ARM and len(pk.data) >= 2:
            self.arm_requests += 1
            want = bool(pk.data[1])
            ok = not fw.crashed or not want
            fw.arm(want)
            return [Packet(SUPERVISOR, 1, bytes((0x80 | cmd, int(ok), int(fw.armed))))]
        if cmd == CMD_RECOVER:
            ok = recover(self.cf)
            return [Packet(SUPERVISOR, 1, bytes((0x80 | cmd, int(ok), int(ok))))]
        if cmd in (CMD_ESTOP, CMD_ESTOP_WATCHDOG):
            fw.emergency_stop()
        return []
