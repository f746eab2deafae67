"""The frame gate: perception skips a camera frame whose view barely moved since the last
frame it processed, and never one whose view moved; the rig setting validates."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from drivers.rig.loader import ConfigError, load_rig
from drivers.vehicle.types import Pose
from nodes.perception_session import PerceptionSession
from perception.frame_gate import FrameGate, FrameGateParams, view_change_px
from perception.synth.camera_model import CameraModel, CameraPose

CAMERA = CameraModel()
RATE_HZ = 15.0  # the simulated AI-deck's frame rate


def passed(params: FrameGateParams, poses: list[CameraPose]) -> list[int]:
    """Indices of the frames (one every 1/15 s, from the given poses) the gate lets through."""
    gate = FrameGate(CAMERA, params)
    return [k for k, pose in enumerate(poses) if gate.wants(k / RATE_HZ, pose)]


def sideways(step_m: float, n: int = 12) -> list[CameraPose]:
    """The drone flying along y (to its left, facing +x), ``step_m`` per frame."""
    return [CameraPose.from_yaw(0.0, k * step_m, 0.3, 0.0) for k in range(n)]


def test_a_sideways_step_moves_the_view_by_fx_times_step_over_depth():
    a = CameraPose.from_yaw(0.0, 0.0, 0.3, 0.0)
    b = CameraPose.from_yaw(0.0, 0.01, 0.3, 0.0)
    assert view_change_px(CAMERA, a, b, 0.4) == pytest.approx(CAMERA.fx * 0.01 / 0.4)
    assert view_change_px(CAMERA, a, a, 0.4) == 0.0


def test_a_turn_moves_the_view_even_without_moving():
    a = CameraPose.from_yaw(0.0, 0.0, 0.3, 0.0)
    b = CameraPose.from_yaw(0.0, 0.0, 0.3, math.radians(2.0))
    assert view_change_px(CAMERA, a, b, 0.4) > CAMERA.fx * math.tan(math.radians(2.0)) - 1e-6


def test_a_still_view_is_processed_only_once_per_gap():
    still = [CameraPose.from_yaw(1.0, 2.0, 0.3, 0.5)] * 12
    # 0.2 s gap at 15 frames/s: every third frame
    assert passed(FrameGateParams(3.0, 0.2), still) == [0, 3, 6, 9]
    assert passed(FrameGateParams(3.0, 0.5), still) == [0, 8]


def test_a_moving_view_is_never_skipped():
    step = 3.5 * 0.4 / CAMERA.fx  # 3.5 px a frame at 0.4 m
    assert passed(FrameGateParams(3.0, 10.0), sideways(step)) == list(range(12))


def test_a_slow_scan_is_processed_every_few_frames():
    step = 2.0 * 0.4 / CAMERA.fx  # 2 px a frame: the pallet scan at 7 cm/s, 0.4 m
    assert passed(FrameGateParams(3.0, 10.0), sideways(step)) == [0, 2, 4, 6, 8, 10]
    assert passed(FrameGateParams(5.0, 10.0), sideways(step)) == [0, 3, 6, 9]
    # nearer things move more: measured at 0.2 m, the same scan moves 4 px a frame
    assert passed(FrameGateParams(5.0, 10.0, 0.2), sideways(step)) == [0, 2, 4, 6, 8, 10]


def test_zero_processes_every_frame_and_no_pose_is_never_skipped():
    still = [CameraPose.from_yaw(0.0, 0.0, 0.3, 0.0)] * 6
    assert passed(FrameGateParams(0.0, 0.2), still) == list(range(6))
    gate = FrameGate(CAMERA, FrameGateParams(3.0, 0.2))
    assert all(gate.wants(k / RATE_HZ, None) for k in range(6))


@pytest.mark.parametrize(
    "params", [FrameGateParams(-1.0), FrameGateParams(3.0, -0.1), FrameGateParams(3.0, 0.2, 0.0)]
)
def test_bad_parameters_are_refused(params):
    with pytest.raises(ValueError):
        FrameGate(CAMERA, params)


def test_the_rig_setting_validates_and_reaches_the_session():
    with pytest.raises(ConfigError, match="min_view_change_px"):
        load_rig(None, {"perception.min_view_change_px": "-2"})
    rig = load_rig(None, {"perception.min_view_change_px": "7", "perception.max_frame_gap_s": "1"})
    gate = PerceptionSession(rig).frame_gate()
    assert (gate.params.min_view_change_px, gate.params.max_frame_gap_s) == (7.0, 1.0)
    assert PerceptionSession().frame_gate().params == FrameGateParams()


def test_the_session_counts_skipped_frames_and_never_skips_a_frame_without_a_pose():
    session = PerceptionSession()
    gate = session.frame_gate()
    here = Pose(1.0, 2.0, 0.3, 0.0, source="truth")

    def frame(k: int, pose: Pose) -> SimpleNamespace:
        return SimpleNamespace(t_s=k / RATE_HZ, pose=pose, index=k)

    assert gate.params == FrameGateParams(8.0, 0.3, 0.4)  # the defaults
    got = [session.wants(gate, frame(k, here)) for k in range(6)]
    assert got == [True, False, False, False, False, True]  # 0.3 s gap at 15 frames/s
    assert session.frames_skipped == 4
    unknown = Pose(0.0, 0.0, 0.0, 0.0, source="none")  # e.g. an AI-deck without pose_fn
    assert all(session.wants(gate, frame(k, unknown)) for k in range(6, 10))
    assert session.summary()["frames_skipped"] == 4


@pytest.mark.slow
def test_the_pallet_scan_skips_still_frames_and_keeps_its_answer(pallet_scan_flight):
    m = pallet_scan_flight.mission
    session = m.ctx.resources["perception"]
    assert m.blackboard["pallet_id"] == "3A"
    assert session.frames_skipped > 0
    assert session.frames > 60  # the scan still sees each block in many frames
