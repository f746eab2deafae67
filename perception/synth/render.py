"""Frame synthesis: a :class:`~perception.synth.scene.Scene` seen by the AI-deck camera.

:func:`render_frame` = :func:`render_scene` (true-colour BGR, every quad drawn with one
``cv2.warpPerspective`` into its bounding box, mip-mapped textures, painter's order) followed
by :func:`apply_sensor` (motion blur along the image-space motion, Bayer mosaic, per-channel
sensor gains = green cast, illuminant colour, vignetting, exposure, brightness gradient,
contrast, shot and read noise). The raw frame is 244 x 324 uint8 Bayer; OpenCV's
``COLOR_BayerBG2BGR`` turns it back into colour (red at even rows and even columns, blue at odd
rows and odd columns, green elsewhere).
"""

from __future__ import annotations

import math
import os
import threading
from collections import deque
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np

from perception.synth.camera_model import CameraModel, CameraPose, world_to_optical
from perception.synth.scene import PalletSpec, Quad, Scene, SceneLight

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


@dataclass(frozen=True)
class Lighting:
    """Per-frame light and exposure: overall gain, contrast about mid-grey, a linear
    brightness gradient (fractional change from the centre to the image edge, direction in
    the image), and the exposure time used for motion blur."""

    exposure: float = 1.0
    contrast: float = 1.0
    gradient: float = 0.0
    gradient_angle_rad: float = 0.0
    exposure_time_s: float = 0.02


@dataclass(frozen=True)
class SensorModel:
    """Raw sensor response: per-channel gains (B, G, R; green strongest = the green cast of
    the raw AI-deck image), vignetting (corner fall-off), black level, read noise (DN) and
    shot noise (variance per DN)."""

    channel_gain_bgr: tuple[float, float, float] = (0.78, 1.0, 0.70)
    vignetting: float = 0.25
    black_level: float = 3.0
    read_noise: float = 1.8
    shot_noise: float = 0.18


def illuminant_bgr(kelvin: float) -> tuple[float, float, float]:
    """Relative (B, G, R) of a light of colour temperature ``kelvin`` (green = 1; 5500 K
    neutral); a mild blackbody approximation (warm light: more red, less blue)."""
    t = math.log(max(kelvin, 1000.0) / 5500.0)
    return (float(np.clip(1.0 + 0.55 * t, 0.4, 1.6)), 1.0, float(np.clip(1.0 - 0.35 * t, 0.6, 1.6)))


# ---------------------------------------------------------------------------- textures ahead
class _Textures:
    """Quad textures made ahead of need on one worker thread (:func:`render_scene`'s
    ``lookahead_m``), so the second core makes them while the first draws.

    A quad's texture is a pure function of the quad (made on first use, deterministically:
    :attr:`perception.synth.scene.Quad.levels`), so who makes it, and when, changes no pixel.
    Each quad is made once: whoever starts it (the worker or a drawing thread) registers it,
    and a drawing thread that needs a texture being made waits for it."""

    def __init__(self) -> None:
        self._reset()
        # a forked child has no worker: it starts afresh (what was being made is made again)
        os.register_at_fork(after_in_child=self._reset)

    def _reset(self) -> None:
        self._lock = threading.Condition(threading.Lock())
        self._making: dict[int, threading.Event] = {}  # id(quad) -> set when made
        self._queue: deque[Quad] = deque()
        self._queued: set[int] = set()
        self._thread: threading.Thread | None = None

    def ready(self, quad: Quad) -> None:
        """Make sure ``quad``'s texture is made (here, or by the worker: then wait)."""
        if not callable(quad.texture):
            return
        with self._lock:
            event = self._making.get(id(quad))
            mine = event is None and callable(quad.texture)
            if mine:
                event = self._making[id(quad)] = threading.Event()
        if mine:
            self._make(quad, event)
        elif event is not None:
            event.wait()
        quad.levels  # noqa: B018  (made here if the worker could not)

    def want(self, quads: list[Quad]) -> None:
        """Queue ``quads`` (nearest first) to be made on the worker thread."""
        with self._lock:
            for q in quads:
                if id(q) not in self._queued and id(q) not in self._making and callable(q.texture):
                    self._queue.append(q)
                    self._queued.add(id(q))
            if self._queue:
                if self._thread is None:
                    self._thread = threading.Thread(
                        target=self._run, name="texture-lookahead", daemon=True
                    )
                    self._thread.start()
                self._lock.notify()

    def _make(self, quad: Quad, event: threading.Event) -> None:
        try:
            quad.levels  # noqa: B018
        finally:
            with self._lock:
                self._making.pop(id(quad), None)
            event.set()

    def _run(self) -> None:
        while True:
            with self._lock:
                while not self._queue:
                    self._lock.wait()
                quad = self._queue.popleft()
                self._queued.discard(id(quad))
                if id(quad) in self._making or not callable(quad.texture):
                    continue
                event = self._making[id(quad)] = threading.Event()
            try:
                self._make(quad, event)
            except Exception:  # noqa: BLE001 - a drawing thread makes it again and raises
                pass


_TEXTURES = _Textures()


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


def _look_ahead(objects: list[Quad], near: np.ndarray, rel: np.ndarray, reach_m: float) -> None:
    """Queue the untextured quads of ``near`` (facing the camera, in front of it, not in
    this frame) within ``reach_m`` of the camera for the texture worker, nearest first."""
    idx = np.flatnonzero(near)
    if not len(idx):
        return
    d2 = np.sum(rel[idx] ** 2, axis=1)
    close = d2 < reach_m * reach_m
    idx, d2 = idx[close], d2[close]
    want = [objects[i] for i in idx[np.argsort(d2, kind="stable")].tolist()]
    want = [q for q in want if callable(q.texture)]
    if want:
        _TEXTURES.want(want)


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


# ---------------------------------------------------------------------------- sensor stage
@lru_cache(maxsize=8)
def _cfa(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat gather indices of the BayerBG mosaic (R at even/even) and per-pixel channel."""
    rows, cols = np.mgrid[0:height, 0:width]
    ch = np.ones((height, width), np.int64)  # green
    ch[(rows % 2 == 0) & (cols % 2 == 0)] = 2  # red
    ch[(rows % 2 == 1) & (cols % 2 == 1)] = 0  # blue
    idx = (rows * width + cols) * 3 + ch
    return idx.ravel(), ch


@lru_cache(maxsize=16)
def _static_gain(
    width: int, height: int, sensor: SensorModel, illuminant: tuple[float, float, float]
) -> np.ndarray:
    _, ch = _cfa(width, height)
    gains = np.asarray(sensor.channel_gain_bgr) * np.asarray(illuminant)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    r2 = ((xx - (width - 1) / 2) ** 2 + (yy - (height - 1) / 2) ** 2) / (
        (width / 2) ** 2 + (height / 2) ** 2
    )
    vignette = 1.0 - sensor.vignetting * r2
    return (gains[ch] * vignette).astype(np.float32)


@lru_cache(maxsize=4)
def _grids(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    return (xx - (width - 1) / 2) / (width / 2), (yy - (height - 1) / 2) / (height / 2)


@lru_cache(maxsize=4)
def _noise_bank(n: int) -> np.ndarray:
    return np.random.default_rng(20240611).standard_normal(4 * n).astype(np.float32)


def motion_kernel(du: float, dv: float) -> np.ndarray | None:
    """Linear blur kernel for an image-space smear (du, dv) in pixels (None if < 1 px)."""
    length = math.hypot(du, dv)
    if length < 1.0:
        return None
    n = int(math.ceil(length)) | 1
    k = np.zeros((n, n), np.float32)
    c = n // 2
    cv2.line(
        k,
        (int(round(c - du / 2)), int(round(c - dv / 2))),
        (int(round(c + du / 2)), int(round(c + dv / 2))),
        1.0,
        1,
        cv2.LINE_AA,
    )
    return k / k.sum()


def image_motion(
    camera: CameraModel,
    pose: CameraPose,
    velocity: tuple[float, float, float],
    yaw_rate: float,
    depth_m: float,
    exposure_time_s: float,
) -> tuple[float, float]:
    """Smear (du, dv) in pixels at the image centre over one exposure: translation at
    ``depth_m`` plus the yaw rotation (rad/s)."""
    R, _ = world_to_optical(camera, pose)
    vc = R @ np.asarray(velocity, float)
    f = camera.fx
    depth = max(depth_m, 0.05) if math.isfinite(depth_m) else 5.0
    du = -f * vc[0] / depth + f * yaw_rate
    dv = -f * vc[1] / depth
    return du * exposure_time_s, dv * exposure_time_s


def apply_sensor(
    bgr: np.ndarray,
    rng: np.random.Generator,
    *,
    lighting: Lighting = Lighting(),
    sensor: SensorModel = SensorModel(),
    illuminant: tuple[float, float, float] = (1.0, 1.0, 1.0),
    blur: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """True-colour BGR uint8 -> raw BayerBG uint8 (blur, mosaic, gains, noise, clipping)."""
    h, w = bgr.shape[:2]
    k = motion_kernel(*blur)
    if k is not None:
        bgr = cv2.filter2D(bgr, -1, k, borderType=cv2.BORDER_REPLICATE)
    raw8 = np.empty((h, w), np.uint8)  # BayerBG as OpenCV reads it: R at (even, even)
    raw8[0::2, 0::2] = bgr[0::2, 0::2, 2]
    raw8[0::2, 1::2] = bgr[0::2, 1::2, 1]
    raw8[1::2, 0::2] = bgr[1::2, 0::2, 1]
    raw8[1::2, 1::2] = bgr[1::2, 1::2, 0]
    gain = _gain_map(
        w,
        h,
        sensor,
        tuple(float(v) for v in illuminant),
        lighting.exposure,
        lighting.gradient,
        lighting.gradient_angle_rad,
    )
    raw = cv2.multiply(raw8, gain, dtype=cv2.CV_32F)
    if lighting.contrast != 1.0:
        raw -= 100.0
        raw *= lighting.contrast
        raw += 100.0
    sigma = cv2.LUT(cv2.convertScaleAbs(raw), _sigma_lut(sensor.shot_noise, sensor.read_noise))
    bank = _noise_bank(h * w)
    off = int(rng.integers(0, bank.size - h * w))
    raw += cv2.multiply(sigma, bank[off : off + h * w].reshape(h, w))
    # |x + black| saturated to uint8: values below -black (rare noise) fold back up.
    return cv2.convertScaleAbs(raw, alpha=1.0, beta=sensor.black_level)


@lru_cache(maxsize=8)
def _sigma_lut(shot: float, read: float) -> np.ndarray:
    """Noise standard deviation per signal level 0..255: sqrt(shot * x + read^2)."""
    return np.sqrt(np.arange(256, dtype=np.float32) * shot + read * read).astype(np.float32)


@lru_cache(maxsize=64)
def _gain_map(
    w: int,
    h: int,
    sensor: SensorModel,
    illuminant: tuple[float, float, float],
    exposure: float,
    gradient: float,
    angle: float,
) -> np.ndarray:
    """Per-pixel gain: Bayer channel gain x illuminant x vignetting x exposure x gradient."""
    gain = _static_gain(w, h, sensor, illuminant) * np.float32(exposure)
    if gradient:
        gx, gy = _grids(w, h)
        gain = gain * (1.0 + gradient * math.cos(angle) * gx + gradient * math.sin(angle) * gy)
    return gain.astype(np.float32)


def render_frame(
    camera: CameraModel,
    pose: CameraPose,
    scene: Scene,
    rng: np.random.Generator,
    *,
    velocity: tuple[float, float, float] | None = None,
    yaw_rate: float = 0.0,
    lighting: Lighting = Lighting(),
    sensor: SensorModel = SensorModel(),
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
