"""Pure maths of the Vehicle: yaw wrapping, path-facing yaw, reference profiles, battery."""

import math

import pytest

from drivers.vehicle.angles import (
    path_facing_yaw_rad,
    quaternion_from_yaw,
    wrap_angle_rad,
    yaw_error_rad,
    yaw_from_quaternion,
)
from drivers.vehicle.battery import ocv_from_soc, percent_from_voltage
from drivers.vehicle.health import HealthTracker
from drivers.vehicle.progress import MotionProgress
from drivers.vehicle.trajectory import (
    Limits,
    LineReference,
    PathReference,
    StopReference,
    slew_yaw,
    trapezoid_duration_s,
    trapezoid_profile,
)

D = math.radians


@pytest.mark.parametrize("angle", [-10.0, -math.pi, -1.0, 0.0, 1.0, math.pi, 7.0, 100.0])
def test_wrap_angle_stays_in_range_and_keeps_direction(angle):
    w = wrap_angle_rad(angle)
    assert -math.pi <= w < math.pi
    assert math.isclose(math.sin(w), math.sin(angle), abs_tol=1e-9)
    assert math.isclose(math.cos(w), math.cos(angle), abs_tol=1e-9)


def test_yaw_error_takes_the_shortest_way():
    assert yaw_error_rad(D(-170), D(170)) == pytest.approx(D(20))
    assert yaw_error_rad(D(170), D(-170)) == pytest.approx(D(-20))
    assert yaw_error_rad(D(10), D(-10)) == pytest.approx(D(20))


def test_path_facing_faces_travel_and_keeps_yaw_when_too_close():
    assert path_facing_yaw_rad((0, 0, 1), (1, 1, 1), 0.3) == pytest.approx(D(45))
    assert path_facing_yaw_rad((0, 0, 1), (-1, 0, 2), 0.3) == pytest.approx(math.pi)
    assert path_facing_yaw_rad((0, 0, 1), (0.05, 0.05, 3), 0.3) == 0.3


def test_quaternion_round_trip():
    for yaw in (-3.0, -1.0, 0.0, 2.5):
        assert yaw_from_quaternion(quaternion_from_yaw(yaw)) == pytest.approx(yaw)


def test_trapezoid_profile_respects_limits_and_ends_at_rest():
    dist, v, a = 2.0, 0.5, 1.0
    total = trapezoid_duration_s(dist, v, a)
    assert total == pytest.approx(2 * 0.5 + (2.0 - 0.25) / 0.5)
    samples = [trapezoid_profile(dist, v, a, k * 0.01) for k in range(int(total * 100) + 50)]
    assert max(s for _, s in samples) <= v + 1e-12
    speeds = [s for _, s in samples]
    assert max(abs(b - c) for b, c in zip(speeds, speeds[1:], strict=False)) <= a * 0.01 + 1e-9
    assert samples[-1] == (dist, 0.0)
    s_mid, _ = trapezoid_profile(dist, v, a, total / 2)
    assert s_mid == pytest.approx(dist / 2)


def test_short_moves_use_a_triangular_profile():
    total = trapezoid_duration_s(0.1, 1.0, 1.0)
    assert total == pytest.approx(2 * math.sqrt(0.1))
    peak = max(trapezoid_profile(0.1, 1.0, 1.0, k * 0.001)[1] for k in range(1000))
    assert peak < 1.0


def test_line_reference_turns_the_short_way():
    ref = LineReference((0, 0, 1), (0, 0, 1), D(170), D(-170), Limits(), t0_s=5.0)
    yaws = [ref.sample(5.0 + k * 0.01).yaw_rad for k in range(int(ref.duration_s * 100) + 2)]
    assert all(abs(y) > D(165) for y in yaws)
    assert yaws[-1] == pytest.approx(D(-170))
    assert ref.sample(100.0).done


def test_line_reference_goes_straight_at_the_speed_limit():
    lim = Limits(speed_mps=0.5, accel_mps2=1.0)
    ref = LineReference((0, 0, 1), (3, 4, 1), 0.0, 0.0, lim, t0_s=0.0)
    mid = ref.sample(ref.duration_s / 2)
    assert (mid.x_m, mid.y_m) == pytest.approx((1.5, 2.0))
    assert math.hypot(mid.vx_mps, mid.vy_mps) == pytest.approx(0.5)
    assert not mid.done


def test_path_reference_passes_waypoints_and_slews_yaw():
    pts = [(0, 0, 1), (1, 0, 1), (1, 1, 1)]
    ref = PathReference(pts, [0.0, D(90)], 0.0, Limits(speed_mps=0.5), t0_s=0.0)
    t, last = 0.0, None
    while t < ref.duration_s + 3.0:
        last = ref.sample(t)
        t += 0.01
    assert last.position == pytest.approx((1, 1, 1))
    assert last.yaw_rad == pytest.approx(D(90), abs=1e-3)
    assert last.done


def test_stop_reference_decelerates_to_a_hold():
    ref = StopReference((0, 0, 1), (0.5, 0, 0), 0.0, Limits(accel_mps2=1.0), t0_s=0.0)
    assert ref.goal == pytest.approx((0.125, 0, 1))
    assert ref.sample(1.0).vx_mps == 0.0


def test_slew_yaw_converges_the_short_way():
    yaw, rate = D(170), 0.0
    for _ in range(500):
        yaw, rate = slew_yaw(yaw, rate, D(-170), D(90), D(180), 0.01)
        assert abs(yaw) > D(165)
    assert yaw == pytest.approx(D(-170))


def test_battery_curve_and_percentage():
    assert ocv_from_soc(1.0) == 4.2
    assert percent_from_voltage(4.2) == 100.0
    assert percent_from_voltage(3.0) == 0.0
    assert percent_from_voltage(ocv_from_soc(0.5)) == pytest.approx(50.0)


def test_health_tracker_age_rate_and_drops():
    h = HealthTracker("mocap", stale_after_s=0.1)
    for k in range(100):
        h.sample(k * 0.01)
    h.drop(3)
    r = h.report(0.995)
    assert r.healthy and r.rate_hz == pytest.approx(100, abs=2) and r.drops == 3
    h.sample(1.0, changed=False)  # a repeated (frozen) frame is not fresh
    assert not h.report(1.2).healthy


def test_progress_reached_settled_and_timeout():
    p = MotionProgress(
        "go_to", (0, 0, 1), 0.0, 0.05, D(15), started_s=0.0, settle_time_s=0.3, timeout_s=5.0
    )
    p.update(1.0, 0.5, 0.0, False)
    assert not p.reached
    p.update(2.0, 0.01, D(5), True)
    assert p.reached and not p.settled
    p.update(2.4, 0.01, D(5), True)
    assert p.settled
    q = MotionProgress("go_to", (0, 0, 1), 0.0, 0.05, D(15), started_s=0.0, timeout_s=1.0)
    q.update(1.5, 0.5, 0.0, False)
    assert q.failed and "timeout" in q.reason
