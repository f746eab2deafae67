"""SITL link figures: the real cflib driver against the CRTP emulator on 127.0.0.1.

1. connect-to-ready: ``CrazyflieLink.open()`` (link, TOCs, every parameter read, the rig's
   parameters written and confirmed, log blocks started, first sample) - median of N.
2. pose log rate at 100 Hz: ``stateEstimate`` pose blocks received per second over a hover,
   gaps counted from the firmware timestamps (a gap = a missing 10 ms period).
3. control loop jitter at 100 Hz through the link: ``CrazyfliePlatform``'s control thread
   flying a hover; intervals between control steps (sender) and between set-points arriving
   at the emulator (receiver), p50/p99/max, and the jitter |interval - 10 ms| p99.
4. camera over the SITL AI-deck stream (rigs/sitl.yaml: the emulated deck renders the true
   pose with the pallet renderer, 15 fps, CPX over TCP): frames sent by the deck, received by
   the client, taken by the Vehicle, fps, dropped/corrupt frames, frames replaced before the
   Vehicle polled, the longest gap between frames, render time.
5. connect-to-ready of the whole SITL rig: ``link.open()`` to link ready + first camera frame
   at the Vehicle (the simulated hardware's boot, i.e. the emulators and the renderer's
   textures, is reported apart).

    .venv/bin/python bench/sitl_link.py [--connects 5] [--hover-s 10]
"""

from __future__ import annotations

import argparse
import statistics
import time

from bt_engine.clock import WallClock
from drivers.crazyflie.cflib_link import CrazyflieLink, CrazyflieLinkConfig
from drivers.rig.factory import make_platform
from drivers.rig.loader import REPO_ROOT, load_rig
from drivers.sim.emulators.sitl import SitlSession


def pct(values: list[float], q: float) -> float:
    """The q-quantile (0..1) of ``values``."""
    s = sorted(values)
    return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))]


def connect_times(n: int) -> list[float]:
    """Seconds from ``open()`` to ready, ``n`` fresh emulators."""
    data = load_rig().data
    out = []
    for i in range(n):
        with SitlSession(data, i) as s:
            link = CrazyflieLink(CrazyflieLinkConfig(uri=s.uri, imu_rate_hz=20.0))
            t0 = time.perf_counter()
            link.open()
            out.append(time.perf_counter() - t0)
            link.close()
    return out


def hover(hover_s: float) -> dict:
    """Fly take-off + hover on rigs/sitl.yaml; measure log rate, gaps and control jitter."""
    rig = load_rig(f"{REPO_ROOT}/rigs/sitl.yaml")
    clock = WallClock(1.0)
    t_boot = time.monotonic()
    platform = make_platform(rig, clock, 0)
    end = time.monotonic() + 5.0
    while platform.connect_to_ready_s() is None and time.monotonic() < end:
        time.sleep(0.002)
    em = platform.sitl.emulator
    arrivals: list[float] = []
    apply = em.setpoints._apply

    def record(mode, values):  # the emulator thread: arrival time of each set-point
        arrivals.append(time.monotonic())
        apply(mode, values)

    em.setpoints._apply = record
    cam, emu = platform.camera, platform.camera_emulator
    frame_times: list[float] = []
    cam.on_frame = lambda f: frame_times.append(time.monotonic())  # reader thread
    v = platform.vehicle
    p = v.takeoff(0.5)
    end = time.monotonic() + 10.0
    while not p.settled and time.monotonic() < end:
        time.sleep(0.02)
    link = platform.link
    s0, g0, t0 = link.pose_samples, link.pose_gaps, time.monotonic()
    c0, e0, k0 = cam.stats(), (emu.frames_sent, emu.slots_skipped), v.health.camera.samples
    arrivals.clear()
    frame_times.clear()
    platform.step_times.clear()
    time.sleep(hover_s)
    s1, g1, t1 = link.pose_samples, link.pose_gaps, time.monotonic()
    c1, e1, k1 = cam.stats(), (emu.frames_sent, emu.slots_skipped), v.health.camera.samples
    gaps = [b - a for a, b in zip(frame_times, frame_times[1:], strict=False)]
    sender = platform.control_periods_s()
    recv = [b - a for a, b in zip(arrivals, arrivals[1:], strict=False)]
    platform.shutdown("bench done")
    return {
        "pose_rate_hz": (s1 - s0) / (t1 - t0),
        "pose_gaps": g1 - g0,
        "pose_samples": s1 - s0,
        "sender": sender,
        "receiver": recv,
        "landed": platform.summary()["landed"],
        "camera": {
            "sent": e1[0] - e0[0],
            "slots_skipped": e1[1] - e0[1],
            "received": c1.frames - c0.frames,
            "at_vehicle": k1 - k0,
            "fps": (c1.frames - c0.frames) / (t1 - t0),
            "dropped": c1.dropped - c0.dropped,
            "corrupt": c1.corrupt - c0.corrupt,
            "replaced_before_poll": c1.skipped - c0.skipped,
            "max_gap_ms": 1000 * max(gaps) if gaps else float("nan"),
            "render_ms_mean": 1000 * emu.render_s_mean,
            "render_ms_max": 1000 * emu.render_s_max,
        },
        "boot_s": platform.connect_started_monotonic_s - t_boot,
        "link_open_s": link.connect_time_s,
        "connect_to_ready_s": platform.connect_to_ready_s(),
    }


def main() -> None:
    """Print the figures."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--connects", type=int, default=5)
    ap.add_argument("--hover-s", type=float, default=10.0)
    args = ap.parse_args()
    ct = connect_times(args.connects)
    print(
        f"connect-to-ready: median {1000 * statistics.median(ct):.0f} ms, "
        f"max {1000 * max(ct):.0f} ms (n={len(ct)})"
    )
    h = hover(args.hover_s)
    print(
        f"pose log at 100 Hz: {h['pose_rate_hz']:.1f} Hz over {args.hover_s:g} s, "
        f"{h['pose_gaps']} gaps in {h['pose_samples']} samples"
    )
    for name in ("sender", "receiver"):
        d = [1000 * x for x in h[name]]
        jit = [abs(x - 10.0) for x in d]
        print(
            f"control 100 Hz {name}: p50 {pct(d, 0.5):.2f} ms, p99 {pct(d, 0.99):.2f} ms, "
            f"max {max(d):.2f} ms, jitter p99 {pct(jit, 0.99):.2f} ms (n={len(d)})"
        )
    c = h["camera"]
    print(
        f"camera over the SITL stream: {c['fps']:.2f} fps, sent {c['sent']}, received "
        f"{c['received']}, at the Vehicle {c['at_vehicle']}, dropped {c['dropped']}, corrupt "
        f"{c['corrupt']}, replaced before poll {c['replaced_before_poll']}, deck slots skipped "
        f"{c['slots_skipped']}, longest gap {c['max_gap_ms']:.1f} ms, render mean/max "
        f"{c['render_ms_mean']:.1f}/{c['render_ms_max']:.1f} ms"
    )
    print(
        f"SITL rig connect-to-ready (link + first camera frame): "
        f"{1000 * h['connect_to_ready_s']:.0f} ms (link {1000 * h['link_open_s']:.0f} ms; "
        f"simulated hardware boot before it {1000 * h['boot_s']:.0f} ms)"
    )
    print(f"landed after shutdown: {h['landed']}")


if __name__ == "__main__":
    main()
