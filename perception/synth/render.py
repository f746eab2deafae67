"""Frame synthesis: a :class:`~perception.synth.scene.Scene` seen by the AI-deck camera.

:func:`render_frame` = :func:`render_scene` (true-colour BGR, every quad drawn with one
``cv2.warpPerspective`` into its bounding box, mip-mapped textures, painter's order) followed
by :func:`apply_sensor` (motion blur along the image-space motion, Bayer mosaic, per-channel
sensor gains = green cast, illuminant colour, vignetting, exposure, brightness gradient,
contrast, shot and read noise). The raw frame is 244 x 324 uint8 Bayer; OpenCV's
``COLOR_BayerBG2BGR`` turns it back into colour (red at even rows and even columns, blue at odd
rows and odd columns, green elsewhere).

The sensor stage lives in :mod:`perception.synth.sensor`, the texture look-ahead in
:mod:`perception.synth.texture_lookahead`; the sensor stage's names are importable from here
too.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np

from perception.synth.camera_model import CameraModel, CameraPose, world_to_optical
from perception.synth.scene import PalletSpec, Quad, Scene, SceneLight
from perception.synth.sensor import (
    Lighting,
    SensorModel,
    apply_sensor,
    illuminant_bgr,
    image_motion,
    motion_kernel,
)
from perception.synth.texture_lookahead import _TEXTURES, _look_ahead

NEAR_M = 0.02


class BlockBox(NamedTuple):
    """Ground-truth box of a visible support block face, in pixels of the frame.

    ``visible`` is the fraction of the projected box inside the image (occlusion by other
    objects is not accounted for); ``block`` is 0, 1, 2 left to right seen from the front.
    """

    x1: float
    y1: float
    x2: float
    y2: float
    visible: float
    block: int
    identity: str


# ---------------------------------------------------------------------------- scene drawing
def _clip_near(pc: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clip of a polygon (N, 3, optical frame) to z >= NEAR_M."""
    out = []
    n = len(pc)
    for i in range(n):
        a, b = pc[i], pc[(i + 1) % n]
        ina, inb = a[2] >= NEAR_M, b[2] >= NEAR_M
        if ina:
            out.append(a)
        if ina != inb:
            s = (NEAR_M - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out)


def _horizon_row(K: np.ndarray, R: np.ndarray, width: int) -> float | None:
    """Lowest image row of the horizon (vanishing line of horizontal planes), or None if the
    camera is not upright enough for "below the horizon = floor in front" to hold."""
    line = np.linalg.inv(K).T @ (R @ np.array([0.0, 0.0, 1.0]))
    if line[1] >= -1e-6 or R[1, 2] > -0.2:  # image "up" must point roughly along world z
        return None
    vs = [-(line[0] * u + line[2]) / line[1] for u in (0.0, width - 1.0)]
    return max(vs)


def _mip_level(quad: Quad, scale: float) -> int:
    """Pyramid level whose texels are closest to one pixel at linear ``scale`` (px/texel)."""
    if scale <= 0.0:
        return 0
    return min(max(int(math.floor(-math.log2(scale) + 0.5)), 0), len(quad.levels) - 1)


@lru_cache(maxsize=16)
def _mip_matrix(level: int) -> np.ndarray:
    """Level-0 texel coordinates of the texels of mip ``level`` (centres), as a homography."""
    sc = float(2**level)
    return np.array([[sc, 0.0, (sc - 1) / 2], [0.0, sc, (sc - 1) / 2], [0.0, 0.0, 1.0]])


def _draw_quad(
    canvas: np.ndarray,
    quad: Quad,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    cam_pos: np.ndarray,
    horizon: float | None = None,
    pc: np.ndarray | None = None,
) -> float | None:
    """Draw one quad; returns its mean depth if anything was drawn.

    One ``warpPerspective`` into the quad's bounding box with a transparent border (pixels
    outside the texture stay untouched). A quad crossing the camera plane is clipped: the
    floor is then drawn only below the horizon (every such pixel sees the floor in front of
    the camera), anything else through a polygon mask. ``pc``: the corners already in the
    optical frame (skips the back-face test, done by the caller).
    """
    if pc is None:
        if float(quad.normal @ (cam_pos - quad.centre)) <= 1e-4:
            return None  # back face, or the camera lies in the quad's plane
        pc = quad.corners @ R.T + t
    zs = pc[:, 2].tolist()
    if max(zs) < NEAR_M:
        return None
    clipped = min(zs) < NEAR_M
    poly = _clip_near(pc) if clipped else pc
    uv = (poly @ K.T)[:, :2] / poly[:, 2:3]
    us, vs = uv[:, 0].tolist(), uv[:, 1].tolist()
    hgt, wid = canvas.shape[:2]
    x0, y0 = max(int(math.floor(min(us))), 0), max(int(math.floor(min(vs))), 0)
    x1, y1 = min(int(math.ceil(max(us))) + 1, wid), min(int(math.ceil(max(vs))) + 1, hgt)
    use_mask = False
    if clipped and quad.kind == "floor" and horizon is not None:
        y0 = max(y0, int(math.floor(horizon)) + 1)
    elif clipped:
        use_mask = True
    if x1 <= x0 or y1 <= y0:
        return None
    _TEXTURES.ready(quad)
    levels = quad.levels
    th, tw = levels[0].shape[:2]
    A = R @ quad.texture_map()
    A[:, 2] += t
    H0 = K @ A
    if not clipped:  # linear scale from the projected area (shoelace) over the texture area
        area = 0.5 * abs(sum(us[k] * vs[k - 1] - us[k - 1] * vs[k] for k in range(4)))
        scale = math.sqrt(area / (tw * th))
    else:  # local scale at the middle of the drawn part: det(H0) * p_z^3, p = H0^-1 (u, v, 1)
        try:
            p = np.linalg.solve(H0, np.array([(x0 + x1) / 2, (y0 + y1) / 2, 1.0]))
        except np.linalg.LinAlgError:
            return None
        scale = math.sqrt(abs(float(np.linalg.det(H0)) * float(p[2]) ** 3))
    level = _mip_level(quad, scale)
    Hroi = H0 @ _mip_matrix(level)
    Hroi[0] -= x0 * Hroi[2]
    Hroi[1] -= y0 * Hroi[2]
    roi = canvas[y0:y1, x0:x1]
    tex = levels[level]
    if not use_mask:
        cv2.warpPerspective(
            tex,
            Hroi,
            (x1 - x0, y1 - y0),
            dst=roi,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_TRANSPARENT,
        )
    else:
        warped = cv2.warpPerspective(tex, Hroi, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR)
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        pts = np.round((uv - (x0, y0)) * 16).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 1, cv2.LINE_8, 4)
        np.copyto(roi, warped, where=mask.astype(bool)[..., None])
    return sum(zs) / 4.0


def _draw_objects(
    canvas: np.ndarray,
    objects: list[Quad],
    order: np.ndarray,
    pcs: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    cam: np.ndarray,
) -> float:
    """Draw ``objects[order]`` (corners ``pcs`` in the optical frame, front-facing, far to
    near) as :func:`_draw_quad` would one by one, the same pixels to the bit; returns the
    nearest drawn quad's mean depth (inf if none).

    The per-quad arithmetic of the quads wholly in front of the camera (their bounding
    boxes, projected areas and homographies) is done for all of them at once with the
    same operations in the same order; a quad crossing the camera plane goes through
    :func:`_draw_quad`. Textures are still made only for quads that reach the image."""
    nearest = math.inf
    if not len(order):
        return nearest
    hgt, wid = canvas.shape[:2]
    z = pcs[..., 2]
    whole = z.min(axis=1) >= NEAR_M
    uv = np.matmul(pcs, K.T)[..., :2] / pcs[..., 2:3]
    us, vs = uv[..., 0], uv[..., 1]
    x0 = np.maximum(np.floor(us.min(axis=1)), 0).astype(np.int64)
    y0 = np.maximum(np.floor(vs.min(axis=1)), 0).astype(np.int64)
    x1 = np.minimum(np.ceil(us.max(axis=1)).astype(np.int64) + 1, wid)
    y1 = np.minimum(np.ceil(vs.max(axis=1)).astype(np.int64) + 1, hgt)
    # shoelace terms summed in _draw_quad's order: k = 0, 1, 2, 3 (u_k v_{k-1} - u_{k-1} v_k)
    cross = us * np.roll(vs, 1, axis=1) - np.roll(us, 1, axis=1) * vs
    area = 0.5 * np.abs(((cross[:, 0] + cross[:, 1]) + cross[:, 2]) + cross[:, 3])
    depth = (((z[:, 0] + z[:, 1]) + z[:, 2]) + z[:, 3]) / 4.0
    drawn = whole & (x1 > x0) & (y1 > y0)
    sel = np.flatnonzero(drawn)
    homog = None
    if len(sel):
        for i in sel:
            _TEXTURES.ready(objects[order[i]])  # made on first sight (or by the look-ahead)
        maps = np.stack([objects[order[i]].texture_map() for i in sel])
        A = np.matmul(R, maps)
        A[:, :, 2] += t
        homog = np.matmul(K, A)
    at = {int(i): k for k, i in enumerate(sel)}
    xs0, ys0, xs1, ys1 = x0.tolist(), y0.tolist(), x1.tolist(), y1.tolist()
    areas, depths = area.tolist(), depth.tolist()
    for i, (q, w) in enumerate(zip(order.tolist(), whole.tolist(), strict=True)):
        quad = objects[q]
        if not w:
            d = _draw_quad(canvas, quad, K, R, t, cam, pc=pcs[i])
            if d is not None:
                nearest = min(nearest, d)
            continue
        k = at.get(i)
        if k is None:
            continue
        levels = quad.levels
        th, tw = levels[0].shape[:2]
        level = _mip_level(quad, math.sqrt(areas[i] / (tw * th)))
        Hroi = homog[k] @ _mip_matrix(level)
        a, b = xs0[i], ys0[i]
        Hroi[0] -= a * Hroi[2]
        Hroi[1] -= b * Hroi[2]
        cv2.warpPerspective(
            levels[level],
            Hroi,
            (xs1[i] - a, ys1[i] - b),
            dst=canvas[b : ys1[i], a : xs1[i]],
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_TRANSPARENT,
        )
        nearest = min(nearest, depths[i])
    return nearest


def render_scene(
    camera: CameraModel,
    pose: CameraPose,
    scene: Scene,
    background: tuple[int, int, int] = (92, 94, 96),
    lookahead_m: float = 0.0,
) -> tuple[np.ndarray, float]:
    """True-colour BGR image (uint8) of the scene, and the depth of the nearest object drawn
    (m, inf if none) for motion blur.

    Floor and walls are drawn at half resolution and upscaled (they are far and smooth);
    objects (pallets, stands) at full resolution, far to near. ``lookahead_m`` > 0: the
    textures not made yet of the objects within that distance that face the camera and lie
    in front of it are made on a worker thread, nearest first, before they come into view
    (the same pixels: textures are pure functions of their quads)."""
    R, t = world_to_optical(camera, pose)
    K = camera.K()
    cam = pose.position
    hw, hh = camera.width // 2, camera.height // 2
    small = np.empty((hh, hw, 3), np.uint8)
    small[:] = background
    Kh = K.copy()
    Kh[0, 0], Kh[1, 1] = K[0, 0] * hw / camera.width, K[1, 1] * hh / camera.height
    Kh[0, 2], Kh[1, 2] = (
        (K[0, 2] + 0.5) * hw / camera.width - 0.5,
        (K[1, 2] + 0.5) * hh / camera.height - 0.5,
    )
    horizon = _horizon_row(Kh, R, hw)
    for q in scene.background:
        _draw_quad(small, q, Kh, R, t, cam, horizon)
    canvas = cv2.resize(small, (camera.width, camera.height), interpolation=cv2.INTER_LINEAR)
    nearest = math.inf
    objects = scene.objects
    if objects:
        # Vectorised culling: back faces, quads behind the camera or outside the image.
        rel = cam - scene.object_centres
        front = np.einsum("ij,ij->i", scene.object_normals, rel) > 0.0
        pc = scene.object_corners @ R.T + t
        z = pc[..., 2]
        ahead = z > NEAR_M
        uv = (pc[..., :2] * K[0, 0]) / np.where(ahead, z, 1.0)[..., None] + K[:2, 2]
        outside = ahead.all(axis=1) & (
            (uv[..., 0].max(axis=1) < 0)
            | (uv[..., 0].min(axis=1) > camera.width)
            | (uv[..., 1].max(axis=1) < 0)
            | (uv[..., 1].min(axis=1) > camera.height)
        )
        keep = front & ahead.any(axis=1) & ~outside
        if lookahead_m > 0.0:
            _look_ahead(objects, front & ahead.any(axis=1) & outside, rel, lookahead_m)
        idx = np.flatnonzero(keep)
        d2 = np.sum(rel[idx] ** 2, axis=1)
        order = idx[np.argsort(-d2, kind="stable")]
        nearest = _draw_objects(canvas, objects, order, pc[order], K, R, t, cam)
    return canvas, nearest


def block_boxes(camera: CameraModel, pose: CameraPose, scene: Scene) -> list[BlockBox]:
    """Boxes of every support-block face that faces the camera and is at least partly in view."""
    R, t = world_to_optical(camera, pose)
    K = camera.K()
    cam = pose.position
    W, H = camera.width, camera.height
    out = []
    for q in scene.quads:
        if not q.blocks or float(q.normal @ (cam - q.centre)) <= 0.0:
            continue
        for k, identity, corners in q.blocks:
            pc = corners @ R.T + t
            if (pc[:, 2] < NEAR_M).any():
                continue
            uv = (pc @ K.T)[:, :2] / pc[:, 2:3]
            bx1, by1 = float(uv[:, 0].min()), float(uv[:, 1].min())
            bx2, by2 = float(uv[:, 0].max()), float(uv[:, 1].max())
            area = (bx2 - bx1) * (by2 - by1)
            cx1, cy1 = max(bx1, -0.5), max(by1, -0.5)
            cx2, cy2 = min(bx2, W - 0.5), min(by2, H - 0.5)
            if cx2 <= cx1 or cy2 <= cy1 or area <= 0:
                continue
            vis = (cx2 - cx1) * (cy2 - cy1) / area
            out.append(BlockBox(cx1 + 0.5, cy1 + 0.5, cx2 + 0.5, cy2 + 0.5, vis, k, identity))
    return out


def render_frame(
    camera: CameraModel,
    pose: CameraPose,
    scene: Scene,
    rng: np.random.Generator,
    *,
    velocity: tuple[float, float, float] | None = None,
    yaw_rate: float = 0.0,
    lighting: Lighting = Lighting(),  # noqa: B008 (frozen dataclass: immutable)
    sensor: SensorModel = SensorModel(),  # noqa: B008 (frozen dataclass: immutable)
    colour_temperature_k: float | None = None,
    return_boxes: bool = False,
    lookahead_m: float = 0.0,
) -> np.ndarray | tuple[np.ndarray, list[BlockBox]]:
    """Raw 244 x 324 uint8 BayerBG frame of ``scene`` from ``pose`` (and, if asked, the
    ground-truth :class:`BlockBox` list). ``velocity`` (m/s, world) and ``yaw_rate`` (rad/s)
    add motion blur; ``rng`` drives the sensor noise; ``colour_temperature_k`` overrides
    the scene light's colour; ``lookahead_m``: see :func:`render_scene`."""
    bgr, nearest = render_scene(camera, pose, scene, lookahead_m=lookahead_m)
    blur = (0.0, 0.0)
    if velocity is not None or yaw_rate:
        blur = image_motion(
            camera, pose, velocity or (0.0, 0.0, 0.0), yaw_rate, nearest, lighting.exposure_time_s
        )
    raw = apply_sensor(
        bgr,
        rng,
        lighting=lighting,
        sensor=sensor,
        illuminant=illuminant_bgr(colour_temperature_k or scene.light.colour_temperature_k),
        blur=blur,
    )
    if return_boxes:
        return raw, block_boxes(camera, pose, scene)
    return raw


__all__ = [
    "BlockBox",
    "Lighting",
    "PalletSpec",
    "Scene",
    "SceneLight",
    "SensorModel",
    "apply_sensor",
    "block_boxes",
    "illuminant_bgr",
    "image_motion",
    "motion_kernel",
    "render_frame",
    "render_scene",
]
