"""The lock-step speed-ups change no result (issue 27, docs/performance.md "Lock-step speed
of the site fleet"): the renderer's batched drawing of objects gives the frames of one
``_draw_quad`` per quad to the bit, and the texture verifier's batched masked correlation,
its cache of band-passed crops and its one pass over every side give the figures of one
``cv2.matchTemplate`` per enrolled crop (to OpenCV's float32 rounding) and the same
rankings."""

from __future__ import annotations

import math
import time

import cv2
import numpy as np
import pytest

import perception.verify as tv
from perception.synth.camera_model import CameraModel, CameraPose, world_to_optical
from perception.synth.render import NEAR_M, _draw_quad, render_scene
from perception.synth.scene import PalletSpec, Scene, SceneLight

# -- rendering ------------------------------------------------------------------------------

CAM = CameraModel()
LIGHT = SceneLight(0.6, (((4.0, 0.0, 4.0), 1.0),), 4000.0)
SCENE = Scene.build(
    [
        PalletSpec("3", "A", 9.30, -0.05, 0.194, math.pi),
        PalletSpec("4", "B", 9.30, 1.25, 0.194, math.pi),
        PalletSpec("5", "A", 9.60, -0.05, 1.2, math.pi),
    ],
    boxes=[
        ((9.7, -0.05, 0.097), (0.4, 0.6, 0.097), 0.0),
        ((9.2, 0.6, 1.0), (0.05, 0.05, 1.0), 0.0),  # an upright between the pallets
        ((9.2, 0.6, 1.15), (0.05, 1.5, 0.04), 0.0),  # a beam across both
    ],
    light=LIGHT,
)


def _one_by_one(pose: CameraPose) -> tuple[np.ndarray, float]:
    """render_scene as it was: every object quad through _draw_quad, far to near."""
    R, t = world_to_optical(CAM, pose)
    K = CAM.K()
    cam = pose.position
    canvas, _ = render_scene(CAM, pose, Scene([q for q in SCENE.quads if q.kind != "object"]))
    nearest = math.inf
    rel = cam - SCENE.object_centres
    d2 = np.sum(rel**2, axis=1)
    for i in np.argsort(-d2, kind="stable"):
        q = SCENE.objects[i]
        if float(q.normal @ rel[i]) <= 0.0:
            continue
        pc = SCENE.object_corners[i] @ R.T + t
        if not (pc[:, 2] > NEAR_M).any():
            continue
        d = _draw_quad(canvas, q, K, R, t, cam, pc=pc)
        if d is not None:
            nearest = min(nearest, d)
    return canvas, nearest


POSES = [
    CameraPose.from_yaw(8.90, -0.05, 0.255, 0.0),  # the scan slot
    CameraPose.from_yaw(8.85, 0.6, 0.9, 0.0),  # the beam and the upright in front
    CameraPose.from_yaw(9.15, 0.6, 1.1, 0.3),  # inside the beam's box: quads cross the camera
    CameraPose.from_yaw(8.5, 1.6, 0.7, -0.4, pitch=math.radians(10)),
    CameraPose.from_yaw(9.25, 0.0, 0.3, 0.1, roll=math.radians(5)),  # close: clipped quads
    CameraPose.from_yaw(5.0, 0.0, 1.0, math.pi),  # looking away
]


@pytest.mark.parametrize("k", range(len(POSES)))
def test_batched_drawing_gives_the_frames_of_one_quad_at_a_time(k):
    pose = POSES[k]
    img, nearest = render_scene(CAM, pose, SCENE)
    ref, ref_nearest = _one_by_one(pose)
    assert np.array_equal(img, ref)
    assert nearest == ref_nearest


# -- texture verification -------------------------------------------------------------------


def _crop(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A grey crop with grain (float32, 0..255)."""
    g = rng.normal(128, 30, (h, w)).astype(np.float32)
    return cv2.GaussianBlur(g, (0, 0), 1.2) + np.linspace(0, 20, w, dtype=np.float32)


def _bgr_query(rng: np.random.Generator, h: int, w: int, blot: bool) -> np.ndarray:
    g = np.clip(_crop(rng, h, w), 0, 255)
    if blot:  # a dark stain: the template is masked
        cv2.circle(g, (w // 3, h // 2), max(2, h // 6), 10.0, -1)
    return cv2.cvtColor(g.astype(np.uint8), cv2.COLOR_GRAY2BGR)


def _one_crop_score(template, work_hw, enrolled, mask) -> float:
    """block_score as it was: one cv2.matchTemplate per scale of one enrolled crop."""
    h, w = work_hw
    best = -1.0
    for s in tv.SCALES:
        eh, ew = int(round(h * s)), int(round(w * s))
        if eh < template.shape[0] or ew < template.shape[1]:
            continue
        r = cv2.matchTemplate(
            tv._band(enrolled, (eh, ew)), template, cv2.TM_CCOEFF_NORMED, mask=mask
        )
        if mask is not None:
            r = r[np.isfinite(r)]
        if r.size:
            best = max(best, float(r.max()))
    return best


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("masked", [True, False])
def test_block_scores_equal_one_matchtemplate_per_crop(seed, masked):
    rng = np.random.default_rng(seed)
    qh, qw = int(rng.integers(24, 40)), int(rng.integers(41, 67))  # odd and prime sizes too
    query = _bgr_query(rng, qh, qw, True)
    enrolled = [_crop(rng, int(rng.integers(30, 44)), int(rng.integers(50, 70))) for _ in range(9)]
    enrolled.append(_crop(rng, 20, 30))  # smaller than the query: another work size
    tv.clear_band_cache()
    for e in enrolled:
        hw = tv.work_size((qh, qw), e.shape)
        t, mask = tv._template(tv.grey(query), hw, query)
        assert mask is not None
        mask = mask if masked else None
        got = tv.block_scores(t, hw, [e], mask)[0]
        assert got == pytest.approx(_one_crop_score(t, hw, e, mask), abs=2e-6)
    hw = (qh, qw)
    same = [e for e in enrolled if tv.work_size(hw, e.shape) == hw]
    t, mask = tv._template(tv.grey(query), hw, query)
    mask = mask if masked else None
    together = tv.block_scores(t, hw, same, mask)
    alone = [tv.block_scores(t, hw, [e], mask)[0] for e in same]
    assert np.allclose(together, alone, rtol=0, atol=1e-12)  # batching changes nothing
    cached = tv.block_scores(t, hw, same, mask)
    tv.clear_band_cache()
    assert np.array_equal(cached, tv.block_scores(t, hw, same, mask))  # nor the cache


def test_the_band_cache_follows_the_pixels_not_the_array():
    rng = np.random.default_rng(7)
    query = _bgr_query(rng, 30, 52, True)
    e = _crop(rng, 36, 60)
    t, mask = tv._template(tv.grey(query), (30, 52), query)
    before = tv.block_scores(t, (30, 52), [e], mask)[0]
    e[:, : e.shape[1] // 2] = _crop(rng, 36, e.shape[1] // 2)  # the same array, new pixels
    after = tv.block_scores(t, (30, 52), [e], mask)[0]
    tv.clear_band_cache()
    assert after == tv.block_scores(t, (30, 52), [e], mask)[0] and after != before
    frozen = e.copy()
    frozen.flags.writeable = False  # read-only: its key is remembered
    assert tv.block_scores(t, (30, 52), [frozen], mask)[0] == after
    assert tv.block_scores(t, (30, 52), [frozen], mask)[0] == after


def _side(rng: np.random.Generator) -> list[np.ndarray]:
    return [_crop(rng, int(rng.integers(32, 38)), int(rng.integers(56, 64))) for _ in range(3)]


def _verify_apart(query, candidates, cohort):
    """verify as it was: the cohort, the cross blocks and each candidate scored apart."""
    queries = [tv.grey(c) for c in query]
    colours = [np.asarray(c) for c in query]
    names = [n for n, _ in cohort]
    ref = tv._scores(queries, [s for _, s in cohort], colours)
    cross = [[views[0][(b + k) % 3] for b in range(3)] for _, views in candidates for k in (1, 2)]
    ref = np.concatenate([ref, tv._scores(queries, cross, colours)])
    names += [""] * len(cross)
    out = []
    for ident, views in candidates:
        keep = ref[[i for i, n in enumerate(names) if n != ident]]
        top = np.sort(np.where(np.isfinite(keep), keep, -np.inf), axis=0)[::-1][: tv.COHORT_TOP]
        top = np.where(np.isfinite(top), top, np.nan)
        spread = np.maximum(np.nanstd(top, axis=0), tv.MIN_SPREAD)
        raw = np.nanmax(tv._scores(queries, views, colours), axis=0)
        out.append((ident, (raw - np.nanmean(top, axis=0)) / spread))
    return out


def test_one_pass_verification_ranks_as_separate_passes():
    rng = np.random.default_rng(3)
    cohort = [(f"c{i}", _side(rng)) for i in range(20)]
    candidates = [(f"s{i}", [_side(rng)]) for i in range(4)]
    candidates[1] = ("s1", [_side(rng), _side(rng)])  # two views: the best per block
    truth = candidates[2][1][0]
    query = [  # the true side seen a little smaller
        cv2.cvtColor(
            np.clip(cv2.resize(c, (c.shape[1] - 6, c.shape[0] - 4)), 0, 255).astype(np.uint8),
            cv2.COLOR_GRAY2BGR,
        )
        for c in truth
    ]
    query[1][5:9, 10:16] = 5  # a stain: a masked template
    ver = tv.verify(query, candidates, cohort)
    assert ver.best[0] == "s2"
    apart = dict(_verify_apart(query, candidates, cohort))
    for ident, _, blocks in ver.ranking:
        assert np.allclose(blocks, apart[ident], rtol=0, atol=1e-9)
    again = tv.verify(query, candidates, cohort, cohort_scores=tv.cohort_scores(query, cohort))
    assert again.ranking == ver.ranking


def test_textures_made_ahead_on_a_worker_give_the_same_frames():
    """A scan along a row of pallets with the texture look-ahead on (the worker makes the
    faces ahead) renders the frames of a scene whose textures are made as they are drawn."""

    def row() -> Scene:
        return Scene.build(
            [PalletSpec(str(k), "AB"[k % 2], 9.3, -2.0 + 1.3 * k, 0.2, math.pi) for k in range(5)],
            light=LIGHT,
        )

    ahead, plain = row(), row()
    poses = [CameraPose.from_yaw(8.85, -2.6 + 0.25 * k, 0.27, 0.0) for k in range(24)]
    face = next(q for q in ahead.objects if q.blocks and q.blocks[0][1] == "1B" and q.normal[0] < 0)
    img, _ = render_scene(CAM, poses[0], ahead, lookahead_m=3.0)
    for _ in range(300):  # the next pallet's face, not in view yet, is made by the worker
        if not callable(face.texture):
            break
        time.sleep(0.1)
    assert not callable(face.texture)
    assert np.array_equal(img, render_scene(CAM, poses[0], plain)[0])
    for pose in poses[1:]:
        img, nearest = render_scene(CAM, pose, ahead, lookahead_m=3.0)
        ref, ref_nearest = render_scene(CAM, pose, plain)
        assert np.array_equal(img, ref) and nearest == ref_nearest


def _verify_and_render_in_child(queue) -> None:
    rng = np.random.default_rng(11)
    cohort = [(f"c{i}", _side(rng)) for i in range(6)]
    query = [_bgr_query(rng, 30, 52, True) for _ in range(3)]
    ver = tv.verify(query, [("s0", [_side(rng)])], cohort)
    img, _ = render_scene(CAM, POSES[0], SCENE, lookahead_m=3.0)
    queue.put((ver.best[0], int(img.sum())))


def test_a_forked_child_verifies_and_renders_without_the_parents_workers():
    """The verifier's and the texture look-ahead's worker threads do not survive a fork:
    a child made after they started scores and draws on its own (no wait on a thread
    that is not there)."""
    import multiprocessing

    _verify_and_render_in_child(queue := multiprocessing.get_context("fork").Queue())
    here = queue.get(timeout=60)
    child = multiprocessing.get_context("fork").Process(
        target=_verify_and_render_in_child, args=(queue,)
    )
    child.start()
    child.join(120)
    assert child.exitcode == 0
    assert queue.get(timeout=5) == here
