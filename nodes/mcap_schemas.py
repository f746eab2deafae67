"""The JSON schemas and channels of ``run.mcap`` (see :mod:`nodes.mcap_log`, docs/monitoring.md).

Foxglove's well-known schemas in their JSON encoding (written from Foxglove's documentation),
btrun's own for the tick records, and :data:`CHANNELS`: topic -> (schema, what one message is).
"""

from __future__ import annotations


def _obj(title: str, props: dict, desc: str = "") -> dict:
    out: dict = {"title": title, "type": "object", "properties": props}
    if desc:
        out["description"] = desc
    return out


def _arr(item: dict) -> dict:
    return {"type": "array", "items": item}


def _enum(title: str, names: list[str]) -> dict:
    return {"title": title, "oneOf": [{"title": n, "const": i} for i, n in enumerate(names)]}


_NUM, _STR, _BOOL, _INT = (
    {"type": "number"},
    {"type": "string"},
    {"type": "boolean"},
    {"type": "integer"},
)
_TIME = _obj(
    "time", {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}
)
_DURATION = _obj("duration", {"sec": _INT, "nsec": {"type": "integer", "minimum": 0}})
_VEC3 = _obj("foxglove.Vector3", {"x": _NUM, "y": _NUM, "z": _NUM})
_POINT3 = _obj("foxglove.Point3", {"x": _NUM, "y": _NUM, "z": _NUM})
_POINT2 = _obj("foxglove.Point2", {"x": _NUM, "y": _NUM})
_QUAT = _obj("foxglove.Quaternion", {"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM})
_COLOR = _obj("foxglove.Color", {"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM})
_POSE = _obj("foxglove.Pose", {"position": _VEC3, "orientation": _QUAT})
_KV = _obj("foxglove.KeyValuePair", {"key": _STR, "value": _STR})

POSE_IN_FRAME = _obj(
    "foxglove.PoseInFrame",
    {"timestamp": _TIME, "frame_id": _STR, "pose": _POSE},
    "A timestamped pose for an object or reference frame in 3D space",
)
FRAME_TRANSFORM = _obj(
    "foxglove.FrameTransform",
    {
        "timestamp": _TIME,
        "parent_frame_id": _STR,
        "child_frame_id": _STR,
        "translation": _VEC3,
        "rotation": _QUAT,
    },
    "A transform between two reference frames in 3D space",
)
FRAME_TRANSFORMS = _obj(
    "foxglove.FrameTransforms",
    {"transforms": _arr(FRAME_TRANSFORM)},
    "An array of FrameTransform messages",
)
_LINE_TYPE = _enum("foxglove.LineType", ["LINE_STRIP", "LINE_LOOP", "LINE_LIST"])
SCENE_UPDATE = _obj(
    "foxglove.SceneUpdate",
    {
        "deletions": _arr(
            _obj(
                "foxglove.SceneEntityDeletion",
                {
                    "timestamp": _TIME,
                    "type": _enum("foxglove.SceneEntityDeletionType", ["MATCHING_ID", "ALL"]),
                    "id": _STR,
                },
            )
        ),
        "entities": _arr(
            _obj(
                "foxglove.SceneEntity",
                {
                    "timestamp": _TIME,
                    "frame_id": _STR,
                    "id": _STR,
                    "lifetime": _DURATION,
                    "frame_locked": _BOOL,
                    "metadata": _arr(_KV),
                    "arrows": _arr(
                        _obj(
                            "foxglove.ArrowPrimitive",
                            {
                                "pose": _POSE,
                                "shaft_length": _NUM,
                                "shaft_diameter": _NUM,
                                "head_length": _NUM,
                                "head_diameter": _NUM,
                                "color": _COLOR,
                            },
                        )
                    ),
                    "cubes": _arr(
                        _obj(
                            "foxglove.CubePrimitive",
                            {"pose": _POSE, "size": _VEC3, "color": _COLOR},
                        )
                    ),
                    "spheres": _arr(
                        _obj(
                            "foxglove.SpherePrimitive",
                            {"pose": _POSE, "size": _VEC3, "color": _COLOR},
                        )
                    ),
                    "cylinders": _arr(
                        _obj(
                            "foxglove.CylinderPrimitive",
                            {
                                "pose": _POSE,
                                "size": _VEC3,
                                "bottom_scale": _NUM,
                                "top_scale": _NUM,
                                "color": _COLOR,
                            },
                        )
                    ),
                    "lines": _arr(
                        _obj(
                            "foxglove.LinePrimitive",
                            {
                                "type": _LINE_TYPE,
                                "pose": _POSE,
                                "thickness": _NUM,
                                "scale_invariant": _BOOL,
                                "points": _arr(_POINT3),
                                "color": _COLOR,
                                "colors": _arr(_COLOR),
                                "indices": _arr(_INT),
                            },
                        )
                    ),
                    "triangles": _arr(
                        _obj(
                            "foxglove.TriangleListPrimitive",
                            {
                                "pose": _POSE,
                                "points": _arr(_POINT3),
                                "color": _COLOR,
                                "colors": _arr(_COLOR),
                                "indices": _arr(_INT),
                            },
                        )
                    ),
                    "texts": _arr(
                        _obj(
                            "foxglove.TextPrimitive",
                            {
                                "pose": _POSE,
                                "billboard": _BOOL,
                                "font_size": _NUM,
                                "scale_invariant": _BOOL,
                                "color": _COLOR,
                                "text": _STR,
                            },
                        )
                    ),
                    "models": _arr(
                        _obj(
                            "foxglove.ModelPrimitive",
                            {
                                "pose": _POSE,
                                "scale": _VEC3,
                                "color": _COLOR,
                                "override_color": _BOOL,
                                "url": _STR,
                                "media_type": _STR,
                                "data": {"type": "string", "contentEncoding": "base64"},
                            },
                        )
                    ),
                },
            )
        ),
    },
    "An update to the entities displayed in a 3D scene",
)
COMPRESSED_IMAGE = _obj(
    "foxglove.CompressedImage",
    {
        "timestamp": _TIME,
        "frame_id": _STR,
        "data": {"type": "string", "contentEncoding": "base64"},
        "format": _STR,
    },
    "A compressed image",
)
IMAGE_ANNOTATIONS = _obj(
    "foxglove.ImageAnnotations",
    {
        "circles": _arr(
            _obj(
                "foxglove.CircleAnnotation",
                {
                    "timestamp": _TIME,
                    "position": _POINT2,
                    "diameter": _NUM,
                    "thickness": _NUM,
                    "fill_color": _COLOR,
                    "outline_color": _COLOR,
                },
            )
        ),
        "points": _arr(
            _obj(
                "foxglove.PointsAnnotation",
                {
                    "timestamp": _TIME,
                    "type": _enum(
                        "foxglove.PointsAnnotationType",
                        ["UNKNOWN", "POINTS", "LINE_LOOP", "LINE_STRIP", "LINE_LIST"],
                    ),
                    "points": _arr(_POINT2),
                    "outline_color": _COLOR,
                    "outline_colors": _arr(_COLOR),
                    "fill_color": _COLOR,
                    "thickness": _NUM,
                },
            )
        ),
        "texts": _arr(
            _obj(
                "foxglove.TextAnnotation",
                {
                    "timestamp": _TIME,
                    "position": _POINT2,
                    "text": _STR,
                    "font_size": _NUM,
                    "text_color": _COLOR,
                    "background_color": _COLOR,
                },
            )
        ),
    },
    "Array of annotations for a 2D image",
)
LOG = _obj(
    "foxglove.Log",
    {
        "timestamp": _TIME,
        "level": _enum(
            "foxglove.LogLevel", ["UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL"]
        ),
        "message": _STR,
        "name": _STR,
        "file": _STR,
        "line": {"type": "integer", "minimum": 0},
    },
    "A log message",
)
_ANY: dict = {}
TREE_STATUS = _obj(
    "btrun.TreeStatus",
    {
        "tick": _INT,
        "t": _NUM,
        "status": _STR,
        "changed": {"type": "object", "additionalProperties": _STR},
        "done": {"type": "object", "additionalProperties": _STR},
        "messages": _arr(_STR),
    },
    "One tick of the tree: root status, statuses changed in the tick (ticks.jsonl's fields)",
)
BLACKBOARD_WRITE = _obj(
    "btrun.BlackboardWrite",
    {"tick": _INT, "t": _NUM, "key": _STR, "value": _ANY},
    "One blackboard entry written in a tick",
)
TELEMETRY = _obj(
    "btrun.Telemetry",
    {"tick": _INT, "t": _NUM, "vehicle": {"type": "object"}},
    "The tick log's vehicle row (pose, reference, state, battery)",
)
SAFETY_EVENT = _obj(
    "btrun.SafetyEvent",
    {"tick": _INT, "t": _NUM, "key": _STR, "value": _ANY},
    "A value the safety supervisor published (safety_state, safety_fault, safety_faults)",
)
IDENTIFICATION = _obj(
    "btrun.Identification",
    {"t": _NUM, "identification": {"type": "object"}},
    "One pallet identification (the perception session's record, without the crops)",
)
RUN_SUMMARY = _obj(
    "btrun.RunSummary",
    {"t": _NUM, "reason": _STR, "sim": {"type": "object"}, "safety": {"type": "object"}},
    "How the run ended: the platform's ground truth and the safety supervisor's summary",
)

#: topic -> (schema, what one message is)
CHANNELS: dict[str, tuple[dict, str]] = {
    "/tree/status": (TREE_STATUS, "one per tick"),
    "/blackboard": (BLACKBOARD_WRITE, "one per blackboard entry written (ticks.jsonl bb)"),
    "/log": (LOG, "one per node message, and one per safety event"),
    "/vehicle/pose": (POSE_IN_FRAME, "one per tick with a vehicle row"),
    "/vehicle/telemetry": (TELEMETRY, "one per tick with a vehicle row (with the reference)"),
    "/tf": (FRAME_TRANSFORMS, "one per tick with a vehicle row (base_link, camera, reference)"),
    "/scene": (SCENE_UPDATE, "one at the start, one per new motion request (planned path)"),
    "/camera/image": (COMPRESSED_IMAGE, "one per recorded frame with detections"),
    "/camera/annotations": (IMAGE_ANNOTATIONS, "one per recorded frame (same count)"),
    "/safety": (SAFETY_EVENT, "one per safety_* blackboard write"),
    "/result": (IDENTIFICATION, "one per pallet identification"),
    "/run/summary": (RUN_SUMMARY, "one, when the run ends"),
}
