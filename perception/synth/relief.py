"""Relief of a pallet's long face, lit per pixel by the scene's lamps.

Real wood is not a printed bitmap: sawn faces have grain ridges, saw marks, cracks, a
brand burnt into them and worn edges, and how they look depends on where the light comes
from. A face drawn as one colour bitmap shaded by one number per quad looks the same
under every lamp, which flatters a pixel-correlation check (:mod:`perception.verify`):
enrolment and query then see the same texture. Here every long face gets

* a **height map** (mm) from the same seeds as its colours (:func:`face_height`): the
  band-passed luminance of the face without paint or ageing (late wood, cracks, brands
  and knots sit lower; a faint-grain face keeps the relief of its full-contrast grain),
  saw marks and a gentle undulation of each block and board from the part's own seed,
  and rounded edges around every block and board (the fork gaps stay flat);
* a **normal map** from it (:func:`face_normals`, cached per identity and style: a
  deterministic function of the texture seed, computed once);
* **shading** per pixel by the scene's point lamps (:func:`shade_map`): the direction
  from each point of the face to each lamp, Lambert with the same distance fall-off and
  ambient as :meth:`perception.synth.scene.SceneLight.shade` (a flat normal gives exactly
  the old scalar shade), plus a little specular (Blinn-Phong, the viewer taken along the
  face normal: the texture is baked once per scene, not per frame, so a highlight moves
  with the lamps but not with the camera).

So the same face looks different under another lamp layout (another place in the
warehouse, another hall), while a scene's static lamps still cost nothing per frame.
:data:`ENABLED` False draws faces as before issue 28 (benches' ``--flat-faces``).
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import Protocol

import cv2
import numpy as np

from perception.synth import appearance as ap
from perception.synth.appearance import EPAL, PalletGeometry, SideStyle
from perception.synth.woodgen import smooth_noise


class SceneLight(Protocol):
    """What the shading reads of :class:`perception.synth.scene.SceneLight` (typed as a
    protocol: the scene module imports this one)."""

    ambient: float
    lamps: tuple[tuple[tuple[float, float, float], float], ...]

    def shade(self, centre: np.ndarray, normal: np.ndarray) -> float:
        """Brightness factor of a flat surface at ``centre`` facing ``normal``."""
        ...


#: bump when the relief or its shading changes (caches of rendered galleries key on it)
RELIEF_VERSION = 1
#: relief on the long faces (False: one scalar shade per face, as before issue 28)
ENABLED = True
#: height of the grain relief per unit of band-passed luminance (mm)
GRAIN_MM = 2.5
#: saw marks and undulation (mm, standard deviation)
SAW_MM, UNDULATION_MM = 0.08, 0.25
#: worn edges: depth (mm) and width (mm) of the rounding around blocks and boards
EDGE_MM, EDGE_WIDTH_MM = 1.5, 4.0
#: specular strength and exponent (a little sheen of sawn wood)
SPECULAR, SHININESS = 0.06, 16.0
#: lamp directions are computed on a grid this coarse (px) and interpolated
GRID_PX = 24
#: rows of the face shaded at a time (the same numbers as all at once, faster)
_ROWS = 32


def _mm_px(v_m: float) -> int:
    return int(round(v_m * 1000.0 * ap.PX_PER_MM))


def _parts(g: PalletGeometry) -> list[tuple[str, tuple[int, int, int, int]]]:
    """(part name, (x0, y0, x1, y1)) of every piece of wood on a long face, in texels."""
    W, H, b = _mm_px(g.length_m), _mm_px(g.height_m), _mm_px(g.board_m)
    parts = [("deck", (0, 0, W, b)), ("bottom", (0, H - b, W, H))]
    for k in range(3):
        x0, y0, x1, y1 = ap.block_rect_px(k, g)
        parts.append((f"end{k}", (x0, b, x1, 2 * b)))
        parts.append((f"block{k}", (x0, y0, x1, min(y1, H - b))))
    return parts


@lru_cache(maxsize=16)
def _edge_profile(h: int, w: int, width_px: float) -> np.ndarray:
    """0 inside a part, falling to -1 at its edges (a quarter-circle rounding); read-only,
    cached (a part's shape is the same on every face of a geometry)."""
    yy = np.minimum(np.arange(h), np.arange(h)[::-1])[:, None].astype(np.float32)
    xx = np.minimum(np.arange(w), np.arange(w)[::-1])[None, :].astype(np.float32)
    d = np.minimum(np.minimum(yy, xx) + 0.5, width_px) / width_px
    out = -(1.0 - np.sqrt(np.clip(1.0 - (1.0 - d) ** 2, 0.0, 1.0)))
    out.setflags(write=False)
    return out


def face_height(
    pallet_id: str, side: str, style: SideStyle | None = None, geometry: PalletGeometry = EPAL
) -> np.ndarray:
    """Height map (mm, float32, the shape of :func:`~perception.synth.appearance.face_texture`)
    of a long face: grain, cracks and brands from the bare face's luminance, saw marks and
    undulation per part, rounded edges; 0 in the fork gaps."""
    style = _bare(style)
    lum = cv2.cvtColor(ap.face_texture(pallet_id, side, style, geometry), cv2.COLOR_BGR2GRAY)
    lum = lum.astype(np.float32) / 255.0
    band = cv2.GaussianBlur(lum, (0, 0), 0.8) - cv2.GaussianBlur(lum, (0, 0), 8.0)
    height = np.zeros_like(lum)
    px_mm = ap.PX_PER_MM
    for name, (x0, y0, x1, y1) in _parts(geometry):
        h, w = y1 - y0, x1 - x0
        if h <= 2 or w <= 2:
            continue
        rng = np.random.default_rng(
            ap.part_seed(pallet_id, side, f"relief/{name}", style.texture_seed)
        )
        period = rng.uniform(2.5, 6.0) * px_mm  # saw marks across the part
        angle = rng.normal(0.0, 0.15)
        yy = np.arange(h, dtype=np.float32)[:, None]  # a column and a row, broadcast
        xx = np.arange(w, dtype=np.float32)[None, :]
        saw = np.sin(2 * np.pi * (xx * np.cos(angle) + yy * np.sin(angle)) / period)
        saw *= 1.0 + 0.5 * smooth_noise(rng, h, w, 2, max(2, w // 80))
        und = smooth_noise(rng, h, w, 2, max(2, w // 60))
        part = GRAIN_MM * band[y0:y1, x0:x1] + SAW_MM * saw + UNDULATION_MM * und
        part += EDGE_MM * _edge_profile(h, w, EDGE_WIDTH_MM * px_mm)
        height[y0:y1, x0:x1] = part
    return height


def _bare(style: SideStyle | None) -> SideStyle:
    """What the relief depends on: the style without paint, ageing and grain contrast."""
    return replace(style or SideStyle(), paint=None, paint_parts="all", ageing=None, grain=1.0)


def face_normals(
    pallet_id: str, side: str, style: SideStyle | None = None, geometry: PalletGeometry = EPAL
) -> np.ndarray:
    """Unit normals (H, W, 3; float16; x along the face's columns, y down its rows, z out
    of the face) of :func:`face_height`; read-only, cached (a pure function of the seeds).
    The style's paint, ageing and grain contrast do not change them (paint and dirt keep
    the wood's relief; faint grain is faint in colour only)."""
    return _normals(pallet_id, side, _bare(style), geometry)


@lru_cache(maxsize=32)
def _normals(pallet_id: str, side: str, style: SideStyle, geometry: PalletGeometry) -> np.ndarray:
    height = face_height(pallet_id, side, style, geometry)
    per_px = 1.0 / ap.PX_PER_MM  # mm per texel
    gx = cv2.Sobel(height, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / (8.0 * per_px))
    gy = cv2.Sobel(height, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / (8.0 * per_px))
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    # Kept as three planes (x, y, z) seen through an (H, W, 3) view: shade_map reads a
    # component at a time, and np.stack(...).astype(float16) was slow.
    planes = np.empty((3, *height.shape), np.float16)
    planes[0] = _half(-gx * inv)
    planes[1] = _half(-gy * inv)
    planes[2] = _half(inv)
    planes.setflags(write=False)
    return np.moveaxis(planes, 0, -1)


def _half(x: np.ndarray) -> np.ndarray:
    """``x.astype(np.float16)`` (float32 in), by OpenCV: the same rounding to nearest even
    (compared on every float32 from -2 to 2), a few times faster than numpy's."""
    try:
        return cv2.multiply(x, 1.0, dtype=cv2.CV_16F)
    except (cv2.error, TypeError):  # an OpenCV without half-float arithmetic
        return x.astype(np.float16)


def _single(x: np.ndarray) -> np.ndarray:
    """``x.astype(np.float32)`` (float16 in; exact either way), by OpenCV when it can."""
    if x.flags.c_contiguous:
        try:
            return cv2.multiply(x, 1.0, dtype=cv2.CV_32F)
        except (cv2.error, TypeError):
            pass
    return x.astype(np.float32)


def shade_map(normals: np.ndarray, corners: np.ndarray, light: SceneLight) -> np.ndarray:
    """Brightness factor (H, W, float32) of a face with ``normals`` whose texture's corners
    TL, TR, BR, BL lie at ``corners`` (4, 3, world m), under ``light``'s lamps: ambient +
    Lambert per lamp (distance fall-off as :meth:`SceneLight.shade`) + a little specular.
    Without lamps the face is lit evenly (the scalar shade: no relief shows)."""
    global _LAST_FIELDS
    H, W = normals.shape[:2]
    c = np.asarray(corners, float)
    if not light.lamps:
        U, V = c[1] - c[0], c[3] - c[0]
        n_face = np.cross(V, U)
        n_face /= np.linalg.norm(n_face)
        return np.full((H, W), light.shade(c.mean(0), n_face), np.float32)
    key = (c.tobytes(), repr(light.lamps), H, W, GRID_PX)
    last_key, fields = _LAST_FIELDS
    if key != last_key:
        _LAST_FIELDS = (key, None)
        fields = _lamp_fields(c, H, W, light.lamps, planar=False)
    elif fields is None:  # the second face in a row with these: keep them
        fields = _lamp_fields(c, H, W, light.lamps, planar=True)
        _LAST_FIELDS = (key, fields)
    nx, ny, nz = (_single(normals[..., i]) for i in range(3))
    direct = np.zeros((H, W), np.float32)
    for F, fall_full in fields:
        for r0 in range(0, H, _ROWS):  # a band of rows at a time: its fields stay in cache
            r = slice(r0, r0 + _ROWS)
            x, y, z = nx[r], ny[r], nz[r]
            lam = x * F[0, r] + y * F[1, r] + z * F[2, r]
            np.maximum(lam, 0.0, out=lam)
            spec = x * F[3, r] + y * F[4, r] + z * F[5, r]
            np.maximum(spec, 0.0, out=spec)
            direct[r] += lam + SPECULAR * fall_full[r] * spec**SHININESS
    return np.clip(light.ambient + 0.6 * direct, 0.15, 1.4).astype(np.float32)


#: (key, lamp fields) of the last face shaded; the fields are kept (read-only, about 20 MB
#: a lamp for a europallet's face) only once a second face in a row has the same corners,
#: lamps and size, as every side of a demo gallery build has (its canonical slot); the
#: faces of a simulated world each have their own corners, and then nothing is kept
_LAST_FIELDS: tuple = (None, None)


def _lamp_fields(
    c: np.ndarray, H: int, W: int, lamps: tuple, planar: bool
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per lamp, at every texel of an (H, W) face with corners ``c``: the direction to the
    lamp times its fall-off (planes 0-2, face coordinates) and the half vector (planes
    3-5) as a (6, H, W) array (``planar``: contiguous planes, else a view of the resized
    six-channel field), and the fall-off where the lamp is in front of the face (H, W).
    Both are made on a grid of :data:`GRID_PX` texels and interpolated."""
    U, V = c[1] - c[0], c[3] - c[0]
    lu, lv = np.linalg.norm(U), np.linalg.norm(V)
    n_face = np.cross(V, U)
    n_face /= np.linalg.norm(n_face)
    gh, gw = max(2, H // GRID_PX + 2), max(2, W // GRID_PX + 2)
    su = (np.linspace(0.0, W - 1.0, gw) + 0.5) / W
    sv = (np.linspace(0.0, H - 1.0, gh) + 0.5) / H
    P = c[0] + su[None, :, None] * U + sv[:, None, None] * V  # (gh, gw, 3)
    basis = np.stack([U / lu, V / lv, n_face])  # face x, y, z in the world
    out = []
    for pos, intensity in lamps:
        d = np.asarray(pos, float) - P
        dist = np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-6)
        fall = intensity * np.minimum(1.0, (4.0 / dist) ** 2)
        l_face = (d / dist) @ basis.T  # (gh, gw, 3) in face coordinates
        h_face = l_face + np.array([0.0, 0.0, 1.0])
        h_face /= np.maximum(np.linalg.norm(h_face, axis=-1, keepdims=True), 1e-6)
        fields = np.concatenate([l_face * fall, h_face], axis=-1).astype(np.float32)
        # one 6-channel resize (a channel alone is interpolated with other roundings)
        full = np.moveaxis(cv2.resize(fields, (W, H), interpolation=cv2.INTER_LINEAR), -1, 0)
        lit = (l_face[..., 2] > 0.0).astype(np.float32)  # the lamp is in front of the face
        fall_full = cv2.resize((fall[..., 0] * lit).astype(np.float32), (W, H))
        if planar:
            full = np.ascontiguousarray(full)
            full.setflags(write=False)
            fall_full.setflags(write=False)
        out.append((full, fall_full))
    return out


def lit_face(
    pallet_id: str,
    side: str,
    style: SideStyle | None,
    geometry: PalletGeometry,
    corners: np.ndarray,
    light: SceneLight,
) -> np.ndarray:
    """The long face's texture (BGR uint8) shaded per pixel by ``light`` at ``corners``."""
    # None draws as SideStyle() and is the relief's bare style: one texture for both
    style = style or SideStyle()
    tex = ap.face_texture(pallet_id, side, style, geometry)
    shade = shade_map(face_normals(pallet_id, side, style, geometry), corners, light)
    return cv2.multiply(tex, cv2.merge([shade, shade, shade]), dtype=cv2.CV_8U)


__all__ = [
    "ENABLED",
    "RELIEF_VERSION",
    "face_height",
    "face_normals",
    "lit_face",
    "shade_map",
]
