"""Port 7 (generic commander) and port 3 (legacy RPYT commander) -> the sim firmware.

Port 7 ch 0 (no reply): type 7 position ``<ffff`` (x, y, z m, yaw deg), type 8 velocity world
``<ffff`` (vx, vy, vz m/s, yaw rate deg/s, counter-clockwise positive: the firmware's
``velocityDecoder`` takes it as is, and cflib's ``MotionCommander.start_turn_left`` sends a
positive rate), type 1 the pre-protocol-9 velocity world (``legacyVelocityDecoder`` negates
the rate: clockwise positive; cflib negates it when it talks to firmware <= 8), type 0 stop.
Port 7 ch 1 type 0 ``notify_setpoint_stop`` (``<BI``, remain-valid ms) is counted and hands
the commander back to the high-level commander (:mod:`.high_level`), which every low-level
set-point pre-empts. Port 3 ``<fffH`` with zero
thrust (what ``Crazyflie.close_link`` sends) stops the motors; attitude flight is not modelled.
Every set-point feeds the firmware's commander watchdog (level after 0.5 s, off after 2 s).
"""

from __future__ import annotations

import math
import struct

from drivers.sim.emulators.crtp.crtp import COMMANDER, COMMANDER_GENERIC, Packet
from drivers.sim.emulators.crtp.high_level import HighLevelPort
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie
from drivers.sim.firmware import POSITION, STOP, VELOCITY

TYPE_STOP, TYPE_VELOCITY_WORLD_LEGACY, TYPE_POSITION, TYPE_VELOCITY_WORLD = 0, 1, 7, 8


class SetpointPort:
    """Port 7 handler (also registered for port 3)."""

    port = COMMANDER_GENERIC

    def __init__(self, cf: EmulatedCrazyflie, high_level: HighLevelPort | None = None) -> None:
        self.cf = cf
        self.high_level = high_level
        self.unsupported_types: dict[int, int] = {}

    def _apply(self, mode: str, values: tuple[float, float, float, float]) -> None:
        cf = self.cf
        if not all(math.isfinite(v) for v in values):
            self.unsupported_types[-2] = self.unsupported_types.get(-2, 0) + 1
            return
        cf.setpoint_count += 1
        cf.last_setpoint = (mode, values)
        if self.high_level is not None:
            self.high_level.lowlevel_setpoint(cf.t_s)
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
                remain_ms = struct.unpack("<I", d[1:5])[0] if len(d) >= 5 else 0
                if self.high_level is not None:
                    self.high_level.notify_setpoint_stop(self.cf.t_s, remain_ms)
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
            if kind == TYPE_VELOCITY_WORLD_LEGACY:
                rate_dps = -rate_dps  # legacyVelocityDecoder: clockwise positive
            self._apply(VELOCITY, (vx, vy, vz, math.radians(rate_dps)))
        else:
            self.unsupported_types[kind] = self.unsupported_types.get(kind, 0) + 1
        return []
