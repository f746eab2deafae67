"""bench/fault_campaign.py's jobs are runnable: every --set it plans is accepted by the rig
(the camera_stall row once named a test-only renderer whose signature had gone stale)."""

from __future__ import annotations

import importlib.util
import os
import sys

import pytest
from helpers import REPO

from drivers.rig.loader import load_rig
from drivers.sim.renderers import RENDERERS


@pytest.fixture(scope="module")
def campaign():
    path = os.path.join(REPO, "bench", "fault_campaign.py")
    spec = importlib.util.spec_from_file_location("bench_fault_campaign", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def test_every_planned_job_is_a_valid_rig_override(campaign) -> None:
    for fault in campaign.FAULT_TYPES:
        for i in range(3):
            job = campaign.plan(fault, i, 1)
            sets = dict(s.split("=", 1) for s in job["sets"])
            rig = load_rig(None, sets)  # raises ConfigError on a stale key or value
            renderer = rig.data["sensors"]["camera"]["renderer"]
            assert renderer == "none" or renderer in RENDERERS, (fault, renderer)


def test_the_camera_stall_job_streams_frames_from_the_rig_renderer(campaign) -> None:
    job = campaign.plan("camera_stall", 0, 1)
    assert "sensors.camera.renderer=pallet" in job["sets"]
