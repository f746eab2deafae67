"""Software in the loop: the CRTP emulator and the AI-deck emulator, in-process.

:class:`SitlSession` builds the simulated Crazyflie from a rig's ``sim``/``sensors``/``wind``/
``battery`` sections (the same drone the lock-step simulator flies), serves it over CRTP/UDP
on 127.0.0.1 at a free port (or the one given) and offers its simulated mocap as a
:class:`drivers.vehicle.interfaces.PoseSource`. The real cflib driver then connects to :attr:`uri`.
:meth:`SitlSession.start_camera` also serves the AI-deck stream (CPX over TCP, a free port on
127.0.0.1) rendered from the drone's true pose at the camera rate, in real time; the real
stream client (:class:`drivers.crazyflie.aideck_stream.AIDeckStream`) connects to :attr:`camera_port`.

    with SitlSession.from_rig_data(load_rig().data, seed=0) as sitl:
        link = CrazyflieLink(CrazyflieLinkConfig(uri=sitl.uri)).open()
"""

from __future__ import annotations

import math
from typing import Any

from drivers.sim.drone import make_rng
from drivers.sim.emulators.crtp import (
    CrtpEmulator,
    EmulatedCrazyflie,
    EmulatorMocap,
    build_sim_drone,
)
from drivers.sim.sensors import SimMocap
from drivers.sim.world import World
from drivers.vehicle.angles import quaternion_from_euler
from drivers.vehicle.faults import FaultHandler, FaultInjector
from drivers.vehicle.types import Pose

LOOPBACK = "127.0.0.1"


class SitlSession:
    """A started-on-demand emulator + simulated mocap for one drone."""

    def __init__(
        self,
        rig_data: dict[str, Any],
        seed: int = 0,
        world: World | None = None,
        host: str = LOOPBACK,
        port: int = 0,
        feed_mocap: bool = False,
    ) -> None:
        self.cf = EmulatedCrazyflie(build_sim_drone(rig_data, seed, world))
        m = rig_data["sensors"]["mocap"]
        self.mocap: EmulatorMocap | None = None
        if m["enabled"]:
            self.mocap = EmulatorMocap(
                SimMocap(
                    make_rng(seed, "mocap"),
                    m["rate_hz"],
                    m["position_noise_std_m"],
                    m["orientation_noise_std_deg"],
                    m["latency_s"],
                    m["dropout_probability"],
                )
            )
        self.emulator = CrtpEmulator(self.cf, host, port, self.mocap, feed_mocap)
        self.camera: Any = None  # the AIDeckEmulator once start_camera() ran

    @classmethod
    def from_rig_data(cls, rig_data: dict[str, Any], seed: int = 0, **kw: Any) -> SitlSession:
        """Same as the constructor (reads well next to ``load_rig``)."""
        return cls(rig_data, seed, **kw)

    @property
    def uri(self) -> str:
        """cflib URI of the emulator."""
        return self.emulator.uri

    def start(self) -> SitlSession:
        """Start serving (the simulated drone's clock starts now)."""
        self.emulator.start()
        return self

    def stop(self) -> None:
        """Stop serving, the camera stream too (idempotent)."""
        if self.camera is not None:
            self.camera.close()
        self.emulator.stop()

    @property
    def camera_port(self) -> int | None:
        """TCP port of the AI-deck emulator on 127.0.0.1 (None before :meth:`start_camera`)."""
        return self.camera.port if self.camera is not None else None

    def true_pose(self) -> Pose:
        """The simulated drone's true pose (``t_s``: the emulator's firmware time)."""
        with self.emulator.lock:
            d = self.cf.drone
            b = d.body
            q = quaternion_from_euler(b.roll, b.pitch, b.yaw)
            return Pose(b.x, b.y, b.z, b.yaw, q, d.t_s, "truth")

    def start_camera(
        self, rig_data: dict[str, Any], seed: int = 0, world: World | None = None
    ) -> Any:
        """Serve the AI-deck stream of the drone's camera; returns the ``AIDeckEmulator``.

        Frames: ``sensors.camera.renderer`` (``pallet`` if that is ``none``) with the rig's
        camera settings and the simulator's random stream (``make_rng(seed, "cam")``), at
        ``sensors.camera.rate_hz``, sent as ``aideck.format`` (raw BayerBG or JPEG). The
        renderer's textures are made here, before serving (about 1.5 s for the warehouse):
        made lazily in flight they would stall the stream for up to 0.7 s as new pallets
        come into view (like a real deck, the simulated one is ready before you connect).
        """
        from drivers.sim.emulators.aideck import AIDeckEmulator
        from drivers.sim.renderers import make_renderer

        cam = rig_data["sensors"]["camera"]
        name = cam["renderer"] if cam["renderer"] not in (None, "none") else "pallet"
        renderer = make_renderer(name, world=world, camera=cam, rng=make_rng(seed, "cam"))
        prewarm_renderer(renderer)
        self.camera = AIDeckEmulator(
            LOOPBACK,
            0,
            cam["rate_hz"],
            rig_data["aideck"]["format"],
            renderer=renderer,
            seed=seed,
            pose_fn=self.true_pose,
            warm_up=True,
        ).start()
        return self.camera

    def __enter__(self) -> SitlSession:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def truth(self) -> dict[str, Any]:
        """Ground truth of the simulated drone (consistent snapshot)."""
        with self.emulator.lock:
            d = self.cf.drone
            b, fw = d.body, d.firmware
            return {
                "t_s": round(d.t_s, 4),
                "final_pose": {
                    "x_m": round(b.x, 4),
                    "y_m": round(b.y, 4),
                    "z_m": round(b.z, 4),
                    "yaw_deg": round(math.degrees(b.yaw), 3),
                },
                "landed": b.on_ground and not fw.motors_running and not d.crashed,
                "crashed": d.crashed,
                "flying": not b.on_ground,
                "armed": fw.armed,
                "battery_v": round(d.battery.voltage_v, 3),
                "collisions": list(d.collisions),
                "max_speed_mps": round(d.max_speed_mps, 3),
                "setpoints": self.cf.setpoint_count,
                "extposes": self.cf.extpose_count,
                "link": self.emulator.stats.as_dict(),
            }

    def register_faults(self, faults: FaultInjector) -> None:
        """Register ``link_drop`` (both ways), the mocap faults and, with the camera,
        ``camera_stall`` (connected, no frames) and ``camera_disconnect`` (deck offline)."""
        em, mocap, cam = self.emulator, self.mocap, self.camera
        if cam is not None:
            faults.register(
                "camera_stall",
                FaultHandler(
                    lambda: cam.set_stalled(True),
                    lambda: cam.set_stalled(False),
                    "AI-deck connected but sends no frames",
                ),
            )
            faults.register(
                "camera_disconnect",
                FaultHandler(
                    lambda: cam.set_online(False),
                    lambda: cam.set_online(True),
                    "AI-deck stream disconnected (deck offline)",
                ),
            )
        faults.register(
            "link_drop",
            FaultHandler(
                lambda: em.set_dropping(True),
                lambda: em.set_dropping(False),
                "radio link down both ways",
            ),
        )
        if mocap is not None:

            def drop(probability: float = 1.0) -> None:
                mocap.set_drop_probability(probability)

            faults.register(
                "mocap_freeze",
                FaultHandler(
                    lambda: mocap.freeze(True),
                    lambda: mocap.freeze(False),
                    "mocap repeats its last frame",
                ),
            )
            faults.register(
                "mocap_drop",
                FaultHandler(
                    drop,
                    lambda: mocap.set_drop_probability(None),
                    "mocap frames lost",
                    {"probability": 1.0},
                ),
            )


def prewarm_renderer(renderer: Any) -> None:
    """Make every lazily built texture of a scene renderer now (no-op for other renderers)."""
    for quad in getattr(getattr(renderer, "scene", None), "quads", ()):
        _ = quad.levels
