"""Cross-check the fast simulator against rotorpy's Crazyflie model (optional extra).

Flies the same references (z step, x step, 90 deg yaw step, 2 m square) twice: through the
Vehicle API on btrun's simulator (lock-step) and with rotorpy's full multirotor model
(``crazyflie_params``, its SE3 geometric controller) tracking the *same* reference samples.
Prints RMS differences of position and yaw. Needs ``pip install rotorpy``; never imported by
tests.

    .venv/bin/python bench/crosscheck_rotorpy.py
"""

from __future__ import annotations

import math

import numpy as np

from drivers.rig.harness import SimHarness
from drivers.vehicle.types import YawMode


def fly_btrun(script, seed: int = 0):
    """Run ``script(vehicle)`` -> list of progress getters; record ref and truth at 100 Hz."""
    h = SimHarness.create(
        seed,
        {"sensors.onboard.yaw_bias_deg": "0", "sensors.onboard.yaw_bias_wander_deg": "0"},
        tick_hz=100,
    )
    v = h.vehicle
    p = v.takeoff(0.5, 0.5)
    h.run_until(lambda: p.settled, 10.0)
    h.run_for(1.0)
    rows = []

    def record():
        r, b = v.reference, h.platform.drone.body
        rows.append(
            (
                h.now_s,
                r.x_m,
                r.y_m,
                r.z_m,
                r.vx_mps,
                r.vy_mps,
                r.vz_mps,
                r.yaw_rad,
                r.yaw_rate_radps,
                b.x,
                b.y,
                b.z,
                b.yaw,
            )
        )

    for step in script:
        g = step(v)
        h.run_until(lambda g=g: g.settled, 30.0, on_tick=record)
    h.run_for(1.0, on_tick=record)
    return np.array(rows)


def fly_rotorpy(rows: np.ndarray) -> np.ndarray:
    """Track the recorded reference with rotorpy; return positions and yaw at the same times."""
    from rotorpy.controllers.quadrotor_control import SE3Control
    from rotorpy.vehicles.crazyflie_params import quad_params
    from rotorpy.vehicles.multirotor import Multirotor
    from scipy.spatial.transform import Rotation

    r0 = rows[0]
    state = {
        "x": np.array(r0[9:12]),
        "v": np.zeros(3),
        "q": Rotation.from_euler("z", r0[12]).as_quat(),
        "w": np.zeros(3),
        "wind": np.zeros(3),
        "rotor_speeds": np.full(4, 1788.53),
    }
    quad = Multirotor(quad_params, state)
    ctrl = SE3Control(quad_params)
    out, dt_ctrl, sub = [], 0.01, 5
    for row in rows:
        flat = {
            "x": row[1:4],
            "x_dot": row[4:7],
            "x_ddot": np.zeros(3),
            "x_dddot": np.zeros(3),
            "x_ddddot": np.zeros(3),
            "yaw": row[7],
            "yaw_dot": row[8],
        }
        u = ctrl.update(row[0], state, flat)
        for _ in range(sub):
            state = quad.step(state, u, dt_ctrl / sub)
        yaw = Rotation.from_quat(state["q"]).as_euler("zyx")[0]
        out.append([*state["x"], yaw])
    return np.array(out)


def rms(a: np.ndarray) -> float:
    """Root mean square."""
    return float(np.sqrt(np.mean(a * a)))


def main() -> None:
    """Print RMS differences for each manoeuvre."""
    cases = {
        "z step 0.5 -> 1.0 m": [lambda v: v.go_to(0, 0, 1.0)],
        "x step 1 m": [lambda v: v.go_to(1.0, 0, 0.5)],
        "yaw step 90 deg": [lambda v: v.go_to(0, 0, 0.5, YawMode.FIXED_YAW, math.pi / 2)],
        "2 m square": [
            lambda v, p=p: v.go_to(*p, YawMode.KEEP_YAW, 0.0, 0.5)
            for p in ((2, 0, 0.5), (2, 2, 0.5), (0, 2, 0.5), (0, 0, 0.5))
        ],
    }
    print(
        f"{'case':22s} {'pos RMS btrun-rotorpy':>22s} {'yaw RMS (deg)':>14s} "
        f"{'btrun track RMS':>16s} {'rotorpy track RMS':>18s}"
    )
    for name, script in cases.items():
        rows = fly_btrun(script)
        rp = fly_rotorpy(rows)
        ours, ref = rows[:, 9:12], rows[:, 1:4]
        dpos = np.linalg.norm(ours - rp[:, :3], axis=1)
        dyaw = np.degrees(np.angle(np.exp(1j * (rows[:, 12] - rp[:, 3]))))
        print(
            f"{name:22s} {rms(dpos):20.4f} m {rms(dyaw):12.2f}   "
            f"{rms(np.linalg.norm(ours - ref, axis=1)):14.4f} m "
            f"{rms(np.linalg.norm(rp[:, :3] - ref, axis=1)):16.4f} m"
        )


if __name__ == "__main__":
    main()
