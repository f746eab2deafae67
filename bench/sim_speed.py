"""Lock-step speed of the simulator: a 60 s scripted flight through the Vehicle API alone.

Take off to 0.5 m, fly a 2 m square (PATH_FACING at the corners), then hover until 60 s of
mission time are done and land. Ticks at 50 Hz on a SimClock exactly as the runner does and
prints the speed factor (mission seconds per wall-clock second).

    .venv/bin/python bench/sim_speed.py [--seed N] [--set key=value ...]
"""

from __future__ import annotations

import argparse
import time

from bt_engine.clock import SimClock
from drivers.rig.factory import make_platform
from drivers.rig.loader import load_rig
from drivers.vehicle.types import YawMode

MISSION_S = 60.0
TICK_HZ = 50.0


def scripted_flight(seed: int, overrides: dict[str, str]) -> tuple[float, dict]:
    """Fly the script; return (wall seconds, platform summary)."""
    rig = load_rig(None, overrides)
    clock = SimClock()
    platform = make_platform(rig, clock, seed)
    v = platform.vehicle
    square = [(2.0, 0.0, 0.5), (2.0, 2.0, 0.5), (0.0, 2.0, 0.5), (0.0, 0.0, 0.5)]
    steps: list = ["takeoff", *square]
    progress = None
    wall0 = time.perf_counter()
    while clock.now() < MISSION_S:
        clock.advance(1.0 / TICK_HZ)
        platform.before_tick(clock.now())
        if progress is None or progress.settled:
            if steps:
                step = steps.pop(0)
                if step == "takeoff":
                    progress = v.takeoff(0.5, 0.5)
                else:
                    progress = v.go_to(*step, YawMode.PATH_FACING, 0.0, 0.5)
            elif clock.now() >= MISSION_S - 6.0 and progress.kind != "land":
                progress = v.land(0.5)  # hover until then
        platform.after_tick(clock.now())
    platform.shutdown("end of script")
    return time.perf_counter() - wall0, platform.summary()


def main() -> None:
    """Run the flight and print the speed factor."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    overrides = dict(item.split("=", 1) for item in args.set)
    wall_s, summary = scripted_flight(args.seed, overrides)
    print(
        f"mission {summary['t_s']:.1f} s simulated in {wall_s:.3f} s wall: "
        f"speed factor {summary['t_s'] / wall_s:.0f}x real time"
    )
    print(
        f"end state {summary['state']}, crashed={summary['crashed']}, "
        f"max tracking error {summary['max_tracking_error_m']:.3f} m, "
        f"battery {summary['battery']['voltage_v']:.2f} V"
    )


if __name__ == "__main__":
    main()
