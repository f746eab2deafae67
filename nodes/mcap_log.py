"""``run.mcap``: the run as MCAP channels for Foxglove Studio and PlotJuggler.

:class:`McapRecorder` is a runner hook (``after_tick``/``shutdown``) that
:meth:`nodes.plugin.RigTarget.make_hooks` puts after the safety hook. It adds nothing to the
tick records: it follows ``ticks.jsonl`` as the runner writes it (line-buffered, one line per
tick, the tick's line lands right after the hooks ran), so at ``after_tick`` of tick N it
writes the channels of ticks up to N-1, and at ``shutdown`` the rest (the last tick's line is
written before the shutdown hooks run). MCAP therefore holds exactly what the tick log holds,
values bounded the same way, and ``ticks.jsonl`` stays byte-identical with or without it.

Beside the tick records it reads, without changing anything: the vehicle's current motion
request (the planned path), the perception session's recent frames with detections (camera
images and their boxes), its identifications, the world (the scene), and at the end the
platform's and the safety supervisor's summaries.

Channels, schemas and message counts are listed in :data:`CHANNELS` (the schemas:
:mod:`nodes.mcap_schemas`) and docs/monitoring.md.
All messages are JSON; log times are mission time (the simulator starts at 0 s, i.e. 1970).
Chunks are written and flushed as they fill (a killed run keeps all but the last chunk).
A killed run's file has no summary or index, so indexed readers cannot open it:
``btrun replay --repair RUN`` (:func:`bt_engine.replay.repair_mcap`) rewrites it, and btrun
does so by itself when it next reads the run (``btrun replay``, ``--resume``). The recorder
holds an advisory lock on the file while it writes, so a repair never touches a live run.
Any exception while recording is logged once as a tick-log message and recording stops;
the run goes on.
"""

from __future__ import annotations

import base64
import json
import math
import os
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from bt_engine.ticklog import to_jsonable
from nodes.mcap_schemas import CHANNELS

#: chunk size: small enough that a killed run loses little
CHUNK_BYTES = 128 * 1024
#: camera frames (with detections) recorded per second of mission time at most
FRAMES_PER_S = 5.0
JPEG_QUALITY = 80
FILE_NAME = "run.mcap"
WORLD, BODY, CAMERA, REFERENCE = "world", "base_link", "camera", "reference"

#: the metadata record holding the tick log's header (the tree's nodes; btrun replay)
HEADER_METADATA = "btrun.header"

# camera optical frame (x right, y down, z forward) in the body frame (x forward, z up)
_OPTICAL_Q = (-0.5, 0.5, -0.5, 0.5)
_SAFETY_KEYS = ("safety_state", "safety_fault", "safety_faults")
#: the camera's transform in /tf after its timestamp (it never moves on the body)
_CAMERA_TF = (
    f',"parent_frame_id":"{BODY}","child_frame_id":"{CAMERA}",'
    f'"translation":{{"x":0.0,"y":0.0,"z":0.0}},'
    f'"rotation":{{"x":{_OPTICAL_Q[0]},"y":{_OPTICAL_Q[1]},"z":{_OPTICAL_Q[2]},"w":{_OPTICAL_Q[3]}}}}}'
)


def _stamp(t: float) -> str:
    ns = max(0, round(t * 1e9))
    sec, nsec = divmod(ns, 1_000_000_000)
    return f'{{"sec":{sec},"nsec":{nsec}}}'


def _yaw_q(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def _pose(x: float, y: float, z: float, q: tuple[float, float, float, float]) -> dict:
    return {
        "position": {"x": x, "y": y, "z": z},
        "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
    }


def _color(r: float, g: float, b: float, a: float = 1.0) -> dict:
    return {"r": r, "g": g, "b": b, "a": a}


def _compression() -> CompressionType:
    """lz4, else zstd, if its library is installed; else none (the mcap extras are optional)."""
    try:
        import lz4.frame  # noqa: F401

        return CompressionType.LZ4
    except ImportError:
        pass
    try:
        import zstandard  # noqa: F401

        return CompressionType.ZSTD
    except ImportError:
        return CompressionType.NONE


class McapRecorder:
    """Runner hook writing ``run.mcap`` beside ``ticks.jsonl`` (see the module doc).

    Args:
        run_dir: the run folder (``ticks.jsonl`` must exist there, header written).
        mission: the mission (its context: log messages, the perception session).
        platform: the platform (vehicle motion, world, ``summary()``), optional.
        safety: the safety hook (its ``summary()``), optional.
    """

    def __init__(
        self,
        run_dir: str,
        mission: Any,
        platform: Any = None,
        safety: Any = None,
        tee: Any = None,
    ):
        self.mission, self.platform, self.safety = mission, platform, safety
        #: also publishes every message live (``--foxglove``: :mod:`nodes.foxglove_live`)
        self.tee = tee
        self.path = os.path.join(run_dir, FILE_NAME)
        self.error: str | None = None
        self.counts: dict[str, int] = dict.fromkeys(CHANNELS, 0)
        self._log: IO[bytes] = open(os.path.join(run_dir, "ticks.jsonl"), "rb")
        self._partial = b""
        self._header: dict | None = None
        self._f: IO[bytes] | None = open(self.path, "wb")
        _lock(self._f)  # a repair (btrun replay) leaves a file being written alone
        self._w = Writer(self._f, chunk_size=CHUNK_BYTES, compression=_compression())
        self._w.start(profile="", library="btrun")
        self._add = self._w.add_message
        self._ids: dict[str, int] = {}
        for topic, (schema, _) in CHANNELS.items():
            sid = self._w.register_schema(
                schema["title"], "jsonschema", json.dumps(schema).encode()
            )
            self._ids[topic] = self._w.register_channel(topic, "json", sid)
        self._motion: Any = None
        self._plan: list[list[float]] = []
        self._frame_index = -1
        self._frame_t = -math.inf
        self._identified = 0
        self._last_t = 0.0
        self._closed = False
        self._guard(self._follow)  # the header (and the world scene)

    # -- runner hook ------------------------------------------------------------------------
    def after_tick(self, t_s: float) -> None:
        """Write the ticks logged so far (up to the previous one) and what came meanwhile."""
        self._guard(self._follow)

    def shutdown(self, reason: str) -> None:
        """Write the rest (the last tick, the run summary) and finish the file."""
        self._guard(self._follow)
        self._guard(lambda: self._summary(reason))
        self.close()

    def close(self) -> None:
        """Finish the file (summary section, index); safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self._w.finish()  # after an error too: what was written stays readable
        except Exception as exc:  # noqa: BLE001  (recording never breaks a run)
            self._fail(exc)
        finally:
            if self._f is not None:
                self._f.close()
            self._log.close()
            if self.tee is not None:
                self.tee.close()

    # -- internals --------------------------------------------------------------------------
    def _guard(self, fn: Any) -> None:
        if self.error is not None or self._closed:
            return
        try:
            fn()
        except Exception as exc:  # noqa: BLE001  (recording never breaks a run)
            self._fail(exc)

    def _fail(self, exc: BaseException) -> None:
        if self.error is None:
            self.error = f"{type(exc).__name__}: {exc}"
            ctx = getattr(self.mission, "ctx", None)
            if ctx is not None:
                ctx.log(f"{FILE_NAME}: recording stopped: {self.error}")

    def _put(self, topic: str, t: float, data: str) -> None:
        ns = round(t * 1e9) if t > 0 else 0
        n = self.counts[topic]
        payload = data.encode()
        self._add(self._ids[topic], ns, payload, ns, n)
        self.counts[topic] = n + 1
        if self.tee is not None:
            try:
                self.tee.log(topic, ns, payload)
            except Exception as exc:  # noqa: BLE001 - the live view never stops the file
                self.tee = None
                ctx = getattr(self.mission, "ctx", None)
                if ctx is not None:
                    ctx.log(f"foxglove: live stream stopped: {type(exc).__name__}: {exc}")

    def _follow(self) -> None:
        chunk = self._log.read()
        if chunk:
            lines = (self._partial + chunk).split(b"\n")
            self._partial = lines.pop()
            for line in lines:
                if line.strip():
                    self._line(json.loads(line))
        self._perception()
        if self._f is not None:
            self._f.flush()

    def _line(self, rec: dict) -> None:
        if "header" in rec:
            self._header = rec["header"]
            self._w.add_metadata(HEADER_METADATA, {"header": json.dumps(rec["header"])})
            self._scene_world()
            return
        self._tick(rec)

    def _tick(self, rec: dict) -> None:
        tick, t = rec["tick"], rec["t"]
        self._last_t = t
        ts = _stamp(t)
        for key, value in rec.get("bb", {}).items():
            item = json.dumps({"tick": tick, "t": t, "key": key, "value": value})
            self._put("/blackboard", t, item)
            if key in _SAFETY_KEYS:
                self._put("/safety", t, item)
                level = 4 if key == "safety_fault" and value else 2
                self._log_msg(ts, t, level, "safety", f"{key} = {value}")
        for msg in rec.get("messages", ()):
            self._log_msg(ts, t, 2, "tree", str(msg))
        v = rec.get("vehicle")
        if v:
            self._vehicle(ts, tick, t, v)
        # last: a tick whose status is in the file has all its messages there (torn files)
        status = {
            k: rec[k] for k in ("tick", "t", "status", "changed", "done", "messages") if k in rec
        }
        self._put("/tree/status", t, json.dumps(status, separators=(",", ":")))

    def _log_msg(self, ts: str, t: float, level: int, name: str, text: str) -> None:
        body = json.dumps(text)
        self._put(
            "/log",
            t,
            f'{{"timestamp":{ts},"level":{level},"message":{body},"name":"{name}","file":"","line":0}}',
        )

    def _vehicle(self, ts: str, tick: int, t: float, v: dict) -> None:
        x, y, z, yaw = v.get("x", 0.0), v.get("y", 0.0), v.get("z", 0.0), v.get("yaw", 0.0)
        qz, qw = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
        # the position and the rotation appear in the pose and in the body transform
        xyz = f'{{"x":{x},"y":{y},"z":{z}}}'
        rot = f'{{"x":0.0,"y":0.0,"z":{qz!r},"w":{qw!r}}}'
        self._put(
            "/vehicle/pose",
            t,
            f'{{"timestamp":{ts},"frame_id":"{WORLD}","pose":'
            f'{{"position":{xyz},"orientation":{rot}}}}}',
        )
        self._put(
            "/vehicle/telemetry",
            t,
            json.dumps({"tick": tick, "t": t, "vehicle": v}, separators=(",", ":")),
        )
        ref = ""
        if "ref_x" in v:
            ry = v.get("ref_yaw", 0.0)
            ref = (
                f',{{"timestamp":{ts},"parent_frame_id":"{WORLD}",'
                f'"child_frame_id":"{REFERENCE}","translation":'
                f'{{"x":{v["ref_x"]},"y":{v["ref_y"]},"z":{v["ref_z"]}}},'
                f'"rotation":{{"x":0.0,"y":0.0,"z":{math.sin(ry / 2.0)!r},'
                f'"w":{math.cos(ry / 2.0)!r}}}}}'
            )
        self._put(
            "/tf",
            t,
            f'{{"transforms":[{{"timestamp":{ts},"parent_frame_id":"{WORLD}",'
            f'"child_frame_id":"{BODY}","translation":{xyz},"rotation":{rot}}},'
            f'{{"timestamp":{ts}{_CAMERA_TF}{ref}]}}',
        )
        self._plan_update(t, (x, y, z))

    # -- scene ------------------------------------------------------------------------------
    def _entity(self, t: float, eid: str, frame: str = WORLD, **prims: Any) -> dict:
        ns = max(0, round(t * 1e9))
        sec, nsec = divmod(ns, 1_000_000_000)
        ent: dict = {
            "timestamp": {"sec": sec, "nsec": nsec},
            "frame_id": frame,
            "id": eid,
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": frame != WORLD,
            "metadata": [],
        }
        for kind in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts"):
            ent[kind] = prims.get(kind, [])
        ent["models"] = []
        return ent

    def _scene_world(self) -> None:
        world = getattr(self.platform, "world", None)
        ents = []
        if world is not None:
            floor = world.data.get("floor", {})
            (sx, sy), (ox, oy) = floor.get("size_m", (20, 10)), floor.get("origin_m", (-2, -5))
            fz = float(floor.get("z_m", 0.0))
            floor_cube = {
                "pose": _pose(ox + sx / 2, oy + sy / 2, fz - 0.005, (0, 0, 0, 1)),
                "size": {"x": sx, "y": sy, "z": 0.01},
                "color": _color(0.55, 0.55, 0.55),
            }
            ents.append(self._entity(0.0, "floor", cubes=[floor_cube]))
            pallet_bodies = {id(p.body) for p in world.pallets}
            cubes, texts = [], []
            for b in world.boxes:
                if id(b) in pallet_bodies:
                    continue
                cubes.append(self._box(b, _color(0.4, 0.4, 0.45, 0.8)))
            for p in world.pallets:
                cubes.append(self._box(p.body, _color(0.76, 0.6, 0.4, 0.6)))
                cubes += [self._box(blk, _color(0.45, 0.3, 0.15)) for blk in p.blocks]
                top = p.body.cz + p.body.hz + 0.15
                texts.append(
                    {
                        "pose": _pose(p.x_m, p.y_m, top, (0, 0, 0, 1)),
                        "billboard": True,
                        "font_size": 14.0,
                        "scale_invariant": True,
                        "color": _color(1, 1, 1),
                        "text": p.identity,
                    }
                )
            ents.append(self._entity(0.0, "warehouse", cubes=cubes, texts=texts))
        drone = self._entity(
            0.0,
            "drone",
            BODY,
            cubes=[
                {
                    "pose": _pose(0, 0, 0, (0, 0, 0, 1)),
                    "size": {"x": 0.1, "y": 0.1, "z": 0.03},
                    "color": _color(0.1, 0.4, 0.9),
                }
            ],
            arrows=[
                {
                    "pose": _pose(0, 0, 0, (0, 0, 0, 1)),
                    "shaft_length": 0.12,
                    "shaft_diameter": 0.01,
                    "head_length": 0.04,
                    "head_diameter": 0.03,
                    "color": _color(1, 0.3, 0.1),
                }
            ],
        )
        ents.append(drone)
        self._put("/scene", 0.0, json.dumps({"deletions": [], "entities": ents}))

    @staticmethod
    def _box(b: Any, color: dict) -> dict:
        return {
            "pose": _pose(b.cx, b.cy, b.cz, _yaw_q(b.yaw_rad)),
            "size": {"x": 2 * b.hx, "y": 2 * b.hy, "z": 2 * b.hz},
            "color": color,
        }

    def _plan_update(self, t: float, here: tuple[float, float, float]) -> None:
        vehicle = getattr(self.platform, "vehicle", None)
        motion = getattr(vehicle, "motion", None)
        if motion is None or motion is self._motion:
            return
        self._motion = motion
        goal = [float(c) for c in motion.goal]
        if not self._plan:
            self._plan.append(list(here))
        self._plan.append(goal)
        line = {
            "type": 0,
            "pose": _pose(0, 0, 0, (0, 0, 0, 1)),
            "thickness": 0.02,
            "scale_invariant": False,
            "points": [{"x": p[0], "y": p[1], "z": p[2]} for p in self._plan],
            "color": _color(0.2, 0.9, 0.3),
            "colors": [],
            "indices": [],
        }
        goal_sphere = {
            "pose": _pose(goal[0], goal[1], goal[2], (0, 0, 0, 1)),
            "size": {"x": 0.06, "y": 0.06, "z": 0.06},
            "color": _color(0.2, 0.9, 0.3),
        }
        ent = self._entity(t, "planned_path", lines=[line], spheres=[goal_sphere])
        ent["metadata"] = [{"key": "motion", "value": str(getattr(motion, "kind", ""))}]
        self._put("/scene", t, json.dumps({"deletions": [], "entities": [ent]}))

    # -- perception -------------------------------------------------------------------------
    def _perception(self) -> None:
        ctx = getattr(self.mission, "ctx", None)
        session = ctx.resources.get("perception") if ctx is not None else None
        if session is None:
            return
        recent = getattr(session, "recent", None)
        if recent and recent[-1].index > self._frame_index:
            self._frames(recent)
        idents = getattr(session, "identifications", [])
        while self._identified < len(idents):
            rec = {k: v for k, v in idents[self._identified].items() if k != "crops"}
            self._identified += 1
            data = {"t": self._last_t, "identification": to_jsonable(rec)}
            self._put("/result", self._last_t, json.dumps(data))

    def _frames(self, recent: Any) -> None:
        for kf in list(recent):
            if kf.index <= self._frame_index:
                continue
            self._frame_index = kf.index
            if kf.t_s - self._frame_t < 1.0 / FRAMES_PER_S:
                continue
            self._frame_t = kf.t_s
            self._frame(kf)

    def _frame(self, kf: Any) -> None:
        import cv2

        ok, jpeg = cv2.imencode(".jpg", kf.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            return
        ts = _stamp(kf.t_s)
        data = base64.b64encode(jpeg.tobytes()).decode("ascii")
        self._put(
            "/camera/image",
            kf.t_s,
            f'{{"timestamp":{ts},"frame_id":"{CAMERA}","data":"{data}","format":"jpeg"}}',
        )
        stamp = json.loads(ts)
        green, black = _color(0.1, 1.0, 0.2), _color(0, 0, 0, 0.6)
        points, texts = [], []
        for x1, y1, x2, y2, score in kf.boxes:
            x1, y1, x2, y2 = float(x1), float(y1), float(x2), float(y2)
            points.append(
                {
                    "timestamp": stamp,
                    "type": 2,
                    "points": [
                        {"x": x1, "y": y1},
                        {"x": x2, "y": y1},
                        {"x": x2, "y": y2},
                        {"x": x1, "y": y2},
                    ],
                    "outline_color": green,
                    "outline_colors": [],
                    "fill_color": _color(0, 0, 0, 0),
                    "thickness": 2.0,
                }
            )
            texts.append(
                {
                    "timestamp": stamp,
                    "position": {"x": x1, "y": max(0.0, y1 - 2.0)},
                    "text": f"block {float(score):.2f}",
                    "font_size": 10.0,
                    "text_color": green,
                    "background_color": black,
                }
            )
        ann = {"circles": [], "points": points, "texts": texts}
        self._put("/camera/annotations", kf.t_s, json.dumps(ann))

    # -- end --------------------------------------------------------------------------------
    def _summary(self, reason: str) -> None:
        out: dict[str, Any] = {"t": self._last_t, "reason": reason}
        summ = getattr(self.platform, "summary", None)
        if callable(summ):
            out["sim"] = to_jsonable(summ())
        ssum = getattr(self.safety, "summary", None)
        if callable(ssum):
            out["safety"] = to_jsonable(ssum())
        self._put("/run/summary", self._last_t, json.dumps(out))


def _lock(f: IO[bytes]) -> None:
    """Hold an advisory lock on ``f`` until it is closed (or the process dies)."""
    try:
        import fcntl

        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except (ImportError, OSError):  # no advisory locks here: nothing to guard against
        pass


def repair_previous(run_dir: str | None) -> str | None:
    """Make the ``run.mcap`` of a previous run folder (``--resume RUN``) readable by indexed
    readers if a killed run left it torn (:func:`bt_engine.replay.repair_mcap`); returns the
    console line, None if there was nothing to do. Never raises."""
    from bt_engine.replay import repair_run

    if not run_dir:
        return None
    try:
        done = repair_run(run_dir)
    except Exception as exc:  # noqa: BLE001 - a repair is never a reason not to fly
        return f"{os.path.join(run_dir, FILE_NAME)}: not repaired: {type(exc).__name__}: {exc}"
    if done is None or not (done.repaired or getattr(done, "unreadable", False)):
        return None
    return done.line()  # repaired (the original kept beside), or said unreadable and left


def make_mcap_recorder(
    run_dir: str | None, platform: Any, mission: Any, safety: Any = None, tee: Any = None
) -> McapRecorder | None:
    """The recorder of a run in ``run_dir`` (None without a run folder or tick log, or if the
    file cannot be opened: recording is never a reason not to fly); ``tee`` also publishes
    every message live (a :class:`nodes.foxglove_live.FoxgloveTee`)."""
    ctx = getattr(mission, "ctx", None)
    previous = (getattr(ctx, "resources", None) or {}).get("resume_from")
    if previous and os.path.abspath(previous) != os.path.abspath(run_dir or ""):
        line = repair_previous(previous)  # btrun touches the killed run's folder again
        if line and ctx is not None:
            ctx.log(line)
    if not run_dir or not os.path.exists(os.path.join(run_dir, "ticks.jsonl")):
        return None
    try:
        return McapRecorder(run_dir, mission, platform, safety, tee)
    except Exception as exc:  # noqa: BLE001
        ctx = getattr(mission, "ctx", None)
        if ctx is not None:
            ctx.log(f"{FILE_NAME}: not recorded: {type(exc).__name__}: {exc}")
        return None
