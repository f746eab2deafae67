"""Flight actions: Arm, Disarm, Offboard, TakeOff, GoTo, FollowPath, Hover, Land, Echo.

Names and ports follow Aerostack2's behaviour-tree nodes, so its mission files run unchanged
(``<Action ID="TakeOff" height="1" speed="0.5"/>``, ``pose="x;y;z"``, integer yaw modes).
Every motion has a time-out; a halted motion leaves the drone holding position.
"""

from __future__ import annotations

import math

from bt_engine.node import (
    FAILURE,
    RUNNING,
    SUCCESS,
    BTNode,
    NodeStatus,
    StatefulActionNode,
    SyncActionNode,
)
from bt_engine.ports import (
    ANY,
    BOOL,
    DURATION,
    FLOAT,
    PATH,
    STRING,
    VEC3,
    input_port,
    output_port,
)
from bt_engine.registry import register
from nodes.common import (
    CATEGORY_FLIGHT,
    YAW_MODE,
    angle_input,
    outside_geofence,
    vehicle_of,
    yaw_mode_value,
)

DEFAULT_POS_THRESHOLD_M = 0.03  # the reference study's go-to completion threshold
DEFAULT_YAW_THRESHOLD_RAD = math.radians(15.0)


_SERVICE = input_port("service_name", STRING, "", "accepted for Aerostack2 files; ignored")


def _motion_ports(timeout_s: float) -> tuple:
    return (
        input_port(
            "pos_threshold",
            FLOAT,
            DEFAULT_POS_THRESHOLD_M,
            "position tolerance in m",
            low=0.005,
            high=2.0,
        ),
        input_port(
            "yaw_threshold",
            FLOAT,
            DEFAULT_YAW_THRESHOLD_RAD,
            "yaw tolerance in rad",
            low=0.001,
            high=3.15,
        ),
        input_port(
            "yaw_threshold_deg",
            FLOAT,
            None,
            "yaw tolerance in degrees (overrides yaw_threshold)",
            low=0.05,
            high=180.0,
        ),
        input_port(
            "settle_time", DURATION, 0.0, "time both tolerances must hold before SUCCESS, s"
        ),
        input_port("timeout", DURATION, timeout_s, "FAILURE if not done within this time, s"),
        output_port("distance_to_go", FLOAT, "distance to the goal in m, every tick"),
        output_port("yaw_error", FLOAT, "goal yaw minus yaw in rad, wrapped to [-pi, pi]"),
    )


class _Motion(StatefulActionNode):
    """Common run loop of motions: wait for the vehicle's progress, settle, time out."""

    category = CATEGORY_FLIGHT

    def start_motion(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def on_start(self) -> NodeStatus:
        self.vehicle = vehicle_of(self)
        self.settle_s = self.get_input("settle_time") if self.port_decl("settle_time") else 0.0
        self.timeout_s = self.get_input("timeout")
        self.started_s = self.now()
        self.reached_since: float | None = None
        self.progress = self.start_motion()
        p = self.progress
        pos_tol, yaw_tol = (
            self.tolerances()
            if self.port_decl("pos_threshold")
            else (p.position_tolerance_m, p.yaw_tolerance_rad)
        )
        # One record per motion, for the flight report (what was asked, when, and how it ended).
        self.record = {
            "node": self.path,
            "name": self.name,
            "kind": self.bt_id,
            "goal": list(p.goal),
            "goal_yaw_rad": p.goal_yaw_rad,
            "pos_threshold_m": pos_tol,
            "yaw_threshold_rad": yaw_tol,
            "t_start": self.started_s,
            "t_reached": None,
            "t_end": None,
            "result": "RUNNING",
        }
        self.ctx.resources.setdefault("motions", []).append(self.record)
        if p.failed:
            return self._fail(p.reason)
        return self.on_running()

    def done(self) -> bool:
        """True when the motion has completed (default: both tolerances hold)."""
        return self.progress.reached

    def on_running(self) -> NodeStatus:
        p = self.progress
        self.set_output("distance_to_go", p.distance_m)
        self.set_output("yaw_error", p.yaw_error_rad)
        if p.failed or p.cancelled:
            return self._fail(p.reason or "cancelled by another motion")
        now = self.now()
        if self.done():
            if self.reached_since is None:
                self.reached_since = now
                if self.record["t_reached"] is None:
                    self.record["t_reached"] = now
            if now - self.reached_since >= self.settle_s - 1e-9:
                return self._finish(SUCCESS)
        else:
            self.reached_since = None
        if now - self.started_s >= self.timeout_s - 1e-9:
            self.vehicle.hover()
            return self._fail(
                f"time-out after {self.timeout_s:g} s (distance to go {p.distance_m:.3f} m, "
                f"yaw error {math.degrees(p.yaw_error_rad):.1f} deg)"
            )
        return RUNNING

    def _finish(self, status: NodeStatus, reason: str = "") -> NodeStatus:
        rec = getattr(self, "record", None)
        if rec is not None:
            p = self.progress
            rec.update(
                t_end=self.now(),
                result=status.value,
                reason=reason,
                final_distance_m=p.distance_m,
                final_yaw_error_rad=p.yaw_error_rad,
            )
        return status

    def _fail(self, reason: str) -> NodeStatus:
        self.ctx.log(f"{self.describe()} failed: {reason}")
        self.failure_reason = reason  # the run's result line and summary say why
        return self._finish(FAILURE, reason)

    def on_halted(self) -> None:
        self._finish(NodeStatus.IDLE, "halted")
        v = getattr(self, "vehicle", None)
        # Hold position, unless a newer motion (a sibling that took over, e.g. a Land in a
        # ReactiveFallback) already replaced ours: never cancel someone else's motion.
        if v is not None and v.is_flying and v.motion is getattr(self, "progress", None):
            v.hover()

    def tolerances(self) -> tuple[float, float]:
        """(position m, yaw rad) tolerances from the ports."""
        yaw = angle_input(self, "yaw_threshold", "yaw_threshold_deg")
        return self.get_input("pos_threshold"), yaw


def _start_point(node: BTNode) -> tuple[float, float, float]:
    """Where the drone stands before flight: a simulated rig's ``sim.start_m`` (its
    vehicle reads the origin until the simulation steps); raises for a real drone, whose
    start is only known once it is connected and tracked."""
    data = node.ctx.resources["rig"].data
    if data["link"] != "sim":
        raise LookupError("the drone's start is not known before it connects")
    x, y, z = data["sim"]["start_m"]
    return float(x), float(y), float(z)


@register
class TakeOff(_Motion):
    """Climb ``height`` metres above the current position at ``speed`` m/s (arms if needed).

    RUNNING while climbing; SUCCESS at the height; FAILURE if the drone cannot take off
    (crashed, link down, already flying) or on time-out.
    """

    bt_id = "TakeOff"
    ports = (
        input_port("height", FLOAT, 1.0, "height above the take-off point, m", low=0.05, high=20.0),
        input_port("speed", FLOAT, 0.5, "climb speed, m/s", low=0.01, high=5.0),
        input_port("timeout", DURATION, 30.0, "FAILURE if not done within this time, s"),
        output_port("takeoff_point", VEC3, "where the climb ends (x;y;z): a place to return to"),
    )

    def preflight(self) -> list[tuple[str, str]]:
        """A climb that would end above the rig's geofence, refused before it starts."""
        try:
            height = float(self.get_input("height"))
            x, y, z = _start_point(self)
        except Exception:  # noqa: BLE001 - no start known, or written in flight: checked then
            return []
        if self.port_decl("height").out_of_range(height) is not None:  # the range check says it
            return []
        what = f"height {height:g} (the climb ends at z {z + height:g} m)"
        return outside_geofence(self, "height", [(x, y, z + height)], what)

    def start_motion(self):
        progress = self.vehicle.takeoff(self.get_input("height"), self.get_input("speed"))
        self.set_output("takeoff_point", tuple(progress.goal))
        return progress


@register
class GoTo(_Motion):
    """Fly a straight line to ``pose`` ("x;y;z", m) at up to ``max_speed`` m/s.

    The yaw follows ``yaw_mode``: KEEP_YAW (0), PATH_FACING (1: face the direction of travel,
    chosen when the node starts) or FIXED_YAW (2: ``yaw_angle`` rad or ``yaw_angle_deg``),
    always turning the shortest way. RUNNING until the position error is within
    ``pos_threshold`` and the wrapped yaw error within ``yaw_threshold`` (held for
    ``settle_time``), then SUCCESS. FAILURE on ``timeout`` (the drone then holds) or a vehicle
    fault. Halted by a parent, the drone holds position. ``relative`` makes ``pose`` an
    offset from the current position.
    """

    bt_id = "GoTo"
    ports = (
        input_port("pose", VEC3, description="goal position x;y;z in m"),
        input_port("max_speed", FLOAT, 0.5, "speed limit, m/s", low=0.01, high=5.0),
        input_port(
            "yaw_mode", YAW_MODE, "KEEP_YAW", "KEEP_YAW, PATH_FACING or FIXED_YAW (or 0, 1, 2)"
        ),
        input_port("yaw_angle", FLOAT, 0.0, "yaw for FIXED_YAW, rad"),
        input_port(
            "yaw_angle_deg", FLOAT, None, "yaw for FIXED_YAW in degrees (overrides yaw_angle)"
        ),
        input_port("relative", BOOL, False, "pose is an offset from the current position"),
        input_port("frame_id", STRING, "earth", "reference frame (only 'earth' is supported)"),
    ) + _motion_ports(60.0)

    def preflight(self) -> list[tuple[str, str]]:
        """A goal outside the rig's geofence (not an offset: ``relative``), refused before
        anything flies."""
        try:
            if self.get_input("relative"):
                return []
            pose = self.get_input("pose")
        except Exception:  # noqa: BLE001 - written in flight: the supervisor watches it
            return []
        return outside_geofence(self, "pose", [pose])

    def start_motion(self):
        x, y, z = self.get_input("pose")
        if self.get_input("relative"):
            px, py, pz = self.vehicle.position
            x, y, z = x + px, y + py, z + pz
        frame = self.get_input("frame_id")
        if frame not in ("earth", "world", "map"):
            from bt_engine.node import NodeRuntimeError

            raise NodeRuntimeError(self, f"frame_id {frame!r} is not supported (use 'earth')")
        pos_tol, yaw_tol = self.tolerances()
        return self.vehicle.go_to(
            x,
            y,
            z,
            yaw_mode_value(self.get_input("yaw_mode")),
            angle_input(self, "yaw_angle", "yaw_angle_deg"),
            self.get_input("max_speed"),
            position_tolerance_m=pos_tol,
            yaw_tolerance_rad=yaw_tol,
            timeout_s=None,
        )


@register
class FollowPath(_Motion):
    """Fly through the waypoints of ``path`` ("x;y;z|x;y;z|...") at ``speed`` m/s.

    SUCCESS when the last waypoint is reached within the tolerances; yaw per ``yaw_mode``.
    """

    bt_id = "FollowPath"
    ports = (
        input_port("path", PATH, description="waypoints x;y;z|x;y;z|... in m"),
        input_port("speed", FLOAT, 0.5, "speed along the path, m/s", low=0.01, high=5.0),
        input_port("yaw_mode", YAW_MODE, "KEEP_YAW", "KEEP_YAW, PATH_FACING or FIXED_YAW"),
        input_port("yaw_angle", FLOAT, 0.0, "yaw for FIXED_YAW, rad"),
        input_port("yaw_angle_deg", FLOAT, None, "yaw for FIXED_YAW in degrees"),
        input_port("path_topic_name", STRING, "", "accepted for Aerostack2 files; ignored"),
        input_port("server_timeout", STRING, "", "accepted for Aerostack2 files; ignored"),
        _SERVICE,
    ) + _motion_ports(120.0)

    def preflight(self) -> list[tuple[str, str]]:
        """Waypoints outside the rig's geofence, refused before anything flies."""
        try:
            path = self.get_input("path")
        except Exception:  # noqa: BLE001 - written in flight: the supervisor watches it
            return []
        return outside_geofence(self, "path", path)

    def start_motion(self):
        pos_tol, yaw_tol = self.tolerances()
        return self.vehicle.follow_path(
            list(self.get_input("path")),
            self.get_input("speed"),
            yaw_mode_value(self.get_input("yaw_mode")),
            angle_input(self, "yaw_angle", "yaw_angle_deg"),
            position_tolerance_m=pos_tol,
            yaw_tolerance_rad=yaw_tol,
        )


@register
class Hover(_Motion):
    """Stop and hold position for ``duration`` seconds, then SUCCESS."""

    bt_id = "Hover"
    ports = (
        input_port("duration", DURATION, 1.0, "how long to hold, s"),
        input_port("timeout", DURATION, 3600.0, "FAILURE if not done within this time, s"),
    )

    def start_motion(self):
        self.until = self.now() + self.get_input("duration")
        return self.vehicle.hover()

    def done(self) -> bool:
        return self.now() >= self.until - 1e-9


@register
class Land(_Motion):
    """Descend at ``speed`` m/s and stop the motors; SUCCESS once landed."""

    bt_id = "Land"
    ports = (
        input_port("speed", FLOAT, 0.5, "descent speed, m/s", low=0.01, high=3.0),
        input_port("timeout", DURATION, 60.0, "FAILURE if not landed within this time, s"),
    )

    def start_motion(self):
        if self.vehicle.is_landed:
            self.already = True
            from drivers.vehicle.progress import MotionProgress

            return MotionProgress("land", self.vehicle.position, 0.0, 0.0, 0.0, self.now())
        self.already = False
        return self.vehicle.land(self.get_input("speed"))

    def done(self) -> bool:
        return self.vehicle.is_landed

    def on_halted(self) -> None:
        pass  # a halted landing keeps going down: never leave a drone hovering by accident


@register
class Arm(SyncActionNode):
    """Arm the motors. SUCCESS if the request was accepted."""

    bt_id = "Arm"
    category = CATEGORY_FLIGHT
    ports = (_SERVICE,)

    def tick_impl(self) -> NodeStatus:
        return SUCCESS if vehicle_of(self).arm() else FAILURE


@register
class Disarm(SyncActionNode):
    """Disarm the motors. FAILURE while flying."""

    bt_id = "Disarm"
    category = CATEGORY_FLIGHT
    ports = (_SERVICE,)

    def tick_impl(self) -> NodeStatus:
        return SUCCESS if vehicle_of(self).disarm() else FAILURE


@register
class Offboard(SyncActionNode):
    """Accepted for Aerostack2 files: a Crazyflie has no offboard mode, so this is a no-op."""

    bt_id = "Offboard"
    category = CATEGORY_FLIGHT
    ports = (_SERVICE,)

    def tick_impl(self) -> NodeStatus:
        return SUCCESS


@register
class Echo(SyncActionNode):
    """Print ``data`` in the run log (and the terminal); SUCCESS."""

    bt_id = "Echo"
    category = CATEGORY_FLIGHT
    ports = (input_port("data", ANY, "", "text or {entry} to print"),)

    def tick_impl(self) -> NodeStatus:
        self.ctx.log(f"{self.name}: {self.get_input('data')}")
        return SUCCESS
