"""The texture synthesis as it was before it was made faster (issue 28), for comparison.

``bench/gallery_build_speed.py`` times a side's enrolment with these (the baseline, in the
same run) and ``tests/test_relief_speed.py`` checks that the shipped code gives the same
pixels, bit for bit. The functions below are the pre-optimisation code of
:mod:`perception.synth.woodgen`, :mod:`perception.synth.appearance`,
:mod:`perception.synth.scene` (``box_quads``) and :mod:`perception.synth.relief`, unchanged
but for how they name the other modules. :func:`reference` puts them in place of the
shipped ones, empties the texture caches both share on the way in and out, and turns off
the demo gallery's block offsets kept per scan geometry; the caches only the shipped code
reads (shared box quads, edge profiles, lamp fields) are left as a build worker has them."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from functools import lru_cache

import cv2
import numpy as np

from perception.synth import ageing, marks, relief, scene
from perception.synth import appearance as ap
from perception.synth import woodgen as wg
from perception.synth.appearance import EPAL, PalletGeometry, SideStyle
from perception.synth.materials import MATERIALS
from perception.synth.woodgen import smooth_noise

Rng = np.random.Generator


# ------------------------------------------------------------------ perception.synth.woodgen
def wood_grain(
    rng: Rng,
    h: int,
    w: int,
    *,
    period_px: float,
    slope: float = 0.0,
    warp_px: float = 6.0,
    knots: list[tuple[float, float, float, float]] | None = None,
) -> np.ndarray:
    """Side-grain luminance (h, w) in 0..1: warped growth rings along x, fibres, knots.

    ``knots`` lists (x, y, rx, ry) in pixels; the rings bend around each knot and the knot
    itself is a dark ellipse with a few rings of its own.
    """
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    coord = yy + slope * xx
    coord += warp_px * smooth_noise(rng, h, w, 3, max(3, w // 60))
    coord += 0.35 * warp_px * smooth_noise(rng, h, w, 6, max(4, w // 25))
    knot_dark = np.zeros((h, w), np.float32)
    for kx, ky, rx, ry in knots or []:
        d2 = ((xx - kx) / (rx * 2.5)) ** 2 + ((yy - ky) / (ry * 2.5)) ** 2
        push = np.exp(-d2) * (ry * 2.2)
        coord += np.where(yy >= ky, push, -push)
        dk = np.sqrt(((xx - kx) / rx) ** 2 + ((yy - ky) / ry) ** 2)
        core = np.clip(1.2 - dk, 0.0, 1.0)
        rings = 0.5 + 0.5 * np.cos(dk * 9.0)
        knot_dark = np.maximum(knot_dark, core * (0.55 + 0.35 * rings))
    phase = coord / period_px
    ring = np.mod(phase, 1.0)
    # Early wood (light, wide) then late wood (dark, narrow): a skewed saw-tooth.
    late = np.clip((ring - 0.6) / 0.4, 0.0, 1.0) ** 1.5
    lum = 0.78 - 0.17 * late
    fibre = cv2.resize(
        rng.standard_normal((h, max(w // 18, 2)), dtype=np.float32),
        (w, h),
        interpolation=cv2.INTER_LINEAR,
    )
    lum += 0.045 * fibre + 0.03 * rng.standard_normal((h, w), dtype=np.float32)
    lum += 0.06 * smooth_noise(rng, h, w, 2, max(2, w // 120))
    lum *= 1.0 - 0.75 * knot_dark
    return np.clip(cv2.GaussianBlur(lum, (3, 3), 0.8), 0.0, 1.0)


def end_grain(rng: Rng, h: int, w: int, *, period_px: float) -> np.ndarray:
    """End-grain luminance (h, w): arcs of growth rings around a pith outside the board."""
    cx = rng.uniform(-0.3, 1.3) * w
    cy = rng.choice([-1.0, 1.0]) * rng.uniform(1.2, 4.0) * h + (h if rng.random() < 0.5 else 0)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r = np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)
    r += 2.0 * smooth_noise(rng, h, w, 3, max(3, w // 40))
    ring = np.mod(r / period_px, 1.0)
    lum = 0.62 - 0.22 * np.clip((ring - 0.7) / 0.3, 0.0, 1.0)
    lum += 0.06 * rng.standard_normal((h, w), dtype=np.float32)  # rough saw cut
    lum += 0.05 * smooth_noise(rng, h, w, 2, 4)
    return np.clip(lum, 0.0, 1.0)


def chipboard(rng: Rng, h: int, w: int) -> np.ndarray:
    """Pressed wood-chip block luminance (h, w): overlapping flakes of varying tone."""
    lum = 0.68 + 0.05 * smooth_noise(rng, h, w, max(h // 30, 2), max(w // 30, 2))
    lum = np.ascontiguousarray(lum, np.float32)
    n = h * w // 40
    xs, ys = rng.uniform(0, w, n), rng.uniform(0, h, n)
    ax, ay = rng.uniform(2.0, 9.0, n), rng.uniform(1.0, 3.5, n)
    ang = rng.normal(0.0, 25.0, n)
    tone = np.clip(0.68 + rng.normal(0.0, 0.09, n), 0.3, 0.95)
    for i in range(n):
        cv2.ellipse(
            lum,
            (int(xs[i]), int(ys[i])),
            (int(ax[i]), int(ay[i])),
            float(ang[i]),
            0,
            360,
            float(tone[i]),
            -1,
        )
    lum += 0.03 * rng.standard_normal((h, w), dtype=np.float32)
    lum = cv2.GaussianBlur(lum, (3, 3), 0.6)
    return np.clip(lum, 0.0, 1.0)


def colourise(lum: np.ndarray, base_bgr: np.ndarray, dark_bgr: np.ndarray) -> np.ndarray:
    """BGR float image: ``dark_bgr`` at luminance 0, ``base_bgr`` at about 0.8 and above."""
    t = np.clip(lum / 0.8, 0.0, 1.25)[..., None]
    return dark_bgr[None, None, :] * (1.0 - t) + base_bgr[None, None, :] * t


def blend(img: np.ndarray, alpha: np.ndarray, colour: tuple[float, float, float]) -> None:
    """In place: ``img = img * (1 - alpha) + colour * alpha`` (alpha (h, w) in 0..1)."""
    a = alpha[..., None]
    img *= 1.0 - a
    img += a * np.asarray(colour, np.float32)[None, None, :]


# --------------------------------------------------------------- perception.synth.appearance
def _gap(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """The dark fork opening between two blocks: shadowed interior, dim far opening."""
    sh, sw = max(h // 8, 4), max(w // 8, 4)
    v = np.linspace(0.0, 1.0, sh, dtype=np.float32)[:, None]
    lum = 18.0 + 22.0 * v**1.5 + np.zeros((sh, sw), np.float32)
    x0, x1 = int(sw * rng.uniform(0.2, 0.3)), int(sw * rng.uniform(0.7, 0.8))
    lum[int(sh * 0.25) : int(sh * 0.9), x0:x1] += 18.0  # the opening on the far side
    lum = cv2.resize(cv2.GaussianBlur(lum, (0, 0), 0.6), (w, h), interpolation=cv2.INTER_LINEAR)
    lum += 2.0 * rng.standard_normal((h, w), dtype=np.float32)
    return np.stack([lum * 1.0, lum * 1.02, lum * 1.08], axis=-1)


@lru_cache(maxsize=48)
def face_texture(
    pallet_id: str, side: str, style: SideStyle | None = None, geometry: PalletGeometry = EPAL
) -> np.ndarray:
    """A whole long side of a pallet: deck board, board ends, three blocks, gaps, bottom board.

    BGR uint8 of (height_m x length_m) at :data:`PX_PER_MM` (2400 x 288 for EPAL), read-only.
    """
    g = geometry
    look = ap._look(pallet_id, side, style)
    ts = (style or SideStyle()).texture_seed
    rng = ap._rng(pallet_id, side, "face", ts)
    W, H, b, bh = (
        ap._mm(g.length_m),
        ap._mm(g.height_m),
        ap._mm(g.board_m),
        ap._mm(g.block_height_m),
    )
    img = np.zeros((H, W, 3), np.float32)
    img[:, :] = _gap(rng, W, H)
    centres = [int(round((g.length_m / 2 + o) * 1000 * ap.PX_PER_MM)) for o in g.block_offsets_m()]
    img[0:b] = ap._board(rng, look, W, b, centres)
    img[H - b : H] = ap._board(rng, look, W, b, centres)
    for k, (cx, bw_m) in enumerate(zip(centres, g.block_widths_m(), strict=True)):
        bw = ap._mm(bw_m)
        x0 = max(0, cx - bw // 2)
        tex = ap.block_texture(pallet_id, side, k, style, (bw_m, g.block_height_m))
        x1 = min(W, x0 + tex.shape[1])
        img[2 * b : 2 * b + bh, x0:x1] = tex[:bh, : x1 - x0]
        base = np.asarray(look.base, np.float32) * 0.85
        lum = end_grain(rng, b, x1 - x0, period_px=rng.uniform(6, 12))
        end = colourise(lum, base, ap._dark(base)).astype(np.float32)
        if look.paint is not None and not look.paint_blocks_only:
            marks.paint_over(end, rng, look.paint, look.wear)
        img[b : 2 * b, x0:x1] = end
        img[2 * b - 1 : 2 * b + 1, x0:x1] *= 0.55  # joint between board end and block
    img[b - 1 : b + 1] *= 0.6
    img[H - b - 1 : H - b + 1] *= 0.6
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


# ------------------------------------------------------------------- perception.synth.scene
def box_quads(
    centre: tuple[float, float, float],
    half: tuple[float, float, float],
    yaw_rad: float,
    light: scene.SceneLight,
    material: str = "stand",
) -> list[scene.Quad]:
    """The four vertical faces of a yawed box (stand, obstacle, rack steel), drawn with
    ``material``'s texture (:data:`perception.synth.materials.MATERIALS`)."""

    cx, cy, cz = centre
    hx, hy, hz = half
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    ex, ey = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    quads = []
    tex = MATERIALS.get(material, ap.stand_texture)
    for normal, half_depth, width in (
        (ex, hx, 2 * hy),
        (-ex, hx, 2 * hy),
        (ey, hy, 2 * hx),
        (-ey, hy, 2 * hx),
    ):
        fc = np.array([cx, cy, 0.0]) + normal * half_depth
        corners = scene._rect(fc, normal, width, cz + hz, cz - hz)
        quads.append(
            scene.Quad(corners, scene._shaded(tex, light.shade(corners.mean(0), normal)), normal)
        )
    return quads


# ------------------------------------------------------------------ perception.synth.relief
def face_height(
    pallet_id: str, side: str, style: SideStyle | None = None, geometry: PalletGeometry = EPAL
) -> np.ndarray:
    """Height map (mm, float32, the shape of :func:`~perception.synth.appearance.face_texture`)
    of a long face: grain, cracks and brands from the bare face's luminance, saw marks and
    undulation per part, rounded edges; 0 in the fork gaps."""
    style = relief._bare(style)
    lum = cv2.cvtColor(face_texture(pallet_id, side, style, geometry), cv2.COLOR_BGR2GRAY)
    lum = lum.astype(np.float32) / 255.0
    band = cv2.GaussianBlur(lum, (0, 0), 0.8) - cv2.GaussianBlur(lum, (0, 0), 8.0)
    height = np.zeros_like(lum)
    px_mm = ap.PX_PER_MM
    for name, (x0, y0, x1, y1) in relief._parts(geometry):
        h, w = y1 - y0, x1 - x0
        if h <= 2 or w <= 2:
            continue
        rng = np.random.default_rng(
            ap.part_seed(pallet_id, side, f"relief/{name}", style.texture_seed)
        )
        period = rng.uniform(2.5, 6.0) * px_mm  # saw marks across the part
        angle = rng.normal(0.0, 0.15)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        saw = np.sin(2 * np.pi * (xx * np.cos(angle) + yy * np.sin(angle)) / period)
        saw *= 1.0 + 0.5 * smooth_noise(rng, h, w, 2, max(2, w // 80))
        und = smooth_noise(rng, h, w, 2, max(2, w // 60))
        part = (
            relief.GRAIN_MM * band[y0:y1, x0:x1] + relief.SAW_MM * saw + relief.UNDULATION_MM * und
        )
        profile = relief._edge_profile.__wrapped__  # made per part, as it was
        part += relief.EDGE_MM * profile(h, w, relief.EDGE_WIDTH_MM * px_mm)
        height[y0:y1, x0:x1] = part
    return height


@lru_cache(maxsize=32)
def _normals(pallet_id: str, side: str, style: SideStyle, geometry: PalletGeometry) -> np.ndarray:
    height = face_height(pallet_id, side, style, geometry)
    per_px = 1.0 / ap.PX_PER_MM  # mm per texel
    gx = cv2.Sobel(height, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / (8.0 * per_px))
    gy = cv2.Sobel(height, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / (8.0 * per_px))
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    out = np.stack([-gx * inv, -gy * inv, inv], axis=-1).astype(np.float16)
    out.setflags(write=False)
    return out


def shade_map(normals: np.ndarray, corners: np.ndarray, light: relief.SceneLight) -> np.ndarray:
    """Brightness factor (H, W, float32) of a face with ``normals`` whose texture's corners
    TL, TR, BR, BL lie at ``corners`` (4, 3, world m), under ``light``'s lamps: ambient +
    Lambert per lamp (distance fall-off as :meth:`SceneLight.shade`) + a little specular.
    Without lamps the face is lit evenly (the scalar shade: no relief shows)."""
    H, W = normals.shape[:2]
    c = np.asarray(corners, float)
    U, V = c[1] - c[0], c[3] - c[0]
    lu, lv = np.linalg.norm(U), np.linalg.norm(V)
    n_face = np.cross(V, U)
    n_face /= np.linalg.norm(n_face)
    if not light.lamps:
        return np.full((H, W), light.shade(c.mean(0), n_face), np.float32)
    gh, gw = max(2, H // relief.GRID_PX + 2), max(2, W // relief.GRID_PX + 2)
    su = (np.linspace(0.0, W - 1.0, gw) + 0.5) / W
    sv = (np.linspace(0.0, H - 1.0, gh) + 0.5) / H
    P = c[0] + su[None, :, None] * U + sv[:, None, None] * V  # (gh, gw, 3)
    basis = np.stack([U / lu, V / lv, n_face])  # face x, y, z in the world
    nx, ny, nz = (normals[..., i].astype(np.float32) for i in range(3))
    direct = np.zeros((H, W), np.float32)
    for pos, intensity in light.lamps:
        d = np.asarray(pos, float) - P
        dist = np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-6)
        fall = intensity * np.minimum(1.0, (4.0 / dist) ** 2)
        l_face = (d / dist) @ basis.T  # (gh, gw, 3) in face coordinates
        h_face = l_face + np.array([0.0, 0.0, 1.0])
        h_face /= np.maximum(np.linalg.norm(h_face, axis=-1, keepdims=True), 1e-6)
        fields = np.concatenate([l_face * fall, h_face], axis=-1).astype(np.float32)
        full = cv2.resize(fields, (W, H), interpolation=cv2.INTER_LINEAR)
        lam = nx * full[..., 0] + ny * full[..., 1] + nz * full[..., 2]
        np.maximum(lam, 0.0, out=lam)
        spec = nx * full[..., 3] + ny * full[..., 4] + nz * full[..., 5]
        np.maximum(spec, 0.0, out=spec)
        lit = (l_face[..., 2] > 0.0).astype(np.float32)  # the lamp is in front of the face
        fall_full = cv2.resize((fall[..., 0] * lit).astype(np.float32), (W, H))
        direct += lam + relief.SPECULAR * fall_full * spec**relief.SHININESS
    return np.clip(light.ambient + 0.6 * direct, 0.15, 1.4).astype(np.float32)


def lit_face(
    pallet_id: str,
    side: str,
    style: SideStyle | None,
    geometry: PalletGeometry,
    corners: np.ndarray,
    light: relief.SceneLight,
) -> np.ndarray:
    """The long face's texture (BGR uint8) shaded per pixel by ``light`` at ``corners``."""
    tex = face_texture(pallet_id, side, style, geometry)
    shade = shade_map(_normals(pallet_id, side, relief._bare(style), geometry), corners, light)
    return cv2.multiply(tex, cv2.merge([shade, shade, shade]), dtype=cv2.CV_8U)


_PATCHES = (
    (wg, ("wood_grain", "end_grain", "chipboard", "colourise", "blend")),
    (marks, ("blend",)),
    (ageing, ("blend",)),
    (ap, ("wood_grain", "end_grain", "chipboard", "colourise", "_gap", "face_texture")),
    (relief, ("face_height", "_normals", "shade_map", "lit_face")),
    (scene, ("box_quads",)),
)


def _clear_caches() -> None:
    """Empty the caches of textures both ways make (the caches only the shipped code
    reads, of quads, edge profiles and lamp fields, stay: as in a build worker)."""
    for f in (ap.face_texture, ap.block_texture, ap.short_face_texture, ap.top_texture):
        f.cache_clear()
    relief._normals.cache_clear()
    face_texture.cache_clear()
    _normals.cache_clear()


@contextlib.contextmanager
def reference() -> Iterator[None]:
    """The pre-optimisation texture synthesis in place of the shipped one (caches emptied
    on the way in and out, so no texture made by one is used by the other)."""
    from nodes.gallery import enrol_scan

    here = globals()
    saved = [(m, name, getattr(m, name)) for m, names in _PATCHES for name in names]
    saved.append((enrol_scan, "CACHE_OFFSETS", enrol_scan.CACHE_OFFSETS))
    _clear_caches()
    try:
        for m, name, _ in saved[:-1]:
            setattr(m, name, here[name])
        enrol_scan.CACHE_OFFSETS = False
        yield
    finally:
        for m, name, f in saved:
            setattr(m, name, f)
        _clear_caches()
