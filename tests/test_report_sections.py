"""The report names scans and identifications by their blackboard keys, shows every scan's
crops, survives a failed identification, draws the pallets, and keeps wide tables scrollable."""

from __future__ import annotations

import types

import numpy as np

from nodes.perception_session import BlockScan, PerceptionSession
from nodes.report.html import _motion_table
from nodes.report.perception import perception_section
from nodes.report.plots import pallet_outline


def _mission(session: PerceptionSession) -> types.SimpleNamespace:
    return types.SimpleNamespace(ctx=types.SimpleNamespace(resources={"perception": session}))


def test_every_scan_and_identification_is_named_by_its_key(tmp_path) -> None:
    s = PerceptionSession()
    crop = np.full((40, 30, 3), 128, np.uint8)
    s.scans += [
        BlockScan(crops=[crop, crop], key="first_scan", t_s=20.0),
        BlockScan(crops=[crop, crop, crop], key="second_scan", t_s=40.0),
    ]
    s.identifications += [
        {"key": "left_pallet", "pallet_id": "3A", "best_id": "3A", "distance": 0.2,
         "margin": 0.7, "known": True, "reason": "", "thresholds": [0.6, 0.1],
         "ranking": [["3A", 0.2, [0.2, 0.2, 0.2]]], "crops": [crop, crop, crop]},
        {"key": "right_pallet", "node": "IdentifyPallet 'right'", "failed": "2 of 3 blocks"},
    ]  # fmt: skip
    html = perception_section(str(tmp_path), _mission(s))
    assert "Scan 1 into {first_scan} at 20.0 s: 2 of 3 blocks" in html
    assert "Scan 2 into {second_scan} at 40.0 s: 3 of 3 blocks" in html
    assert (tmp_path / "perception" / "scan_1_block_2.png").exists()
    assert (tmp_path / "perception" / "scan_2_block_3.png").exists()
    assert "Identification {left_pallet}: 3A" in html
    assert "Identification {right_pallet}: failed" in html and "2 of 3 blocks" in html


def test_pallet_outline_is_the_footprint_facing_its_side() -> None:
    p = {"centre_m": [9.7, -0.05], "facing_deg": 180.0}
    o = pallet_outline(p)
    assert np.allclose(sorted(o[:, 0]), [9.3, 9.3, 10.1, 10.1])  # 0.8 m deep, face at 9.3
    assert np.allclose(sorted(o[:, 1]), [-0.65, -0.65, 0.55, 0.55])  # 1.2 m along the face


def test_the_motion_table_scrolls_instead_of_overflowing() -> None:
    label = "GoTo 'a very long leaf label that would overflow the page' " * 3
    row = {"n": 1, "label": label, "node": "Main/GoTo", "reason": "", "kind": "GoTo",
           "result": "SUCCESS", "goal": (1.0, 2.0, 1.0), "goal_yaw_deg": 0.0, "pos_thr": 0.03,
           "yaw_thr_deg": 15.0, "duration": 3.0, "reach": 2.5, "track_max": 0.02,
           "track_rms": 0.01, "final_dist": 0.01, "final_yaw_deg": 1.0, "settle": 1.0}  # fmt: skip
    html = _motion_table([row])
    assert html.startswith('<div class="wide"><table>') and html.endswith("</table></div>")
