"""Benchmark: the AI-deck CPX stream client against the emulator on 127.0.0.1.

For each format, streams ``--seconds`` of frames at ``--fps`` and reports the delivered frame
rate, frames sent vs received (drops), the client's drop/corrupt counters, the transfer
latency (header packet -> last chunk) and the end-to-end latency (emulator capture stamp in
the extended header -> frame decoded; both on this machine's monotonic clock).

    .venv/bin/python bench/aideck_stream.py [--seconds 10] [--fps 15] [--renderer pattern]
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from drivers.crazyflie.aideck_stream import AIDeckStream  # noqa: E402
from drivers.sim.emulators.aideck import AIDeckEmulator, default_pose, make_frame_source  # noqa: E402
from drivers.vehicle.types import CameraFrame  # noqa: E402


def run(fmt: str, seconds: float, fps: float, renderer: str, output: str) -> dict:
    """Stream ``seconds`` of ``fmt`` frames; return the figures."""
    world = None
    if renderer != "pattern":
        from drivers.rig.loader import REPO_ROOT
        from drivers.sim.world import load_world

        world = load_world(os.path.join(REPO_ROOT, "worlds", "warehouse.yaml"))
    e2e: list[float] = []
    lock = threading.Lock()

    def on_frame(f: CameraFrame) -> None:
        now_ms = time.monotonic() * 1000.0
        with lock:
            e2e.append(((now_ms - f.meta["deck_timestamp_ms"]) % 2**32) / 1000.0)

    emu = AIDeckEmulator(
        fps=fps,
        fmt=fmt,
        header="extended",
        renderer=make_frame_source(renderer, 0, world),
        pose=default_pose(world),
    ).start()
    cam = AIDeckStream("127.0.0.1", emu.port, output=output, on_frame=on_frame)
    try:
        emu.client_connected.wait(5.0)
        time.sleep(0.5)  # warm-up
        f0, s0, t0 = cam.stats().frames, emu.frames_sent, time.monotonic()
        time.sleep(seconds)
        st, s1, t1 = cam.stats(), emu.frames_sent, time.monotonic()
        emu.close()  # stop producing ...
        time.sleep(0.3)  # ... and let the frames in flight arrive
        received, s1 = cam.stats().frames - f0, emu.frames_sent
    finally:
        cam.close()
        emu.close()
    lat = np.array(e2e[-max(1, received) :])
    return {
        "format": fmt,
        "fps": (st.frames - f0) / (t1 - t0),
        "sent": s1 - s0,
        "received": received,
        "dropped": st.dropped,
        "corrupt": st.corrupt,
        "bytes_per_frame": st.bytes / max(1, st.frames),
        "transfer_ms": st.latency_mean_s * 1e3,
        "transfer_max_ms": st.latency_max_s * 1e3,
        "e2e_median_ms": float(np.median(lat)) * 1e3,
        "e2e_p95_ms": float(np.percentile(lat, 95)) * 1e3,
    }


def main() -> None:
    """Run the benchmark for raw and JPEG and print a Markdown table."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--renderer", default="pattern", help="pattern or pallet")
    ap.add_argument("--output", default="bgr", choices=("bayer", "bgr"))
    args = ap.parse_args()
    print(f"renderer={args.renderer} output={args.output} target={args.fps:g} fps, "
          f"{args.seconds:g} s per format")  # fmt: skip
    print("| format | fps | sent | received | dropped | corrupt | bytes/frame "
          "| transfer mean/max ms | end-to-end median/p95 ms |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for fmt in ("raw", "jpeg"):
        r = run(fmt, args.seconds, args.fps, args.renderer, args.output)
        print(
            f"| {r['format']} | {r['fps']:.2f} | {r['sent']} | {r['received']} | {r['dropped']} "
            f"| {r['corrupt']} | {r['bytes_per_frame']:.0f} "
            f"| {r['transfer_ms']:.2f} / {r['transfer_max_ms']:.2f} "
            f"| {r['e2e_median_ms']:.2f} / {r['e2e_p95_ms']:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
