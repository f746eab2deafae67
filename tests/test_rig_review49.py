"""Review 49: rig and world inputs that passed validation and then crashed, flew nonsense or
flew the wrong world. Each is now refused before anything flies, located (file:line:col or
the ``--set`` key), with the offending value and what was expected; ``btrun validate``,
``btrun rig check`` and a run give the same verdict (exit 2, no run folder)."""

from __future__ import annotations

import os
import shutil

import pytest
from helpers import REPO

from bt_engine.cli import main
from drivers.rig.loader import load_rig
from drivers.settings import ConfigError
from drivers.sim.crazyflie_params import crazyflie_params

SQUARE = os.path.join(REPO, "missions", "square.xml")
WAREHOUSE = os.path.join(REPO, "worlds", "warehouse.yaml")


def _refused_everywhere(capsys, tmp_path, argv_tail: list[str], rig: str | None = None) -> str:
    """``validate``, ``rig check`` (with a rig) and a run all exit 2 with the same first
    problem and leave no run folder; returns that problem."""
    rig_args = ["--rig", rig] if rig else []
    firsts = []
    assert main(["validate", *rig_args, *argv_tail, SQUARE]) == 2
    firsts.append(capsys.readouterr().err.splitlines()[0])
    if rig:
        assert main(["rig", "check", rig, *argv_tail]) == 2
        firsts.append(capsys.readouterr().err.splitlines()[0])
    out = tmp_path / "run"
    assert main([SQUARE, *rig_args, *argv_tail, "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.rstrip().endswith("nothing was run.")
    firsts.append(err.splitlines()[0])
    assert not out.exists()  # nothing flown, no run folder
    assert len(set(firsts)) == 1, firsts
    return firsts[0]


def _rig(tmp_path, text: str, name: str = "r.yaml") -> str:
    path = tmp_path / name
    path.write_text(f"link: sim\nworld:\n  path: {WAREHOUSE}\n{text}", encoding="utf-8")
    return str(path)


# -- 1. sim.params: names and ranges --------------------------------------------------------


def test_every_sim_parameter_has_a_range_holding_its_default() -> None:
    from drivers.rig.schema import SIM_PARAMS
    from drivers.sim.crazyflie_params import crazyflie_param_limits

    assert set(crazyflie_param_limits) == set(crazyflie_params) == set(SIM_PARAMS)
    for name, (lo, hi, doc) in crazyflie_param_limits.items():
        assert lo <= crazyflie_params[name] <= hi and doc, name
    assert SIM_PARAMS["motor_count"].kind == "int"
    load_rig(None)  # the shipped defaults pass every check together


def test_a_misspelt_sim_parameter_is_refused_with_the_real_name(tmp_path, capsys) -> None:
    """``sim.params.mas=1`` was silently ignored."""
    first = _refused_everywhere(capsys, tmp_path, ["--set", "sim.params.mas=1"])
    assert first.startswith("--set sim.params: unknown key 'mas' (did you mean 'mass_kg'?)")
    assert "drivers/sim/crazyflie_params.py" in first


@pytest.mark.parametrize(
    ("setting", "said"),
    [
        ("mass_kg=0", "sim.params.mass_kg: 0.0 is below the minimum 0.01"),  # ZeroDivisionError
        ("mass_kg=-1", "sim.params.mass_kg: -1.0 is below the minimum 0.01"),  # flew, timed out
        ("motor_count=0", "sim.params.motor_count: 0 is below the minimum 1"),  # ZeroDivision
        ("motor_count=2.5", "sim.params.motor_count: expected an integer, got 2.5"),
        (
            "attitude_time_constant_s=0",  # an "ABORTED: internal error" run folder
            "sim.params.attitude_time_constant_s: 0.0 is below the minimum 0.001",
        ),
        ("gravity_mps2=1.0e+6", "sim.params.gravity_mps2: 1000000.0 is above the maximum 30"),
    ],
)
def test_a_sim_parameter_out_of_its_range_is_refused(tmp_path, capsys, setting, said) -> None:
    first = _refused_everywhere(capsys, tmp_path, ["--set", f"sim.params.{setting}"])
    assert first.startswith(f"--set {said}"), first
    assert "(its range: " in first


def test_sim_parameters_that_cannot_fly_together_are_refused(tmp_path, capsys) -> None:
    first = _refused_everywhere(capsys, tmp_path, ["--set", "sim.params.mass_kg=1"])
    assert "the motors cannot lift the drone: 4 x max_thrust_per_motor_n 0.12 N = 0.48 N" in first
    first = _refused_everywhere(
        capsys, tmp_path, ["--set", "sim.params.motor_time_constant_s=0.001"]
    )
    assert "motor_time_constant_s 0.001 s is shorter than one physics step" in first
    assert main(["validate", "--set", "sim.params.tumble_tilt_deg=15", SQUARE]) == 2
    assert "tumble_tilt_deg 15 must be above max_tilt_deg 20" in capsys.readouterr().err


def test_sim_parameter_problems_in_a_rig_file_are_located(tmp_path, capsys) -> None:
    rig = _rig(tmp_path, "sim:\n  params:\n    mas: 0.04\n    motor_count: 0\n")
    problems = _refused_everywhere(capsys, tmp_path, [], rig=rig)
    assert problems.startswith(f"{rig}:6:10: sim.params: unknown key 'mas' (did you mean")
    assert main(["rig", "check", rig]) == 2
    err = capsys.readouterr().err
    assert f"{rig}:7:18: sim.params.motor_count: 0 is below the minimum 1" in err
    assert err.rstrip().endswith("2 problems found; nothing was run.")


def test_sane_sim_parameters_still_fly(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    argv = [SQUARE, "--set", "sim.params.mass_kg=0.04", "--out", str(out), "-q"]
    assert main(argv) == 0, capsys.readouterr().err
    assert out.is_dir()


# -- 2. sim.start_yaw_deg -------------------------------------------------------------------


def test_an_absurd_start_yaw_is_refused(tmp_path, capsys) -> None:
    """1.0e+20 passed, and the drone ran away."""
    first = _refused_everywhere(capsys, tmp_path, ["--set", "sim.start_yaw_deg=1.0e+20"])
    assert first == (
        "--set sim.start_yaw_deg=1.0e+20: sim.start_yaw_deg: 1e+20 is above the maximum 360.0"
    )
    rig = _rig(tmp_path, "sim:\n  start_yaw_deg: -400\n")
    assert main(["rig", "check", rig]) == 2
    assert capsys.readouterr().err.startswith(
        f"{rig}:5:18: sim.start_yaw_deg: -400.0 is below the minimum -360.0"
    )
    assert main(["validate", "--set", "sim.start_yaw_deg=-90", SQUARE]) == 0


# -- 3. empty rig and world files -----------------------------------------------------------


@pytest.mark.parametrize("text", ["", "# nothing here yet\n\n", "---\n"])
def test_an_empty_rig_file_is_refused_by_every_command(tmp_path, capsys, text) -> None:
    """``rig check`` said ok, a run flew on the defaults, ``validate`` called it a bad
    mission."""
    rig = tmp_path / "empty.yaml"
    rig.write_text(text, encoding="utf-8")
    first = _refused_everywhere(capsys, tmp_path, [], rig=str(rig))
    assert first.startswith(f"{rig}:1:1: the rig file is empty: expected rig settings")
    assert main(["validate", str(rig)]) == 2  # what it is meant to be, no one can tell
    err = capsys.readouterr().err
    assert err.startswith(f"{rig}:1:1: the file is empty: expected a mission")
    assert "rig" in err.splitlines()[0] and "trees:` (the file" not in err


def test_an_empty_world_file_is_refused(tmp_path, capsys) -> None:
    """``--set world.path=EMPTY`` said scan_pallet '3A' is not a pallet side."""
    world = tmp_path / "w.yaml"
    world.write_text("# to be written\n", encoding="utf-8")
    first = _refused_everywhere(capsys, tmp_path, ["--set", f"world.path={world}"])
    assert first.startswith(f"{world}:1:1: the world file is empty: expected a world")
    rig = tmp_path / "r.yaml"
    rig.write_text("link: sim\nworld: {path: w.yaml}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="the world file is empty"):
        load_rig(str(rig))


# -- 4. world numbers without bounds --------------------------------------------------------


@pytest.mark.parametrize(
    ("key", "written", "value", "said"),
    [
        ("pallet_geometry.length_m", "length_m: 1.2", "0", "0.0 is below the minimum 0.2"),
        ("pallet_geometry.board_m", "board_m: 0.022", "-0.02", "-0.02 is below the minimum"),
        ("pallet_geometry.height_m", "height_m: 0.144", "40", "40.0 is above the maximum 0.5"),
        (
            "lighting.colour_temperature_k",
            "colour_temperature_k: 4000",
            "0",
            "0.0 is below the minimum 1000.0",
        ),
        ("scan_slot.facing_deg", "facing_deg: 180}", "1.0e+20", "1e+20 is above the maximum"),
    ],
)
def test_world_numbers_are_bounded(tmp_path, capsys, key, written, value, said) -> None:
    """``pallet_geometry.length_m: 0`` was ok, then pre-flight failed on an OpenCV
    assertion; a world of no colour temperature rendered as if lit at 1000 K."""
    text = open(WAREHOUSE, encoding="utf-8").read()
    at = text.index(written)  # the value's line and column
    line = text.count("\n", 0, at) + 1
    col = at - text.rfind("\n", 0, at) + written.index(":") + 2
    world = tmp_path / "w.yaml"
    closing = "}" if written.endswith("}") else ""
    world.write_text(text.replace(written, f"{written.split(':')[0]}: {value}{closing}", 1))
    assert main(["validate", str(world)]) == 2
    assert capsys.readouterr().err.startswith(f"{world}:{line}:{col}: {key}: {said}")
    first = _refused_everywhere(capsys, tmp_path, ["--set", f"world.{key}={value}"])
    assert first.startswith(f"--set world.{key}={value}: {key}: {said}"), first


# -- 5. a rig's world.path: relative to the rig file, nowhere else ---------------------------


def test_a_rig_world_path_is_read_beside_the_rig_only(tmp_path, capsys, monkeypatch) -> None:
    """``worlds/warehouse.yaml`` in a rig outside the repository was looked for beside the
    rig, then in the working folder and btrun's own: a mistyped path flew the demo world."""
    (tmp_path / "rigs").mkdir()
    rig = tmp_path / "rigs" / "mine.yaml"
    rig.write_text("link: sim\nworld:\n  path: worlds/warehouse.yaml\n", encoding="utf-8")
    monkeypatch.chdir(REPO)  # where worlds/warehouse.yaml is
    assert main(["validate", "--rig", str(rig), SQUARE]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"{rig}:3:9: world.path 'worlds/warehouse.yaml': no such world file "
        f"({tmp_path}/rigs/worlds/warehouse.yaml; relative to the rig file)"
    ), err
    # a world beside the rig is found from any folder; a near miss gets a "did you mean"
    (tmp_path / "worlds").mkdir()
    shutil.copy(WAREHOUSE, tmp_path / "worlds" / "house.yaml")
    rig.write_text("link: sim\nworld:\n  path: ../worlds/house.yaml\n", encoding="utf-8")
    assert main(["rig", "check", str(rig)]) == 0
    assert load_rig(str(rig)).world_path == str(tmp_path / "worlds" / "house.yaml")
    rig.write_text("link: sim\nworld:\n  path: ../worlds/hose.yaml\n", encoding="utf-8")
    assert main(["rig", "check", str(rig)]) == 2
    assert "(did you mean '../worlds/house.yaml'?)" in capsys.readouterr().err


def test_a_world_path_given_by_set_is_relative_to_the_working_folder(
    tmp_path, capsys, monkeypatch
) -> None:
    (tmp_path / "worlds").mkdir()
    shutil.copy(WAREHOUSE, tmp_path / "worlds" / "house.yaml")
    monkeypatch.chdir(tmp_path)
    assert main(["validate", "--set", "world.path=worlds/house.yaml", SQUARE]) == 0
    capsys.readouterr()
    assert main(["validate", "--set", "world.path=worlds/warehouse.yaml", SQUARE]) == 2
    err = capsys.readouterr().err  # not btrun's own worlds/warehouse.yaml
    assert err.startswith("--set world.path 'worlds/warehouse.yaml': no such world file")
    assert "relative to the working folder" in err


@pytest.mark.parametrize(
    "setting, said",
    [
        ("pallet_geometry.height_m=0.05", "expected at least 3 boards and a block"),
        ("pallet_geometry.length_m=0.3", "its three blocks along the face take 0.435 m"),
        ("pallet_geometry.corner_block_m=[0,0.1]", "expected lengths > 0"),
    ],
)
def test_a_pallet_whose_parts_do_not_fit_together_is_refused(
    tmp_path, capsys, setting, said
) -> None:
    # each value in its range, the pallet not buildable: the pre-flight had failed in numpy
    first = _refused_everywhere(capsys, tmp_path, ["--set", f"world.{setting}"])
    assert first.startswith(f"--set world.{setting.split('=')[0]}: ") and said in first, first


@pytest.mark.parametrize(
    "setting",
    ["sim.shutdown_max_s=1000.0", "sim.telemetry_rate_hz=5000.0", "crazyflie.link_timeout_s=60.0"],
)
def test_time_outs_and_rates_have_an_upper_bound(tmp_path, capsys, setting) -> None:
    # 1.0e+300 had been a shutdown that never gives up: every action has a time-out
    first = _refused_everywhere(capsys, tmp_path, ["--set", setting])
    assert "is above the maximum" in first, first
