"""The :class:`drivers.vehicle.interfaces.Link` to a real Crazyflie over cflib (radio, USB or UDP/SITL).

``CrazyflieLink(CrazyflieLinkConfig(uri=...)).open()`` connects with cflib's
``SyncCrazyflie`` (bounded by ``connect_timeout_s``: over UDP an unanswered request would
stall cflib forever), waits until every parameter was read, writes the rig's parameters
(estimator, controller, mocap standard deviations; each write confirmed by the firmware's
echo), then starts log blocks that fit the 26-byte limit:

* ``pose`` - ``stateEstimate.x/y/z/vx/vy/vz`` (24 bytes) at ``pose_rate_hz``;
* ``status`` - ``stateEstimate.qx/qy/qz/qw``, ``pm.vbat``, ``supervisor.info`` (22 bytes) at
  ``status_rate_hz``;
* ``imu`` - ``gyro.x/y/z``, ``acc.x/y/z`` (24 bytes) at ``imu_rate_hz`` (0: off).

Threads: cflib calls back on its own threads; every pose block becomes one
:class:`LinkTelemetry` (with the latest status values) in a ``queue.Queue`` that
:meth:`poll` drains on the Vehicle's thread. Commands go out from the caller's thread
(cflib's ``send_packet`` is locked).

Link loss: ``connected`` turns False when cflib reports a link error (e.g. the radio or the
UDP peer disappears) or when nothing at all arrived for ``link_timeout_s`` (a silent link:
out of range, emulator dropping packets); it turns True again if packets resume, unless
cflib closed the link. :meth:`health` gives the details.

Units: metres, m/s, radians at this API; the firmware takes degrees (yaw of position
set-points, yaw rate of velocity set-points, counter-clockwise positive like cflib's
``MotionCommander``).
"""

from __future__ import annotations

import dataclasses
import math
import os
import queue
import tempfile
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drivers.crazyflie.link_lock import LinkLock
from drivers.vehicle.angles import yaw_from_quaternion
from drivers.vehicle.interfaces import LinkTelemetry

LOG_TYPE_SIZES = {"uint8_t": 1, "int8_t": 1, "uint16_t": 2, "int16_t": 2, "FP16": 2}
MAX_LOG_BYTES = 26
POSE_VARS = [f"stateEstimate.{a}" for a in ("x", "y", "z", "vx", "vy", "vz")]
STATUS_VARS = [f"stateEstimate.q{a}" for a in "xyzw"] + ["pm.vbat", "supervisor.info"]
IMU_VARS = [f"gyro.{a}" for a in "xyz"] + [f"acc.{a}" for a in "xyz"]
DEFAULT_PARAMS = {
    "stabilizer.estimator": 2.0,  # Kalman (fuses extpose)
    "stabilizer.controller": 1.0,  # PID
    "locSrv.extPosStdDev": 0.01,
    "locSrv.extQuatStdDev": 4.5e-3,
}
BIT_ARMED, BIT_FLYING, BIT_TUMBLED, BIT_CRASHED = 1, 4, 5, 7
_init_lock = threading.Lock()
_drivers_ready = False


def init_drivers() -> None:
    """``cflib.crtp.init_drivers()`` once per process."""
    global _drivers_ready
    with _init_lock:
        if not _drivers_ready:
            import cflib.crtp

            cflib.crtp.init_drivers()
            _drivers_ready = True


#: how long a link error waits for cflib's ping thread to end (it may be waiting for the
#: send lock the erroring thread holds)
PING_STOP_WAIT_S = 0.2


def bound_ping_stop(cf: Any) -> None:
    """Make cflib's link-statistics stop of ``cf`` wait at most :data:`PING_STOP_WAIT_S`
    for its ping thread. cflib's UDP driver reports a failed send from inside
    ``Crazyflie.send_packet``, which holds the send lock; the link-error handling then
    stops the link statistics, which joined the ping thread, itself waiting for that lock:
    the sending thread (the guard's, forwarding a set-point or landing) waited for ever,
    never landed the drone nor wrote its record. The thread still ends by itself at its next
    loop once told to stop."""
    latency = getattr(getattr(cf, "link_statistics", None), "latency", None)
    if latency is None or not hasattr(latency, "_stop_event"):
        return

    def stop() -> None:
        latency._stop_event.set()
        thread = getattr(latency, "_ping_thread_instance", None)
        if thread is not None and thread is not threading.current_thread():
            thread.join(PING_STOP_WAIT_S)
        if thread is None or not thread.is_alive():  # alive: it ends at its next loop
            latency._ping_thread_instance = None

    latency.stop = stop


def plan_log_blocks(
    names: list[str], type_of: Callable[[str], str | None], max_bytes: int = MAX_LOG_BYTES
) -> tuple[list[list[str]], list[str]]:
    """Split ``names`` into blocks of at most ``max_bytes`` (in order); also the missing ones.

    ``type_of(name)`` is the TOC type (``float``, ``uint16_t``, ...) or None if absent.
    """
    blocks: list[list[str]] = [[]]
    used, missing = 0, []
    for n in names:
        t = type_of(n)
        if t is None:
            missing.append(n)
            continue
        size = LOG_TYPE_SIZES.get(t, 4)
        if used + size > max_bytes:
            blocks.append([])
            used = 0
        blocks[-1].append(n)
        used += size
    return [b for b in blocks if b], missing


def real_battery_service(kind: str) -> str:
    """On a real Crazyflie a battery is swapped by hand (which restarts it and ends the
    link): ``swap`` is refused with what to do instead. ``charge`` / ``stop_charging``
    need no command: a Crazyflie with a Qi charging deck charges while it rests on its
    pad, and the battery voltage shows it."""
    if kind == "swap":
        return (
            "a real battery is swapped by hand: the run stops here; swap it and "
            "continue with btrun MISSION --resume RUN_FOLDER"
        )
    if kind in ("charge", "stop_charging"):
        return ""
    return f"unknown battery service {kind!r} (swap, charge, stop_charging)"


@dataclass
class CrazyflieLinkConfig:
    """Settings of the cflib link (the rig's ``crazyflie:`` section)."""

    uri: str = "radio://0/80/2M/E7E7E7E7E7"
    params: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_PARAMS))
    pose_rate_hz: float = 100.0
    status_rate_hz: float = 50.0
    imu_rate_hz: float = 0.0
    link_timeout_s: float = 0.5
    connect_timeout_s: float = 10.0
    toc_cache_dir: str | None = None

    @classmethod
    def from_rig(cls, section: dict[str, Any], uri: str | None = None) -> CrazyflieLinkConfig:
        """From a validated rig ``crazyflie:`` section (``uri`` overrides its uri)."""
        lg = section["log"]
        return cls(
            uri=uri or section["uri"],
            params=dict(section["params"]),
            pose_rate_hz=lg["pose_rate_hz"],
            status_rate_hz=lg["status_rate_hz"],
            imu_rate_hz=lg["imu_rate_hz"],
            link_timeout_s=section["link_timeout_s"],
            connect_timeout_s=section["connect_timeout_s"],
            toc_cache_dir=section["toc_cache_dir"],
        )


class CrazyflieLink:
    """Implements :class:`drivers.vehicle.interfaces.Link` with cflib."""

    def __init__(self, config: CrazyflieLinkConfig, time_fn: Callable[[], float] = time.monotonic):
        self.config = config
        self._now = time_fn
        self.scf: Any = None
        self.cf: Any = None
        self.protocol_version = -1
        self.connect_time_s = math.nan
        self.params_set: dict[str, str] = {}
        self.missing: list[str] = []
        self.lost_reason: str | None = None
        self.closed = False
        self._address_lock: LinkLock | None = None  # held while the link is open
        self._queue: queue.Queue[LinkTelemetry] = queue.Queue()
        self._lock = threading.Lock()
        self._status = {n: 0.0 for n in STATUS_VARS}
        self._status["stateEstimate.qw"] = 1.0
        self._status_seen = threading.Event()
        self.imu: dict[str, float] = {}
        self._last_rx = -math.inf
        self.packets_rx = 0
        self.pose_samples = 0
        self.pose_gaps = 0
        self._last_stamp_ms: int | None = None
        self._pose_period_ms = 1000.0 / config.pose_rate_hz
        self._configs: list[Any] = []
        self.block_errors: list[str] = []

    # ------------------------------------------------------------------ connection
    def open(self) -> CrazyflieLink:
        """Connect, read parameters, write the rig's, start logging. Raises ConnectionError
        (:class:`~drivers.crazyflie.link_lock.LinkInUse` while another process of this host
        has a link to the same address open)."""
        init_drivers()
        c = self.config
        self._address_lock = LinkLock(c.uri).acquire()  # LinkInUse: another btrun flies it
        try:
            return self._open()
        except BaseException:
            self._address_lock.release()
            raise

    def _open(self) -> CrazyflieLink:
        from cflib.crazyflie import Crazyflie
        from cflib.crazyflie.syncCrazyflie import SyncCrazyflie

        c = self.config
        t0 = self._now()
        cache = c.toc_cache_dir or os.path.join(tempfile.gettempdir(), "btrun-cflib-toc")
        os.makedirs(cache, exist_ok=True)
        self.cf = Crazyflie(rw_cache=cache)
        bound_ping_stop(self.cf)
        self.scf = SyncCrazyflie(c.uri, cf=self.cf)
        self.cf.packet_received.add_callback(self._on_packet)
        self.cf.connection_lost.add_callback(self._on_lost)
        errors: list[BaseException] = []

        def connect() -> None:
            try:
                self.scf.open_link()
            except Exception as exc:  # cflib raises plain Exception with its message
                errors.append(exc)

        th = threading.Thread(target=connect, name="cf-connect", daemon=True)
        th.start()
        th.join(c.connect_timeout_s)
        if th.is_alive():  # nothing answers: release SyncCrazyflie and give up
            self.cf.connection_failed.call(c.uri, "timeout")
            th.join(1.0)
            self._abort()
            raise ConnectionError(f"{c.uri}: no answer within {c.connect_timeout_s:g} s")
        if errors or not self.scf.is_link_open():
            self._abort()
            raise ConnectionError(f"{c.uri}: {errors[0] if errors else 'connection failed'}")
        end = t0 + c.connect_timeout_s
        while not self.scf.is_params_updated():
            if self._now() > end:
                self.close()
                raise ConnectionError(f"{c.uri}: parameters not read within the timeout")
            time.sleep(0.005)
        self.protocol_version = self.cf.platform.get_protocol_version()
        self._write_params(end)
        self._start_logging(end)
        self.connect_time_s = self._now() - t0
        return self

    def _abort(self) -> None:
        try:
            self.cf.close_link()
        except Exception:
            pass
        self.closed = True

    def _write_params(self, end: float) -> None:
        toc = self.cf.param.toc
        for name, value in self.config.params.items():
            if toc.get_element_by_complete_name(name) is None:
                self.missing.append(name)
                continue
            group, var = name.split(".", 1)
            done = threading.Event()
            got: list[str] = []

            def cb(_name: str, v: str, got: list[str] = got, done: threading.Event = done) -> None:
                got.append(v)
                done.set()

            self.cf.param.add_update_callback(group=group, name=var, cb=cb)
            try:
                self.cf.param.set_value(name, value)
                if not done.wait(max(0.0, end - self._now())):
                    raise ConnectionError(f"{self.config.uri}: no echo for parameter {name}")
            finally:
                self.cf.param.remove_update_callback(group=group, name=var, cb=cb)
            self.params_set[name] = got[-1]

    def _type_of(self, name: str) -> str | None:
        el = self.cf.log.toc.get_element_by_complete_name(name)
        return None if el is None else el.ctype

    def _start_logging(self, end: float) -> None:
        from cflib.crazyflie.log import LogConfig

        c = self.config
        plan = [("pose", POSE_VARS, c.pose_rate_hz, self._on_pose)]
        plan.append(("status", STATUS_VARS, c.status_rate_hz, self._on_status))
        if c.imu_rate_hz > 0:
            plan.append(("imu", IMU_VARS, c.imu_rate_hz, self._on_imu))
        for name, names, rate, cb in plan:
            blocks, missing = plan_log_blocks(names, self._type_of)
            self.missing += missing
            for i, block in enumerate(blocks):
                conf = LogConfig(f"{name}{i}", period_in_ms=max(10, round(1000.0 / rate)))
                for n in block:
                    conf.add_variable(n)
                self.cf.log.add_config(conf)
                conf.data_received_cb.add_callback(cb)
                conf.error_cb.add_callback(lambda lc, msg: self.block_errors.append(msg))
                conf.start()
                self._configs.append(conf)
        while not all(conf.started for conf in self._configs):
            if self._now() > end or self.block_errors:
                raise ConnectionError(f"{c.uri}: log blocks not started {self.block_errors}")
            time.sleep(0.002)
        while self.pose_samples == 0:  # the first complete sample (status, then pose)
            if self._now() > end:
                raise ConnectionError(f"{c.uri}: no telemetry within the timeout")
            time.sleep(0.002)

    # ------------------------------------------------------------------ cflib threads
    def _on_packet(self, _pk: Any) -> None:
        self._last_rx = self._now()
        self.packets_rx += 1

    def _on_lost(self, _uri: str, msg: str) -> None:
        self.lost_reason = f"cflib: {msg.splitlines()[0] if msg else 'link error'}"

    def _on_status(self, _stamp: int, data: dict[str, float], _conf: Any) -> None:
        with self._lock:
            self._status.update(data)
        self._status_seen.set()

    def _on_imu(self, _stamp: int, data: dict[str, float], _conf: Any) -> None:
        with self._lock:
            self.imu = dict(data)

    def _on_pose(self, stamp: int, d: dict[str, float], _conf: Any) -> None:
        if not self._status_seen.is_set():  # no battery/attitude yet: not a full sample
            return
        last = self._last_stamp_ms
        if last is not None:
            dt = (stamp - last) & 0xFFFFFF
            if dt > 1.5 * self._pose_period_ms:
                self.pose_gaps += round(dt / self._pose_period_ms) - 1
        self._last_stamp_ms = stamp
        self.pose_samples += 1
        with self._lock:
            s = dict(self._status)
        q = (
            s["stateEstimate.qx"],
            s["stateEstimate.qy"],
            s["stateEstimate.qz"],
            s["stateEstimate.qw"],
        )
        bits = int(s.get("supervisor.info", 0))
        self._queue.put(
            LinkTelemetry(
                stamp / 1000.0,
                d["stateEstimate.x"],
                d["stateEstimate.y"],
                d["stateEstimate.z"],
                d["stateEstimate.vx"],
                d["stateEstimate.vy"],
                d["stateEstimate.vz"],
                yaw_from_quaternion(q),
                q,
                s["pm.vbat"],
                bool(bits >> BIT_ARMED & 1),
                bool(bits >> BIT_FLYING & 1),
                bool(bits >> BIT_CRASHED & 1),
                bool(bits >> BIT_TUMBLED & 1),
            )
        )

    # ------------------------------------------------------------------ Link protocol
    @property
    def connected(self) -> bool:
        """True while cflib has the link open and packets arrived within ``link_timeout_s``."""
        if self.closed or self.lost_reason is not None or self.cf is None:
            return False
        return self._now() - self._last_rx <= self.config.link_timeout_s

    def _usable(self) -> bool:
        return not self.closed and self.cf is not None and self.cf.link is not None

    def arm(self, armed: bool) -> bool:
        """Supervisor arming (protocol >= 12; cflib falls back to the platform request)."""
        if not self._usable():
            return False
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", UserWarning)
            self.cf.supervisor.send_arming_request(bool(armed))
        return True

    def send_position_setpoint(self, x_m: float, y_m: float, z_m: float, yaw_rad: float) -> None:
        if self._usable():
            self.cf.commander.send_position_setpoint(x_m, y_m, z_m, math.degrees(yaw_rad))

    def send_velocity_setpoint(
        self, vx_mps: float, vy_mps: float, vz_mps: float, yaw_rate_radps: float
    ) -> None:
        if self._usable():
            self.cf.commander.send_velocity_world_setpoint(
                vx_mps, vy_mps, vz_mps, math.degrees(yaw_rate_radps)
            )

    def send_stop_setpoint(self) -> None:
        if self._usable():
            self.cf.commander.send_stop_setpoint()

    def send_external_pose(
        self, x_m: float, y_m: float, z_m: float, quaternion: tuple[float, float, float, float]
    ) -> None:
        if self._usable():
            qx, qy, qz, qw = quaternion
            self.cf.extpos.send_extpose(x_m, y_m, z_m, qx, qy, qz, qw)

    def emergency_stop(self) -> None:
        if self._usable():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self.cf.supervisor.send_emergency_stop()
            self.cf.commander.send_stop_setpoint()

    def poll(self, now_s: float) -> list[LinkTelemetry]:
        """Telemetry received since the last poll, stamped with ``now_s`` (mission time)."""
        out = []
        while True:
            try:
                tel = self._queue.get_nowait()
            except queue.Empty:
                break
            out.append(dataclasses.replace(tel, t_s=now_s))
        return out

    def battery_service(self, kind: str) -> str:
        """See :func:`real_battery_service`."""
        return real_battery_service(kind)

    def close(self) -> None:
        """Stop the motors (stop set-point, notify stop) and close the link (idempotent)."""
        if self.cf is None or self.closed:
            return
        self.closed = True
        try:
            if self.cf.link is not None:
                self.cf.commander.send_stop_setpoint()
                self.cf.commander.send_notify_setpoint_stop()
        finally:
            try:
                if self.scf is not None and self.scf.is_link_open():
                    self.scf.close_link()
                else:
                    self.cf.close_link()
            finally:
                if self._address_lock is not None:
                    self._address_lock.release()

    # ------------------------------------------------------------------ reporting
    def health(self) -> dict[str, Any]:
        """Link state for logs and summaries."""
        age = self._now() - self._last_rx
        return {
            "uri": self.config.uri,
            "connected": self.connected,
            "lost_reason": self.lost_reason
            or ("closed" if self.closed else None)
            or (None if age <= self.config.link_timeout_s else f"silent for {age:.2f} s"),
            "age_s": round(age, 4) if math.isfinite(age) else None,
            "protocol_version": self.protocol_version,
            "connect_time_s": round(self.connect_time_s, 4),
            "packets_rx": self.packets_rx,
            "pose_samples": self.pose_samples,
            "pose_gaps": self.pose_gaps,
            "params_set": dict(self.params_set),
            "missing": list(self.missing),
        }
