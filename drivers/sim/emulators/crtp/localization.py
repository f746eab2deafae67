"""Port 6 (localization): external position/pose from a mocap system -> the sim estimator.

ch 0: ``extpos`` ``<fff`` (x, y, z). ch 1 (generic): type 8 ``EXT_POSE`` ``<B fff ffff``
(x, y, z, qx, qy, qz, qw), type 9 packed poses (``<B`` then ``<B hhh I`` per drone, mm and a
compressed quaternion: only the arrival is used), type 3 emergency stop. No replies.
The simulated estimator models the effect of the fusion (it follows the truth while poses
keep arriving); the received values are kept in ``EmulatedCrazyflie.last_extpose``.
"""

from __future__ import annotations

import struct

from drivers.sim.emulators.crtp.crtp import LOCALIZATION, Packet
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie

EMERGENCY_STOP, EMERGENCY_STOP_WATCHDOG, EXT_POSE, EXT_POSE_PACKED = 3, 4, 8, 9


class LocalizationPort:
    """Port 6 handler."""

    port = LOCALIZATION

    def __init__(self, cf: EmulatedCrazyflie) -> None:
        self.cf = cf

    def _pose(self, values: tuple[float, ...]) -> None:
        cf = self.cf
        cf.last_extpose = values
        cf.extpose_count += 1
        cf.drone.estimator.external_pose(cf.t_s)

    def feed(
        self, x_m: float, y_m: float, z_m: float, quaternion: tuple[float, float, float, float]
    ) -> None:
        """A mocap frame handed to the firmware inside the emulator (no radio packet)."""
        self._pose((x_m, y_m, z_m, *quaternion))

    def handle(self, pk: Packet) -> list[Packet]:
        d = pk.data
        if pk.channel == 0:
            self._pose(struct.unpack("<fff", d[:12]))
        elif pk.channel == 1 and d:
            if d[0] == EXT_POSE:
                self._pose(struct.unpack("<fffffff", d[1:29]))
            elif d[0] == EXT_POSE_PACKED and len(d) >= 12:
                x, y, z = (v / 1000.0 for v in struct.unpack("<hhh", d[2:8]))
                self._pose((x, y, z))
            elif d[0] in (EMERGENCY_STOP, EMERGENCY_STOP_WATCHDOG):
                self.cf.drone.firmware.emergency_stop()
        return []
