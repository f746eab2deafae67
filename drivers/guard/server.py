"""The guard process: what must outlive the mission process.

``btrun`` starts one guard per run (``python -m drivers.guard --fd N``, in a session of its
own so a Ctrl-C to the terminal or a ``kill`` of btrun's process group does not reach it) and
talks to it over a Unix sequenced-packet socket pair (:mod:`drivers.guard.wire`).

* **link** mode (a Crazyflie rig): the guard owns the cflib link. Set-points, external poses
  and arming requests of the mission process's Vehicle are forwarded to the drone; the
  drone's telemetry is forwarded back (:class:`drivers.guard.client.GuardLink`).
* **watch** mode (the simulator): no link; the guard only watches the heartbeats, so that a
  run that can never end by itself (a leaf holding the GIL in native code) still ends and
  leaves its record. A simulated drone lives in the mission process and ends with it.

The guard **takes over** when

* the mission process is gone without saying goodbye (crash, OOM kill, ``kill -9``): its
  end of the socket closes, which the guard sees at once;
* it is silent (no set-point, heartbeat or anything) for longer than ``silence_s`` while the
  drone is airborne (``rest_silence_s`` on the ground): blocked holding the GIL, stopped;
* its heartbeat says one tick has been running for longer than its limit (the in-process
  tick watchdog already fired and did not get the tree back: a leaf in ``time.sleep`` or one
  that swallows the watchdog's exception);
* it says goodbye with the drone still flying.

Taking over: stop listening to the mission process; land the drone (position set-points
straight down from where it is at ``land_speed_mps``, then a stop set-point and disarm); end
the mission process if it is still there (SIGKILL: it may hold the GIL); write
``summary.json`` with ``guard: {took_over: true, reason, ...}`` (merged into the mission's
own summary if that was written); close the link and exit.

Messages from the mission process: ``p`` position / ``v`` velocity set-point (with the
sender's monotonic send time, for the latency figures), ``s`` stop set-point, ``e`` external
pose, ``arm``, ``estop``, ``hb`` heartbeat, ``close`` (close the link; reply ``closed``),
``stats`` (reply ``stats``), ``bye``. To the mission process: ``ready`` / ``error`` after
the hello, ``T`` telemetry batches, ``H`` link health, ``took_over``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import os
import select
import signal
import socket
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from drivers.guard.wire import MAX_MESSAGE_BYTES, decode, encode

#: Telemetry fields on the wire, in :class:`drivers.vehicle.interfaces.LinkTelemetry` order.
TELEMETRY_FIELDS = (
    "t_s", "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps", "yaw_rad", "quaternion",
    "battery_v", "armed", "motors_running", "crashed", "tumbled",
)  # fmt: skip

#: A drone below this height with its motors off is on the ground.
GROUND_Z_M = 0.08
#: The guard's loop comes round every 5 ms; a longer gap than this means the guard itself
#: did not run (the host paused the machine or starved the guard, or it was stopped).
STALL_S = 0.25
#: a set-point older than this when the guard reads it (queued while the guard was stopped
#: or starved) is not flown: the drone would fly where it was asked to be seconds ago
STALE_SETPOINT_S = 0.3
#: After such a gap the mission process, most likely paused with the guard, has at least this
#: long to be heard from before its silence (or a tick's running time) is held against it.
RESUME_GRACE_S = 0.5

#: telemetry older than this (s) is not the drone's state now: the guard's record says so
STALE_TELEMETRY_S = 1.0


@dataclass
class GuardSettings:
    """What the mission process tells the guard in its hello (rig ``guard:`` section)."""

    run_dir: str
    mission_pid: int
    link: dict[str, Any] | None = None
    silence_s: float = 0.5
    rest_silence_s: float = 10.0
    land_speed_mps: float = 0.3
    land_max_s: float = 15.0
    record: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_hello(cls, data: dict[str, Any]) -> GuardSettings:
        """From the hello message's settings (unknown keys ignored)."""
        known = {k: v for k, v in data.items() if k in cls.__dataclass_fields__}
        return cls(**known)


def _percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    s = sorted(values)
    return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))]


class Guard:
    """One guard: its socket to the mission process, and the link in link mode."""

    def __init__(self, sock: socket.socket, settings: GuardSettings, link: Any = None) -> None:
        self.sock = sock
        self.s = settings
        self.link = link
        self.started = time.monotonic()
        self.last_rx = self.started
        self.last_tel: Any = None
        self.last_tel_at: float | None = None  # time.monotonic() when it arrived
        self.last_stall: tuple[float, float] | None = None  # (when it ended, how long)
        self.last_hb: list[Any] | None = None
        self.last_hb_rx = self.started
        self.took_over: dict[str, Any] | None = None
        self.said_bye = False
        self.mission_gone = False
        self.link_closed = link is None
        self.latencies_s: deque[float] = deque(maxlen=50_000)
        self.forward_times: deque[float] = deque(maxlen=50_000)
        self.counts = {
            "setpoints": 0,
            "extposes": 0,
            "heartbeats": 0,
            "telemetry": 0,
            "stale_setpoints": 0,  # older than STALE_SETPOINT_S when read: not flown
            "unsent": 0,  # messages to a mission process that was not reading
        }
        self._next_health = 0.0
        self.last_loop = self.started
        #: gaps in the guard's own loop (see :data:`STALL_S`): how many, and the longest (s)
        self.stalls, self.longest_stall_s = 0, 0.0

    # ------------------------------------------------------------------ messages in
    def _send(self, message: list[Any]) -> None:
        if self.mission_gone:
            return
        try:  # never a wait: a stopped mission process must not stop the guard
            self.sock.send(encode(message), socket.MSG_DONTWAIT)
        except BlockingIOError:  # its buffer is full (it is not reading): telemetry is
            self.counts["unsent"] += 1  # periodic, the next batch supersedes this one
        except OSError:  # the mission process is gone; the read side will see it
            self.mission_gone = True

    def _handle(self, msg: list[Any], now: float) -> None:
        kind = msg[0]
        self.last_rx = now
        if kind == "hb":
            self.last_hb, self.last_hb_rx = msg, now
            self.counts["heartbeats"] += 1
            return
        if kind == "stats":
            self._send(["stats", self.stats()])
            return
        if kind == "bye":
            self.said_bye = True
            return
        if self.took_over is not None:
            return  # nothing the mission process says moves the drone any more
        link = self.link
        if kind == "close":
            self._close_link()
            self._send(["closed", self._health()])
            return
        if link is None or self.link_closed:
            return
        args = msg[1:]
        if kind in ("p", "v") and len(args) >= 5 and all(_finite(a) for a in args[:5]):
            if now - float(args[4]) > STALE_SETPOINT_S:  # queued while the guard was stopped
                self.counts["stale_setpoints"] += 1  # (a newer one follows: never flown late)
                return
            (link.send_position_setpoint if kind == "p" else link.send_velocity_setpoint)(*args[:4])
            self.latencies_s.append(now - float(args[4]))
            self.forward_times.append(now)
            self.counts["setpoints"] += 1
        elif kind == "s":
            link.send_stop_setpoint()
        elif kind == "e" and len(args) >= 7 and all(_finite(a) for a in args[:7]):
            link.send_external_pose(args[0], args[1], args[2], tuple(args[3:7]))
            self.counts["extposes"] += 1
        elif kind == "arm" and args:
            link.arm(bool(args[0]))
        elif kind == "estop":
            link.emergency_stop()

    def _read(self, now: float) -> None:
        """Every message waiting on the socket; notes the mission process's end."""
        while True:
            try:
                data = self.sock.recv(MAX_MESSAGE_BYTES, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                data = b""
            if not data:
                self.mission_gone = True
                return
            msg = decode(data)
            if msg is not None:
                self._handle(msg, now)

    # ------------------------------------------------------------------ telemetry out
    def _pump_link(self, now: float) -> None:
        link = self.link
        if link is None or self.link_closed:
            return
        samples = link.poll(0.0)
        if samples:
            self._got_telemetry(samples[-1])
            self.counts["telemetry"] += len(samples)
            if self.took_over is None:
                rows = [[getattr(t, f) for f in TELEMETRY_FIELDS] for t in samples]
                self._send(["T", rows, bool(link.connected)])
        if now >= self._next_health and self.took_over is None:
            self._next_health = now + 0.25
            self._send(["H", self._health()])

    def _health(self) -> dict[str, Any]:
        if self.link is None:
            return {}
        try:
            return dict(self.link.health())
        except Exception as exc:  # a half-closed cflib link
            return {"connected": False, "lost_reason": f"health: {exc}"}

    # ------------------------------------------------------------------ the watch
    def airborne(self) -> bool:
        """The drone is (as far as its last telemetry says) in the air."""
        t = self.last_tel
        if self.link is None or self.link_closed or t is None:
            return False
        return bool(t.motors_running) or t.z_m > GROUND_Z_M

    def note_resume(self, now: float) -> None:
        """Called at every turn of the loop, before reading. After a gap in the guard's own
        loop longer than :data:`STALL_S` (the machine paused, the guard starved or stopped),
        what the guard did not see is not held against the mission process: it gets
        :data:`RESUME_GRACE_S` of the guard's running time to be heard from (its messages
        from before the gap are read first). Without this, a pause of the whole machine
        longer than the silence limit ended a healthy run: the guard, woken first, found
        the limit passed before the mission process could speak. A mission process that
        stays silent while the guard runs is taken over as before."""
        gap, self.last_loop = now - self.last_loop, now
        if gap <= STALL_S:
            return
        self.stalls += 1
        self.longest_stall_s = max(self.longest_stall_s, gap)
        self.last_stall = (now, gap)
        limit = self._silence_limit()
        self.last_rx = max(self.last_rx, now - limit + min(limit, RESUME_GRACE_S))
        clock = self._tick_clock()
        if clock is not None:
            left = max(clock[2] - clock[1], 0.0)  # the tick's time left at that beat
            self.last_hb_rx = max(self.last_hb_rx, now - left + min(left, RESUME_GRACE_S))

    def _own_stall(self, now: float) -> str:
        """What to add to a reason when the guard itself had just been stopped or starved
        (what it then saw happened while it was not looking)."""
        if self.last_stall is None or now - self.last_stall[0] > 5.0:
            return ""
        return f" (the guard itself had been stopped for {self.last_stall[1]:.1f} s just before)"

    def _got_telemetry(self, sample: Any) -> None:
        self.last_tel = sample
        self.last_tel_at = time.monotonic()

    def _silence_limit(self) -> float:
        """How long the mission process may be silent: airborne, or on the ground."""
        return self.s.silence_s if self.airborne() else self.s.rest_silence_s

    def _tick_clock(self) -> tuple[Any, float, float] | None:
        """(the tick, seconds it had run, its limit) at the last heartbeat; None between
        ticks."""
        hb = self.last_hb
        if hb is not None and len(hb) >= 4 and hb[2] is not None and hb[3] is not None:
            return hb[1], float(hb[2]), float(hb[3])
        return None

    def why_take_over(self, now: float) -> str | None:
        """The reason to take over now, or None while the mission process is in charge."""
        if not self.mission_gone and not _alive(self.s.mission_pid):
            self.mission_gone = True  # ended; its goodbye may still be unread or was lost
            self._read(now)
        own = self._own_stall(now)
        if self.mission_gone and not self.said_bye and self.airborne():
            return f"the mission process ended without a goodbye (killed or crashed){own}"
        if self.mission_gone or self.said_bye:
            if self.airborne():
                return f"the mission process ended with the drone flying{own}"
            return None
        silent = now - self.last_rx
        limit = self._silence_limit()
        if silent > limit:
            return (
                f"the mission process was silent for {silent:.2f} s (limit {limit:g} s): "
                f"blocked or stopped{own}"
            )
        clock = self._tick_clock()
        if clock is not None:
            tick, ran, limit = clock
            running = ran + (now - self.last_hb_rx)
            if running > limit:
                return (
                    f"tick {tick} has been running for {running:.1f} s (limit {limit:g} s) "
                    "and the tick watchdog could not end it"
                )
        return None

    def run(self) -> int:
        """Serve until the mission process says goodbye (or the guard took over); exit code."""
        self.last_loop = time.monotonic()  # the hello (and a link's connection) came before
        while True:
            try:
                select.select([self.sock], [], [], 0.005)
            except (OSError, ValueError):
                self.mission_gone = True
            now = time.monotonic()
            self.note_resume(now)
            self._read(now)
            self._pump_link(now)
            why = self.why_take_over(now)
            if why is not None:
                self.take_over(why)
                return 0
            if self.mission_gone or self.said_bye:
                self._finish_normally()
                return 0

    # ------------------------------------------------------------------ ending
    def _finish_normally(self) -> None:
        """The mission process ended with the drone on the ground. Without a goodbye (killed
        or crashed) and without a summary.json, the guard writes the record."""
        self._close_link()
        summary = os.path.join(self.s.run_dir, "summary.json")
        started = os.path.isdir(self.s.run_dir)  # a refused run made no folder
        if not os.path.isfile(summary) and (started or not self.said_bye):
            how = "said goodbye" if self.said_bye else "ended without a goodbye (killed or crashed)"
            # a simulated drone lives in the mission process: it ended with it, wherever it
            # was; a real one's last telemetry said it was on the ground
            where = (
                "the drone on the ground"
                if self.link is not None
                else ("a simulated drone: it ended with the process" + self._last_known())
            )
            self.took_over = {
                "reason": f"the mission process {how} and wrote no summary.json; {where}",
                "at_s": round(time.monotonic() - self.started, 3),
            }
            self._write_record({"mission_process": "gone", **self._final()})

    def _log_tail(self) -> list[bytes]:
        """The last lines of the run's tick log (about 64 kB), [] if it cannot be read."""
        try:
            with open(os.path.join(self.s.run_dir, "ticks.jsonl"), "rb") as f:
                f.seek(max(0, os.path.getsize(f.name) - 65536))
                return f.read().splitlines()
        except OSError:
            return []

    def _last_tick(self) -> tuple[int, float] | None:
        """(tick, mission time) of the tick log's last complete tick record, or None."""
        for line in reversed(self._log_tail()):
            try:
                rec = json.loads(line)
                return int(rec["tick"]), float(rec["t"])
            except (ValueError, KeyError, TypeError):
                continue
        return None

    def _last_known(self) -> str:
        """``; last known: <state> at z <m> (tick N)`` from the mission process's last
        heartbeat and tick log line, or ""."""
        lines = self._log_tail()
        for line in reversed(lines):
            if b'"vehicle"' not in line:
                continue
            try:
                rec = json.loads(line)
                v = rec["vehicle"]
                return f" (last known: {v.get('state', '?')} at z {float(v['z']):.2f} m, tick {rec.get('tick', '?')})"
            except (ValueError, KeyError, TypeError):
                continue
        return ""

    def take_over(self, reason: str) -> None:
        """Land, end the mission process, write the record, close the link."""
        at = time.monotonic()
        self.took_over = {"reason": reason, "at_s": round(at - self.started, 3)}
        self._send(["took_over", reason])
        _say(f"btrun guard: taking over: {reason}")
        landing = self.land()
        ended = self._end_mission_process()
        self._close_link()
        self._write_record({**landing, "mission_process": ended})

    def land(self) -> dict[str, Any]:
        """Land the drone straight down from its last telemetry; what happened."""
        link = self.link
        if link is None:
            return {"landing": "no link: the drone, if any, was simulated in the mission process"}
        if self.link_closed:
            return {"landing": "not needed: the mission process had closed the link"}
        t0 = time.monotonic()
        self._settle_telemetry(t0 + 0.1)
        tel = self.last_tel
        if tel is None:
            return {"landing": "no telemetry from the drone: nothing sent"}
        if not self.airborne():
            link.send_stop_setpoint()
            link.arm(False)
            return {"landing": "not needed: on the ground", **self._final()}
        x, y, yaw, z0 = tel.x_m, tel.y_m, tel.yaw_rad, tel.z_m
        period = 0.02
        touched: float | None = None
        deadline = t0 + self.s.land_max_s
        next_t = t0
        while time.monotonic() < deadline:
            now = time.monotonic()
            z = max(0.0, z0 - self.s.land_speed_mps * (now - t0))
            link.send_position_setpoint(x, y, z, yaw)
            for t in link.poll(0.0):
                self._got_telemetry(t)
            cur = self.last_tel
            if z == 0.0 and cur.z_m < GROUND_Z_M:
                touched = touched or now
                if now - touched > 0.3:
                    break
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))
        link.send_stop_setpoint()
        link.arm(False)
        self._settle_telemetry(time.monotonic() + 0.5, until_disarmed=True)
        heard = self.last_tel_at is not None and self.last_tel_at > t0
        outcome = "landed" if touched is not None else "timed out"
        if not heard:  # set-points went out, but nothing says where the drone is
            outcome = "no telemetry during the landing: the drone's state is unknown"
        return {
            "landing": outcome,
            "landing_s": round(time.monotonic() - t0, 2),
            "from_z_m": round(z0, 3),
            **self._final(),
        }

    def _settle_telemetry(self, until: float, until_disarmed: bool = False) -> None:
        while time.monotonic() < until and self.link is not None:
            for t in self.link.poll(0.0):
                self._got_telemetry(t)
            if until_disarmed and self.last_tel is not None and not self.last_tel.armed:
                return
            time.sleep(0.01)

    def _final(self) -> dict[str, Any]:
        """The drone's last telemetry, with its age: older than
        :data:`STALE_TELEMETRY_S`, it is not the drone's state now (``confirmed`` false)."""
        t = self.last_tel
        if t is None:
            return {}
        age = time.monotonic() - (self.last_tel_at or self.started)
        return {
            "final": {
                "x_m": round(t.x_m, 3),
                "y_m": round(t.y_m, 3),
                "z_m": round(t.z_m, 3),
                "armed": bool(t.armed),
                "motors_running": bool(t.motors_running),
                "battery_v": round(t.battery_v, 3),
                "telemetry_age_s": round(age, 2),
                "confirmed": age <= STALE_TELEMETRY_S,
            }
        }

    def _end_mission_process(self) -> str:
        pid = self.s.mission_pid
        if not _alive(pid):
            return "gone"
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)  # it may hold the GIL: nothing softer reaches it
        end = time.monotonic() + 2.0
        while _alive(pid) and time.monotonic() < end:
            time.sleep(0.01)
        return "killed by the guard"

    def _close_link(self) -> None:
        if self.link is not None and not self.link_closed:
            self.link_closed = True
            with contextlib.suppress(Exception):
                self.link.close()

    # ------------------------------------------------------------------ the record
    def stats(self) -> dict[str, Any]:
        """The guard's figures: IPC latency of set-points, their forwarding period."""
        lat = [1000.0 * v for v in self.latencies_s]
        ft = list(self.forward_times)
        periods = [1000.0 * (b - a) for a, b in zip(ft, ft[1:], strict=False)]
        out: dict[str, Any] = {
            "pid": os.getpid(),
            "mode": "link" if self.link is not None else "watch",
            "took_over": self.took_over is not None,
            **self.counts,
            "stalls": self.stalls,
            "longest_stall_s": round(self.longest_stall_s, 3),
        }
        if lat:
            out["setpoint_latency_ms"] = {
                "p50": _r(_percentile(lat, 0.5)),
                "p99": _r(_percentile(lat, 0.99)),
                "max": _r(max(lat)),
            }
        if periods:
            out["setpoint_period_ms"] = {
                "p50": _r(_percentile(periods, 0.5)),
                "p99": _r(_percentile(periods, 0.99)),
                "max": _r(max(periods)),
            }
        return out

    def _write_record(self, landing: dict[str, Any] | None) -> None:
        section = {**self.stats(), **(self.took_over or {}), **(landing or {})}
        section["took_over"] = True
        path = os.path.join(self.s.run_dir, "summary.json")
        summary = _read_summary(path)
        hb = self.last_hb or []
        if summary is None:
            rec = self.s.record
            ticks = hb[1] if len(hb) > 1 else 0
            mission_s = hb[4] if len(hb) > 4 else None
            logged = self._last_tick()  # the tick log's last tick, if later than the
            if logged is not None and logged[0] > (ticks or 0):  # last heartbeat's (the
                ticks, mission_s = logged  # reason's "tick N" is the log's)
            summary = {
                "status": "ABORTED",
                "reason": f"guard: {section.get('reason', 'took over')}",
                "mission": rec.get("mission"),
                "seed": rec.get("seed"),
                "rig": rec.get("rig"),
                "ticks": ticks,
                "mission_time_s": mission_s,
                "wall_time_s": round(time.monotonic() - self.started, 3),
                "written_by": "guard",
            }
        summary["guard"] = section
        try:
            _atomic_write(path, json.dumps(summary, indent=2, default=str) + "\n")
        except OSError as exc:  # no room even so: said in one line, and the state on stderr
            _say(
                f"btrun guard: {path}: cannot be written ({exc.strerror or exc}); "
                f"{summary.get('status')}: {summary.get('reason')}"
            )


def _say(line: str) -> None:
    """``line`` on the guard's stderr (btrun's terminal), if it is still there: a closed
    terminal (EIO) or pipe must never stop the guard before it has landed the drone."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _first_line(exc: BaseException) -> str:
    """An exception's message on one line, without a traceback: cflib's link errors carry
    the traceback of its reader thread in their text (``Error communicating with the
    Crazyflie`` / ``Exception:[Errno 111] Connection refused`` / ``Traceback ...``)."""
    kept: list[str] = []
    for line in str(exc).splitlines():
        if line.startswith("Traceback"):
            break
        if line.strip():
            kept.append(line.strip())
    return "; ".join(kept) or type(exc).__name__


def _r(v: float | None) -> float | None:
    return None if v is None else round(v, 3)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            state = f.read().rsplit(")", 1)[-1].split()[0]
        return state not in ("Z", "X")
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except OSError:
            return False
        return True


def _read_summary(path: str) -> dict[str, Any] | None:
    try:
        with open(path, "rb") as f:
            data = f.read(50_000_001)
        if len(data) > 50_000_000:
            return None
        out = json.loads(data)
    except (OSError, ValueError):
        return None
    return out if isinstance(out, dict) else None


def _atomic_write(path: str, text: str) -> None:
    """``text`` to ``path`` atomically; on a full disk the run folder's reserve
    (:data:`bt_engine.summary.SPACE_RESERVE`, kept for the record) is given back and it is
    tried once more."""
    reserve = os.path.join(os.path.dirname(os.path.abspath(path)), ".btrun-reserve")
    try:
        _write_once(path, text)
    except OSError:
        try:
            os.unlink(reserve)
        except OSError:
            raise  # no reserve: the first error stands
        _write_once(path, text)
    with contextlib.suppress(OSError):  # the record is written: the reserve is not needed
        os.unlink(reserve)
    with contextlib.suppress(OSError):
        os.chmod(path, 0o644)  # as btrun's own summary (mkstemp made it 0600)


def _write_once(path: str, text: str) -> None:
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".summary-", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _open_link(config: dict[str, Any]) -> Any:
    from drivers.crazyflie.cflib_link import CrazyflieLink, CrazyflieLinkConfig

    return CrazyflieLink(CrazyflieLinkConfig(**config)).open()


def main(argv: list[str] | None = None) -> int:
    """``python -m drivers.guard --fd N``: serve the mission process on socket ``N``."""
    ap = argparse.ArgumentParser(prog="python -m drivers.guard")
    ap.add_argument("--fd", type=int, required=True, help="the guard's end of the socket pair")
    args = ap.parse_args(argv)
    for sig in (signal.SIGINT, signal.SIGHUP):  # Ctrl-C and a closed terminal are btrun's
        signal.signal(sig, signal.SIG_IGN)
    # cflib logs link errors (with tracebacks) through logging's last-resort handler: the
    # guard's stderr is btrun's terminal, where only the guard's own lines belong
    logging.getLogger().addHandler(logging.NullHandler())
    sock = socket.socket(fileno=args.fd)
    ready = select.select([sock], [], [], 30.0)[0]
    msg = decode(sock.recv(MAX_MESSAGE_BYTES)) if ready else None
    if msg is None or msg[0] != "hello" or len(msg) < 2 or not isinstance(msg[1], dict):
        _say("btrun guard: no hello from the mission process")
        return 2
    settings = GuardSettings.from_hello(msg[1])
    link = None
    info: dict[str, Any] = {"pid": os.getpid()}
    if settings.link is not None:
        try:
            link = _open_link(settings.link)
        except Exception as exc:  # cflib's own errors: tell the mission process, stop
            sock.send(encode(["error", _first_line(exc)]))
            return 1
        info.update(connect_time_s=link.connect_time_s, protocol_version=link.protocol_version)
    try:
        sock.send(encode(["ready", info]))
    except OSError:  # the mission process died while the link was opening: close it quietly
        if link is not None:
            with contextlib.suppress(Exception):
                link.close()
        return 1
    return Guard(sock, settings, link).run()
