"""Software in the loop: the CRTP emulator (and later the AI-deck emulator) in-process.

:class:`SitlSession` builds the simulated Crazyflie from a rig's ``sim``/``sensors``/``wind``/
``battery`` sections (the same drone the lock-step simulator flies), serves it over CRTP/UDP
on 127.0.0.1 at a free port (or the one given) and offers its simulated mocap as a
:class:`drivers.link.PoseSource`. The real cflib driver then connects to :attr:`uri`.

    with SitlSession.from_rig_data(load_rig().data, seed=0) as sitl:
        link = CrazyflieLink(CrazyflieLinkConfig(uri=sitl.uri)).open()
"""

from __future__ import annotations

import math
from typing import Any

from drivers.faults import FaultHandler, FaultInjector
from drivers.sim.crtp_emulator import (
    CrtpEmulator,
    EmulatedCrazyflie,
    EmulatorMocap,
    build_sim_drone,
)
from drivers.sim.drone import make_rng
from drivers.sim.sensors import SimMocap
from drivers.sim.world import World

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
        self.emulator = CrtpEmulator(self.cf, host, port, self.mocap)

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
        """Stop serving (idempotent)."""
        self.emulator.stop()

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
        """Register ``link_drop`` (both ways) and the mocap faults on ``faults``."""
        em, mocap = self.emulator, self.mocap
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
