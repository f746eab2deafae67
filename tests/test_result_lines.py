"""The console's last lines: every identification by its blackboard key, and every failure
the tree handled and went on after."""

from __future__ import annotations

import json

from helpers import wrap

from bt_engine.cli import main
from nodes.perception_session import PerceptionSession


def test_every_identification_is_printed_by_key() -> None:
    s = PerceptionSession()
    s.identifications += [
        {"key": "pallet_id", "pallet_id": "3A", "best_id": "3A", "distance": 0.2,
         "margin": 0.7, "known": True},
        {"key": "second", "pallet_id": "unknown", "best_id": "1B", "distance": 0.9,
         "margin": 0.01, "known": False},
        {"key": "third", "node": "IdentifyPallet 'id3'", "failed": "only 2 of 3 blocks"},
    ]  # fmt: skip
    assert s.result_lines() == [
        "pallet: 3A (distance 0.200, margin 0.700)",
        "pallet {second}: unknown (distance 0.900, margin 0.010, closest 1B)",
        "pallet {third}: failed in IdentifyPallet 'id3': only 2 of 3 blocks",
    ]


def test_a_failure_the_tree_handled_is_listed_after_the_result(tmp_path, capsys) -> None:
    xml = wrap(
        """    <Sequence>
      <Fallback>
        <BatteryAbove percent="101" name="check_battery"/>
        <AlwaysSuccess name="continue_anyway"/>
      </Fallback>
      <TakeOff height="0.5"/>
      <Land/>
    </Sequence>"""
    )
    path = tmp_path / "m.xml"
    path.write_text(xml)
    assert main(["run", str(path), "--out", str(tmp_path / "r"), "-q", "--no-report"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("SUCCESS")
    handled = [line for line in out if line.startswith("handled: ")]
    assert len(handled) == 1 and "check_battery" in handled[0] and "m.xml:5:" in handled[0]
    assert "not above 101 %" in handled[0]
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["leaf_failures"][0]["times"] == 1


def test_btrun_run_prints_validation_warnings_and_still_flies(tmp_path, capsys) -> None:
    xml = wrap(
        """    <Sequence>
      <Script code="y := from_outside + 1"/>
      <AlwaysSuccess/>
    </Sequence>"""
    )
    path = tmp_path / "m.xml"
    path.write_text(xml)
    out = str(tmp_path / "r")
    args = ["run", str(path), "--out", out, "-q", "--no-report", "--set", "from_outside=2"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "m.xml:4:" in err and "warning: script reads blackboard entry 'from_outside'" in err
