"""Port 8 (high-level commander): take-off, land, go-to and stop, planned on board.

Mirrors the firmware's ``crtp_commander_high_level.c`` + ``planner.c`` as cflib's
``HighLevelCommander`` drives them. Commands (ch 0, first byte), all little-endian:

* 0 set group mask ``<B mask``; 3 stop ``<B group``;
* 7 take-off-2 and 8 land-2 ``<Bff?f`` (group, absolute height m, yaw rad, use current yaw,
  duration s); 9 take-off and 10 land with velocity ``<Bf?f?f`` (group, height, height is
  relative, yaw, use current yaw, velocity m/s; 0 = ``hlCommander.vtoff``/``vland``, 0.5);
* 4 go-to ``<BBfffff`` (group, relative, x, y, z, yaw rad, duration s) and 12 go-to-2
  ``<BBBfffff`` (group, relative, linear, ...), as cflib sends for protocol >= 8.

Every command is answered ``[command, byte 1, byte 2, errno]`` like the firmware task
(0 = accepted, 1 = refused by the planner, 8 = ENOEXEC unknown command; 22 = EINVAL for a
NaN or infinite value, which the firmware would not check). Trajectories are
the firmware's 7th-order polynomials with zero velocity, acceleration and jerk at the end
(start: the current set-point's position, velocity and acceleration; ``linear`` go-tos are
straight constant-speed lines). Yaw goes the shortest way to the target.

Planner states as the firmware's: IDLE at boot and after stop or a finished landing (the
commander then asks for motors off), FLYING, LANDING, DISABLED (pre-empted by a low-level
set-point). Take-off is accepted only from IDLE, land from anything but LANDING, go-to from
any state. Priorities as ``commander.c``: a low-level set-point (port 7/3) disables the
planner and holds the commander until ``notify_setpoint_stop`` (after its ``remain valid``
time) or the 2 s watchdog; while held, the planner's set-points are not applied. While it
flies, the planner feeds the firmware a position set-point at every emulator step (which
also keeps the commander watchdog fed).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from drivers.sim.emulators.crtp.crtp import SETPOINT_HL, Packet
from drivers.sim.emulators.crtp.state import EmulatedCrazyflie
from drivers.sim.firmware import POSITION, STOP

CMD_SET_GROUP_MASK, CMD_STOP, CMD_GO_TO = 0, 3, 4
CMD_TAKEOFF_2, CMD_LAND_2, CMD_TAKEOFF_VEL, CMD_LAND_VEL, CMD_GO_TO_2 = 7, 8, 9, 10, 12
ENOEXEC, EINVAL = 8, 22  # EINVAL: NaN/inf never reach the planner (emulator's choice)
IDLE, FLYING, LANDING, DISABLED = "idle", "flying", "landing", "disabled"
DEFAULT_VELOCITY_MPS = 0.5  # hlCommander.vtoff / vland


def _septic_coefficients(p0: float, v0: float, a0: float, p1: float, T: float) -> np.ndarray:
    """Coefficients c0..c7 of p(u), u = t / T in [0, 1], such that p, dp/dt, d2p/dt2 and the
    jerk go from (p0, v0, a0, 0) to (p1, 0, 0, 0) over ``T`` seconds (normalised time keeps
    the system well conditioned for any duration)."""
    rows, rhs = [], []
    for u, vals in ((0.0, (p0, v0 * T, a0 * T * T, 0.0)), (1.0, (p1, 0.0, 0.0, 0.0))):
        for d, val in enumerate(vals):
            rows.append([math.perm(k, d) * u ** (k - d) if k >= d else 0.0 for k in range(8)])
            rhs.append(val)
    return np.linalg.solve(np.array(rows), np.array(rhs))


@dataclass
class Goal:
    """The planner's set-point at one instant (world frame, metres, radians)."""

    pos: tuple[float, float, float]
    vel: tuple[float, float, float]
    acc: tuple[float, float, float]
    yaw: float


class Trajectory:
    """One planned piece: per-axis 7th-order polynomials (or a straight line) from ``t0``."""

    def __init__(
        self, t0: float, duration: float, start: Goal, end_pos: tuple[float, float, float],
        end_yaw: float, linear: bool = False,
    ) -> None:  # fmt: skip
        self.t0, self.duration, self.linear = t0, max(duration, 1e-3), linear
        self.start, self.end_pos = start, end_pos
        yaw1 = start.yaw + math.remainder(end_yaw - start.yaw, 2.0 * math.pi)
        self.end_yaw = yaw1
        self.coeffs = [
            _septic_coefficients(start.pos[i], start.vel[i], start.acc[i], end_pos[i], duration)
            for i in range(3)
        ] + [_septic_coefficients(start.yaw, 0.0, 0.0, yaw1, duration)]

    def finished(self, t: float) -> bool:
        """True once the piece has ended."""
        return t - self.t0 >= self.duration

    def eval(self, t: float) -> Goal:
        """The set-point at time ``t`` (the end point after the end)."""
        s = min(max(t - self.t0, 0.0), self.duration)
        if self.linear:
            f = s / self.duration
            v = [(e - b) / self.duration for b, e in zip(self.start.pos, self.end_pos, strict=True)]
            pos = tuple(b + f * (e - b) for b, e in zip(self.start.pos, self.end_pos, strict=True))
            yaw = self.start.yaw + f * (self.end_yaw - self.start.yaw)
            vel = tuple(v) if s < self.duration else (0.0, 0.0, 0.0)
            return Goal(pos, vel, (0.0, 0.0, 0.0), yaw)  # type: ignore[arg-type]
        P = np.polynomial.polynomial
        u, T = s / self.duration, self.duration
        out = []
        for c in self.coeffs:
            dc = P.polyder(c)
            p, v, a = P.polyval(u, c), P.polyval(u, dc) / T, P.polyval(u, P.polyder(dc)) / T**2
            out.append((float(p), float(v), float(a)))
        return Goal(
            (out[0][0], out[1][0], out[2][0]),
            (out[0][1], out[1][1], out[2][1]),
            (out[0][2], out[1][2], out[2][2]),
            out[3][0],
        )


class HighLevelPort:
    """Port 8 handler plus the on-board planner it drives (see the module doc)."""

    port = SETPOINT_HL

    def __init__(self, cf: EmulatedCrazyflie) -> None:
        self.cf = cf
        self.state = IDLE
        self.group_mask = 0
        self.trajectory: Trajectory | None = None
        self.commands: dict[int, int] = {}  # command -> count
        self.refused = 0
        self.last_goal: Goal | None = None  # last set-point the planner produced
        self._lowlevel_until = -math.inf  # commander held by low-level set-points until then
        self._applied_stop = True

    # ------------------------------------------------------------------ commander priorities
    def lowlevel_setpoint(self, t_s: float) -> None:
        """A low-level set-point arrived: disable the planner, hold the commander."""
        if self.state != DISABLED:
            self.state, self.trajectory = DISABLED, None
        self._lowlevel_until = math.inf

    def notify_setpoint_stop(self, t_s: float, remain_valid_ms: int) -> None:
        """``notify_setpoint_stop``: release the commander after ``remain_valid_ms``."""
        self._lowlevel_until = t_s + remain_valid_ms / 1000.0

    def _held(self, t_s: float) -> bool:
        fw = self.cf.drone.firmware
        if t_s - fw.last_setpoint_s > self.cf.drone.params["setpoint_shutdown_timeout_s"]:
            self._lowlevel_until = -math.inf  # the watchdog resets the priority
        return t_s < self._lowlevel_until

    # ------------------------------------------------------------------ state
    def _current(self, t_s: float) -> Goal:
        """Where a new plan starts: the last set-point while flying, else the estimate."""
        if self.state in (FLYING, LANDING) and self.trajectory is not None:
            return self.trajectory.eval(t_s)
        e = self.cf.drone.estimator
        return Goal((e.x, e.y, e.z), (e.vx, e.vy, e.vz), (0.0, 0.0, 0.0), e.yaw)

    def update(self, t_s: float) -> None:
        """Feed the firmware the planner's set-point for ``t_s`` (call every emulator step)."""
        if self.state == DISABLED or self._held(t_s):
            return
        fw = self.cf.drone.firmware
        if self.state == LANDING and self.trajectory is not None and self.trajectory.finished(t_s):
            self.state, self.trajectory = IDLE, None
        if self.state == IDLE:
            if not self._applied_stop:  # motors off, once (the firmware's null set-point)
                fw.setpoint(t_s, STOP, (0.0, 0.0, 0.0, 0.0))
                self._applied_stop = True
            return
        if self.trajectory is None:
            return
        g = self.trajectory.eval(t_s)
        if not all(math.isfinite(v) for v in (*g.pos, g.yaw)):
            return  # absurd (but finite) command values overflowed: ignore them
        self.last_goal = g
        fw.setpoint(t_s, POSITION, (g.pos[0], g.pos[1], g.pos[2], g.yaw))
        self._applied_stop = False

    # ------------------------------------------------------------------ commands
    def _in_group(self, g: int) -> bool:
        return g == 0 or (g & self.group_mask) != 0

    def _vertical(self, t_s: float, height: float, yaw: float, use_current: bool,
                  duration: float, landing: bool) -> int:  # fmt: skip
        if not all(math.isfinite(v) for v in (height, yaw, duration)):
            return EINVAL
        if landing and self.state == LANDING:
            return 1
        if not landing and self.state != IDLE:
            return 1
        cur = self._current(t_s)
        start = Goal(cur.pos, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), cur.yaw)
        target = (cur.pos[0], cur.pos[1], height)
        self.trajectory = Trajectory(t_s, duration, start, target, cur.yaw if use_current else yaw)
        self.state = LANDING if landing else FLYING
        return 0

    def _go_to(self, t_s: float, relative: bool, linear: bool, xyz: tuple[float, float, float],
               yaw: float, duration: float) -> int:  # fmt: skip
        if not all(math.isfinite(v) for v in (*xyz, yaw, duration)):
            return EINVAL
        cur = self._current(t_s)
        if relative:
            xyz = (cur.pos[0] + xyz[0], cur.pos[1] + xyz[1], cur.pos[2] + xyz[2])
            yaw += cur.yaw
        self.trajectory = Trajectory(t_s, duration, cur, xyz, yaw, linear)
        self.state = FLYING
        return 0

    def execute(self, t_s: float, data: bytes) -> int:
        """Run one command at firmware time ``t_s``; the firmware's return code."""
        cmd, d = data[0], data[1:]
        self.commands[cmd] = self.commands.get(cmd, 0) + 1
        if cmd == CMD_SET_GROUP_MASK:
            self.group_mask = d[0]
            return 0
        if cmd == CMD_STOP:
            if self._in_group(d[0]):
                self.state, self.trajectory = IDLE, None
                self._applied_stop = False
            return 0
        if cmd in (CMD_TAKEOFF_2, CMD_LAND_2):
            g, h, yaw, cur, dur = struct.unpack("<Bff?f", d[:14])
            if not self._in_group(g):
                return 0
            return self._vertical(t_s, h, yaw, cur, dur, cmd == CMD_LAND_2)
        if cmd in (CMD_TAKEOFF_VEL, CMD_LAND_VEL):
            g, h, rel, yaw, cur, vel = struct.unpack("<Bf?f?f", d[:15])
            if not self._in_group(g):
                return 0
            z = self._current(t_s).pos[2]
            landing = cmd == CMD_LAND_VEL
            if rel:
                h = z - h if landing else z + h
            vel = vel if vel > 0 else DEFAULT_VELOCITY_MPS
            return self._vertical(t_s, h, yaw, cur, abs(h - z) / vel, landing)
        if cmd == CMD_GO_TO:
            g, rel, x, y, z, yaw, dur = struct.unpack("<BBfffff", d[:22])
            return (
                self._go_to(t_s, bool(rel), False, (x, y, z), yaw, dur) if self._in_group(g) else 0
            )
        if cmd == CMD_GO_TO_2:
            g, rel, lin, x, y, z, yaw, dur = struct.unpack("<BBBfffff", d[:23])
            if not self._in_group(g):
                return 0
            return self._go_to(t_s, bool(rel), bool(lin), (x, y, z), yaw, dur)
        return ENOEXEC

    def handle(self, pk: Packet) -> list[Packet]:
        """Answer one port 8 packet (``[cmd, d1, d2, errno]``, as the firmware task)."""
        if pk.channel != 0 or not pk.data:
            return []
        ret = self.execute(self.cf.t_s, pk.data)
        if ret:
            self.refused += 1
        head = (pk.data + bytes(3))[:3]
        return [Packet(SETPOINT_HL, 0, head + bytes((ret & 0xFF,)))]
