"""Settings of the Vehicle's reference generator and control loop (from the rig's ``control``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class VehicleConfig:
    """How the Vehicle turns motion requests into set-points.

    Defaults follow FACTS.md: 100 Hz loop, goto thresholds 3 cm / 15 deg of the reference
    study would be ``position_tolerance_m=0.03``; the default here is a little looser.
    """

    rate_hz: float = 100.0
    setpoint_mode: str = "velocity"  # "velocity" | "position"
    max_speed_mps: float = 1.0
    accel_mps2: float = 1.0
    yaw_rate_dps: float = 90.0
    yaw_accel_dps2: float = 180.0
    position_tolerance_m: float = 0.05
    yaw_tolerance_deg: float = 15.0
    settle_time_s: float = 0.3
    lead_s: float = 0.5  # position mode: send ref + lead_s * ref velocity (1 / firmware Kp)
    velocity_kp: float = 2.5  # velocity mode: v_sp = v_ff + kp * (p_ref - p)
    # Both modes: feed-forward velocity v_ff = v_ref + lead * a_ref, lead ~ the lag of the
    # firmware velocity loop (xy: 1/(g * 25 deg/(m/s)) ~ 0.23 s + attitude 0.05 s; z: 0.19 s
    # + motor 0.03 s), so the drone's actual velocity follows v_ref (no lag, no overshoot).
    velocity_lead_s: float = 0.25
    velocity_lead_z_s: float = 0.2
    yaw_kp: float = 3.0  # velocity mode: yaw_rate_sp = r_ref + kp * wrap(yaw_ref - yaw)
    pose_source: str = "mocap"  # "mocap" | "onboard"
    link_stale_s: float = 0.5
    mocap_stale_s: float = 0.1
    camera_stale_s: float = 1.0
    auto_arm: bool = True
    landed_height_m: float = 0.04
    low_battery_v: float = 3.2
    path_facing_min_distance_m: float = 0.1

    @property
    def period_s(self) -> float:
        """Control period in seconds."""
        return 1.0 / self.rate_hz

    @property
    def yaw_tolerance_rad(self) -> float:
        """Yaw tolerance in radians."""
        return math.radians(self.yaw_tolerance_deg)

    @classmethod
    def from_dict(cls, data: dict) -> VehicleConfig:
        """Build from a rig's ``control`` mapping (unknown keys are ignored)."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names and v is not None})
