"""Port 7 (generic commander) and port 3 (legacy RPYT commander) -> the sim firmware.

Port 7 ch 0 (no reply): type 7 position ``<ffff`` (x, y, z m, yaw deg), type 8 velocity world
``<ffff`` (vx, vy, vz m/s, yaw rate deg/s, counter-clockwise positive, as cflib's
``MotionCommander`` sends it), type 1 the pre-protocol-9 velocity world, type 0 stop.
Port 7 ch 1 type 0 ``notify_setpoint_stop`` (``<BI``) is counted. Port 3 ``<fffH`` with zero
thrust (what ``Crazyflie.close_link`` sends) stops the motors; attitude flight is not modelled.
Every set-point feeds the firmware's commander watchdog (level after 0.5 s, off after 2 s).
"""

from __future__ import annotations

import math
import struct

from drivers.sim.crtp_emulator.crtp import COMMANDER, COMMANDER_GENERIC, Packet
from drivers.sim.crtp_emulator.state import EmulatedCrazyflie
from drivers.sim.firmware import POSITION, STOP, VELOCITY

TYPE_STOP, TYPE_VELOCITY_WORLD_LEGACY, TYPE_POSITION, TYPE_VELOCITY_WORLD = 0, 1, 7, 8


class SetpointPort:
    """Port 7 handler (also registered for port 3)."""

    port = COMMANDER_GENERIC

    def __init__(self, cf: EmulatedCrazyflie) -> None:
        self.cf = cf
        self.unsupported_types: dict[int, int] = {}

    def _apply(self, mode: str, values: tuple[float, float, float, float]) -> None:
        cf = self.cf
        if not all(math.isfinite(v) for v in values):
            self.unsupported_types[-2] = self.unsupported_types.get(-2, 0) + 1
            return
        cf.setpoint_count += 1
        cf.last_setpoint = (mode, values)
        cf.drone.firmware.setpoint(cf.t_s, mode, values)

    def handle(self, pk: Packet) -> list[Packet]:
        d = pk.data
        if pk.port == COMMANDER:
            _, _, _, thrust = struct.unpack("<fffH", d[:14])
            if thrust == 0:
                self._apply(STOP, (0.0, 0.0, 0.0, 0.0))
            else:
                self.unsupported_types[-1] = self.unsupported_types.get(-1, 0) + 1
            return []
        if not d:
            return []
        if pk.channel == 1:
            if d[0] == 0:
                self.cf.notify_stop_count += 1
            return []
        if pk.channel != 0:
            return []
        kind = d[0]
        if kind == TYPE_STOP:
            self._apply(STOP, (0.0, 0.0, 0.0, 0.0))
        elif kind == TYPE_POSITION:
            x, y, z, yaw_deg = struct.unpack("<ffff", d[1:17])
            self._apply(POSITION, (x, y, z, math.radians(yaw_deg)))
        elif kind in (TYPE_VELOCITY_WORLD, TYPE_VELOCITY_WORLD_LEGACY):
            vx, vy, vz, rate_dps = struct.unpack("<ffff", d[1:17])
            self._apply(VELOCITY, (vx, vy, vz, math.radians(rate_dps)))
        else:
            self.unsupported_types[kind] = self.unsupported_types.get(kind, 0) + 1
        return []
