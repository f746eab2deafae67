"""Port 5 (logging): TOC v2 of log variables and log blocks streamed from the simulated drone.

ch 0: TOC (see :mod:`.toc`). ch 1 (control), every reply ``[cmd, id, errno]``:
create block v2 ``[6, id, (type, id lo, id hi)...]`` (v1 ``[0, id, (type, id)...]``), append
``[7, ...]``/``[1, ...]``, delete ``[2, id]``, start ``[3, id, period in 10 ms]``, stop
``[4, id]``, reset ``[5]`` (reply ``[5, 0, 0]``). ch 2: data ``[id, 24-bit ms timestamp,
values]`` with at most 26 bytes of values, sent every period while a block runs.
Errors: unknown variable ENOENT, block over 26 bytes E2BIG, more than 16 blocks or 128
variables ENOMEM, existing id EEXIST, unknown block ENOENT, period 0 EINVAL.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from drivers.sim.emulators.crtp.crtp import (
    E2BIG,
    EEXIST,
    EINVAL,
    ENOENT,
    ENOMEM,
    LOGGING,
    Packet,
)
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie
from drivers.sim.emulators.crtp.toc import toc_reply

MAX_BLOCK_BYTES = 26
MAX_BLOCKS = 16
MAX_VARIABLES = 128
# log type id -> (struct code, size); cflib LogTocElement.types
LOG_TYPES: dict[int, tuple[str, int]] = {
    1: ("B", 1),
    2: ("H", 2),
    3: ("I", 4),
    4: ("b", 1),
    5: ("h", 2),
    6: ("i", 4),
    7: ("f", 4),
    8: ("e", 2),
}
UINT8, UINT16, FLOAT = 1, 2, 7

Getter = Callable[[EmulatedCrazyflie], float]


def _variables() -> list[tuple[str, int, Getter]]:
    def est(attr: str) -> Getter:
        return lambda cf: getattr(cf.drone.estimator, attr)

    def quat(i: int) -> Getter:
        return lambda cf: cf.quaternion()[i]

    def gyro(i: int) -> Getter:
        return lambda cf: cf.gyro_dps[i]

    def acc(i: int) -> Getter:
        return lambda cf: cf.acc_g[i]

    out: list[tuple[str, int, Getter]] = [
        (f"stateEstimate.{a}", FLOAT, est(a)) for a in ("x", "y", "z", "vx", "vy", "vz")
    ]
    out += [(f"stateEstimate.q{a}", FLOAT, quat(i)) for i, a in enumerate("xyzw")]
    out += [
        ("stateEstimate.roll", FLOAT, lambda cf: math.degrees(cf.drone.body.roll)),
        ("stateEstimate.pitch", FLOAT, lambda cf: math.degrees(cf.drone.body.pitch)),
        ("stateEstimate.yaw", FLOAT, lambda cf: math.degrees(cf.drone.estimator.yaw)),
        ("stabilizer.roll", FLOAT, lambda cf: math.degrees(cf.drone.body.roll)),
        ("stabilizer.pitch", FLOAT, lambda cf: math.degrees(cf.drone.body.pitch)),
        ("stabilizer.yaw", FLOAT, lambda cf: math.degrees(cf.drone.estimator.yaw)),
        ("stabilizer.thrust", FLOAT, lambda cf: cf.drone.body.cmd_thrust_n),
        ("pm.vbat", FLOAT, lambda cf: cf.drone.battery.voltage_v),
        ("pm.batteryLevel", UINT8, lambda cf: round(100 * cf.drone.battery.soc)),
        ("supervisor.info", UINT16, lambda cf: cf.supervisor_bits()),
    ]
    out += [(f"gyro.{a}", FLOAT, gyro(i)) for i, a in enumerate("xyz")]
    out += [(f"acc.{a}", FLOAT, acc(i)) for i, a in enumerate("xyz")]
    return out


VARIABLES = _variables()


@dataclass
class LogBlock:
    """One configured block: variable ids with their fetch types, period, schedule."""

    ident: int
    items: list[tuple[int, int]] = field(default_factory=list)  # (variable id, fetch type)
    period_s: float = 0.0
    running: bool = False
    next_s: float = 0.0
    sent: int = 0

    def size(self) -> int:
        return sum(LOG_TYPES[t][1] for _, t in self.items)


class LogPort:
    """Port 5 handler plus the block scheduler (:meth:`due`)."""

    port = LOGGING

    def __init__(self, cf: EmulatedCrazyflie) -> None:
        self.cf = cf
        self.entries = [(n, t) for n, t, _ in VARIABLES]
        self._getters = [g for _, _, g in VARIABLES]
        self.blocks: dict[int, LogBlock] = {}
        extra = struct.pack("<BB", MAX_BLOCKS, MAX_VARIABLES)
        self._info_extra = extra

    # ------------------------------------------------------------------ requests
    def handle(self, pk: Packet) -> list[Packet]:
        if pk.channel == 0:
            return toc_reply(LOGGING, self.entries, pk.data, self._info_extra)
        if pk.channel != 1 or not pk.data:
            return []
        cmd = pk.data[0]
        if cmd == 5:  # reset
            self.blocks.clear()
            return [self._reply(cmd, 0, 0)]
        if len(pk.data) < 2:
            return [self._reply(cmd, 0, EINVAL)]
        ident = pk.data[1]
        if cmd in (0, 1, 6, 7):
            return [self._reply(cmd, ident, self._add(cmd, ident, pk.data[2:]))]
        block = self.blocks.get(ident)
        if block is None:
            return [self._reply(cmd, ident, ENOENT)]
        if cmd == 2:  # delete
            del self.blocks[ident]
        elif cmd == 3:  # start
            if len(pk.data) < 3 or pk.data[2] == 0:
                return [self._reply(cmd, ident, EINVAL)]
            block.period_s = pk.data[2] * 0.01
            block.running = True
            block.next_s = self.cf.t_s
        elif cmd == 4:  # stop
            block.running = False
        else:
            return [self._reply(cmd, ident, EINVAL)]
        return [self._reply(cmd, ident, 0)]

    @staticmethod
    def _reply(cmd: int, ident: int, err: int) -> Packet:
        return Packet(LOGGING, 1, bytes((cmd, ident, err)))

    def _add(self, cmd: int, ident: int, spec: bytes) -> int:
        v2 = cmd in (6, 7)
        step = 3 if v2 else 2
        if len(spec) % step:
            return EINVAL
        items = []
        for i in range(0, len(spec), step):
            fetch = spec[i] & 0x0F
            var = spec[i + 1] | (spec[i + 2] << 8 if v2 else 0)
            if var >= len(self.entries):
                return ENOENT
            if fetch not in LOG_TYPES:
                return EINVAL
            items.append((var, fetch))
        if cmd in (0, 6):
            if ident in self.blocks:
                return EEXIST
            if len(self.blocks) >= MAX_BLOCKS:
                return ENOMEM
            block = LogBlock(ident)
        else:
            block = self.blocks.get(ident)
            if block is None:
                return ENOENT
        used = sum(len(b.items) for b in self.blocks.values() if b is not block)
        if used + len(block.items) + len(items) > MAX_VARIABLES:
            return ENOMEM
        trial = LogBlock(ident, block.items + items)
        if trial.size() > MAX_BLOCK_BYTES:
            return E2BIG
        block.items = trial.items
        self.blocks[ident] = block
        return 0

    # ------------------------------------------------------------------ streaming
    def next_due_s(self) -> float:
        """Firmware time of the next block due (inf if none runs)."""
        return min((b.next_s for b in self.blocks.values() if b.running), default=math.inf)

    def due(self, t_s: float) -> list[Packet]:
        """Data packets of every running block due at firmware time ``t_s``."""
        out = []
        stamp = int(t_s * 1000.0) & 0xFFFFFF
        for b in self.blocks.values():
            if not b.running or b.next_s > t_s + 1e-4:
                continue
            b.next_s += b.period_s
            if b.next_s < t_s - b.period_s:  # fell behind (a stall): do not burst
                b.next_s = t_s + b.period_s
            out.append(Packet(LOGGING, 2, self._pack(b, stamp)))
            b.sent += 1
        return out

    def _pack(self, b: LogBlock, stamp: int) -> bytes:
        head = bytes((b.ident, stamp & 0xFF, (stamp >> 8) & 0xFF, stamp >> 16))
        parts = []
        for var, fetch in b.items:
            code, _ = LOG_TYPES[fetch]
            v = self._getters[var](self.cf)
            if code in "fe":
                parts.append(
                    struct.pack("<" + code, max(-6.5e4, min(6.5e4, v)) if code == "e" else v)
                )
            else:
                parts.append(_pack_int(code, v))
        return head + b"".join(parts)


def _pack_int(code: str, v: float) -> bytes:
    bits = struct.calcsize(code) * 8
    if code.islower():
        lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    else:
        lo, hi = 0, (1 << bits) - 1
    return struct.pack("<" + code, max(lo, min(hi, int(v))))
