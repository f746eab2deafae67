"""bench/fault_campaign.py's jobs are runnable: every setting of campaigns/faults.yaml is
accepted by the rig (the camera_stall row once named a test-only renderer whose signature
had gone stale), and the faults that need a process of their own are planned."""

from __future__ import annotations

import pytest
from helpers import bench_module

from bt_engine.campaign.check import check_campaign
from bt_engine.campaign.rows import expand
from bt_engine.campaign.spec import load_campaign
from drivers.rig.loader import load_rig
from drivers.sim.renderers import RENDERERS


@pytest.fixture(scope="module")
def campaign():
    with bench_module("fault_campaign") as module:
        yield module


def test_every_fault_is_either_in_the_campaign_file_or_planned_here(campaign) -> None:
    c = load_campaign(campaign.CAMPAIGN)
    names = [case.name for case in c.faults]
    assert sorted(names + list(campaign.PROCESS_FAULTS)) == sorted(campaign.FAULT_TYPES)
    for fault in campaign.PROCESS_FAULTS:
        for i in range(3):
            job = campaign.plan(fault, i, 1)
            assert job["seed"] == 1000 + i and job["sets"] == []


def test_every_campaign_setting_is_a_valid_rig_override(campaign) -> None:
    c = load_campaign(campaign.CAMPAIGN)
    rows = expand(c)
    check_campaign(c, rows)  # raises MissionError on a stale key or value (every draw bound)
    for row in rows[:: len(c.seeds)]:
        rig = load_rig(None, dict(item.split("=", 1) for item in row.set_items()))
        renderer = rig.data["sensors"]["camera"]["renderer"]
        assert renderer == "none" or renderer in RENDERERS, (row.fault, renderer)


def test_the_camera_stall_runs_stream_frames_from_the_rig_renderer(campaign) -> None:
    c = load_campaign(campaign.CAMPAIGN)
    stall = next(case for case in c.faults if case.name == "camera_stall")
    assert stall.sets["sensors.camera.renderer"] == "pallet"
