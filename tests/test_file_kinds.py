"""``btrun validate`` checks every kind of file btrun reads, each as its command would
(a rig with its world, a world, a fleet as ``btrun fleet --check``, a campaign), told apart
from missions by their top-level keys; ``btrun run`` (and ``show``) given one of them says
what it is instead of listing its keys as unknown mission keys."""

from __future__ import annotations

import os

import pytest
from helpers import REPO

from bt_engine.cli import main
from bt_engine.file_kinds import file_kind

FLEET = os.path.join(REPO, "fleets", "aisle_2.yaml")


def _lines(text: str) -> list[str]:
    """The lines of ``text`` without the progress of what the checks build ([wall ...])."""
    return [line for line in text.strip().splitlines() if not line.startswith("[wall")]


@pytest.mark.parametrize(
    ("path", "kind"),
    [
        ("rigs/site.yaml", "rig"),
        ("worlds/site.yaml", "world"),
        ("fleets/aisle_2.yaml", "fleet"),
        ("campaigns/pallet_scan.yaml", "campaign"),
    ],
)
def test_each_shipped_file_is_checked_as_its_kind(capsys, path, kind) -> None:
    assert main(["validate", path]) == 0
    said = _lines(capsys.readouterr().out)
    if kind != "fleet":
        assert said == [f"{path}: ok ({kind})"]
    else:  # with the drones and their shares, as btrun fleet --check says them
        assert said == [f"{path}: ok (fleet; 2 drones; cf1: 8 places, cf2: 8 places)"]


def test_missions_stay_missions() -> None:
    assert file_kind("missions/inventory.yaml") is None
    assert file_kind("missions/inventory.xml") is None


def test_a_mission_with_a_misspelt_key_is_still_read_as_a_mission(tmp_path, capsys) -> None:
    bad = tmp_path / "m.yaml"
    bad.write_text("btrun: 4\nmian: square\ntrees: {}\n")
    assert main(["validate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:2:1: unknown top-level key 'mian'" in err


def _fleet(tmp_path, drones: str, extra: str = "") -> str:
    path = tmp_path / "fleet.yaml"
    path.write_text(
        f"name: f\nmission: {REPO}/missions/inventory.xml\nrig: {REPO}/rigs/aisle.yaml\n"
        f"places: all\nsplit: faces\n{extra}drones:\n{drones}"
    )
    return str(path)


def test_a_fleet_file_is_checked_before_flight_by_validate_and_check(tmp_path, capsys) -> None:
    """A pad used twice is the fleet file's own check; a drone's ``set:`` value its mission
    cannot take (``sweep_speed: abc``) is found only by checking that drone's mission with
    its settings, as btrun fleet does before take-off: both are located."""
    path = _fleet(
        tmp_path,
        "  - {name: cf1, pad: pad-1, set: {sweep_speed: abc}}\n  - {name: cf2, pad: pad-2}\n",
    )
    for argv in (["validate", path], ["fleet", path, "--check"]):
        assert main(argv) == 2
        err = _lines(capsys.readouterr().err)
        assert err[0].startswith("--set sweep_speed=abc: expected a number, got 'abc'"), err
        assert err[-1] == "1 problem found; nothing was run."
    twice = _fleet(tmp_path, "  - {name: cf1, pad: pad-1}\n  - {name: cf2, pad: pad-1}\n")
    assert main(["validate", twice]) == 2
    err = _lines(capsys.readouterr().err)
    assert err[0] == f"{twice}:8:22: pad 'pad-1' is cf1's already: one drone per pad", err


def test_fleet_check_flies_nothing_and_names_each_drones_share(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert main(["fleet", FLEET, "--check", "--out", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f"{FLEET}: ok (2 drones; cf1: ")
    shares = [int(part.split(": ")[1].split()[0]) for part in line[:-1].split("; ")[1].split(", ")]
    assert sum(shares) == 16 and all(shares)
    assert not out.exists()


def test_a_rig_and_a_world_are_checked_with_their_settings(capsys) -> None:
    assert main(["validate", "rigs/site.yaml", "--set", "world.racks.0.depth_m=0.5"]) == 2
    err = capsys.readouterr().err
    assert "--set world.racks[0].depth_m: 0.5 m is too shallow" in err
    assert main(["validate", "worlds/site.yaml", "--set", "racks.0.depth_m=0.5"]) == 2
    assert "0.5 m is too shallow" in capsys.readouterr().err
    assert main(["validate", "rigs/site.yaml", "--set", "sim.bogus=1"]) == 2
    assert "unknown key 'sim.bogus'" in capsys.readouterr().err


def test_options_that_do_not_apply_are_refused(capsys) -> None:
    assert main(["validate", "fleets/site_4.yaml", "--rig", "rigs/site.yaml"]) == 2
    err = _lines(capsys.readouterr().err)
    assert err[0].startswith("--rig applies to missions only: fleets/site_4.yaml is a fleet file")
    assert main(["validate", "campaigns/pallet_scan.yaml", "--set", "seed=1"]) == 2
    err = _lines(capsys.readouterr().err)
    assert err[0].startswith("--set does not apply to campaigns/pallet_scan.yaml, a campaign")


@pytest.mark.parametrize(
    ("argv", "kind", "usage"),
    [
        (["rigs/site.yaml"], "rig", "btrun MISSION --rig FILE"),
        (["run", "fleets/site_4.yaml", "-q"], "fleet", "btrun fleet FILE (--check)"),
        (["show", "worlds/site.yaml"], "world", "the world.path of a rig"),
    ],
)
def test_run_and_show_say_what_a_file_is_when_it_is_not_a_mission(
    tmp_path, capsys, argv, kind, usage
) -> None:
    out = tmp_path / "run"
    extra = ["--out", str(out)] if argv[0] != "show" else []
    assert main([*argv, *extra]) == 2
    err = _lines(capsys.readouterr().err)
    path = argv[1] if argv[0] in ("run", "show") else argv[0]
    assert err[0].startswith(f"{path}:1:1: this is a {kind} file, not a mission; it is used as:")
    assert usage in err[0] and len(err) == 2
    assert not out.exists()
