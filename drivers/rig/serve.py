"""``btrun sim serve crazyflie|aideck``: the emulators alone on loopback, for cfclient, cflib
scripts and the AI-deck viewers.

* ``crazyflie``: a software Crazyflie answering CRTP over UDP (``udp://127.0.0.1:19850``; a
  cflib scan of 127.0.0.1 finds ports 19850-19859), flying the rig's simulated drone in real
  time.
* ``aideck``: the AI-deck image stream (CPX over TCP), a test pattern or the pallet renderer
  seen from a fixed pose.

Both need a rig or a world, so they live here, on the rig floor, above the simulator.
Also ``python -m drivers.rig.serve crazyflie|aideck [options]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from drivers.rig.loader import load_rig
from drivers.rig.paths import DEFAULT_WORLD
from drivers.sim.emulators.aideck import AIDeckEmulator, default_pose, make_frame_source
from drivers.sim.emulators.sitl import LOOPBACK, SitlSession
from drivers.sim.world import load_world
from drivers.vehicle.types import Pose


def serve_crazyflie(argv: list[str] | None = None) -> int:
    """Serve a software Crazyflie on UDP until interrupted; returns the exit code."""
    ap = argparse.ArgumentParser(
        prog="btrun sim serve crazyflie",
        description="A software Crazyflie answering CRTP over UDP (cflib udp:// URIs).",
    )
    ap.add_argument("--host", default=LOOPBACK, help="bind address (default 127.0.0.1)")
    ap.add_argument("--port", type=int, default=19850, help="UDP port (cflib scans 19850-19859)")
    ap.add_argument("--rig", default=None, help="rig file for the simulated drone (default sim)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stats-every", type=float, default=0.0, help="print counters every N s")
    ap.add_argument(
        "--mocap",
        action="store_true",
        help="the firmware takes the simulated mocap pose itself (as extpose), as when a lab's "
        "mocap bridge feeds the drone: fly it with crazyflie.pose_source=none",
    )
    args = ap.parse_args(argv)
    sitl = SitlSession(
        load_rig(args.rig).data, args.seed, host=args.host, port=args.port, feed_mocap=args.mocap
    )
    fed = ", mocap fed to the firmware" if args.mocap else ""
    # a Ctrl-C at any point from here, even while the line below is still being printed,
    # stops the emulator and exits 0
    try:
        sitl.start()
        print(f"CRTP emulator serving {sitl.uri}{fed} (Ctrl-C to stop)", flush=True)
        while True:
            time.sleep(args.stats_every or 3600)
            if args.stats_every:
                print(sitl.truth(), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        sitl.stop()
    return 0


def serve_aideck(argv: list[str] | None = None) -> int:
    """Serve the AI-deck image stream on TCP until interrupted; returns the exit code."""
    ap = argparse.ArgumentParser(
        prog="btrun sim serve aideck",
        description="The AI-deck image stream (CPX over TCP) for the AI-deck viewers.",
    )
    ap.add_argument("--host", default="127.0.0.1", help="listen address (default loopback)")
    ap.add_argument("--port", type=int, default=5000)
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--format", choices=("raw", "jpeg"), default="raw")
    ap.add_argument("--header", choices=("basic", "extended"), default="basic",
                    help="basic: 11-byte header; extended: 25 bytes (newer viewer)")  # fmt: skip
    ap.add_argument("--renderer", default="pattern", help="pattern, or a renderer name (pallet)")
    ap.add_argument("--world", default=None, help="world file for the pallet renderer")
    ap.add_argument("--pose", type=float, nargs=4, metavar=("X", "Y", "Z", "YAW_DEG"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    world = None
    if args.renderer != "pattern":
        world = load_world(args.world or DEFAULT_WORLD)
    pose = (
        Pose(args.pose[0], args.pose[1], args.pose[2], math.radians(args.pose[3]))
        if args.pose
        else default_pose(world)
    )
    emu = AIDeckEmulator(
        args.host, args.port, args.fps, args.format, args.header,
        make_frame_source(args.renderer, args.seed, world), pose, seed=args.seed,
    )  # fmt: skip
    try:  # a Ctrl-C at any point from here stops the stream and exits 0
        print(f"AI-deck emulator on {emu.host}:{emu.port} ({args.format}, {args.fps} fps, "
              f"{args.renderer}); Ctrl-C to stop", flush=True)  # fmt: skip
        emu.start()
        while True:
            time.sleep(5.0)
            print(f"clients={emu.clients} frames={emu.frames_sent} bytes={emu.bytes_sent}",
                  flush=True)  # fmt: skip
    except KeyboardInterrupt:
        pass
    finally:
        emu.close()
    return 0


SERVERS = {"crazyflie": serve_crazyflie, "aideck": serve_aideck}


def main(argv: list[str] | None = None) -> int:
    """``python -m drivers.rig.serve crazyflie|aideck [options]``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in SERVERS:
        print("usage: python -m drivers.rig.serve crazyflie|aideck [options]", file=sys.stderr)
        return 2
    return SERVERS[argv[0]](argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
