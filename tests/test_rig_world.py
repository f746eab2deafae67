"""Rig and world files: defaults, the reference layout, located validation errors, --set."""

import math
import os

import pytest

from drivers.rig.factory import make_platform
from drivers.rig.loader import REPO_ROOT, ConfigError, apply_overrides, load_rig
from drivers.sim.world import load_world

WORLD = os.path.join(REPO_ROOT, "worlds", "warehouse.yaml")


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_default_rig_loads_with_every_setting():
    rig = load_rig(None)
    assert rig.kind == "sim" and rig.path.endswith(os.path.join("rigs", "sim.yaml"))
    assert rig.data["control"]["rate_hz"] == 100.0
    assert rig.data["control"]["setpoint_mode"] in ("position", "velocity")
    assert os.path.exists(rig.world_path)


def test_warehouse_reproduces_the_reference_layout():
    world = load_world(WORLD)
    assert world.identities() == [f"{n}{s}" for n in "12345" for s in "AB"]
    scan = world.pallet_at_scan()
    assert scan.identity == "3A"
    face_x, face_y, block_z = scan.face_center_m
    line = world.data["scan_line"]
    assert (line["x_m"], line["z_m"]) == (8.90, 0.255)
    assert 0.35 <= face_x - line["x_m"] <= 0.5  # stand-off in front of the scan line
    assert face_y == pytest.approx(-0.05)
    assert block_z == pytest.approx(0.255, abs=0.005)  # blocks centred at the scan height
    assert math.cos(scan.facing_rad) == pytest.approx(-1.0)  # the face looks at the drone
    assert len(scan.blocks) == 3
    ys = sorted(b.cy for b in scan.blocks)
    # The line starts with the first block left of the camera (it enters the image left of
    # the centre, more than the sequencer's 60 px window away) and ends after the last one
    # passed the centre by more than 20 px (0.05 m at the 0.40 m stand-off).
    assert ys[0] - line["y_from_m"] > 0.15 and line["y_to_m"] - ys[-1] > 0.05
    assert len(world.pallets) == 5
    # Nothing stands on the scan line itself.
    assert world.collision(8.90, -0.05, 0.255, 0.06) is None
    assert world.collision(face_x + 0.1, -0.05, 0.255, 0.06) is not None


def test_scan_pallet_is_overridable_by_key():
    rig = load_rig(None, {"world.scan_pallet": "2B"})
    platform = make_platform(rig, None, seed=0)
    scan = platform.world.pallet_at_scan()
    assert scan.identity == "2B" and scan.shown_side == "B"
    assert platform.summary()["scan_pallet"] == "2B"
    with pytest.raises(ConfigError, match="7A"):
        load_rig(None, {"world.scan_pallet": "7A"})


def test_rig_problems_are_all_located(tmp_path):
    path = write(
        tmp_path,
        "bad.yaml",
        (
            "link: sim\n"
            "control:\n"
            "  setpoint_mod: position\n"
            "  rate_hz: fast\n"
            "sensors:\n"
            "  mocap: {rate_hz: 100, latency: 0.01}\n"
            "clock: {mode: lockstp}\n"
        ),
    )
    with pytest.raises(ConfigError) as exc:
        load_rig(path)
    problems = exc.value.problems
    assert len(problems) == 4
    assert f"{path}:3:3: unknown key 'setpoint_mod' (did you mean 'setpoint_mode'?)" in problems
    assert any(p.startswith(f"{path}:4:12: ") and "expected a number" in p for p in problems)
    assert any(
        p.startswith(f"{path}:6:25: ") and "'latency'" in p and "latency_s" in p for p in problems
    )
    assert any(p.startswith(f"{path}:7:15: ") and "did you mean 'lockstep'" in p for p in problems)


def test_yaml_syntax_errors_are_located(tmp_path):
    path = write(tmp_path, "broken.yaml", "link: sim\ncontrol: {rate_hz: 100\n")
    with pytest.raises(ConfigError) as exc:
        load_rig(path)
    assert exc.value.problems[0].startswith(f"{path}:3:")


def test_world_problems_are_located(tmp_path):
    text = open(WORLD).read()
    text = text.replace("scan_pallet: 3A", "scan_pallet: 9Z").replace('id: "2"', 'id: "1"')
    text = text.replace("ambient: 0.6", "ambient: 2.0")
    path = write(tmp_path, "world.yaml", text)
    with pytest.raises(ConfigError) as exc:
        load_world(path)
    problems = exc.value.problems
    lines = text.splitlines()
    ambient_line = next(i for i, s in enumerate(lines) if "ambient: 2.0" in s) + 1
    assert problems == [f"{path}:{ambient_line}:12: lighting.ambient: 2.0 is above the maximum 1.0"]
    text = text.replace("ambient: 2.0", "ambient: 0.6")
    path = write(tmp_path, "world2.yaml", text)
    with pytest.raises(ConfigError) as exc:
        load_world(path)
    problems = exc.value.problems
    scan_line = next(i for i, s in enumerate(lines) if s.startswith("scan_pallet:")) + 1
    assert any(p.startswith(f"{path}:{scan_line}:14: scan_pallet '9Z'") for p in problems)
    assert any("duplicate pallet id '1'" in p for p in problems)


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_a_number_that_is_not_finite_is_refused_where_it_is_written(tmp_path, value):
    """YAML's .nan passed every bound (NaN compares false) and crashed the world's build
    with a traceback; .inf passed where a setting has no maximum."""
    text = open(WORLD).read().replace("length_m: 1.2", f"length_m: {value}", 1)
    assert value in text
    path = write(tmp_path, "world.yaml", text)
    with pytest.raises(ConfigError) as exc:
        load_world(path)
    line = next(i for i, s in enumerate(text.splitlines()) if f"length_m: {value}" in s) + 1
    (problem,) = exc.value.problems
    assert problem.startswith(f"{path}:{line}:")
    assert "pallet_geometry.length_m: expected a finite number" in problem
    with pytest.raises(ConfigError) as exc:  # in a list of numbers, and as a --set
        load_world(WORLD, {"floor.size_m": f"[{value}, 2.0]"})
    assert "floor.size_m: expected finite numbers" in str(exc.value.problems)


def test_rig_with_a_bad_world_reports_the_world_file(tmp_path):
    world = write(tmp_path, "w.yaml", "name: w\nflor: {}\n")
    rig = write(tmp_path, "r.yaml", f"link: sim\nworld: {{path: {world}}}\n")
    with pytest.raises(ConfigError) as exc:
        load_rig(rig)
    assert exc.value.problems[0].startswith(f"{world}:2:1: unknown key 'flor'")


def test_overrides_are_type_checked_and_unknown_keys_suggested():
    data = load_rig(None).data
    out = apply_overrides(
        data,
        {
            "control.rate_hz": "50",
            "wind.mean_mps": "[1, 0, 0]",
            "control.setpoint_mode": "position",
            "sim.params.mass_kg": "0.04",
        },
    )
    assert out["control"]["rate_hz"] == 50.0 and out["wind"]["mean_mps"] == [1.0, 0.0, 0.0]
    assert out["sim"]["params"] == {"mass_kg": 0.04}
    assert data["control"]["rate_hz"] == 100.0  # the input is not modified
    with pytest.raises(ConfigError) as exc:
        apply_overrides(
            data,
            {
                "control.rate": "50",
                "control.setpoint_mode": "posit",
                "sensors.mocap.rate_hz": "many",
            },
        )
    problems = exc.value.problems
    assert len(problems) == 3
    assert "did you mean 'control.rate_hz'" in problems[0]
    assert "did you mean 'position'" in problems[1]
    assert "expected a number" in problems[2]


def test_overrides_schedule_faults():
    rig = load_rig(None, {"faults.link_drop.at_s": "12.5"})
    assert rig.data["faults"]["link_drop"]["at_s"] == 12.5


def test_summary_sim_names_every_pallet_and_where_it_stands() -> None:
    from bt_engine import SimClock
    from drivers.rig.factory import make_platform

    rig = load_rig(None, {"world.scan_pallet": "2B"})
    platform = make_platform(rig, SimClock(), seed=0)
    pallets = platform.summary()["pallets"]
    assert [p["identity"] for p in pallets] == ["2B", "1A", "3A", "4A", "5A"]
    scan = pallets[0]
    assert scan["slot"] == "scan" and scan["face_centre_m"][0] == 9.3
    assert scan["block_centre_z_m"] == 0.255  # raised on the stand: blocks at scan height
    assert all(p["block_centre_z_m"] == 0.061 for p in pallets[1:])  # on the floor
