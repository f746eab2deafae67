"""Rig files: what a mission flies on (link, control loop, sensors, world, faults).

``load_rig(path, overrides)`` validates a rig file (every problem located as
``file:line:col: message``, unknown keys with a "did you mean"), applies ``--set`` overrides
and returns a :class:`Rig`; ``Rig.make_platform(clock, seed)`` builds the platform the runner
drives. ``rigs/sim.yaml`` documents every setting; :data:`RIG_SCHEMA` is the source of truth.
"""

from __future__ import annotations

import os
from typing import Any

from drivers.config_schema import (
    ConfigError,
    Field,
    load_yaml_file,
)
from drivers.config_schema import (
    apply_overrides as _apply,
)

__all__ = ["ConfigError", "Rig", "RIG_SCHEMA", "apply_overrides", "load_rig", "REPO_ROOT"]

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_RIG = os.path.join(REPO_ROOT, "rigs", "sim.yaml")


def _m(children: dict[str, Field], doc: str = "") -> Field:
    return Field("map", children=children, doc=doc)


def _f(kind: str, default: Any, doc: str, **kw: Any) -> Field:
    return Field(kind, default, doc, **kw)


def _fault(doc: str, **params: Field) -> Field:
    return _m(
        {
            "at_s": _f(
                "float", None, "mission time to fire (null: not scheduled)", nullable=True, min=0.0
            ),
            "duration_s": _f(
                "float", None, "clear after this long (null: never)", nullable=True, min=0.0
            ),
            **params,
        },
        doc,
    )


RIG_SCHEMA = _m(
    {
        "name": _f("str", "sim", "rig name (shown in logs)"),
        "link": _f(
            "choice",
            "sim",
            "link kind: sim (in-process simulator) or crazyflie (cflib: radio, usb, udp)",
            choices=("sim", "crazyflie"),
        ),
        "world": _m(
            {
                "path": _f(
                    "str", "../worlds/warehouse.yaml", "world file (relative to this rig file)"
                ),
                "scan_pallet": _f(
                    "str", None, "override the world's scan_pallet (e.g. 2B)", nullable=True
                ),
            }
        ),
        "clock": _m(
            {
                "mode": _f(
                    "choice",
                    "lockstep",
                    "lockstep (SimClock) or realtime (WallClock)",
                    choices=("lockstep", "realtime"),
                ),
                "realtime_factor": _f(
                    "float", 1.0, "realtime mode: mission seconds per wall second", min=0.01
                ),
            }
        ),
        "control": _m(
            {
                "rate_hz": _f("float", 100.0, "Vehicle control loop rate", min=1.0, max=1000.0),
                "setpoint_mode": _f(
                    "choice",
                    "velocity",
                    "set-points sent to the drone",
                    choices=("position", "velocity"),
                ),
                "max_speed_mps": _f("float", 1.0, "speed limit of every reference", min=0.01),
                "accel_mps2": _f("float", 1.0, "acceleration limit of every reference", min=0.01),
                "yaw_rate_dps": _f("float", 90.0, "yaw-rate limit of the reference", min=1.0),
                "yaw_accel_dps2": _f("float", 180.0, "yaw acceleration limit", min=1.0),
                "position_tolerance_m": _f(
                    "float", 0.05, "default goal position tolerance", min=0.0
                ),
                "yaw_tolerance_deg": _f("float", 15.0, "default goal yaw tolerance", min=0.0),
                "settle_time_s": _f(
                    "float", 0.3, "time inside tolerances to count as settled", min=0.0
                ),
                "lead_s": _f(
                    "float", 0.5, "position mode: reference lead (s) to cancel lag", min=0.0
                ),
                "velocity_kp": _f(
                    "float", 2.5, "velocity mode: position error gain (1/s)", min=0.0
                ),
                "velocity_lead_s": _f(
                    "float",
                    0.25,
                    "feed-forward v_ref + lead * a_ref (x, y): firmware velocity-loop lag (s)",
                    min=0.0,
                    max=2.0,
                ),
                "velocity_lead_z_s": _f(
                    "float", 0.2, "feed-forward v_ref + lead * a_ref (z) (s)", min=0.0, max=2.0
                ),
                "yaw_kp": _f("float", 3.0, "velocity mode: yaw error gain (1/s)", min=0.0),
                "pose_source": _f(
                    "choice", "mocap", "pose the Vehicle reports", choices=("mocap", "onboard")
                ),
                "link_stale_s": _f("float", 0.5, "link unhealthy after this silence", min=0.0),
                "mocap_stale_s": _f("float", 0.1, "mocap unhealthy after this silence", min=0.0),
                "camera_stale_s": _f("float", 1.0, "camera unhealthy after this silence", min=0.0),
                "auto_arm": _f("bool", True, "takeoff arms the motors if needed"),
                "landed_height_m": _f("float", 0.04, "touch-down height above take-off", min=0.0),
                "low_battery_v": _f("float", 3.2, "battery.low below this voltage", min=0.0),
            }
        ),
        "sim": _m(
            {
                "physics_rate_hz": _f(
                    "float", 500.0, "physics step rate (multiple of 100)", min=100.0, max=5000.0
                ),
                "start_m": _f("vec", [0.0, 0.0, 0.0], "start position (m)", length=3),
                "start_yaw_deg": _f("float", 0.0, "start yaw (deg)"),
                "shutdown_max_s": _f(
                    "float", 30.0, "shutdown: simulate at most this long to land", min=0.0
                ),
                "params": Field(
                    "dict", {}, "overrides of drivers/sim/crazyflie_params.py", item=Field("float")
                ),
                "telemetry_rate_hz": _f("float", 100.0, "link telemetry rate", min=1.0),
                "link_loss_probability": _f(
                    "float", 0.0, "probability of losing one packet", min=0.0, max=1.0
                ),
            }
        ),
        "crazyflie": _m(
            {
                "uri": _f(
                    "str", "radio://0/80/2M/E7E7E7E7E7", "cflib URI (radio://, usb://, udp://)"
                ),
                "sitl": _f("bool", False, "start the CRTP emulator in-process (uri ignored)"),
                "sitl_world": _f("bool", True, "sitl: the simulated drone collides with the world"),
                "pose_source": _f(
                    "choice",
                    "mocap",
                    "pose forwarded to the drone: mocap (drivers/mocap.py), sitl, none",
                    choices=("mocap", "sitl", "none"),
                ),
                "params": Field(
                    "dict",
                    {
                        "stabilizer.estimator": 2.0,
                        "stabilizer.controller": 1.0,
                        "locSrv.extPosStdDev": 0.01,
                        "locSrv.extQuatStdDev": 4.5e-3,
                    },
                    "firmware parameters written after connecting",
                    item=Field("float"),
                ),
                "log": _m(
                    {
                        "pose_rate_hz": _f(
                            "float", 100.0, "stateEstimate pose+velocity", min=1.0, max=100.0
                        ),
                        "status_rate_hz": _f(
                            "float", 50.0, "quaternion, battery, supervisor", min=1.0, max=100.0
                        ),
                        "imu_rate_hz": _f("float", 0.0, "gyro+acc (0: off)", min=0.0, max=100.0),
                    }
                ),
                "link_timeout_s": _f("float", 0.5, "link lost after this silence", min=0.05),
                "connect_timeout_s": _f("float", 10.0, "give up connecting after", min=0.5),
                "shutdown_max_s": _f(
                    "float", 15.0, "at shutdown, wait at most this to land", min=0.0
                ),
                "toc_cache_dir": _f(
                    "str", None, "cflib TOC cache (null: a temp folder)", nullable=True
                ),
            }
        ),
        "mocap": _m(
            {
                "type": _f(
                    "choice",
                    "vicon",
                    "motioncapture system (drivers/mocap.py; mock: static test poses)",
                    choices=("vicon", "optitrack", "qualisys", "vrpn", "mock"),
                ),
                "host": _f("str", "127.0.0.1", "mocap server host name or address"),
                "rigid_body": _f("str", "cf", "rigid-body name of the drone (x axis = front)"),
                "rate_hz": _f("float", 100.0, "nominal frame rate (drop accounting)", min=1.0),
                "stale_s": _f("float", 0.1, "driver reports stale after this silence", min=0.0),
                "up_axis": _f(
                    "choice",
                    "z",
                    "up axis the server streams (y: converted to z-up)",
                    choices=("z", "y"),
                ),
                "freeze_detect": _f("bool", True, "bit-identical repeated frames are stale"),
                "params": Field(
                    "dict", {}, "extra motioncapture.connect parameters", item=Field("str")
                ),
            },
            "real motion capture (link: crazyflie with crazyflie.pose_source: mocap)",
        ),
        "aideck": _m(
            {
                "enabled": _f(
                    "bool", False, "stream the AI-deck camera (drivers/aideck_stream.py)"
                ),
                "host": _f("str", "127.0.0.1", "deck address (its own access point: 192.168.4.1)"),
                "port": _f("int", 5000, "deck TCP port", min=1, max=65535),
                "format": _f(
                    "choice",
                    "raw",
                    "what the deck firmware (or emulator) sends; both decode",
                    choices=("raw", "jpeg"),
                ),
                "output": _f(
                    "choice",
                    "bayer",
                    "frame image: bayer (as the sim camera) or bgr",
                    choices=("bayer", "bgr"),
                ),
                "white_balance": _f(
                    "vec",
                    None,
                    "B, G, R factors for bgr (null: sensors.camera.white_balance)",
                    length=3,
                    nullable=True,
                ),
                "reconnect_initial_s": _f("float", 0.25, "first reconnect back-off", min=0.01),
                "reconnect_max_s": _f("float", 5.0, "back-off doubles up to this", min=0.01),
                "connect_timeout_s": _f("float", 2.0, "TCP connect time-out", min=0.1),
                "idle_timeout_s": _f("float", 3.0, "reconnect after this silence", min=0.1),
                "emulator": _f(
                    "bool", False, "start drivers/sim/aideck_emulator on 127.0.0.1 (port 0: free)"
                ),
            },
            "AI-deck camera over WiFi (CPX over TCP)",
        ),
        "sensors": _m(
            {
                "mocap": _m(
                    {
                        "enabled": _f("bool", True, "simulate a mocap system"),
                        "rate_hz": _f("float", 100.0, "frame rate", min=1.0),
                        "position_noise_std_m": _f(
                            "float", 3e-5, "position noise per axis", min=0.0
                        ),
                        "orientation_noise_std_deg": _f(
                            "float", 0.05, "orientation noise", min=0.0
                        ),
                        "latency_s": _f("float", 0.005, "capture-to-delivery latency", min=0.0),
                        "dropout_probability": _f(
                            "float", 0.0, "probability of losing a frame", min=0.0, max=1.0
                        ),
                    }
                ),
                "onboard": _m(
                    {
                        "yaw_bias_deg": _f("float", 3.0, "onboard yaw minus true yaw (magnitude)"),
                        "yaw_bias_wander_deg": _f(
                            "float", 1.0, "slow wander of that bias (std)", min=0.0
                        ),
                        "velocity_noise_mps": _f(
                            "float", 0.005, "velocity estimate noise", min=0.0
                        ),
                        "drift_mps_per_sqrt_s": _f(
                            "float", 0.05, "position drift without mocap", min=0.0
                        ),
                    }
                ),
                "camera": _m(
                    {
                        "rate_hz": _f("float", 15.0, "frame rate (AI-deck: 12-17 fps)", min=0.1),
                        "latency_s": _f("float", 0.05, "capture-to-delivery latency", min=0.0),
                        "renderer": _f("str", "none", "registered renderer name, or none"),
                        "fov_deg": _f(
                            "float", 87.0, "horizontal field of view (approx.)", min=10.0, max=170.0
                        ),
                        "white_balance": _f(
                            "vec", [1.0, 1.0, 1.0], "B, G, R white-balance factors", length=3
                        ),
                    }
                ),
            }
        ),
        "wind": _m(
            {
                "mean_mps": _f("vec", [0.0, 0.0, 0.0], "mean wind (m/s, world frame)", length=3),
                "gust_std_mps": _f("float", 0.0, "gust strength (std per axis)", min=0.0),
                "gust_time_constant_s": _f("float", 2.0, "gust correlation time", min=0.01),
            }
        ),
        "battery": _m(
            {
                "initial_soc": _f(
                    "float", 1.0, "state of charge at start (0..1)", min=0.0, max=1.0
                ),
                "capacity_mah": _f("float", 250.0, "capacity", min=1.0),
            }
        ),
        "faults": _m(
            {
                "link_drop": _fault("the radio link goes down"),
                "mocap_freeze": _fault("the mocap server repeats its last frame"),
                "mocap_drop": _fault(
                    "mocap frames are lost",
                    probability=_f("float", 1.0, "loss probability", min=0.0, max=1.0),
                ),
                "camera_stall": _fault("the camera stops delivering frames"),
                "battery_sag": _fault(
                    "the battery voltage drops",
                    drop_v=_f("float", 0.5, "extra voltage drop (V)", min=0.0),
                ),
                "gust": _fault(
                    "a wind gust", speed_mps=_f("vec", [1.0, 0.0, 0.0], "gust wind (m/s)", length=3)
                ),
            }
        ),
    }
)


def _policy(action: str, grace_s: float, hold_s: float, doc: str) -> Field:
    from drivers.safety import ACTIONS

    return _m(
        {
            "action": _f("choice", action, "what the supervisor does", choices=tuple(ACTIONS)),
            "grace_s": _f("float", grace_s, "the tree keeps control this long first", min=0.0),
            "hold_s": _f("float", hold_s, "hold time before landing (hold actions)", min=0.0),
        },
        doc,
    )


SAFETY_SCHEMA = _m(
    {
        "enabled": _f("bool", True, "check faults every tick (off: only land at the end)"),
        "land_speed_mps": _f("float", 0.3, "descent speed of a supervisor landing", min=0.05),
        "return_speed_mps": _f("float", 0.5, "speed of return flights", min=0.05),
        "max_recovery_s": _f(
            "float", 30.0, "recovery flight limit; then the motors are cut", min=1.0
        ),
        "battery_low_v": _f("float", 3.3, "battery_low below this filtered voltage", min=0.0),
        "battery_critical_v": _f(
            "float", 3.1, "battery_critical below this filtered voltage", min=0.0
        ),
        "geofence": _m(
            {
                "enabled": _f("bool", True, "check the geofence box"),
                "min_m": _f("vec", [-1.5, -3.0, -0.5], "box corner x;y;z min (m)", length=3),
                "max_m": _f("vec", [9.2, 3.0, 2.5], "box corner x;y;z max (m)", length=3),
                "margin_m": _f("float", 0.3, "return this far inside the box", min=0.0),
            }
        ),
        "policies": _m(
            {
                "crash": _policy("motors_off", 0.0, 0.0, "crash or motors stopped"),
                "battery_critical": _policy("land", 0.0, 0.0, "battery critical"),
                "link_lost": _policy("hold_then_land", 0.0, 1.0, "no telemetry"),
                "geofence": _policy("return_inside_and_land", 0.0, 0.5, "geofence breach"),
                "mocap_lost": _policy("hold_then_land", 1.0, 0.5, "mocap stale or dropped"),
                "battery_low": _policy("return_and_land", 2.0, 0.0, "battery low"),
                "camera_stalled": _policy("report", 0.0, 0.0, "camera stalled"),
                "operator_interrupt": _policy("land", 0.0, 0.0, "SIGINT / SIGTERM"),
                "leaf_exception": _policy("land", 0.0, 0.0, "exception in a leaf"),
            }
        ),
    },
    "the safety supervisor (docs/safety.md)",
)
RIG_SCHEMA.children["safety"] = SAFETY_SCHEMA


def apply_overrides(config: dict, overrides: dict[str, str] | None) -> dict:
    """Apply ``--set dotted.key=value`` overrides to validated rig data (type-checked).

    Raises :class:`ConfigError` (all problems at once; unknown keys with "did you mean").
    """
    return _apply(config, overrides, RIG_SCHEMA)


class Rig:
    """A validated rig: ``kind`` (link kind), ``data`` (settings), ``path`` (file)."""

    def __init__(self, data: dict, path: str) -> None:
        self.data, self.path = data, path
        self.kind: str = data["link"]

    @property
    def realtime_factor(self) -> float | None:
        """Mission seconds per wall second when the rig asks for real time, else None."""
        clock = self.data.get("clock", {})
        return float(clock.get("realtime_factor", 1.0)) if clock.get("mode") == "realtime" else None

    def load_world(self) -> Any:
        """The rig's world (:class:`drivers.sim.world.World`), with ``world.scan_pallet``
        (which pallet side stands at the scan slot) applied."""
        from drivers.sim.world import load_world

        overrides = {}
        if self.data["world"]["scan_pallet"] is not None:
            overrides["scan_pallet"] = self.data["world"]["scan_pallet"]
        return load_world(self.world_path, overrides)

    @property
    def world_path(self) -> str:
        """The world file, resolved relative to the rig file (then cwd, then the repo)."""
        p = self.data["world"]["path"]
        if os.path.isabs(p):
            return p
        for base in (os.path.dirname(os.path.abspath(self.path)), os.getcwd(), REPO_ROOT):
            candidate = os.path.normpath(os.path.join(base, p))
            if os.path.exists(candidate):
                return candidate
        return os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(self.path)), p))

    def make_platform(self, clock: Any, seed: int) -> Any:
        """Build the platform for this rig (all randomness derived from ``seed``)."""
        if self.kind == "sim":
            from drivers.sim.platform import SimPlatform

            return SimPlatform.from_rig(self, clock, seed)
        if self.kind == "crazyflie":
            from drivers.crazyflie_platform import CrazyfliePlatform

            return CrazyfliePlatform.from_rig(self, clock, seed)
        raise ConfigError([f"{self.path}:1:1: link '{self.kind}' is not available"])


def load_rig(path: str | None = None, overrides: dict[str, str] | None = None) -> Rig:
    """Load and validate a rig file (None -> the repo's ``rigs/sim.yaml``), apply overrides.

    The world file is validated too, so a bad world is reported before anything flies.
    """
    path = path or DEFAULT_RIG
    data = load_yaml_file(path, RIG_SCHEMA)
    data = apply_overrides(data, overrides)
    rig = Rig(data, path)
    if rig.kind == "sim":
        rig.load_world()  # world checks (and the scan pallet) before anything flies
    return rig
