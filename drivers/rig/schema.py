"""The rig schema: every setting a rig file may hold, its type, default and meaning.

One declaration per setting. The ``control`` section comes from
:class:`drivers.vehicle.config.VehicleConfig` and ``safety`` from
:class:`drivers.safety.policies.SafetyConfig`, whose fields are declared with
:func:`drivers.settings.setting`; the others are declared here. ``btrun rig settings`` and
``docs/rig-settings.md`` list them all.
"""

from __future__ import annotations

from typing import Any

from drivers.safety.policies import safety_schema
from drivers.settings import Field, schema_of
from drivers.sim.crazyflie_params import (
    crazyflie_integer_params,
    crazyflie_param_limits,
    crazyflie_params,
)
from drivers.vehicle.config import VehicleConfig


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


#: Each simulator parameter a rig's ``sim.params`` may set, with its range
#: (:data:`~drivers.sim.crazyflie_params.crazyflie_param_limits`); the rig loader checks the
#: keys and values against these (``sim.params`` stays a plain mapping of overrides).
SIM_PARAMS: dict[str, Field] = {
    name: Field(
        "int" if name in crazyflie_integer_params else "float",
        crazyflie_params[name],
        doc,
        min=lo,
        max=hi,
    )
    for name, (lo, hi, doc) in crazyflie_param_limits.items()
}


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
                    "str",
                    "../worlds/warehouse.yaml",
                    "world file (relative to this rig file; given by --set: to the working folder)",
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
        "control": schema_of(VehicleConfig, "the Vehicle's reference generator and control loop"),
        "sim": _m(
            {
                "physics_rate_hz": _f(
                    "float", 500.0, "physics step rate (multiple of 100)", min=100.0, max=5000.0
                ),
                "start_m": _f("vec", [0.0, 0.0, 0.0], "start position (m)", length=3),
                "start_yaw_deg": _f("float", 0.0, "start yaw (deg)", min=-360.0, max=360.0),
                "shutdown_max_s": _f(
                    "float",
                    30.0,
                    "shutdown: simulate at most this long to land",
                    min=0.0,
                    max=600.0,
                ),
                "params": Field(
                    "dict",
                    {},
                    "overrides of drivers/sim/crazyflie_params.py (names and ranges: `sim.params`)",
                    item=Field("float"),
                ),
                "telemetry_rate_hz": _f("float", 100.0, "link telemetry rate", min=1.0, max=1000.0),
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
                    "pose forwarded to the drone: mocap (drivers/crazyflie/mocap.py), sitl, none",
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
                "link_timeout_s": _f(
                    "float", 0.5, "link lost after this silence", min=0.05, max=30.0
                ),
                "connect_timeout_s": _f(
                    "float", 10.0, "give up connecting after", min=0.5, max=600.0
                ),
                "shutdown_max_s": _f(
                    "float", 15.0, "at shutdown, wait at most this to land", min=0.0, max=600.0
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
                    "motioncapture system (drivers/crazyflie/mocap.py; mock: static test poses)",
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
                    "bool", False, "stream the AI-deck camera (drivers/crazyflie/aideck_stream.py)"
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
                    "bool",
                    False,
                    "start drivers/sim/emulators/aideck.py on 127.0.0.1 (port 0: free)",
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
        "perception": _m(
            {
                "min_view_change_px": _f(
                    "float",
                    8.0,
                    "the perception leaves render and detect a camera frame only once the view "
                    "moved this many pixels since the last frame they processed (image centre "
                    "and corners at view_depth_m; perception/frame_gate.py); 0: every frame",
                    min=0.0,
                ),
                "max_frame_gap_s": _f(
                    "float",
                    0.3,
                    "process a frame anyway once this long has passed since the last one",
                    min=0.0,
                ),
                "view_depth_m": _f(
                    "float",
                    0.4,
                    "distance in front of the camera at which the view change is measured",
                    min=0.01,
                ),
            },
            "which camera frames the perception leaves process (docs/performance.md)",
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
                # A Crazyflie draws about 2 A hovering: below 50 mAh that is beyond 40C, more
                # than a LiPo of that size gives (its voltage sags to the cut-off while it still
                # reads half full, and the energy checks' measured rate is far too low)
                "capacity_mah": _f(
                    "float", 250.0, "capacity (a Crazyflie hovers on 50 mAh or more)", min=50.0
                ),
                "charge_current_a": _f(
                    "float",
                    0.5,
                    "charging current on a charging pad (ChangeBattery mode=charge)",
                    min=0.01,
                ),
                "swap_soc": _f(
                    "float",
                    1.0,
                    "state of charge of a fresh battery (ChangeBattery mode=swap)",
                    min=0.0,
                    max=1.0,
                ),
            }
        ),
        "guard": _m(
            {
                "enabled": _f(
                    "bool",
                    True,
                    "btrun run starts a guard process that owns the Crazyflie link and lands "
                    "the drone if the mission process hangs, crashes or is killed (docs/safety.md)",
                ),
                "silence_s": _f(
                    "float",
                    0.5,
                    "take over after the mission process is silent this long, drone airborne",
                    min=0.05,
                    max=60.0,
                ),
                "rest_silence_s": _f(
                    "float",
                    10.0,
                    "the same with the drone on the ground, and for a simulated drone",
                    min=0.5,
                    max=3600.0,
                ),
                "tick_grace_s": _f(
                    "float",
                    2.0,
                    "take over once a tick ran 2 x its watchdog budget + this (it never returned)",
                    min=0.0,
                    max=3600.0,
                ),
                "land_speed_mps": _f(
                    "float", 0.3, "the guard's landing: descent speed", min=0.05, max=2.0
                ),
                "land_max_s": _f(
                    "float", 15.0, "the guard's landing: give up after", min=1.0, max=120.0
                ),
            },
            "the guard process (drivers/guard): what outlives the mission process",
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
                "camera_disconnect": _fault("the camera's stream disconnects (AI-deck offline)"),
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


RIG_SCHEMA.children["safety"] = safety_schema()


def settings_markdown() -> str:
    """Every rig setting as a Markdown page (``docs/rig-settings.md`` is this text)."""
    lines = [
        "# Rig settings",
        "",
        "Generated from the rig schema (`btrun rig settings --markdown > docs/rig-settings.md`;",
        "a test fails when this page is out of date). A rig file states only what differs from",
        "these defaults; `--set dotted.key=value` overrides any of them for one run.",
        "Units are in the names: `_m` metres, `_s` seconds, `_hz` hertz, `_deg` degrees,",
        "`_mps` m/s, `_v` volts.",
    ]

    def section(spec: Field, prefix: str) -> None:
        leaves = [(k, f) for k, f in spec.children.items() if f.kind != "map"]
        maps = [(k, f) for k, f in spec.children.items() if f.kind == "map"]
        if leaves:
            lines.extend(["", f"## `{prefix or '(top level)'}`", ""])
            if spec.doc:
                lines.extend([spec.doc, ""])
            lines.extend(["| key | type | default | meaning |", "|---|---|---|---|"])
            for key, f in leaves:
                kind = f.kind if f.kind != "choice" else " \\| ".join(map(str, f.choices))
                if f.min is not None and f.max is not None:
                    kind += f" {f.min:g}..{f.max:g}"
                elif f.min is not None:
                    kind += f" >= {f.min:g}"
                doc = f.doc.replace("|", "\\|")
                lines.append(f"| `{key}` | {kind} | `{f.default!r}` | {doc} |")
        if prefix == "sim":
            lines.extend(["", "## `sim.params`", ""])
            lines.extend(
                [
                    "Overrides of the simulator's parameters (drivers/sim/crazyflie_params.py);",
                    "any other name is refused, and so is a value out of its range. Together,",
                    "the motors must lift more than the weight, each time constant be at least",
                    "one physics step (1 / `sim.physics_rate_hz`), `tumble_tilt_deg` exceed",
                    "`max_tilt_deg` and the watchdog level the drone before it stops the motors.",
                    "",
                    "| key | type | default | meaning |",
                    "|---|---|---|---|",
                ]
            )
            for key, f in SIM_PARAMS.items():
                doc = f.doc.replace("|", "\\|")
                lines.append(
                    f"| `{key}` | {f.kind} {f.min:g}..{f.max:g} | `{f.default!r}` | {doc} |"
                )
        for key, f in maps:
            section(f, f"{prefix}.{key}" if prefix else key)

    section(RIG_SCHEMA, "")
    return "\n".join(lines) + "\n"
