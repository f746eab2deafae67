"""btrun fleet: the fleet file's checks (located, before anything flies), the place split,
and fleets flown in lock-step: deterministic, one merged inventory, and a drone that loses
its link lands while the other finishes."""

from __future__ import annotations

import json
import os

import pytest
from helpers import REPO

from bt_engine.cli import main
from drivers.sim.world import load_world
from nodes.fleet.plan import bay_blocks, split_places

MISSION = os.path.join(REPO, "missions", "inventory.xml")
AISLE_RIG = os.path.join(REPO, "rigs", "aisle.yaml")


def _fleet(tmp_path, drones: str, rig: str = AISLE_RIG, extra: str = "") -> str:
    path = tmp_path / "fleet.yaml"
    path.write_text(f"name: t\nmission: {MISSION}\nrig: {rig}\n{extra}drones:\n{drones}")
    return str(path)


@pytest.mark.parametrize(
    "drones, line, message",
    [
        ("  - {name: a, pad: pad-1}\n  - {name: a, pad: pad-2}\n", 6, "two drones named 'a'"),
        ("  - {name: a, pad: pad-1}\n  - {name: b, pad: pad-1}\n", 6, "pad 'pad-1' is a's already"),
        ("  - {name: a, pad: pad-9}\n", 5, "pad 'pad-9' is not a pad of the world (pad-1, pad-2)"),
        (
            "  - {name: a, pad: pad-1}\n  - {name: b, start_m: [1.2, 2.9, 0]}\n",
            6,
            "b starts 0.22 m from a (at least the minimum separation 0.5 m)",
        ),
        ("  - {name: a}\n", 5, "drone 'a' needs a pad"),
        (
            "  - {name: a, pad: pad-1, landing_pads: [pad-7]}\n",
            5,
            "pad 'pad-7' is not a pad of the world (pad-1, pad-2)",
        ),
        (
            "  - {name: a, pad: pad-1, landing_pads: [pad-2]}\n  - {name: b, pad: pad-2}\n",
            5,
            "pad 'pad-2' is b's already: a drone lands only on its own pads",
        ),
        (
            "".join(f"  - {{name: d{i}, start_m: [{i}, 0, 0]}}\n" for i in range(5)),
            5,
            "1 to 4 drones",
        ),
    ],
)
def test_bad_fleet_files_are_refused_where_the_problem_is(tmp_path, capsys, drones, line, message):
    path = _fleet(tmp_path, drones)
    assert main(["fleet", path, "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert f"{path}:{line}:" in err and message in err, err
    assert not (tmp_path / "run").exists()  # nothing flew, nothing written


def test_two_drones_on_one_radio_address_are_refused(tmp_path, capsys):
    rig = os.path.join(REPO, "rigs", "crazyflie-vicon.yaml")
    drones = (
        "  - {name: a, start_m: [0, 0, 0], uri: radio://0/80/2M/E7E7E7E701}\n"
        "  - {name: b, start_m: [0, 2, 0], uri: radio://0/80/2M/E7E7E7E701}\n"
        "  - {name: c, start_m: [0, 4, 0]}\n"
        "  - {name: d, start_m: [0, 6, 0]}\n"
    )
    path = _fleet(tmp_path, drones, rig=rig)
    assert main(["fleet", path]) == 2
    err = capsys.readouterr().err
    assert f"{path}:6:" in err and "b and a both use radio://0/80/2M/E7E7E7E701" in err
    assert f"{path}:8:" in err and "d and c both use radio://0/80/2M/E7E7E7E7E7" in err


def test_an_unknown_place_in_the_fleet_file_is_located(tmp_path, capsys):
    path = _fleet(
        tmp_path,
        "  - {name: a, pad: pad-1}\n",
        extra="places: A-01-1;A-10-1\n",
    )
    assert main(["fleet", path]) == 2
    assert f"{path}:4:9: unknown place 'A-10-1'" in capsys.readouterr().err


def test_bays_are_split_into_whole_blocks_swept_side_by_side():
    w = load_world(os.path.join(REPO, "worlds", "aisle.yaml"))
    from nodes.inventory import all_places_order

    places = all_places_order(w)
    blocks = bay_blocks(places, w, 3)
    assert [len(b) for b in blocks] == [6, 6, 4]
    assert sum(blocks, []) == places  # order kept, nothing lost or repeated
    split = split_places(places, w, {"far": (1.0, -2.8, 0.0), "near": (1.0, 2.8, 0.0)})
    assert split["near"][0] == "A-01-1" and split["far"][0] == "A-05-1"  # same direction
    assert {p.split("-")[1] for p in split["near"]} == {"01", "02", "03", "04"}
    rr = split_places(places, w, {"a": (0, 0, 0), "b": (0, 0, 0)}, "round_robin")
    assert rr["a"] == places[::2] and rr["b"] == places[1::2]


def _fly(tmp_path, name: str, extra: list[str], fleet: str | None = None) -> dict:
    out = tmp_path / name
    code = main(
        [
            "fleet",
            fleet or os.path.join(REPO, "fleets", "aisle_2.yaml"),
            "--out",
            str(out),
            "-q",
            "--no-report",
            *extra,
        ]
    )
    summary = json.loads((out / "summary.json").read_text())
    summary["_code"] = code
    summary["_rows"] = json.loads((out / "inventory.json").read_text())["rows"]
    summary["_out"] = out
    return summary


def _ticks(out, drone: str) -> list[dict]:
    """A drone's tick records; the first without its messages (the first run of a session
    builds the demo gallery there and says so)."""
    lines = (out / "drones" / drone / "ticks.jsonl").read_text().splitlines()[1:]
    recs = [json.loads(line) for line in lines]
    recs[0].pop("messages", None)
    return recs


@pytest.mark.slow
def test_a_fleet_is_deterministic_and_merges_its_inventory(tmp_path, monkeypatch, capsys):
    from drivers.safety.airspace import Airspace

    room, add = {}, Airspace.add

    def add_and_see(self, vehicle, inside=None):  # where each drone may step aside
        room[vehicle.name] = inside
        return add(self, vehicle, inside)

    monkeypatch.setattr(Airspace, "add", add_and_see)
    args = ["--set", "places=A-02-1;A-07-1", "--seed", "3"]
    a = _fly(tmp_path, "a", args)
    printed = capsys.readouterr().out  # each drone's line counts its places (one of one)
    assert printed.count(" s, 1 of 1 place answered)") == 2
    b = _fly(tmp_path, "b", args)
    # the airspace has each drone's geofence (rigs/aisle.yaml's box, less its margin)
    assert room["cf1"]((1.0, 0.0, 1.0)) and not room["cf1"]((1.0, 0.0, 2.4))
    assert a["_code"] == 0 and a["status"] == "SUCCESS"
    assert {r["place"]: r["drone"] for r in a["_rows"]} == {"A-02-1": "cf1", "A-07-1": "cf2"}
    assert {r["run"] for r in a["_rows"]} == {"a"}  # rows name the fleet's own run folder

    def answers(rows: list[dict]) -> list[dict]:
        return [{k: v for k, v in r.items() if k != "run"} for r in rows]

    # same seed: the same answers at the same mission times
    assert answers(a["_rows"]) == answers(b["_rows"])
    for drone in ("cf1", "cf2"):
        ta, tb = _ticks(a["_out"], drone), _ticks(b["_out"], drone)
        assert len(ta) > 500 and ta == tb
        assert a["drones"][drone]["landed"] and a["drones"][drone]["collisions"] == 0
    inv = a["inventory"]
    assert inv["places"] == 2 and inv["wrong"] == 0 and inv["not_scanned"] == 0
    assert a["separation"]["violations"] == 0 and a["collisions"]["drones"] == 0
    assert a["separation"]["airspace_asides"] == 0 and a["drones"]["cf1"]["asides"] == 0
    # the inventory bench reads the same folder (bench/inventory_campaign.py)
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "inventory_campaign", os.path.join(REPO, "bench", "inventory_campaign.py")
    )
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    fig = bench.figures(str(a["_out"]), 3, 0, 10.0)
    assert fig["places"] == 2 and fig["in_order"] and fig["violations"] == 0
    assert fig["realtime_x"] == pytest.approx(a["mission_time_s"] / 10.0, abs=0.01)


@pytest.mark.slow
def test_a_drone_that_loses_its_link_lands_and_the_other_finishes(tmp_path):
    path = tmp_path / "fleet.yaml"
    path.write_text(
        f"name: link\nmission: {MISSION}\nrig: {AISLE_RIG}\nplaces: A-02-*;A-07-*\n"
        "drones:\n  - {name: cf1, pad: pad-1}\n"
        "  - {name: cf2, pad: pad-2, set: {faults.link_drop.at_s: 8, faults.link_drop.duration_s: 2}}\n"
    )
    s = _fly(tmp_path, "run", [], fleet=str(path))
    assert s["_code"] == 1 and s["status"] == "ABORTED"
    cf1, cf2 = s["drones"]["cf1"], s["drones"]["cf2"]
    assert cf1["status"] == "SUCCESS" and cf1["landed"]
    assert cf2["status"] == "ABORTED" and "link_lost" in cf2["reason"] and cf2["landed"]
    rows = {r["place"]: r for r in s["_rows"]}
    assert {"A-02-1", "A-02-2"} <= set(rows)  # cf1 answered its places
    missing = s["inventory"]["not_scanned_places"]
    assert missing and all(p.startswith("A-07") for p in missing)
    assert set(missing) | {p for p in rows if p.startswith("A-07")} == {"A-07-1", "A-07-2"}


@pytest.mark.slow
@pytest.mark.sitl
def test_a_sitl_fleet_runs_one_emulator_per_drone(tmp_path, capsys):
    """Two drones through the real cflib and their own CRTP emulators on loopback (real time)."""
    mission = tmp_path / "hop.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Hop"><BehaviorTree ID="Hop"><Sequence>'
        '<TakeOff height="0.5" speed="0.5"/><Sleep msec="1000"/><Land speed="0.5"/>'
        "</Sequence></BehaviorTree></root>"
    )
    path = tmp_path / "fleet.yaml"
    path.write_text(
        f"name: sitl\nmission: {mission}\nrig: {os.path.join(REPO, 'rigs', 'sitl.yaml')}\n"
        "set: {aideck.enabled: false}\n"
        "drones:\n  - {name: cf1, start_m: [0.0, 0.0, 0.0]}\n  - {name: cf2, start_m: [0.0, -2.0, 0.0]}\n"
    )
    out = tmp_path / "run"
    assert main(["fleet", str(path), "--out", str(out), "-q", "--no-report"]) == 0
    printed = capsys.readouterr().out  # a mission without an inventory: no place counts
    assert "places answered" not in printed and "  cf1: SUCCESS:" in printed
    s = json.loads((out / "summary.json").read_text())
    for name in ("cf1", "cf2"):
        d = s["drones"][name]
        assert d["status"] == "SUCCESS" and d["landed"], d
        vehicle = json.loads((out / "drones" / name / "summary.json").read_text())["vehicle"]
        assert vehicle["link"]["uri"].startswith("udp://127.0.0.1:")
    uris = {
        json.loads((out / "drones" / n / "summary.json").read_text())["vehicle"]["link"]["uri"]
        for n in ("cf1", "cf2")
    }
    assert len(uris) == 2  # one emulator each
