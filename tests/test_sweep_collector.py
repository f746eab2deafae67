"""perception/sweep.py on synthetic passes: the camera flies a line in front of a rack face,
detections are made from the map (and from things that are not blocks), and the collector
must finish each place as it passes it with the right outcome. No renderer, no detector."""

from __future__ import annotations

import math

import numpy as np
import pytest

from perception.face import PalletModel
from perception.sequencer import Detection
from perception.sweep import (
    EMPTY,
    IDENTIFY,
    RESCAN,
    PassPlace,
    SweepCollector,
    SweepParams,
    fuse_views,
    slot_points,
)
from perception.synth.camera_model import CameraModel, CameraPose, project

CAM = CameraModel()
MODEL = PalletModel()
LOOK = math.pi  # the drone looks along -x at faces on the plane x = 0
STANDOFF = 0.45
Z = 0.26


def _places(n: int) -> list[PassPlace]:
    return [PassPlace(f"A-{i + 1:02d}-1", (0.0, -3.0 + 1.4 * i, Z), LOOK) for i in range(n)]


def _collector(places: list[PassPlace], **params) -> SweepCollector:
    start = (STANDOFF, places[0].row[1] - 1.2, Z)
    end = (STANDOFF, places[-1].row[1] + 1.2, Z)
    return SweepCollector(
        CAM, places, start, end, MODEL.offsets(), MODEL.block_height_m, SweepParams(**params)
    )


def _box(pose: CameraPose, point: np.ndarray, height_m: float = 0.078) -> Detection | None:
    uv, depth = project(CAM, pose, np.asarray([point]))
    u, v, d = float(uv[0, 0]), float(uv[0, 1]), float(depth[0])
    if d <= 0.05 or not 0 <= u < CAM.width:
        return None
    h = CAM.fx * height_m / d
    w = CAM.fx * 0.145 / d
    return Detection(u - w / 2, v - h / 2, u + w / 2, v + h / 2, 0.95)


def _fly(
    collector, blocks, deep=(), speed=0.8, rate=15.0, y0=None, y1=None, frames=None, z_at=None
):
    """Fly the line (at the height ``z_at(y)`` if given); every frame, detect ``blocks``
    (world points on the face plane) and ``deep`` (points behind it) where they project into
    the image. Returns the places finished, in order, with the camera's y when each was
    finished."""
    img = np.full((CAM.height, CAM.width, 3), 128, np.uint8)
    img[::2, ::3] = 90  # some texture, so crops are not flat
    y0 = collector.origin[1] if y0 is None else y0
    y1 = collector.origin[1] + 20 if y1 is None else y1
    finished = []
    t, y, i = 0.0, y0, 0
    while y <= y1 and collector.open():
        pose = CameraPose.from_yaw(STANDOFF, y, Z if z_at is None else z_at(y), LOOK)
        if (frames is None or i in frames) and collector.wants(t, pose):
            dets = [d for p in list(blocks) + list(deep) if (d := _box(pose, p)) is not None]
            collector.add(pose, img, dets, i, t)
        for w in collector.finish_passed((STANDOFF, y, Z)):
            finished.append((w, y))
        t += 1.0 / rate
        y += speed / rate
        i += 1
    return finished


def _blocks_of(place: PassPlace, shift: float = 0.0) -> list[np.ndarray]:
    return [p + np.array([0.0, shift, 0.0]) for p in slot_points(place.row, LOOK, MODEL.offsets())]


def test_each_place_is_finished_as_the_camera_passes_it():
    places = _places(4)
    c = _collector(places)
    blocks = [b for p in places for b in _blocks_of(p, 0.03)]
    finished = _fly(c, blocks)
    assert [w.name for w, _ in finished] == [p.name for p in places]
    for (w, y), p in zip(finished, places, strict=True):
        assert w.outcome == IDENTIFY, (w.name, w.reason, w.states)
        assert y < p.row[1] + 1.2  # answered right after the drone passed it, not at the end
        assert len(w.ordered_crops()) == 3 and all(len(v) >= 1 for v in w.ordered_views())
        assert w.states == ["block", "block", "block"]


def test_an_empty_place_is_empty_and_what_shows_behind_it_does_not_count():
    places = _places(3)
    c = _collector(places)
    blocks = _blocks_of(places[0]) + _blocks_of(places[2])
    # a neighbour's short face seen through the empty place: blocks 0.4 and 0.8 m deeper
    deep = [
        np.array([-0.4, places[1].row[1] - 0.3, Z]),
        np.array([-0.8, places[1].row[1] + 0.2, Z]),
    ]
    finished = {w.name: w for w, _ in _fly(c, blocks, deep)}
    assert finished["A-02-1"].outcome == EMPTY, finished["A-02-1"].reason
    assert finished["A-01-1"].outcome == IDENTIFY and finished["A-03-1"].outcome == IDENTIFY


def test_one_or_two_blocks_leave_the_place_for_the_rescan():
    places = _places(2)
    c = _collector(places)
    blocks = _blocks_of(places[0])[:2] + _blocks_of(places[1])
    finished = {w.name: w for w, _ in _fly(c, blocks)}
    assert finished["A-01-1"].outcome == RESCAN
    assert "2 of 3 blocks" in finished["A-01-1"].reason
    assert finished["A-02-1"].outcome == IDENTIFY


def test_a_pallet_far_off_its_place_is_not_called_empty():
    places = _places(2)
    c = _collector(places)
    blocks = _blocks_of(places[0], 0.25) + _blocks_of(places[1])  # 25 cm off: no slot matches
    finished = {w.name: w for w, _ in _fly(c, blocks)}
    assert finished["A-01-1"].outcome == RESCAN, finished["A-01-1"].reason


def test_a_pallet_off_its_place_seen_too_briefly_per_block_is_not_called_empty():
    """9 cm off its place, each block is centred in only two of the frames the gate picks
    at its slot, too close together for the parallax test: every slot reads ``none`` (a
    flicker). Alone, that made the place ``empty`` (validation seeds 103 and 104 of the
    site with placement errors of 8 cm: a pallet answered empty); three slots off the map
    alike are a pallet, so the place goes to a second look."""
    places = _places(3)
    blocks = _blocks_of(places[0]) + _blocks_of(places[1], 0.09) + _blocks_of(places[2])
    w = {w.name: w for w, _ in _fly(_collector(places), blocks)}["A-02-1"]
    assert w.states == ["none", "none", "none"], w.states
    assert w.outcome == RESCAN, (w.outcome, w.reason)
    assert "all +9 cm along the face from the map" in w.reason
    # the rule off (as on a second look): the flickers make it empty
    w = {w.name: w for w, _ in _fly(_collector(places, agree_m=0.0), blocks)}["A-02-1"]
    assert w.outcome == EMPTY


def test_frames_from_off_the_pass_line_are_no_evidence():
    """The drone stepped down 0.75 m out of another's way while passing the middle place
    (its motion waited at the airspace's gate there): from down there the camera sees the
    slots' columns but not their blocks. That is no look at them: the place is left for a
    second look, not answered ``empty`` (the aisle with two drones dealt places in turn,
    seed 200: two pallets answered empty so)."""
    places = _places(3)
    blocks = [b for p in places for b in _blocks_of(p)]
    mid = places[1].row[1]
    low = lambda y: Z - 0.75 if abs(y - mid) < 0.9 else Z  # noqa: E731
    finished = {w.name: w for w, _ in _fly(_collector(places), blocks, z_at=low)}
    w = finished["A-02-1"]
    assert w.outcome == RESCAN and w.looked == [0, 0, 0], (w.outcome, w.reason, w.looked)
    assert "frames missing" in w.reason
    assert finished["A-01-1"].outcome == IDENTIFY and finished["A-03-1"].outcome == IDENTIFY


def test_frames_the_host_drops_leave_places_for_the_rescan():
    places = _places(3)
    blocks = [b for p in places for b in _blocks_of(p)]
    slow = _collector(places, host_frame_s=0.6)
    finished = [w for w, _ in _fly(slow, blocks, speed=1.0)]
    assert slow.dropped > 0
    assert any(w.outcome == RESCAN for w in finished)
    fast = _collector(places)
    assert all(w.outcome == IDENTIFY for w, _ in _fly(fast, blocks, speed=1.0))
    assert fast.dropped == 0


def test_the_gate_looks_only_at_frames_a_block_is_centred_in():
    places = _places(3)
    c = _collector(places)
    blocks = [b for p in places for b in _blocks_of(p)]
    _fly(c, blocks, speed=0.8)
    flown = (places[-1].row[1] + 1.2) - (places[0].row[1] - 1.2)
    all_frames = flown / 0.8 * 15
    assert c.frames < 0.6 * all_frames  # most frames are never rendered nor detected


def test_the_pass_ended_early_leaves_the_open_places_for_the_rescan():
    places = _places(3)
    c = _collector(places)
    blocks = [b for p in places for b in _blocks_of(p)]
    _fly(c, blocks, y1=places[1].row[1])
    left = c.finish_all("the battery ran low")
    assert [w.name for w in left] == ["A-02-1", "A-03-1"]
    assert all(w.outcome == RESCAN for w in left)


def test_fused_views_are_unit_stripes_and_one_view_is_itself():
    rng = np.random.default_rng(0)
    parts, dim = 4, 16
    raw = rng.normal(size=(5, parts, dim // parts)).astype(np.float32)
    raw /= np.linalg.norm(raw, axis=2, keepdims=True)
    vecs = (raw / math.sqrt(parts)).reshape(5, dim)
    vis = np.ones((5, parts), np.float32)
    out, out_vis = fuse_views(vecs, vis, [1, 2, 2], parts)
    assert out.shape == (3, dim) and out_vis.shape == (3, parts)
    assert np.allclose(out[0], vecs[0], atol=1e-6)
    norms = np.linalg.norm(out.reshape(3, parts, -1), axis=2)
    assert np.allclose(norms, 1 / math.sqrt(parts), atol=1e-6)
    same, _ = fuse_views(np.vstack([vecs[1], vecs[1]]), vis[:2], [2], parts)
    assert np.allclose(same[0], vecs[1], atol=1e-6)


@pytest.mark.parametrize("bad", [-1.0, 0.0])
def test_params_are_plain_numbers(bad):
    # the collector takes what the leaf checked; a zero host time drops nothing
    c = _collector(_places(1), host_frame_s=max(bad, 0.0))
    assert c.params.host_frame_s == 0.0


def test_the_sweep_takes_a_margin_only_unknown_when_texture_and_embedding_agree():
    from nodes.sweep import sweep_accepts
    from perception.gallery import Match

    def m(**kw):
        base = dict(
            pallet_id="unknown",
            best_id="1080B",
            distance=0.58,
            runner_up_id="1130A",
            runner_up_distance=0.73,
            margin=0.15,
            known=False,
            reason="margin",
            texture_id="1080B",
            texture_z=2.9,
        )
        base.update(kw)
        return Match(**base)

    assert sweep_accepts(m(), 0.653)
    assert not sweep_accepts(m(texture_id="1130A"), 0.653)  # the texture says another side
    assert not sweep_accepts(m(texture_z=0.4), 0.653)  # the texture barely matches
    assert not sweep_accepts(m(distance=0.76), 0.653)  # too far: a pallet it does not know
    assert not sweep_accepts(m(margin=0.05), 0.653)  # a close impostor
    assert not sweep_accepts(m(texture_id=None, texture_z=None), 0.653)
    assert not sweep_accepts(m(known=True, pallet_id="1080B"), 0.653)  # nothing to take


def test_a_flicker_in_each_slot_of_an_empty_place_is_not_a_pallet():
    """A detection that shows once in a slot looked at four or more times is a flicker
    (state ``none``), not a block: an empty place with a flicker in each slot is empty,
    never a pallet to identify (validation seed 102 of the site answered such a place
    ``unknown`` after a slow second look)."""
    places = _places(3)
    c = _collector(places)
    blocks = _blocks_of(places[0]) + _blocks_of(places[2])
    slots = _blocks_of(places[1])
    img = np.full((CAM.height, CAM.width, 3), 128, np.uint8)
    img[::2, ::3] = 90
    speed, rate = 0.3, 15.0  # a slow look: every slot is looked at many times
    finished, flickered = {}, [False, False, False]
    t, y, i = 0.0, c.origin[1], 0
    while c.open():
        pose = CameraPose.from_yaw(STANDOFF, y, Z, LOOK)
        if c.wants(t, pose):
            dets = [d for p in blocks if (d := _box(pose, p)) is not None]
            for k, p in enumerate(slots):  # each slot's block shows in one frame only
                d = _box(pose, p)
                if d is not None and not flickered[k] and abs(p[1] - y) < 0.02:
                    dets.append(d)
                    flickered[k] = True
            c.add(pose, img, dets, i, t)
        finished.update({w.name: w for w in c.finish_passed((STANDOFF, y, Z))})
        t, y, i = t + 1.0 / rate, y + speed / rate, i + 1
    assert all(flickered)
    w = finished["A-02-1"]
    assert w.blocks_seen == 3  # each slot has the flicker's crop ...
    assert w.states == ["none", "none", "none"], w.states
    assert w.outcome == EMPTY, (w.outcome, w.reason)  # ... and the place is empty
    assert finished["A-01-1"].outcome == IDENTIFY and finished["A-03-1"].outcome == IDENTIFY
