"""Plain value types of the Vehicle API (poses, velocities, battery, health, camera frames).

All lengths in metres, angles in radians, times in seconds of mission time.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any


class YawMode(enum.IntEnum):
    """How a motion request chooses its yaw (Aerostack2 numbering)."""

    KEEP_YAW = 0  # keep the yaw the vehicle was commanded to hold at activation
    PATH_FACING = 1  # face the direction of travel (computed at activation)
    FIXED_YAW = 2  # use the given yaw angle (rad)


class FlightState(str, enum.Enum):
    """What the vehicle is doing, as a leaf sees it."""

    LANDED = "landed"
    TAKING_OFF = "taking_off"
    FLYING = "flying"
    LANDING = "landing"
    CRASHED = "crashed"
    EMERGENCY = "emergency"  # motors cut by emergency_stop (or a firmware watchdog)


@dataclass(frozen=True, slots=True)
class Pose:
    """Position (m) and yaw (rad) in the world frame, with the quaternion (qx, qy, qz, qw).

    ``t_s`` is the mission time the pose was measured; ``source`` says where it came from
    (``mocap`` or ``onboard``).
    """

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    t_s: float = 0.0
    source: str = "none"

    @property
    def position(self) -> tuple[float, float, float]:
        """The position as an (x, y, z) tuple in metres."""
        return (self.x_m, self.y_m, self.z_m)


@dataclass(frozen=True, slots=True)
class Velocity:
    """World-frame velocity in m/s and yaw rate in rad/s."""

    vx_mps: float = 0.0
    vy_mps: float = 0.0
    vz_mps: float = 0.0
    yaw_rate_radps: float = 0.0

    @property
    def speed_mps(self) -> float:
        """The magnitude of the 3-D velocity."""
        return (self.vx_mps**2 + self.vy_mps**2 + self.vz_mps**2) ** 0.5


@dataclass(frozen=True, slots=True)
class BatteryState:
    """Battery voltage (under load, as measured), state-of-charge estimate (0..100, corrected
    for the load sag in flight), low flag, and the load sag (V) the estimate added back."""

    voltage_v: float
    percent: float
    low: bool
    sag_v: float = 0.0


@dataclass(frozen=True, slots=True)
class SourceHealth:
    """Health of one data source (link telemetry, mocap, camera).

    ``age_s`` is the time since the last *new* sample (inf if none yet); ``rate_hz`` is the
    measured sample rate over the last second; ``drops`` counts samples expected but missed;
    ``healthy`` is ``age_s <= stale_after_s`` (and the source is connected).
    """

    name: str
    connected: bool
    age_s: float
    rate_hz: float
    drops: int
    samples: int
    healthy: bool


@dataclass(frozen=True, slots=True)
class HealthReport:
    """Health of every source at one instant."""

    t_s: float
    link: SourceHealth
    mocap: SourceHealth
    camera: SourceHealth

    @property
    def all_healthy(self) -> bool:
        """True if link and mocap are healthy (the camera is optional for flight)."""
        return self.link.healthy and self.mocap.healthy


@dataclass(frozen=True, slots=True)
class CameraFrame:
    """One camera image with its capture time and the vehicle pose at capture.

    ``image`` is whatever the camera source produces (a numpy array for the AI-deck and the
    simulated renderer: 244 x 324 Bayer or BGR).
    """

    image: Any
    t_s: float
    pose: Pose
    index: int = 0
    meta: dict = field(default_factory=dict)
