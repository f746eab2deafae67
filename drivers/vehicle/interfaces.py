"""What the Vehicle needs from the things behind it: a link, a pose source and a camera.

Three small protocols, one per data path, so that each real implementation maps onto one
library:

* :class:`Link` - the radio link to the drone (cflib ``Crazyflie``: commander set-points on
  CRTP port 7, external pose on port 6, log blocks of ``stateEstimate.*`` and ``pm.vbat``,
  supervisor arming on port 9). The simulator implements it in :mod:`drivers.sim.sim_link`.
* :class:`PoseSource` - motion capture (``motioncapture.connect(...)``), or the simulated
  mocap in :mod:`drivers.sim.sensors`.
* :class:`CameraSource` - the AI-deck CPX image stream, or the simulated camera hook in
  :mod:`drivers.sim.camera`.

Every call is non-blocking. ``poll(now_s)`` returns what arrived since the last poll.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from drivers.vehicle.types import CameraFrame


@dataclass(frozen=True, slots=True)
class LinkTelemetry:
    """One telemetry sample from the drone (onboard state estimate, battery, flags).

    Mirrors the cflib log variables ``stateEstimate.x/y/z/vx/vy/vz/qx/qy/qz/qw``,
    ``pm.vbat`` and the supervisor info bits.
    """

    t_s: float
    x_m: float
    y_m: float
    z_m: float
    vx_mps: float
    vy_mps: float
    vz_mps: float
    yaw_rad: float
    quaternion: tuple[float, float, float, float]
    battery_v: float
    armed: bool
    motors_running: bool
    crashed: bool
    tumbled: bool = False


@dataclass(frozen=True, slots=True)
class PoseSample:
    """One motion-capture frame of the drone's rigid body (``t_s`` = capture time)."""

    t_s: float
    x_m: float
    y_m: float
    z_m: float
    quaternion: tuple[float, float, float, float]
    yaw_rad: float
    seq: int


class Link(Protocol):
    """The command and telemetry link to one drone."""

    @property
    def connected(self) -> bool:
        """True while the link is believed up (packets flow)."""

    def arm(self, armed: bool) -> bool:
        """Ask the drone to arm (True) or disarm (False); returns whether it was sent."""

    def send_position_setpoint(self, x_m: float, y_m: float, z_m: float, yaw_rad: float) -> None:
        """World-frame position set-point (CRTP port 7 type 7; the firmware takes degrees)."""

    def send_velocity_setpoint(
        self, vx_mps: float, vy_mps: float, vz_mps: float, yaw_rate_radps: float
    ) -> None:
        """World-frame velocity set-point (CRTP port 7 type 8)."""

    def send_stop_setpoint(self) -> None:
        """Stop the motors (CRTP port 7 type 0)."""

    def send_external_pose(
        self, x_m: float, y_m: float, z_m: float, quaternion: tuple[float, float, float, float]
    ) -> None:
        """Forward a mocap pose to the onboard estimator (CRTP port 6 ch 1, ``extpose``)."""

    def emergency_stop(self) -> None:
        """Cut the motors at once (supervisor emergency stop)."""

    def poll(self, now_s: float) -> list[LinkTelemetry]:
        """Telemetry samples received since the last poll (oldest first)."""

    def close(self) -> None:
        """Close the link."""


class PoseSource(Protocol):
    """A motion-capture stream."""

    def poll(self, now_s: float) -> list[PoseSample]:
        """Frames delivered since the last poll (oldest first)."""

    def expected_rate_hz(self) -> float:
        """The nominal frame rate (for drop accounting)."""


class CameraSource(Protocol):
    """A camera stream."""

    def poll(self, now_s: float) -> CameraFrame | None:
        """The newest frame delivered since the last poll, or None."""
