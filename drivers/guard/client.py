"""The mission process's side of the guard: start it, beat, and fly through it.

:class:`GuardClient` starts the guard process (:mod:`drivers.guard.server`) in a session of
its own, sends it the hello, keeps a heartbeat thread beating (the tick in progress and how
long it may take), reads what the guard sends back on a reader thread, and is a runner hook
(``before_tick`` / ``after_tick`` note each tick; ``finished`` says goodbye once
``summary.json`` is written). :class:`GuardLink` is the
:class:`~drivers.vehicle.interfaces.Link` a :class:`~drivers.crazyflie.cf_platform.
CrazyfliePlatform` flies through when the guard owns the cflib link: every call is one
message, never a wait, so the control loop's rate does not depend on the guard.

The heartbeat thread is a plain Python thread: it stops when the process dies, is stopped,
or is blocked holding the GIL, which is exactly when the guard must act.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from drivers.guard.server import TELEMETRY_FIELDS
from drivers.guard.wire import MAX_MESSAGE_BYTES, decode, encode, socket_pair
from drivers.vehicle.interfaces import LinkTelemetry

#: Seconds between heartbeats.
HEARTBEAT_PERIOD_S = 0.05
#: seconds btrun's own link may take to reach a drone whose guard died in flight: the
#: firmware stops the motors 2 s after the last set-point
FALLBACK_CONNECT_S = 1.5
#: seconds the goodbye may wait for a guard that is not reading (every other message is
#: dropped rather than waited for)
BYE_WAIT_S = 2.0


class GuardError(RuntimeError):
    """The guard could not be started, or could not open the link."""


class GuardClient:
    """Start a guard for the run in ``run_dir`` and talk to it.

    Args:
        run_dir: the run folder (the guard writes ``summary.json`` there if it must).
        record: what the guard's own summary names (``mission``, ``seed``, ``rig``).
        silence_s: silence of the mission process after which the guard takes over while
            the drone is airborne; ``rest_silence_s`` on the ground and in watch mode.
        land_speed_mps, land_max_s: the guard's landing.
        tick_limit_s: how long one tick may run before the guard takes over (the in-process
            watchdog's budgets are shorter: this is for a tick nothing in-process can end).
        rest_tick_limit_s: the same while the drone is at rest (a first tick that loads
            models or builds a gallery).
        at_rest: True while the drone is on the ground (read on the ticking thread).
        tick_limit_scale: a factor on ``tick_limit_s``, read at each heartbeat (lock-step on
            a busy host: :func:`bt_engine.watchdog.busy_factor`).
        progress: lock-step: when (``time.monotonic()``) a long tick last did bounded work
            (a texture made), read at each heartbeat; the tick's running time counts from
            then.
    """

    def __init__(
        self,
        run_dir: str,
        record: dict[str, Any] | None = None,
        silence_s: float = 0.5,
        rest_silence_s: float = 10.0,
        land_speed_mps: float = 0.3,
        land_max_s: float = 15.0,
        tick_limit_s: float = 30.0,
        rest_tick_limit_s: float = 1200.0,
        at_rest: Callable[[], bool] | None = None,
        tick_limit_scale: Callable[[], float] | None = None,
        progress: Callable[[], float | None] | None = None,
    ) -> None:
        self.run_dir = run_dir
        self.tick_limit_scale = tick_limit_scale
        self.progress = progress
        self.settings = {
            "run_dir": os.path.abspath(run_dir),
            "mission_pid": os.getpid(),
            "silence_s": float(silence_s),
            "rest_silence_s": float(rest_silence_s),
            "land_speed_mps": float(land_speed_mps),
            "land_max_s": float(land_max_s),
            "record": dict(record or {}),
        }
        self.tick_limit_s = float(tick_limit_s)
        self.rest_tick_limit_s = float(rest_tick_limit_s)
        self.at_rest = at_rest
        self.proc: subprocess.Popen | None = None
        self.sock: Any = None
        self.link: GuardLink | None = None
        self.info: dict[str, Any] = {}
        self.took_over: str | None = None
        self.gone = False
        #: messages dropped while the guard did not read, and the longest such time (s)
        self.unsent, self.longest_unread_s = 0, 0.0
        self._unread_since: float | None = None
        self._replies: dict[str, Any] = {}
        self._reply_events: dict[str, threading.Event] = {}
        self._ticks = 0
        self._tick_started: float | None = None
        self._tick_limit = self.rest_tick_limit_s
        self._mission_t = 0.0
        self._last_beat = 0.0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._said_bye = False

    # ------------------------------------------------------------------ start
    def start(self, link_config: Any = None, timeout_s: float = 30.0) -> GuardClient:
        """Start the guard process; with ``link_config`` (a ``CrazyflieLinkConfig``) the
        guard opens the link first. Raises :class:`GuardError` if it cannot."""
        ours, theirs = socket_pair()
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        self.proc = subprocess.Popen(  # its stderr is btrun's: a take-over is told there
            [sys.executable, "-m", "drivers.guard", "--fd", str(theirs.fileno())],
            pass_fds=[theirs.fileno()],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            start_new_session=True,  # Ctrl-C to the terminal and killpg(btrun) miss it
            env=env,
        )
        theirs.close()
        self.sock = ours
        hello = dict(self.settings)
        if link_config is not None:
            hello["link"] = dataclasses.asdict(link_config)
            timeout_s = max(timeout_s, float(getattr(link_config, "connect_timeout_s", 0)) + 10)
        ours.send(encode(["hello", hello]))
        ours.settimeout(timeout_s)
        try:
            msg = decode(ours.recv(MAX_MESSAGE_BYTES))
        except OSError as exc:
            self._kill()
            raise GuardError(f"the guard did not answer within {timeout_s:g} s ({exc})") from None
        finally:
            ours.settimeout(None)
        if msg is None or msg[0] != "ready":
            why = msg[1] if msg is not None and len(msg) > 1 else "it exited"
            self._kill()
            raise GuardError(f"guard: {why}")
        self.info = dict(msg[1]) if len(msg) > 1 and isinstance(msg[1], dict) else {}
        if link_config is not None:
            self.link = GuardLink(self, link_config)
        for name, target in (("guard-reader", self._read_loop), ("guard-heartbeat", self._beat)):
            th = threading.Thread(target=target, name=name, daemon=True)
            th.start()
            self._threads.append(th)
        return self

    def _kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(2.0)
        if self.sock is not None:
            self.sock.close()

    # ------------------------------------------------------------------ wire
    def send(self, message: list[Any]) -> bool:
        """Send one message, never a wait: False once the guard is gone, or while it does
        not read (stopped or frozen: its socket's buffer full; the message is dropped and
        counted, and how long it stopped reading is kept for the summary). A blocking send
        there froze the whole mission process, tick watchdog included, until the guard
        read again."""
        if self.gone or self.sock is None:
            return False
        try:
            self.sock.send(encode(message), socket.MSG_DONTWAIT)
        except BlockingIOError:
            now = time.monotonic()
            self.unsent += 1
            if self._unread_since is None:
                self._unread_since = now
            self.longest_unread_s = max(self.longest_unread_s, now - self._unread_since)
            return False
        except OSError:
            self.gone = True
            return False
        self._unread_since = None
        return True

    def request(self, kind: str, reply: str, timeout_s: float = 2.0) -> Any:
        """Send ``[kind]`` and wait (bounded) for the guard's ``reply``; None if none came."""
        ev = self._reply_events.setdefault(reply, threading.Event())
        ev.clear()
        if not self.send([kind]):
            return None
        return self._replies.get(reply) if ev.wait(timeout_s) else None

    def _read_loop(self) -> None:
        sock = self.sock
        while not self._stop.is_set():
            try:
                data = sock.recv(MAX_MESSAGE_BYTES)
            except OSError:
                data = b""
            if not data:
                self.gone = True
                return
            msg = decode(data)
            if msg is None:
                continue
            kind = msg[0]
            if kind == "T" and self.link is not None and len(msg) >= 3:
                self.link.receive(msg[1], bool(msg[2]))
            elif kind == "H" and self.link is not None and len(msg) >= 2:
                self.link.last_health = dict(msg[1])
            elif kind == "took_over":
                self.took_over = str(msg[1]) if len(msg) > 1 else "took over"
            else:
                self._replies[kind] = msg[1] if len(msg) > 1 else None
                ev = self._reply_events.setdefault(kind, threading.Event())
                ev.set()

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_PERIOD_S):
            if not self._send_beat():
                return

    def _send_beat(self) -> bool:
        now = time.monotonic()
        self._last_beat = now
        started = self._tick_started
        if self.progress is not None and started is not None:
            with contextlib.suppress(Exception):  # from the tick's last progress
                started = max(started, self.progress() or started)
        running = None if started is None else now - started
        limit = self._tick_limit
        if self.tick_limit_scale is not None and limit == self.tick_limit_s:
            with contextlib.suppress(Exception):
                limit *= max(1.0, float(self.tick_limit_scale()))
        return self.send(["hb", self._ticks, running, limit, self._mission_t])

    # ------------------------------------------------------------------ runner hook
    def before_tick(self, t_s: float) -> None:
        """A tick begins: its limit is the rest one while the drone is on the ground."""
        rest = False
        if self.at_rest is not None:
            with contextlib.suppress(Exception):
                rest = bool(self.at_rest())
        self._tick_limit = self.rest_tick_limit_s if rest else self.tick_limit_s
        self._ticks += 1
        self._mission_t = t_s
        self._tick_started = time.monotonic()
        if self._tick_started - self._last_beat > HEARTBEAT_PERIOD_S:
            # the ticking thread beats too: a busy lock-step loop can starve the beat thread
            self._send_beat()

    def after_tick(self, t_s: float) -> None:
        """The tick returned."""
        self._tick_started = None

    def shutdown(self, reason: str) -> None:
        """Nothing: the platform lands and closes the link through :class:`GuardLink`."""
        self._tick_started = None

    def summary(self) -> dict[str, Any]:
        """``guard`` in summary.json: the guard's figures (IPC latency, set-point period)."""
        stats = self.request("stats", "stats", 1.0) or {}
        out = {"enabled": True, **stats, "took_over": self.took_over is not None}
        if self.unsent:  # the guard stopped reading (stopped, frozen): said, not hidden
            out["mission_messages_unsent"] = self.unsent
            out["guard_not_reading_s"] = round(self.longest_unread_s, 3)
        if self.gone and not self._said_bye:
            out["guard_gone"] = True  # it ended (killed) before the run did
        return out

    def finished(self, summary_written: bool = True) -> None:
        """Say goodbye (summary.json is written) and wait, bounded, for the guard to end."""
        if self._said_bye:
            return
        self._said_bye = True
        if not self.send(["bye", bool(summary_written)]) and not self.gone and self.sock:
            # the guard is not reading (stopped, starved): its buffer is full. The goodbye
            # is the one message worth a wait, bounded: without it the guard, once it runs
            # again, takes the end of this process for a crash
            with contextlib.suppress(OSError):
                self.sock.settimeout(BYE_WAIT_S)
                self.sock.sendall(encode(["bye", bool(summary_written)]))
        proc = self.proc
        if proc is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(5.0)
        self._stop.set()
        if self.sock is not None:
            with contextlib.suppress(OSError):
                self.sock.close()


class GuardLink:
    """A :class:`~drivers.vehicle.interfaces.Link` whose cflib link lives in the guard."""

    def __init__(self, client: GuardClient, config: Any) -> None:
        self.client = client
        self.config = config
        self.connect_time_s = float(client.info.get("connect_time_s") or 0.0)
        self.protocol_version = int(client.info.get("protocol_version") or -1)
        self.last_health: dict[str, Any] = {"uri": config.uri, "connected": True}
        self._samples: deque[LinkTelemetry] = deque(maxlen=10_000)
        self._lock = threading.Lock()
        self._connected = True
        self._last_rx = time.monotonic()
        self.closed = False
        #: btrun's own cflib link, opened when the guard died with the drone in the air:
        #: "" (not needed), "opening", "open" or "failed: <why>"
        self.fallback = ""
        self._direct: Any = None
        self._fb_lock = threading.Lock()

    # ------------------------------------------------------------------ the guard died
    def _guard_died(self) -> bool:
        c = self.client
        return c.gone and not c._said_bye and c.took_over is None and not self.closed

    def _via(self) -> Any:
        """btrun's own link when the guard that held the radio died in flight (opened on a
        thread of its own the first time this is asked; None while it opens, if it could
        not, or while the guard is there). The guard's death released the drone's address
        (:mod:`drivers.crazyflie.link_lock`), and the firmware keeps the motors 2 s after
        the last set-point: reached within that, the safety supervisor lands the drone."""
        if not self._guard_died():
            return None
        with self._fb_lock:
            if not self.fallback:
                self.fallback = "opening"
                threading.Thread(
                    target=self._open_direct, name="guard-fallback", daemon=True
                ).start()
        return self._direct

    def _open_direct(self) -> None:
        from drivers.crazyflie.cflib_link import CrazyflieLink

        timeout = min(float(getattr(self.config, "connect_timeout_s", 10.0)), FALLBACK_CONNECT_S)
        try:
            config = dataclasses.replace(self.config, connect_timeout_s=timeout)
            link = CrazyflieLink(config).open()
        except Exception as exc:  # noqa: BLE001 - said in the summary; the drone is lost
            self.fallback = (
                f"failed: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
            )
            return
        if self.closed:  # the run ended meanwhile
            with contextlib.suppress(Exception):
                link.close()
            return
        self._direct = link
        self.fallback = "open"

    def receive(self, rows: list[list[Any]], connected: bool) -> None:
        """Reader thread: a telemetry batch from the guard."""
        samples = []
        for row in rows:
            if len(row) != len(TELEMETRY_FIELDS):
                continue
            kw = dict(zip(TELEMETRY_FIELDS, row, strict=True))
            kw["quaternion"] = tuple(kw["quaternion"])
            samples.append(LinkTelemetry(**kw))
        with self._lock:
            self._samples.extend(samples)
            self._connected = connected
            self._last_rx = time.monotonic()

    # ------------------------------------------------------------------ Link protocol
    @property
    def connected(self) -> bool:
        """The guard is there, has not taken over, and its link was up at its last batch."""
        direct = self._via()
        if direct is not None:
            return bool(direct.connected)
        c = self.client
        if self.closed or c.gone or c.took_over is not None:
            return False
        return self._connected and time.monotonic() - self._last_rx <= self.config.link_timeout_s

    @property
    def gone_for_good(self) -> bool:
        """The guard process ended before the run did, its cflib link with it, and btrun's
        own link could not reach the drone either (:meth:`_via`): no command reaches it any
        more (the safety supervisor does not wait on it)."""
        if not (self.client.gone and not self.client._said_bye):
            return False
        self._via()
        return self.fallback.startswith("failed")

    def arm(self, armed: bool) -> bool:
        """Forward an arming request."""
        direct = self._via()
        if direct is not None:
            return bool(direct.arm(armed))
        return self.client.send(["arm", bool(armed)])

    def send_position_setpoint(self, x_m: float, y_m: float, z_m: float, yaw_rad: float) -> None:
        """Forward a position set-point (stamped with its send time)."""
        direct = self._via()
        if direct is not None:
            direct.send_position_setpoint(x_m, y_m, z_m, yaw_rad)
            return
        self.client.send(["p", x_m, y_m, z_m, yaw_rad, time.monotonic()])

    def send_velocity_setpoint(
        self, vx_mps: float, vy_mps: float, vz_mps: float, yaw_rate_radps: float
    ) -> None:
        """Forward a velocity set-point (stamped with its send time)."""
        direct = self._via()
        if direct is not None:
            direct.send_velocity_setpoint(vx_mps, vy_mps, vz_mps, yaw_rate_radps)
            return
        self.client.send(["v", vx_mps, vy_mps, vz_mps, yaw_rate_radps, time.monotonic()])

    def send_stop_setpoint(self) -> None:
        """Forward a stop set-point."""
        direct = self._via()
        if direct is not None:
            direct.send_stop_setpoint()
            return
        self.client.send(["s"])

    def send_external_pose(
        self, x_m: float, y_m: float, z_m: float, quaternion: tuple[float, float, float, float]
    ) -> None:
        """Forward a mocap pose to the drone's estimator."""
        direct = self._via()
        if direct is not None:
            direct.send_external_pose(x_m, y_m, z_m, quaternion)
            return
        self.client.send(["e", x_m, y_m, z_m, *quaternion])

    def emergency_stop(self) -> None:
        """Forward an emergency stop."""
        direct = self._via()
        if direct is not None:
            direct.emergency_stop()
            return
        self.client.send(["estop"])

    def poll(self, now_s: float) -> list[LinkTelemetry]:
        """Telemetry received since the last poll, stamped with ``now_s``."""
        direct = self._via()
        if direct is not None:
            return direct.poll(now_s)
        with self._lock:
            out = [dataclasses.replace(t, t_s=now_s) for t in self._samples]
            self._samples.clear()
        return out

    def battery_service(self, kind: str) -> str:
        """As :meth:`drivers.crazyflie.cflib_link.CrazyflieLink.battery_service`."""
        from drivers.crazyflie.cflib_link import real_battery_service

        return real_battery_service(kind)

    def close(self) -> None:
        """Ask the guard to close the cflib link and wait (bounded) until it has (or close
        btrun's own link, opened when the guard died)."""
        if self.closed:
            return
        self.closed = True
        direct, self._direct = self._direct, None
        if direct is not None:
            with contextlib.suppress(Exception):
                direct.close()
            self.last_health = {**self.last_health, "connected": False}
            return
        health = self.client.request("close", "closed", 3.0)
        if isinstance(health, dict):
            self.last_health = health

    def health(self) -> dict[str, Any]:
        """The guard's last report of the link, plus the guard's own state."""
        direct = self._direct
        out = dict(direct.health()) if direct is not None else dict(self.last_health)
        out["via_guard"] = True
        if self.fallback:
            out["fallback_link"] = self.fallback  # btrun's own link after the guard died
        if self.client.took_over is not None:
            out["guard_took_over"] = self.client.took_over
        return out
