"""The simulator platform: world + simulated Crazyflie + mocap + camera + link + Vehicle.

Event loop of :meth:`SimPlatform.before_tick` (all on integer multiples of the periods, so
lock-step runs are exactly repeatable)::

    for each event time t_e <= t (mocap frame, camera frame, control step):
        drone.step_to(t_e)            # physics 500 Hz, firmware 100 Hz
        faults.update(t_e)
        mocap.capture / camera.capture
        vehicle.control_step(t_e)     # reads sources, sends a set-point over the link
    drone.step_to(t)
"""

from __future__ import annotations

import math
from typing import Any

from drivers.sim.camera import SimCamera
from drivers.sim.crazyflie_params import crazyflie_params
from drivers.sim.drone import SimCrazyflie, make_rng
from drivers.sim.estimator import OnboardEstimator
from drivers.sim.renderers import make_renderer
from drivers.sim.sensors import SimMocap
from drivers.sim.sim_link import SimLink
from drivers.sim.wind import WindModel
from drivers.sim.world import World
from drivers.vehicle.angles import quaternion_from_euler
from drivers.vehicle.config import VehicleConfig
from drivers.vehicle.faults import FaultHandler, FaultInjector
from drivers.vehicle.types import FlightState, Pose
from drivers.vehicle.vehicle import Vehicle


class _Periodic:
    __slots__ = ("period_s", "k", "next_s", "run")

    def __init__(self, period_s: float, run) -> None:
        self.period_s, self.k, self.next_s, self.run = period_s, 0, 0.0, run


class SimPlatform:
    """Implements :class:`drivers.vehicle.platform.Platform` on the in-process simulator."""

    def __init__(self, world: World | None, rig_data: dict, seed: int, clock: Any = None) -> None:
        self.rig_data, self.seed, self.clock, self.world = rig_data, seed, clock, world
        s, sensors = rig_data["sim"], rig_data["sensors"]
        params = dict(crazyflie_params)
        params["battery_initial_soc"] = rig_data["battery"]["initial_soc"]
        params["battery_capacity_mah"] = rig_data["battery"]["capacity_mah"]
        params["battery_charge_current_a"] = rig_data["battery"].get("charge_current_a", 0.5)
        params["battery_swap_soc"] = rig_data["battery"].get("swap_soc", 1.0)
        params.update(s["params"])
        self.params = params
        ob = sensors["onboard"]
        estimator = OnboardEstimator(
            make_rng(seed, "estimator"),
            ob["yaw_bias_deg"],
            ob["yaw_bias_wander_deg"],
            velocity_noise_mps=ob["velocity_noise_mps"],
            drift_mps_per_sqrt_s=ob["drift_mps_per_sqrt_s"],
        )
        w = rig_data["wind"]
        self.wind = WindModel(
            make_rng(seed, "wind"),
            tuple(w["mean_mps"]),
            w["gust_std_mps"],
            w["gust_time_constant_s"],
        )
        self.drone = SimCrazyflie(
            params,
            world,
            estimator,
            self.wind,
            tuple(s["start_m"]),
            math.radians(s["start_yaw_deg"]),
            s["physics_rate_hz"],
        )
        self.link = SimLink(
            self.drone, make_rng(seed, "link"), s["telemetry_rate_hz"], s["link_loss_probability"]
        )
        m = sensors["mocap"]
        self.mocap = (
            SimMocap(
                make_rng(seed, "mocap"),
                m["rate_hz"],
                m["position_noise_std_m"],
                m["orientation_noise_std_deg"],
                m["latency_s"],
                m["dropout_probability"],
            )
            if m["enabled"]
            else None
        )
        c = sensors["camera"]
        renderer = make_renderer(c["renderer"], world=world, camera=c, rng=make_rng(seed, "cam"))
        self.camera = SimCamera(c["rate_hz"], renderer, c["latency_s"])
        self.config = VehicleConfig.from_dict(rig_data["control"])
        self.vehicle = Vehicle(self.link, self.config, self.mocap, self.camera)
        self.faults = FaultInjector()
        self._register_faults()
        for name, spec in rig_data["faults"].items():
            # one it cannot inject (a mocap fault without mocap): the factory refuses the rig
            if spec.get("at_s") is not None and name in self.faults.handlers:
                params_ = {k: v for k, v in spec.items() if k != "at_s" and v is not None}
                self.faults.schedule(name, spec["at_s"], **params_)
        self._tasks = [_Periodic(1.0 / self.config.rate_hz, self._control)]
        if self.mocap is not None:
            self._tasks.insert(0, _Periodic(self.mocap.period_s, self._capture_mocap))
        self._tasks.insert(0, _Periodic(self.camera.period_s, self._capture_camera))
        self.t_s = 0.0
        self.max_tracking_error_m = 0.0
        self.shutdown_reason: str | None = None

    @classmethod
    def from_rig(cls, rig: Any, clock: Any, seed: int) -> SimPlatform:
        """Build from a :class:`drivers.rig.loader.Rig`."""
        return cls(rig.load_world(seed), rig.data, seed, clock)

    # ------------------------------------------------------------------ faults
    def _register_faults(self) -> None:
        f, link, battery, wind = self.faults, self.link, self.drone.battery, self.wind
        mocap, camera = self.mocap, self.camera

        def gust(speed_mps=(1.0, 0.0, 0.0)) -> None:
            wind.injected = tuple(float(v) for v in speed_mps)

        def sag(drop_v=0.5) -> None:
            battery.sag_v = float(drop_v)

        f.register(
            "link_drop",
            FaultHandler(
                lambda: link.drop(True), lambda: link.drop(False), "radio link down both ways"
            ),
        )
        f.register(
            "battery_sag",
            FaultHandler(
                sag,
                lambda: setattr(battery, "sag_v", 0.0),
                "extra battery voltage drop",
                {"drop_v": 0.5},
            ),
        )
        f.register(
            "gust",
            FaultHandler(
                gust,
                lambda: setattr(wind, "injected", (0.0, 0.0, 0.0)),
                "wind gust",
                {"speed_mps": (1.0, 0.0, 0.0)},
            ),
        )
        f.register(
            "camera_stall",
            FaultHandler(
                lambda: setattr(camera, "stalled", True),
                lambda: setattr(camera, "stalled", False),
                "camera stops delivering frames",
            ),
        )
        if mocap is not None:

            def drop(probability=1.0) -> None:
                mocap.set_drop_probability(probability)

            f.register(
                "mocap_freeze",
                FaultHandler(
                    lambda: mocap.freeze(True),
                    lambda: mocap.freeze(False),
                    "mocap repeats its last frame",
                ),
            )
            f.register(
                "mocap_drop",
                FaultHandler(
                    drop,
                    lambda: mocap.set_drop_probability(None),
                    "mocap frames lost",
                    {"probability": 1.0},
                ),
            )

    # ------------------------------------------------------------------ stepping
    def _true_pose(self) -> Pose:
        b = self.drone.body
        return Pose(
            b.x,
            b.y,
            b.z,
            b.yaw,
            quaternion_from_euler(b.roll, b.pitch, b.yaw),
            self.drone.t_s,
            "truth",
        )

    def _capture_mocap(self, t_s: float) -> None:
        self.mocap.capture(t_s, self.drone.body)

    def _capture_camera(self, t_s: float) -> None:
        if self.camera.renderer is not None:
            self.camera.capture(t_s, self._true_pose())

    def _control(self, t_s: float) -> None:
        v = self.vehicle
        v.control_step(t_s)
        ref = v.reference
        if ref is not None and v.is_flying and not self.drone.crashed:
            b = self.drone.body
            err = math.dist((b.x, b.y, b.z), ref.position)
            if err > self.max_tracking_error_m:
                self.max_tracking_error_m = err

    def step_to(self, t_s: float) -> None:
        """Advance simulation, faults, sensors and the Vehicle loop to mission time ``t_s``."""
        tasks = self._tasks
        while True:
            t_e = min(task.next_s for task in tasks)
            if t_e > t_s + 1e-9:
                break
            self.drone.step_to(t_e)
            self.faults.update(t_e)
            for task in tasks:
                if task.next_s <= t_e + 1e-9:
                    task.run(t_e)
                    task.k += 1
                    task.next_s = task.k * task.period_s
        self.drone.step_to(t_s)
        self.t_s = max(self.t_s, t_s)

    def before_tick(self, t_s: float) -> None:
        """Lock-step: step physics and the Vehicle control loop up to ``t_s``."""
        self.step_to(t_s)

    def after_tick(self, t_s: float) -> None:
        """Nothing to do after the tree tick (set-points go out at the next control step)."""

    def shutdown(self, reason: str) -> None:
        """Land if flying and keep simulating (at most ``sim.shutdown_max_s``) until down."""
        self.shutdown_reason = reason
        v = self.vehicle
        if v.is_flying and v.flight_state != FlightState.LANDING:
            v.land(0.5)
        end = self.t_s + self.rig_data["sim"]["shutdown_max_s"]
        self._simulate_while(lambda: v.is_flying, end)
        if v.is_flying:  # could not land in time (e.g. link down): cut the motors
            v.emergency_stop()
        # Motors cut in the air (second interrupt, supervisor, this shutdown): simulate the
        # fall (bounded), so the ground truth says where and how it came down, not "flying".
        self._simulate_while(self._falling, max(end, self.t_s) + 5.0)

    def _simulate_while(self, condition, end_s: float) -> None:
        """Step the simulation in 20 ms steps while ``condition()`` holds, until ``end_s``
        (on a wall clock, pacing with it)."""
        simulated = self.clock is None or getattr(self.clock, "is_simulated", True)
        t = self.t_s
        while condition() and t < end_s:
            if simulated:
                t += 0.02
            else:
                self.clock.sleep_until(self.clock.now() + 0.02)
                t = self.clock.now()
            self.step_to(t)

    def _falling(self) -> bool:
        d = self.drone
        return not d.body.on_ground and not d.firmware.motors_running and not d.crashed

    # ------------------------------------------------------------------ outputs
    def summary(self) -> dict:
        """Ground truth for ``summary.json`` (key ``sim``)."""
        d, v = self.drone, self.vehicle
        b = d.body
        bat = d.battery
        return {
            "t_s": round(d.t_s, 4),
            "seed": self.seed,
            "final_pose": {
                "x_m": round(b.x, 4),
                "y_m": round(b.y, 4),
                "z_m": round(b.z, 4),
                "yaw_deg": round(math.degrees(b.yaw), 3),
            },
            "state": v.flight_state.value,
            "landed": b.on_ground and not d.firmware.motors_running and not d.crashed,
            "crashed": d.crashed,
            "flying": not b.on_ground,
            "armed": d.firmware.armed,
            "battery": bat.report(),  # truth and gauge side by side (docs/vehicle.md)
            "max_tracking_error_m": round(self.max_tracking_error_m, 4),
            "max_speed_mps": round(d.max_speed_mps, 3),
            "collisions": list(d.collisions),
            "faults": self.faults.summary(),
            "scan_pallet": self.world.scan_pallet if self.world is not None else None,
            "pallets": self.world.ground_truth() if self.world is not None else [],
            "placement_offset": self.world.placement_offset if self.world is not None else None,
            "yaw_bias_deg": round(math.degrees(d.estimator.yaw_bias_rad), 3),
            "shutdown_reason": self.shutdown_reason,
        }

    def telemetry_row(self) -> dict:
        """Vehicle state for the per-tick log (reported pose, reference, battery, state)."""
        return self.vehicle.telemetry_row()
