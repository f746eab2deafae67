"""Every mission in missions/ is a runnable demo: it flies to SUCCESS on the default rig
(the inventory on the aisle rig it is made for, over two of its places)."""

from __future__ import annotations

import glob
import json
import os

import pytest
from helpers import REPO, sim_mission

from bt_engine.cli import main

MISSIONS = sorted(
    glob.glob(os.path.join(REPO, "missions", "*.xml"))
    + glob.glob(os.path.join(REPO, "missions", "*.yaml"))
)


# the pallet-scan flights take a few seconds each; the other missions are short
SLOW_MISSIONS = (
    "pallet_scan.xml",
    "pallet_scan.yaml",
    "pallet_scan_fixed.xml",
    "pallet_scan_fixed.yaml",
    "enroll_pallet.xml",
    "inventory.xml",
    "inventory.yaml",
    "inventory_per_place.xml",
    "inventory_per_place.yaml",
)
#: missions made for another rig than the default one, and the inputs that keep them short
RIGS = {
    "inventory.xml": ("rigs/aisle.yaml", {"places": "A-02-1;A-02-2"}),
    "inventory.yaml": ("rigs/aisle.yaml", {"places": "A-02-1;A-02-2"}),
    "inventory_per_place.xml": ("rigs/aisle.yaml", {"places": "A-02-1;A-02-2"}),
    "inventory_per_place.yaml": ("rigs/aisle.yaml", {"places": "A-02-1;A-02-2"}),
}


@pytest.mark.parametrize(
    "path",
    [
        pytest.param(p, marks=pytest.mark.slow) if os.path.basename(p) in SLOW_MISSIONS else p
        for p in MISSIONS
    ],
    ids=os.path.basename,
)
def test_mission_flies_to_success_and_lands(path, tmp_path, request):
    name = os.path.basename(path)
    if name == "pallet_scan.xml":  # the same flight as the shared one (conftest.py)
        flight = request.getfixturevalue("pallet_scan_flight")
        result, pf = flight.result, flight.platform
    else:
        # enroll_pallet.xml writes a gallery (pallets.sqlite in the working directory by default)
        bb = {"gallery": str(tmp_path / "pallets.sqlite")} if "enroll" in name else {}
        rig, inputs = RIGS.get(name, (None, {}))
        m, run, pf = sim_mission(path, blackboard={**bb, **inputs}, rig=rig)
        result = run.run(max_time_s=300)
    assert result.status == "SUCCESS", result.reason
    assert pf.vehicle.is_landed and not pf.vehicle.is_crashed
    assert pf.summary()["collisions"] == []


FIRST_SCAN = (
    "PalletScanFixed/pallet_scan/identify_or_come_back/scan_and_identify/scan/"
    "scan_while_detecting/scan_line"
)


@pytest.mark.slow
def test_pallet_scan_fixed_follows_the_scan_line():
    m, run, pf = sim_mission(os.path.join(REPO, "missions", "pallet_scan_fixed.xml"), blackboard={})
    positions = []

    def record(_runner) -> None:
        if any(FIRST_SCAN in n.path for n in m.running_nodes()):
            positions.append(tuple(pf.vehicle.position))

    run.on_tick = record
    result = run.run(max_time_s=300)
    assert result.status == "SUCCESS", result.reason
    ys = []
    for x, y, z in positions:
        ys.append(y)
        assert abs(x - 8.90) < 0.06 and abs(z - 0.255) < 0.06, (x, y, z)
    # From y = -0.80 until the third block is committed (it sits at y = +0.48 and is
    # committed once 20 px right of the image centre), which stops the scan early.
    assert min(ys) < -0.75 and 0.5 < max(ys) <= 0.62
    # three segments: the drone passed both checkpoints, the third stopped by the detection
    done = [
        (rec["t"], p) for rec in run.trace for p, st in finished(rec).items() if st == "SUCCESS"
    ]
    segs = [(t, p.rsplit("/", 1)[-1]) for t, p in done if "/segment_" in p]
    assert [s for _, s in segs] == ["segment_1", "segment_2"]
    # the scan ran at about 0.07 m/s: the middle third of the 1.4 m line takes about 6.7 s
    assert segs[1][0] - segs[0][0] == pytest.approx(1.4 / 3 / 0.07, rel=0.15)


REACTIVE_SCAN = "/scan/align_and_scan/scan_while_detecting/scan_face"


@pytest.mark.slow
def test_pallet_scan_scans_along_the_located_face(pallet_scan_flight):
    """The reactive scan: it located the face where the world put it and flew along it at
    the stand-off distance and the blocks' height, stopping once the third block passed."""
    flight = pallet_scan_flight
    assert flight.result.status == "SUCCESS", flight.result.reason
    faces = flight.mission.ctx.resources["perception"].faces
    located = faces[0]
    assert located["stage"] == "located" and located["blocks_seen"] == 3
    # from 0.75 m the depth is good to a few centimetres; from the scan start, to one or two
    assert located["centre_m"] == pytest.approx([9.30, -0.05, 0.255], abs=0.05)
    aligned = faces[1]
    assert aligned["stage"] == "aligned"
    assert aligned["centre_m"] == pytest.approx([9.30, -0.05, 0.255], abs=0.02)
    assert abs(aligned["facing_deg"]) < 2.0
    ys = []
    for tick in flight.ticks:
        if any(p.endswith(REACTIVE_SCAN) and "rescan" not in p for p in tick.running):
            x, y, z = tick.position
            ys.append(y)
            assert abs(x - 8.90) < 0.05 and abs(z - 0.255) < 0.05, (x, y, z)
    # from 0.15 m before the first block (y = -0.58) until the third (y = +0.48) passed the
    # image centre
    assert min(ys) == pytest.approx(-0.73, abs=0.03) and 0.5 < max(ys) <= 0.65


def finished(rec: dict) -> dict:
    """Leaves that finished in a tick record (whether or not reset to IDLE in the same tick)."""
    out = {p: st for p, st in rec.get("changed", {}).items() if st in ("SUCCESS", "FAILURE")}
    out.update(rec.get("done", {}))
    return out


def test_mission_inputs_can_be_overridden(tmp_path, monkeypatch):
    out = tmp_path / "run"
    monkeypatch.chdir(REPO)
    rc = main(
        [
            "missions/square.xml",
            "--out",
            str(out),
            "-q",
            "--set",
            "height=0.6",
            "--set",
            "speed=1.0",
            "--seed",
            "3",
        ]
    )
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["blackboard"]["height"] == 0.6
    assert s["seed"] == 3


@pytest.mark.slow
def test_pallet_scan_xml_and_yaml_fly_identically(tmp_path):
    """The YAML version is the same mission: same seed, same tick log, tick for tick."""
    logs = []
    for ext in ("xml", "yaml"):
        out = tmp_path / ext
        assert (
            main(
                [
                    os.path.join(REPO, "missions", f"pallet_scan.{ext}"),
                    "--out",
                    str(out),
                    "-q",
                    "--no-report",
                    "--seed",
                    "2",
                ]
            )
            == 0
        )
        logs.append((out / "ticks.jsonl").read_text().splitlines()[1:])
    assert len(logs[0]) > 2000
    assert logs[0] == logs[1]


def test_yaml_copy_is_up_to_date(tmp_path):
    """missions/pallet_scan.yaml is generated from the XML: regenerate it when the XML changes."""
    from bt_engine.loading import convert_file
    from bt_engine.registry import REGISTRY

    out = tmp_path / "p.yaml"
    assert convert_file(os.path.join(REPO, "missions", "pallet_scan.xml"), str(out), REGISTRY) == []
    with open(os.path.join(REPO, "missions", "pallet_scan.yaml"), encoding="utf-8") as f:
        assert f.read() == out.read_text(), (
            "run: btrun convert missions/pallet_scan.xml missions/pallet_scan.yaml"
        )
