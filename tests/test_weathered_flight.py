"""Weathered and painted pallets in flight: enrolled by flying enroll_pallet.xml in the
weathered warehouse, identified by flying pallet_scan.xml, the confident scan added to the
gallery and shown by btrun gallery history."""

from __future__ import annotations

import json
import os

import pytest
from helpers import REPO

from bt_engine.cli import main

WEATHERED = os.path.join(REPO, "worlds", "warehouse_weathered.yaml")


def fly(tmp_path, mission: str, name: str, sets: dict[str, str], seed: int = 0) -> dict:
    out = str(tmp_path / name)
    argv = ["run", os.path.join(REPO, "missions", mission), "--quiet", "--no-report", "--out", out]
    argv += ["--seed", str(seed)]
    for k, v in {"world.path": WEATHERED, **sets}.items():
        argv += ["--set", f"{k}={v}"]
    main(argv)
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)


@pytest.mark.slow
def test_grey_and_painted_pallets_are_enrolled_and_identified_in_flight(tmp_path, capsys):
    g = str(tmp_path / "weathered.sqlite")
    for side in ("1A", "5A"):  # grey wood; painted blue
        s = fly(
            tmp_path,
            "enroll_pallet.xml",
            f"enrol-{side}",
            {"pallet": side, "gallery": g, "world.scan_pallet": side},
        )
        assert s["status"] == "SUCCESS", s.get("reason")
    s = fly(
        tmp_path,
        "pallet_scan.xml",
        "scan-1A",
        {"gallery": g, "world.scan_pallet": "1A", "update_gallery": "true"},
        seed=7,  # another flight than the enrolment's (same seed: the very same frames)
    )
    assert s["status"] == "SUCCESS" and s["blackboard"]["pallet_id"] == "1A"
    ident = s["perception"]["identifications"][-1]
    assert ident["gallery_update"].startswith("added a view to 1A"), ident["gallery_update"]
    capsys.readouterr()
    assert main(["gallery", "history", g, "1A"]) == 0
    out = capsys.readouterr().out
    assert "enrol" in out and "add view" in out and "run scan-1A t=" in out
