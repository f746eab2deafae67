"""Port 2 (parameters): TOC v2, read (ch 1), write (ch 2); writes act on the simulated drone.

Read ``[lo, hi]`` -> ``[lo, hi, 0, value]``; write ``[lo, hi, value]`` -> the request echoed
(cflib waits for exactly these before it sends the next request: no request goes unanswered,
unknown ids get ``[lo, hi, ENOENT]``). Param types (cflib ``ParamTocElement``): 0x08 uint8,
0x06 float; 0x40 marks read-only.

Meaningful writes: the PID gains and speed limits of ``posCtlPid``/``velCtlPid`` change the
simulated firmware's gains, ``kalman.resetEstimation`` = 1 resets the estimate onto the truth,
``stabilizer.stop`` = 1 cuts the motors. ``stabilizer.estimator``/``controller`` and the
``locSrv`` standard deviations are stored (the simulator has one estimator and one controller).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from drivers.sim.emulators.crtp.crtp import ENOENT, PARAM, Packet
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie
from drivers.sim.emulators.crtp.toc import toc_reply

UINT8, FLOAT, READ_ONLY = 0x08, 0x06, 0x40
_CODES = {UINT8: "B", FLOAT: "f"}


@dataclass
class ParamDef:
    """One parameter: name, type byte, default, and what a write does (optional)."""

    name: str
    type_byte: int
    default: float
    sim_param: str | None = None  # key in the drone's params dict
    on_write: Callable[[EmulatedCrazyflie, float], None] | None = None


def _reset_estimation(cf: EmulatedCrazyflie, v: float) -> None:
    if v:
        e = cf.drone.estimator
        e.ex = e.ey = e.ez = e.dvx = e.dvy = 0.0


def _stop(cf: EmulatedCrazyflie, v: float) -> None:
    if v:
        cf.drone.firmware.emergency_stop()


PARAMS: list[ParamDef] = [
    ParamDef("stabilizer.estimator", UINT8, 0),
    ParamDef("stabilizer.controller", UINT8, 0),
    ParamDef("stabilizer.stop", UINT8, 0, on_write=_stop),
    ParamDef("locSrv.extPosStdDev", FLOAT, 0.01),
    ParamDef("locSrv.extQuatStdDev", FLOAT, 4.5e-3),
    ParamDef("commander.enHighLevel", UINT8, 0),
    ParamDef("kalman.resetEstimation", UINT8, 0, on_write=_reset_estimation),
    ParamDef("posCtlPid.xKp", FLOAT, 2.0, "pos_xy_kp"),
    ParamDef("posCtlPid.yKp", FLOAT, 2.0, "pos_xy_kp"),
    ParamDef("posCtlPid.zKp", FLOAT, 2.0, "pos_z_kp"),
    ParamDef("posCtlPid.zKi", FLOAT, 0.5, "pos_z_ki"),
    ParamDef("posCtlPid.xVelMax", FLOAT, 1.1, "vel_max_xy_mps"),
    ParamDef("posCtlPid.yVelMax", FLOAT, 1.1, "vel_max_xy_mps"),
    ParamDef("posCtlPid.zVelMax", FLOAT, 1.1, "vel_max_z_mps"),
    ParamDef("velCtlPid.vxKp", FLOAT, 25.0, "vel_xy_kp_deg_per_mps"),
    ParamDef("velCtlPid.vyKp", FLOAT, 25.0, "vel_xy_kp_deg_per_mps"),
    ParamDef("velCtlPid.vxKi", FLOAT, 1.0, "vel_xy_ki_deg_per_m"),
    ParamDef("velCtlPid.vyKi", FLOAT, 1.0, "vel_xy_ki_deg_per_m"),
    ParamDef("velCtlPid.vzKp", FLOAT, 25.0, "vel_z_kp"),
    ParamDef("velCtlPid.vzKi", FLOAT, 15.0, "vel_z_ki"),
    ParamDef("pm.lowVoltage", FLOAT | READ_ONLY, 3.2),
]


class ParamPort:
    """Port 2 handler; ``values`` holds the current value of every parameter by name."""

    port = PARAM

    def __init__(self, cf: EmulatedCrazyflie) -> None:
        self.cf = cf
        self.defs = PARAMS
        self.entries = [(p.name, p.type_byte) for p in PARAMS]
        self.values: dict[str, float] = {}
        for p in PARAMS:
            v = cf.drone.params.get(p.sim_param, p.default) if p.sim_param else p.default
            self.values[p.name] = float(v)
        self.writes = 0

    def _encode(self, p: ParamDef) -> bytes:
        code = _CODES[p.type_byte & 0x0F]
        v = self.values[p.name]
        return struct.pack("<" + code, v if code == "f" else max(0, min(255, int(v))))

    def handle(self, pk: Packet) -> list[Packet]:
        d = pk.data
        if pk.channel == 0:
            return toc_reply(PARAM, self.entries, d, b"")
        if pk.channel not in (1, 2) or len(d) < 2:
            return []
        ident = d[0] | d[1] << 8
        if ident >= len(self.defs):
            return [Packet(PARAM, pk.channel, d[:2] + bytes((ENOENT,)))]
        p = self.defs[ident]
        if pk.channel == 1:
            return [Packet(PARAM, 1, d[:2] + b"\0" + self._encode(p))]
        code = _CODES[p.type_byte & 0x0F]
        if not p.type_byte & READ_ONLY and len(d) >= 2 + struct.calcsize(code):
            (value,) = struct.unpack("<" + code, d[2 : 2 + struct.calcsize(code)])
            self.set(p.name, float(value))
        return [Packet(PARAM, 2, d[:2] + self._encode(p))]

    def set(self, name: str, value: float) -> None:
        """Write a parameter as if it came over the radio."""
        p = next(q for q in self.defs if q.name == name)
        if p.type_byte & 0x0F == FLOAT and value != value:  # NaN: the firmware would take it
            return
        self.values[name] = value
        self.writes += 1
        if p.sim_param is not None:
            self.cf.drone.params[p.sim_param] = value
        if p.on_write is not None:
            p.on_write(self.cf, value)
