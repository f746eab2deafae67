"""Go-to tracking: the drone follows the smooth reference and arrives without overshoot.

The firmware's velocity loop lags its set-point by ~0.25 s; without the Vehicle's
acceleration feed-forward (``control.velocity_lead_s``) the drone trails the reference while
it accelerates and overshoots the goal by ~7 cm when it brakes (bench/tracking.py).
"""

import math

import pytest

from drivers.rig.harness import SimHarness
from drivers.vehicle.types import YawMode

GOAL = (1.5, 0.0, 0.5)


def fly_go_to(mode: str, overrides: dict | None = None) -> dict:
    """Take off to 0.5 m, go 1.5 m along x at 0.5 m/s; overshoot and tracking figures (m)."""
    h = SimHarness.create(1, {"control.setpoint_mode": mode, **(overrides or {})})
    v = h.vehicle
    p = v.takeoff(0.5, 0.5)
    assert h.run_until(lambda: p.settled, 10.0), p
    start = v.position
    g = v.go_to(*GOAL, YawMode.KEEP_YAW, 0.0, 0.5, position_tolerance_m=0.03)
    body = h.platform.drone.body
    track, track_xy, ahead = [], [], []

    def sample() -> None:
        r = v.reference
        track.append(math.dist((body.x, body.y, body.z), r.position))
        track_xy.append(math.hypot(body.x - r.x_m, body.y - r.y_m))
        ahead.append(body.x - GOAL[0])

    t0 = h.now_s
    assert h.run_until(lambda: g.settled, 10.0, on_tick=sample), g
    reach_s = h.now_s - t0
    h.run_for(1.0, on_tick=sample)  # and it stays there
    assert start[0] == pytest.approx(0.0, abs=0.03)
    return {
        "overshoot": max(0.0, max(ahead)),
        "track": max(track),
        "track_xy": max(track_xy),
        "settled_s": reach_s,
    }


@pytest.mark.parametrize("mode", ["velocity", "position"])
def test_go_to_arrives_without_overshoot(mode):
    f = fly_go_to(mode)
    assert f["overshoot"] < 0.02, f
    assert f["track_xy"] < 0.05, f
    if mode == "velocity":  # position mode: the firmware's z position integrator winds up on
        assert f["track"] < 0.05, f  # the take-off's lead offset (docs/vehicle.md)
    # reference: 3.5 s (trapezoid 1.5 m at 0.5 m/s, 1 m/s^2) + 0.3 s settle time
    assert f["settled_s"] < 4.5, f


def test_without_feed_forward_the_lag_overshoots():
    """The cause, kept visible: no acceleration feed-forward -> ~7 cm past the goal."""
    f = fly_go_to(
        "velocity",
        {
            "control.velocity_lead_s": "0",
            "control.velocity_lead_z_s": "0",
            "control.velocity_kp": "2",
        },
    )
    assert f["overshoot"] > 0.04, f
