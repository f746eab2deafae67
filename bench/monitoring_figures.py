"""The pictures of docs/monitoring.md, made from a run's own run.mcap (no external viewer).

Reads the MCAP file the way Foxglove Studio or PlotJuggler would (the ``mcap`` reader,
channels by topic) and draws what their panels show: the camera channel with its image
annotations (the detected blocks), and the pose channel as a top view and height over time.

Usage::

    .venv/bin/btrun missions/pallet_scan.xml --seed 0 --out /tmp/fig_run -q
    .venv/bin/python bench/monitoring_figures.py /tmp/fig_run/run.mcap docs/img
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import sys

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mcap.reader import make_reader  # noqa: E402


def read(path: str) -> dict[str, list[tuple[float, dict]]]:
    """Messages by topic: ``(log time in s, decoded JSON)``."""
    out: dict[str, list[tuple[float, dict]]] = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append(
                (message.log_time / 1e9, json.loads(message.data))
            )
    return out


def camera_figure(msgs: dict, out_png: str, count: int = 3) -> None:
    """A strip of camera frames with their annotation boxes (as Foxglove's Image panel)."""
    images, notes = msgs.get("/camera/image", []), msgs.get("/camera/annotations", [])
    if not images:
        raise SystemExit("no /camera/image messages (fly a perception mission)")
    picks = np.linspace(0, len(images) - 1, count).round().astype(int)
    tiles = []
    for i in picks:
        t, img = images[i]
        raw = np.frombuffer(base64.b64decode(img["data"]), np.uint8)  # JSON: base64 bytes
        bgr = cv2.imdecode(raw, cv2.IMREAD_COLOR)
        for p in notes[i][1].get("points", []):
            pts = np.array([[q["x"], q["y"]] for q in p["points"]], np.int32)
            cv2.polylines(bgr, [pts], True, (40, 255, 50), 2)
        cv2.putText(bgr, f"t = {t:.1f} s", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (255, 255, 255), 1, cv2.LINE_AA)  # fmt: skip
        tiles.append(bgr)
    cv2.imwrite(out_png, np.hstack(tiles))


def pose_figure(msgs: dict, out_png: str) -> None:
    """Top view of /vehicle/pose and its height over time (as a 3D / Plot panel)."""
    poses = msgs.get("/vehicle/pose", [])
    t = np.array([m[0] for m in poses])
    xyz = np.array([[m[1]["pose"]["position"][k] for k in "xyz"] for m in poses])
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.2))
    a.plot(xyz[:, 0], xyz[:, 1], lw=1.2)
    a.set_xlabel("x (m)")
    a.set_ylabel("y (m)")
    a.set_title("/vehicle/pose, top view")
    a.set_aspect("equal", adjustable="datalim")
    b.plot(t, xyz[:, 2], lw=1.2)
    b.set_xlabel("mission time (s)")
    b.set_ylabel("z (m)")
    b.set_title("/vehicle/pose, height")
    fig.tight_layout()
    fig.savefig(out_png, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Write monitoring_camera.jpg and monitoring_pose.png into the output folder."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mcap", help="a run's run.mcap")
    ap.add_argument("out", help="folder for the PNG files")
    args = ap.parse_args(argv)
    msgs = read(args.mcap)
    os.makedirs(args.out, exist_ok=True)
    camera_figure(msgs, os.path.join(args.out, "monitoring_camera.jpg"))
    pose_figure(msgs, os.path.join(args.out, "monitoring_pose.png"))
    print(f"wrote {args.out}/monitoring_camera.jpg and monitoring_pose.png", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
