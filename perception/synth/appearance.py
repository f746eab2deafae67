"""Procedural europallet appearance: block faces, boards, whole pallet sides, floor and walls.

Every texture is a pure, cached function of its key. A pallet *identity* is a pallet id plus
the side shown (``"3A"``, ``"p0001B"``); each support block of a side gets its own seed,
``zlib.crc32("btrun-pallet/<pallet>/<side>/<part>/<texture_seed>")``, so the same
(identity, side, block) always gives the same pixels, in every process (Python's ``hash`` is
salted and is never used).

All pallets share one wood colour distribution (light spruce/pine, greyed by wear); what tells
two identities apart is what tells real pallets apart: grain pattern, knots, cracks, stamp
content and position, nail heads, scribbles, dirt and wear. Both sides of one pallet share the
base colour and material (solid wood or pressed chips).

Textures are BGR uint8 at :data:`PX_PER_MM` pixels per millimetre, row 0 at the top, column 0
at the left *as seen from in front of the face*.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from perception.synth import marks
from perception.synth.woodgen import (
    chipboard,
    colourise,
    concrete,
    end_grain,
    smooth_noise,
    wood_grain,
)

PX_PER_MM = 2.0
"""Texture resolution of pallet parts (the camera never resolves better than ~1.5 mm)."""

_WOOD_BGR = np.array([118.0, 168.0, 206.0], np.float32)  # fresh spruce/pine, mean colour
_DARK_BGR = np.array([40.0, 62.0, 92.0], np.float32)  # late wood / shadowed grain


@dataclass(frozen=True)
class PalletGeometry:
    """EPAL europallet dimensions in metres ([epal], docs/references.md); blocks are [along face, depth]."""

    length_m: float = 1.2
    width_m: float = 0.8
    height_m: float = 0.144
    board_m: float = 0.022
    block_height_m: float = 0.078
    corner_block_m: tuple[float, float] = (0.145, 0.100)
    middle_block_m: tuple[float, float] = (0.145, 0.145)

    @classmethod
    def from_dict(cls, d: dict) -> PalletGeometry:
        """From a world file's ``pallet_geometry`` mapping (unknown keys are ignored)."""
        keys = cls.__dataclass_fields__
        kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in keys}
        return cls(**kw)

    def block_widths_m(self) -> tuple[float, float, float]:
        """Widths along the long face of blocks 0, 1, 2 (left to right seen from the front)."""
        return (self.corner_block_m[0], self.middle_block_m[0], self.corner_block_m[0])

    def block_offsets_m(self) -> tuple[float, float, float]:
        """Centres of blocks 0, 1, 2 along the long face from its centre (+ = right)."""
        o = self.length_m / 2 - self.corner_block_m[0] / 2
        return (-o, 0.0, o)


EPAL = PalletGeometry()


@dataclass(frozen=True)
class SideStyle:
    """Per-side knobs from a world file; None fields are drawn from the identity's seed.

    ``stamp``: brand on the corner blocks ("EPAL" or "EUR"); ``wear``: 0 new .. 1 very used;
    ``texture_seed``: mixed into every seed of the side (0 = the identity alone decides).
    """

    stamp: str | None = None
    wear: float | None = None
    texture_seed: int = 0


def split_identity(identity: str, side: str | None = None) -> tuple[str, str]:
    """``("3A", None) -> ("3", "A")``; ``("3", "A") -> ("3", "A")`` (a given side wins)."""
    identity = str(identity).strip()
    if side:
        return identity, side.upper()
    if len(identity) < 2 or identity[-1].upper() not in "AB":
        raise ValueError(f"identity '{identity}' does not end in a side letter A or B")
    return identity[:-1], identity[-1].upper()


def part_seed(pallet_id: str, side: str, part: str | int, texture_seed: int = 0) -> int:
    """Deterministic 32-bit seed of one part of a pallet side (CRC-32, process independent)."""
    return zlib.crc32(f"btrun-pallet/{pallet_id}/{side}/{part}/{texture_seed}".encode())


def _rng(pallet_id: str, side: str, part: str | int, texture_seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(part_seed(pallet_id, side, part, texture_seed))


def styles_from_world(world_data: dict) -> dict[str, SideStyle]:
    """Identity -> :class:`SideStyle` from a world file's data (its ``pallets`` list).

    Pass these to the dataset helpers to reproduce exactly what the simulator shows.
    """
    out = {}
    for p in world_data.get("pallets") or []:
        for side, s in (p.get("sides") or {}).items():
            s = s or {}
            out[f"{p['id']}{side}"] = SideStyle(
                s.get("stamp"), s.get("wear"), int(s.get("texture_seed") or 0)
            )
    return out


@dataclass(frozen=True)
class _Look:
    """Resolved look of a pallet side: colour, material, stamp, wear."""

    base: tuple[float, float, float]
    chip: bool
    stamp: str
    wear: float


@lru_cache(maxsize=4096)
def _look(pallet_id: str, side: str, style: SideStyle | None) -> _Look:
    style = style or SideStyle()
    prng = _rng(pallet_id, "*", "pallet")  # shared by both sides of one pallet
    tone = prng.normal(1.0, 0.03)
    warmth = prng.normal(0.0, 0.02)
    base = _WOOD_BGR * tone * np.array([1.0 - warmth, 1.0, 1.0 + warmth * 0.5], np.float32)
    chip = bool(prng.random() < 0.3)
    srng = _rng(pallet_id, side, "style", style.texture_seed)
    stamp = style.stamp or ("EUR" if srng.random() < 0.2 else "EPAL")
    wear = float(style.wear) if style.wear is not None else float(srng.beta(2.0, 3.0))
    return _Look(tuple(float(v) for v in base), chip, stamp, wear)


def _mm(v_m: float) -> int:
    return int(round(v_m * 1000.0 * PX_PER_MM))


@lru_cache(maxsize=768)
def block_texture(
    pallet_id: str,
    side: str,
    block: int,
    style: SideStyle | None = None,
    size_m: tuple[float, float] = (0.145, 0.078),
) -> np.ndarray:
    """Front face of support block ``block`` (0, 1, 2 left to right) of a pallet side.

    ``size_m`` is (width, height) of the face. Returns BGR uint8 (read-only, cached).
    """
    look = _look(pallet_id, side, style)
    rng = _rng(pallet_id, side, f"block{block}", (style or SideStyle()).texture_seed)
    h, w = _mm(size_m[1]), _mm(size_m[0])
    base = np.asarray(look.base, np.float32) * np.float32(rng.normal(1.0, 0.03))
    if look.chip:
        lum = chipboard(rng, h, w)
        n_knots = 0
    else:
        n_knots = int(rng.poisson(0.9))
        knots = [
            (
                rng.uniform(0.05, 0.95) * w,
                rng.uniform(0.1, 0.9) * h,
                rng.uniform(3, 10),
                rng.uniform(2.5, 7),
            )
            for _ in range(n_knots)
        ]
        lum = wood_grain(
            rng,
            h,
            w,
            period_px=rng.uniform(7.0, 16.0),
            slope=rng.normal(0.0, 0.04),
            warp_px=rng.uniform(3.0, 10.0),
            knots=knots,
        )
    img = colourise(lum, base, _DARK_BGR * base / _WOOD_BGR).astype(np.float32)
    if not look.chip:
        marks.cracks(img, rng, int(rng.poisson(0.4 + 1.2 * look.wear)))
    if rng.random() < 0.92:
        marks.stamp_block(img, rng, block % 3, look.stamp, look.wear)
    if block % 3 == 1 and look.stamp == "EPAL":
        marks.control_clip(img, rng)
    marks.nails(img, rng, int(rng.integers(0, 3)), look.wear)
    if rng.random() < 0.25 + 0.2 * look.wear:
        marks.scribble(img, rng)
    marks.dirt_and_wear(img, rng, look.wear)
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


def _board(rng: np.random.Generator, look: _Look, w: int, h: int, nail_xs: list[int]) -> np.ndarray:
    """A side-grain board (w x h) with nail heads near ``nail_xs`` (board coordinates)."""
    base = np.asarray(look.base, np.float32) * np.float32(rng.normal(1.0, 0.03))
    knots = [
        (rng.uniform(0, w), rng.uniform(0.2, 0.8) * h, rng.uniform(3, 8), rng.uniform(2, 5))
        for _ in range(int(rng.poisson(w / 900)))
    ]
    lum = wood_grain(
        rng,
        h,
        w,
        period_px=rng.uniform(6.0, 14.0),
        slope=rng.normal(0.0, 0.01),
        warp_px=rng.uniform(3, 8),
        knots=knots,
    )
    img = colourise(lum, base, _DARK_BGR * base / _WOOD_BGR).astype(np.float32)
    r = max(2, int(h * 0.09))
    for x in nail_xs:
        for dx in (-1, 1):
            if rng.random() < 0.25:
                continue  # nail head sunk or missing
            cx = int(x + dx * rng.uniform(0.15, 0.35) * _mm(0.145) + rng.normal(0, 3))
            cy = int(h * rng.uniform(0.35, 0.65))
            grey = float(rng.uniform(60, 100))
            cv2.circle(img, (cx, cy), int(r * 1.7), (55, 75, 100), -1, cv2.LINE_AA)
            cv2.circle(img, (cx, cy), r, (grey, grey, grey + 5), -1, cv2.LINE_AA)
    marks.dirt_and_wear(img, rng, look.wear)
    return img


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
    look = _look(pallet_id, side, style)
    ts = (style or SideStyle()).texture_seed
    rng = _rng(pallet_id, side, "face", ts)
    W, H, b, bh = _mm(g.length_m), _mm(g.height_m), _mm(g.board_m), _mm(g.block_height_m)
    img = np.zeros((H, W, 3), np.float32)
    img[:, :] = _gap(rng, W, H)
    centres = [int(round((g.length_m / 2 + o) * 1000 * PX_PER_MM)) for o in g.block_offsets_m()]
    img[0:b] = _board(rng, look, W, b, centres)
    img[H - b : H] = _board(rng, look, W, b, centres)
    for k, (cx, bw_m) in enumerate(zip(centres, g.block_widths_m(), strict=True)):
        bw = _mm(bw_m)
        x0 = max(0, cx - bw // 2)
        tex = block_texture(pallet_id, side, k, style, (bw_m, g.block_height_m))
        x1 = min(W, x0 + tex.shape[1])
        img[2 * b : 2 * b + bh, x0:x1] = tex[:bh, : x1 - x0]
        base = np.asarray(look.base, np.float32) * 0.85
        lum = end_grain(rng, b, x1 - x0, period_px=rng.uniform(6, 12))
        img[b : 2 * b, x0:x1] = colourise(lum, base, _DARK_BGR)
        img[2 * b - 1 : 2 * b + 1, x0:x1] *= 0.55  # joint between board end and block
    img[b - 1 : b + 1] *= 0.6
    img[H - b - 1 : H - b + 1] *= 0.6
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


def block_rect_px(block: int, geometry: PalletGeometry = EPAL) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of block ``block``'s face inside :func:`face_texture`."""
    g = geometry
    b, bh = _mm(g.board_m), _mm(g.block_height_m)
    cx = int(round((g.length_m / 2 + g.block_offsets_m()[block]) * 1000 * PX_PER_MM))
    bw = _mm(g.block_widths_m()[block])
    return cx - bw // 2, 2 * b, cx - bw // 2 + bw, 2 * b + bh


@lru_cache(maxsize=48)
def short_face_texture(
    pallet_id: str, side: str, style: SideStyle | None = None, geometry: PalletGeometry = EPAL
) -> np.ndarray:
    """A short (0.8 m) side: deck-board ends, a cross board, three 0.1 m blocks, bottom board.

    Half the resolution of the long face (rarely seen closely). ``side`` is "L" or "R".
    """
    g = geometry
    look = _look(pallet_id, "A", style)
    rng = _rng(pallet_id, side, "short")
    W, H, b = _mm(g.width_m) // 2, _mm(g.height_m) // 2, _mm(g.board_m) // 2
    img = _gap(rng, W, H)
    img[0:b] = _board(rng, look, W, b, [])
    img[H - b :] = _board(rng, look, W, b, [])
    img[b : 2 * b] = _board(rng, look, W, b, [])
    bw = _mm(0.1) // 2
    for cx in (bw // 2, W // 2, W - bw // 2):
        x0 = cx - bw // 2
        lum = end_grain(rng, H - 3 * b, bw, period_px=5.0)
        img[2 * b : H - b, x0 : x0 + bw] = colourise(lum, np.asarray(look.base), _DARK_BGR)
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=48)
def top_texture(
    pallet_id: str, style: SideStyle | None = None, geometry: PalletGeometry = EPAL
) -> np.ndarray:
    """The pallet seen from above (length along columns): five deck boards with gaps.

    Column 0 is side A's left end; row 0 is side A's edge. 1 px = 4 mm.
    """
    g = geometry
    look = _look(pallet_id, "A", style)
    rng = _rng(pallet_id, "*", "top")
    px_per_m = 250
    W, H = int(g.length_m * px_per_m), int(g.width_m * px_per_m)
    img = np.full((H, W, 3), 35.0, np.float32)
    widths = (0.145, 0.100, 0.145, 0.100, 0.145)
    gap = (g.width_m - sum(widths)) / 4
    y = 0.0
    for wd in widths:
        y0, y1 = int(y * px_per_m), int((y + wd) * px_per_m)
        img[y0:y1] = _board(rng, look, W, y1 - y0, [])
        y += wd + gap
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=8)
def floor_texture(w_px: int = 800, h_px: int = 600, joint_px: int = 200) -> np.ndarray:
    """Concrete floor (BGR uint8), row 0 at the floor's smallest x, column 0 at its largest y."""
    img = concrete(np.random.default_rng(zlib.crc32(b"btrun-floor")), h_px, w_px, joint_px=joint_px)
    out = img.astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=8)
def wall_texture(w_px: int = 800, h_px: int = 200) -> np.ndarray:
    """Warehouse wall (BGR uint8, row 0 at the top): painted block work, a dark base band."""
    rng = np.random.default_rng(zlib.crc32(b"btrun-wall"))
    lum = 0.82 + 0.02 * smooth_noise(rng, h_px, w_px, 4, 16)
    lum += 0.012 * rng.standard_normal((h_px, w_px), dtype=np.float32)
    img = np.stack([lum * 200.0, lum * 204.0, lum * 206.0], axis=-1)
    course = max(h_px // 20, 2)
    img[::course] *= 0.8  # mortar joints of the block work
    for r in range(0, h_px, course):
        off = (r // course % 2) * course
        img[r : r + course, off :: course * 2] *= 0.8
    for x in range(w_px // 10, w_px, w_px // 5):  # steel columns
        img[:, x : x + 3] = (120, 110, 60)
    band = int(h_px * 0.75)
    img[band:] = img[band:] * np.array([0.55, 0.45, 0.35], np.float32)  # dark base band
    img[band : band + 2] = (20, 170, 220)  # yellow line
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=8)
def stand_texture(w_px: int = 300, h_px: int = 100) -> np.ndarray:
    """Front of the stand box under a raised pallet: a dark grey plastic crate with ribs."""
    rng = np.random.default_rng(zlib.crc32(b"btrun-stand"))
    img = concrete(rng, h_px, w_px) * np.array([0.55, 0.52, 0.5], np.float32)
    img[:, :: max(w_px // 24, 2)] *= 0.7
    img[:: max(h_px // 6, 2)] *= 0.75
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


def pyramid(tex: np.ndarray, levels: int = 6) -> list[np.ndarray]:
    """Mip levels of a texture (level k = ``tex`` reduced 2^k times) for minified drawing."""
    out = [np.ascontiguousarray(tex)]
    while len(out) < levels and min(out[-1].shape[:2]) >= 4:
        out.append(cv2.pyrDown(out[-1]))
    return out
