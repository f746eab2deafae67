"""run.mcap (nodes/mcap_log.py): channels, schemas and message counts against ticks.jsonl,
``btrun replay`` of the MCAP file, determinism of the tick log, a failing recorder, a file
cut short, and (slow) the camera, annotation and identification channels of the pallet scan."""

from __future__ import annotations

import contextlib
import io
import json
import os

import numpy as np
import pytest
from helpers import REPO
from mcap.reader import make_reader

from bt_engine.cli import main
from bt_engine.replay import read_mcap
from bt_engine.ticklog import read_log
from nodes import mcap_log

SQUARE = os.path.join(REPO, "missions", "square.xml")
PALLET_SCAN = os.path.join(REPO, "missions", "pallet_scan.xml")
SAFETY_KEYS = ("safety_state", "safety_fault", "safety_faults")


def btrun(*argv: str) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(list(argv))
    return code, out.getvalue()


def fly(mission: str, out: str) -> str:
    code, text = btrun(mission, "--seed", "0", "--out", out, "-q", "--no-report")
    assert code == 0, text
    return out


def read(path: str) -> tuple[dict, dict[str, list[tuple[int, dict]]]]:
    """(channel topic -> (schema name, schema encoding, message encoding), messages by topic)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "run.mcap was not finished"
        channels = {
            c.topic: (
                summary.schemas[c.schema_id].name,
                summary.schemas[c.schema_id].encoding,
                c.message_encoding,
            )
            for c in summary.channels.values()
        }
        msgs: dict[str, list[tuple[int, dict]]] = {t: [] for t in channels}
        for _schema, channel, message in reader.iter_messages():
            msgs[channel.topic].append((message.log_time, json.loads(message.data)))
    return channels, msgs


@pytest.fixture(scope="module")
def square(tmp_path_factory):
    """missions/square.xml flown once through btrun: (run folder, channels, messages)."""
    out = fly(SQUARE, str(tmp_path_factory.mktemp("square") / "run"))
    channels, msgs = read(os.path.join(out, "run.mcap"))
    return out, channels, msgs


def test_every_channel_has_its_foxglove_or_btrun_schema(square):
    _, channels, msgs = square
    assert set(channels) == set(mcap_log.CHANNELS)
    for topic, (schema, _what) in mcap_log.CHANNELS.items():
        assert channels[topic] == (schema["title"], "jsonschema", "json"), topic
    names = {c[0] for c in channels.values()}
    assert {
        "foxglove.PoseInFrame",
        "foxglove.FrameTransforms",
        "foxglove.SceneUpdate",
        "foxglove.CompressedImage",
        "foxglove.ImageAnnotations",
        "foxglove.Log",
    } <= names
    # the 3D scene: the floor, the warehouse (pallets as boxes) and the drone at the start,
    # then the planned path as the motions come
    first = msgs["/scene"][0][1]["entities"]
    ids = [e["id"] for e in first]
    assert {"floor", "warehouse", "drone"} <= set(ids)
    assert len(first[ids.index("warehouse")]["cubes"]) >= 5
    plans = [m for _, m in msgs["/scene"][1:]]
    assert plans and all(m["entities"][0]["id"] == "planned_path" for m in plans)
    last_plan = plans[-1]["entities"][0]["lines"][0]["points"]
    assert len(last_plan) == len(plans) + 1  # start + one goal per motion
    assert {round(p["x"]) for p in last_plan} >= {0, 2}


def test_message_counts_follow_the_tick_log(square):
    out, _, msgs = square
    _, records = read_log(os.path.join(out, "ticks.jsonl"))
    with_vehicle = [r for r in records if "vehicle" in r]
    writes = [(r["tick"], k) for r in records for k in r.get("bb", {})]
    safety = [w for w in writes if w[1] in SAFETY_KEYS]
    node_msgs = sum(len(r.get("messages", ())) for r in records)
    n = {topic: len(m) for topic, m in msgs.items()}
    assert n["/tree/status"] == len(records) > 100
    assert n["/vehicle/pose"] == n["/tf"] == n["/vehicle/telemetry"] == len(with_vehicle)
    assert n["/blackboard"] == len(writes) > 0
    assert n["/safety"] == len(safety) > 0
    assert n["/log"] == node_msgs + len(safety)
    assert n["/run/summary"] == 1
    assert n["/camera/image"] == n["/camera/annotations"] == n["/result"] == 0
    # log times are mission time; tree status and pose of a tick share it
    ticks = {m["tick"]: (t, m) for t, m in msgs["/tree/status"]}
    for rec in records[:50]:
        t, m = ticks[rec["tick"]]
        assert t == round(rec["t"] * 1e9) and m["status"] == rec["status"]
    t, pose = msgs["/vehicle/pose"][-1]
    assert pose["frame_id"] == "world"
    assert pose["pose"]["position"]["x"] == with_vehicle[-1]["vehicle"]["x"]
    mid = msgs["/tf"][len(msgs["/tf"]) // 2][1]
    frames = {tf["child_frame_id"] for tf in mid["transforms"]}
    assert frames == {"base_link", "camera", "reference"}
    summary = msgs["/run/summary"][0][1]
    assert summary["sim"]["landed"] is True and summary["safety"]


def test_mcap_reads_back_into_the_tick_log_records(square):
    out, _, _ = square
    assert read_mcap(os.path.join(out, "run.mcap")) == read_log(os.path.join(out, "ticks.jsonl"))


def test_replay_of_run_mcap_shows_the_same_tree(square):
    out, _, _ = square
    _, records = read_log(os.path.join(out, "ticks.jsonl"))
    for tick in (1, 150, len(records) // 2, len(records)):
        code1, from_log = btrun("replay", out, "--tick", str(tick))
        code2, from_mcap = btrun("replay", os.path.join(out, "run.mcap"), "--tick", str(tick))
        assert code1 == code2 == 0
        assert from_mcap == from_log and "tick" in from_log


def test_a_file_cut_short_gives_the_ticks_it_holds(square, tmp_path):
    out, _, _ = square
    header, records = read_log(os.path.join(out, "ticks.jsonl"))
    data = open(os.path.join(out, "run.mcap"), "rb").read()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 3])
    h, recs = read_mcap(str(cut))
    assert h == header and 0 < len(recs) < len(records)
    assert recs == records[: len(recs)]  # complete ticks only


def test_the_recorder_leaves_the_tick_log_byte_identical(square, tmp_path, monkeypatch):
    out, _, _ = square
    monkeypatch.setattr(mcap_log, "make_mcap_recorder", lambda *a, **k: None)
    bare = fly(SQUARE, str(tmp_path / "bare"))
    assert not os.path.exists(os.path.join(bare, "run.mcap"))
    logs = []
    for run in (bare, out):
        with open(os.path.join(run, "ticks.jsonl"), "rb") as f:
            header = json.loads(f.readline())["header"]
            header.pop("started")  # the wall-clock time the run started
            header.pop("run_dir")  # the folder it was written to
            logs.append((header, f.read()))
    assert logs[0] == logs[1]


def test_a_failing_recorder_logs_once_and_the_mission_goes_on(tmp_path, monkeypatch):
    real = mcap_log.McapRecorder._vehicle

    def broken(self, ts, tick, t, v):
        if tick >= 100:
            raise RuntimeError("disk on fire")
        real(self, ts, tick, t, v)

    monkeypatch.setattr(mcap_log.McapRecorder, "_vehicle", broken)
    out = fly(SQUARE, str(tmp_path / "run"))  # exit code 0: SUCCESS
    _, records = read_log(os.path.join(out, "ticks.jsonl"))
    notes = [m for r in records for m in r.get("messages", ()) if "run.mcap" in m]
    assert notes == ["run.mcap: recording stopped: RuntimeError: disk on fire"]
    _, recs = read_mcap(os.path.join(out, "run.mcap"))
    assert 90 <= len(recs) < 110 and recs == records[: len(recs)]


@pytest.mark.slow
def test_pallet_scan_records_camera_frames_boxes_and_the_identification(tmp_path):
    out = fly(PALLET_SCAN, str(tmp_path / "scan"))
    channels, msgs = read(os.path.join(out, "run.mcap"))
    images, notes = msgs["/camera/image"], msgs["/camera/annotations"]
    assert 10 <= len(images) == len(notes)
    times = [t for t, _ in images]
    assert [t for t, _ in notes] == times
    assert (
        min(b - a for a, b in zip(times, times[1:], strict=False))
        >= 1e9 / mcap_log.FRAMES_PER_S - 1
    )
    import cv2

    img = images[0][1]
    assert img["format"] == "jpeg" and img["frame_id"] == "camera"
    import base64

    jpeg = np.frombuffer(base64.b64decode(img["data"]), np.uint8)
    assert cv2.imdecode(jpeg, cv2.IMREAD_COLOR).shape == (244, 324, 3)
    boxes = notes[0][1]["points"]
    assert boxes and all(b["type"] == 2 and len(b["points"]) == 4 for b in boxes)
    assert len(notes[0][1]["texts"]) == len(boxes)
    summary = json.load(open(os.path.join(out, "summary.json")))
    (result,) = [m for _, m in msgs["/result"]]
    assert result["identification"]["pallet_id"] == summary["blackboard"]["pallet_id"]
    scene = msgs["/scene"][0][1]["entities"]
    labels = {t["text"] for e in scene for t in e["texts"]}
    assert len(labels) == len(summary["sim"]["pallets"])
