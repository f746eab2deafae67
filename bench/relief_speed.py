"""Render time of the simulator's camera with and without the faces' relief (issue 28).

Builds the scene of a world (``worlds/warehouse.yaml`` by default) and renders a scan
past every pallet: ``--frames`` frames per pallet, the camera 0.4 m in front of its shown
face, sliding along it. Run once per setting in a fresh process (textures, normal maps
and shading are made on a face's first sight and then cached), so the first pass pays
every face's texture and the second pass is the steady per-frame cost the simulator's
15 fps sees:

    .venv/bin/python bench/relief_speed.py              # relief (the default)
    .venv/bin/python bench/relief_speed.py --flat-faces # one shade per face (before)

Prints wall and CPU milliseconds per frame for both passes.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np

from drivers.sim.renderers.pallet import scene_from_world
from drivers.sim.world import load_world
from perception.synth import relief
from perception.synth.camera_model import CameraModel, CameraPose
from perception.synth.render import render_frame


def scan_poses(world, frames: int) -> list[CameraPose]:
    """``frames`` poses per pallet, 0.4 m off its shown face, sliding 1 m along it."""
    poses = []
    for p in world.pallets:
        fx, fy, fz = p.face_center_m
        n = (math.cos(p.facing_rad), math.sin(p.facing_rad))
        r = (-n[1], n[0])
        for k in range(frames):
            s = -0.5 + k / max(1, frames - 1)
            x, y = fx + 0.4 * n[0] + s * r[0], fy + 0.4 * n[1] + s * r[1]
            poses.append(CameraPose.from_yaw(x, y, fz, p.facing_rad + math.pi))
    return poses


def main(argv: list[str] | None = None) -> int:
    """Time the two passes and print them."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--world", default="worlds/warehouse.yaml")
    ap.add_argument("--frames", type=int, default=20, help="frames per pallet")
    ap.add_argument("--flat-faces", action="store_true", help="no relief (before issue 28)")
    args = ap.parse_args(argv)
    relief.ENABLED = not args.flat_faces
    world = load_world(args.world)
    camera, rng = CameraModel(), np.random.default_rng(0)
    poses = scan_poses(world, args.frames)
    scene = scene_from_world(world)
    for name in ("first pass (textures made)", "second pass (cached)"):
        w0, c0 = time.perf_counter(), time.process_time()
        for pose in poses:
            render_frame(camera, pose, scene, rng)
        w, c = time.perf_counter() - w0, time.process_time() - c0
        print(
            f"{'flat' if args.flat_faces else 'relief'}: {name}: {len(poses)} frames, "
            f"{1000 * w / len(poses):.2f} ms wall, {1000 * c / len(poses):.2f} ms CPU per frame"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
