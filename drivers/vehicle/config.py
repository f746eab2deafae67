"""Settings of the Vehicle's reference generator and control loop (from the rig's ``control``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.settings import from_settings, setting


@dataclass(frozen=True)
class VehicleConfig:
    """How the Vehicle turns motion requests into set-points (the rig's ``control:``).

    Each field is declared once, here: the rig schema's ``control`` section is generated from
    these declarations (:func:`drivers.settings.schema_of`).

    Defaults follow [firmware] and [study] (docs/references.md): 100 Hz loop, goto thresholds 3 cm / 15 deg of the reference
    study would be ``position_tolerance_m=0.03``; the default here is a little looser.
    """

    rate_hz: float = setting(100.0, "Vehicle control loop rate", min=1.0, max=1000.0)
    setpoint_mode: str = setting(
        "velocity", "set-points sent to the drone", choices=("position", "velocity")
    )
    max_speed_mps: float = setting(1.0, "speed limit of every reference", min=0.01)
    accel_mps2: float = setting(1.0, "acceleration limit of every reference", min=0.01)
    yaw_rate_dps: float = setting(90.0, "yaw-rate limit of the reference", min=1.0)
    yaw_accel_dps2: float = setting(180.0, "yaw acceleration limit", min=1.0)
    position_tolerance_m: float = setting(0.05, "default goal position tolerance", min=0.0)
    yaw_tolerance_deg: float = setting(15.0, "default goal yaw tolerance", min=0.0)
    settle_time_s: float = setting(0.3, "time inside tolerances to count as settled", min=0.0)
    # position mode: send ref + lead_s * ref velocity (1 / firmware Kp)
    lead_s: float = setting(0.5, "position mode: reference lead (s) to cancel lag", min=0.0)
    # velocity mode: v_sp = v_ff + kp * (p_ref - p)
    velocity_kp: float = setting(2.5, "velocity mode: position error gain (1/s)", min=0.0)
    # Both modes: feed-forward velocity v_ff = v_ref + lead * a_ref, lead ~ the lag of the
    # firmware velocity loop (xy: 1/(g * 25 deg/(m/s)) ~ 0.23 s + attitude 0.05 s; z: 0.19 s
    # + motor 0.03 s), so the drone's actual velocity follows v_ref (no lag, no overshoot).
    velocity_lead_s: float = setting(
        0.25,
        "feed-forward v_ref + lead * a_ref (x, y): firmware velocity-loop lag (s)",
        min=0.0,
        max=2.0,
    )
    velocity_lead_z_s: float = setting(
        0.2, "feed-forward v_ref + lead * a_ref (z) (s)", min=0.0, max=2.0
    )
    # velocity mode: yaw_rate_sp = r_ref + kp * wrap(yaw_ref - yaw)
    yaw_kp: float = setting(3.0, "velocity mode: yaw error gain (1/s)", min=0.0)
    pose_source: str = setting("mocap", "pose the Vehicle reports", choices=("mocap", "onboard"))
    link_stale_s: float = setting(0.5, "link unhealthy after this silence", min=0.0)
    mocap_stale_s: float = setting(0.1, "mocap unhealthy after this silence", min=0.0)
    camera_stale_s: float = setting(1.0, "camera unhealthy after this silence", min=0.0)
    auto_arm: bool = setting(True, "takeoff arms the motors if needed")
    landed_height_m: float = setting(0.04, "touch-down height above take-off", min=0.0)
    low_battery_v: float = setting(3.2, "battery.low below this voltage", min=0.0)
    max_altitude_m: float = setting(
        5.0, "motion requests above this height over the take-off point are refused", min=0.1
    )
    # not a rig setting: path-facing go-tos keep their yaw for shorter moves
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
        return from_settings(cls, data)
