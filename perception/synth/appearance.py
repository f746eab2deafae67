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
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np

from perception.synth import looks, marks
from perception.synth.ageing import Ageing, age_image
from perception.synth.altgen import face_luminance
from perception.synth.surroundings import floor_texture, pyramid, stand_texture, wall_texture
from perception.synth.woodgen import chipboard, colourise, end_grain, wood_grain

__all__ = [
    "EPAL",
    "PX_PER_MM",
    "PalletGeometry",
    "SideStyle",
    "block_rect_px",
    "block_texture",
    "face_texture",
    "floor_texture",
    "part_seed",
    "pyramid",
    "short_face_texture",
    "split_identity",
    "stand_texture",
    "styles_from_world",
    "world_side_style",
    "top_texture",
    "wall_texture",
]

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

    The look over the range of real pallets (:mod:`perception.synth.looks`): ``wood``, a
    tone name (``fresh``, ``grey``, ``wet``...), or ``wood_hsv``, an explicit (hue deg,
    saturation, value) base colour (default: the identity's fresh wood);
    ``saturation``: multiplies the wood colour's saturation; ``paint``: a paint name or a
    BGR triple, over ``paint_parts`` (``all`` or ``blocks``); ``marking``: ``burnt``,
    ``ink``, ``stencil``, ``label`` or ``none`` (default: the identity's burnt or ink brand);
    ``generator``: the block-face family (:data:`perception.synth.looks.FACE_GENERATORS`);
    ``ageing``: changes since enrolment (:class:`perception.synth.ageing.Ageing`);
    ``grain``: contrast of the block faces' grain (1: the generator's; 0.2: faint grain,
    planed or weathered wood whose rings hardly show in colour; the relief stays,
    :mod:`perception.synth.relief`).
    """

    stamp: str | None = None
    wear: float | None = None
    texture_seed: int = 0
    wood: str | None = None
    wood_hsv: tuple[float, float, float] | None = None
    saturation: float = 1.0
    paint: str | tuple[float, float, float] | None = None
    paint_parts: str = "all"
    marking: str | None = None
    generator: str = "wood"
    ageing: Ageing | None = None
    grain: float = 1.0

    def __post_init__(self) -> None:
        if self.wood is not None:
            looks.wood_colour(self.wood)  # raises for an unknown tone
        if self.paint is not None:
            looks.paint_colour(self.paint)
        if self.paint_parts not in looks.PAINT_PARTS:
            raise ValueError(f"paint_parts must be one of {looks.PAINT_PARTS}")
        if self.marking is not None and self.marking not in looks.MARKINGS:
            raise ValueError(
                f"unknown marking {self.marking!r} (known: {', '.join(looks.MARKINGS)})"
            )
        if self.generator not in looks.FACE_GENERATORS:
            raise ValueError(
                f"unknown face generator {self.generator!r} "
                f"(known: {', '.join(looks.FACE_GENERATORS)})"
            )
        if not 0.0 <= self.saturation <= 3.0:
            raise ValueError(f"saturation must be within 0..3, got {self.saturation}")
        if not 0.0 <= self.grain <= 2.0:
            raise ValueError(f"grain must be within 0..2, got {self.grain}")

    def unaged(self) -> SideStyle:
        """The same side before any :attr:`ageing` (what was enrolled)."""
        return replace(self, ageing=None)


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


def world_side_style(side: dict | None, look: dict | None = None, seed: int = 0) -> SideStyle:
    """The :class:`SideStyle` of one side of a world file (``stamp``, ``wear``,
    ``texture_seed``, ``wood``, ``paint``, ``age``), its ``auto``/missing look keys taken
    from the world's ``pallet_look`` (``look``); ``age`` > 0 becomes a gradual
    :class:`~perception.synth.ageing.Ageing` seeded by ``seed``.

    Raises:
        ValueError: an unknown wood tone or paint (world validation catches these first).
    """
    s, look = side or {}, look or {}
    wood = s.get("wood") or "auto"
    wood = look.get("wood", "auto") if wood == "auto" else wood
    paint = s.get("paint") or "auto"
    paint = look.get("paint", "none") if paint == "auto" else paint
    age = s.get("age")
    age = float(look.get("age") or 0.0) if age is None else float(age)
    return SideStyle(
        s.get("stamp"),
        s.get("wear"),
        int(s.get("texture_seed") or 0),
        wood=None if wood in (None, "auto") else wood,
        paint=None if paint in (None, "none", "auto") else paint,
        ageing=Ageing.gradual(age, seed) if age > 0 else None,
    )


def styles_from_world(world_data: dict) -> dict[str, SideStyle]:
    """Identity -> :class:`SideStyle` from a world file's data (its ``pallets`` list and
    ``pallet_look``). Pass these to the dataset helpers to reproduce exactly what the
    simulator shows.
    """
    out = {}
    look = world_data.get("pallet_look") or {}
    for p in world_data.get("pallets") or []:
        for side, s in (p.get("sides") or {}).items():
            out[f"{p['id']}{side}"] = world_side_style(
                s, look, part_seed(str(p["id"]), side, "age")
            )
    return out


@dataclass(frozen=True)
class _Look:
    """Resolved look of a pallet side: colour, material, stamp, wear, paint, marking."""

    base: tuple[float, float, float]
    chip: bool
    stamp: str
    wear: float
    paint: tuple[float, float, float] | None = None
    paint_blocks_only: bool = False
    marking: str | None = None
    generator: str = "wood"


@lru_cache(maxsize=4096)
def _look(pallet_id: str, side: str, style: SideStyle | None) -> _Look:
    style = style or SideStyle()
    prng = _rng(pallet_id, "*", "pallet")  # shared by both sides of one pallet
    tone = prng.normal(1.0, 0.03)
    warmth = prng.normal(0.0, 0.02)
    base = _WOOD_BGR * tone * np.array([1.0 - warmth, 1.0, 1.0 + warmth * 0.5], np.float32)
    chip = bool(prng.random() < 0.3)
    if style.wood_hsv is not None or style.wood is not None:
        hsv = style.wood_hsv or looks.WOOD_TONES[str(style.wood)]
        base = np.asarray(looks.hsv_to_bgr(*hsv), np.float32) * np.float32(tone)
    if style.saturation != 1.0:
        h, s_, v = looks.bgr_to_hsv(tuple(float(x) for x in base))
        base = np.asarray(looks.hsv_to_bgr(h, s_ * style.saturation, v), np.float32)
    srng = _rng(pallet_id, side, "style", style.texture_seed)
    stamp = style.stamp or ("EUR" if srng.random() < 0.2 else "EPAL")
    wear = float(style.wear) if style.wear is not None else float(srng.beta(2.0, 3.0))
    paint = looks.paint_colour(style.paint) if style.paint is not None else None
    return _Look(
        tuple(float(v) for v in base),
        chip,
        stamp,
        wear,
        paint,
        style.paint_parts == "blocks",
        style.marking,
        style.generator,
    )


def _dark(base: np.ndarray) -> np.ndarray:
    """Late-wood colour of a base colour (as dark as the fresh wood's, in its hue)."""
    return _DARK_BGR * base / _WOOD_BGR


def _mm(v_m: float) -> int:
    return int(round(v_m * 1000.0 * PX_PER_MM))


def _block_face(
    pallet_id: str, side: str, block: int, style: SideStyle, h: int, w: int, stamped: bool
) -> np.ndarray:
    """Float BGR face of one block before ageing (``stamped`` False: without its brand;
    every other draw stays the same, the brand having its own random stream)."""
    look = _look(pallet_id, side, style)
    rng = _rng(pallet_id, side, f"block{block}", style.texture_seed)
    stamp_rng = _rng(pallet_id, side, f"block{block}/stamp", style.texture_seed)
    base = np.asarray(look.base, np.float32) * np.float32(rng.normal(1.0, 0.03))
    if look.generator != "wood":
        lum = face_luminance(look.generator, rng, h, w)
    elif look.chip:
        lum = chipboard(rng, h, w)
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
    if style.grain != 1.0:  # faint (or strong) grain: the same pattern, less contrast
        mean = np.float32(lum.mean())
        lum = mean + np.float32(style.grain) * (lum - mean)
    img = colourise(lum, base, _dark(base)).astype(np.float32, copy=False)
    if not look.chip and look.generator == "wood":
        marks.cracks(img, rng, int(rng.poisson(0.4 + 1.2 * look.wear)))
    if look.paint is not None:
        marks.paint_over(img, rng, look.paint, look.wear)
    stamped_here = stamp_rng.random() < 0.92
    if stamped and stamped_here:
        _mark(img, stamp_rng, block, look)
    if block % 3 == 1 and look.stamp == "EPAL":
        marks.control_clip(img, rng)
    marks.nails(img, rng, int(rng.integers(0, 3)), look.wear)
    if rng.random() < 0.25 + 0.2 * look.wear:
        marks.scribble(img, rng)
    marks.dirt_and_wear(img, rng, look.wear)
    return img


def _mark(img: np.ndarray, rng: np.random.Generator, block: int, look: _Look) -> None:
    """The side's marking on one block face (brand, ink stamp, stencil or label)."""
    if look.marking is None:  # the identity's own brand, as the original generator drew it
        marks.stamp_block(img, rng, block % 3, look.stamp, look.wear)
    elif look.marking == "burnt":
        marks.stamp_block(img, rng, block % 3, look.stamp, look.wear, varied=True)
    elif look.marking == "ink":
        ink = ((30, 30, 34), (110, 45, 20), (30, 30, 150), (40, 90, 30))[int(rng.integers(4))]
        marks.stamp_block(img, rng, block % 3, look.stamp, look.wear, ink=ink, varied=True)
    elif look.marking == "stencil":
        light = float(np.mean(look.paint if look.paint is not None else look.base)) < 120
        colour = (225.0, 225.0, 225.0) if light else (30.0, 30.0, 30.0)
        marks.stencil(img, rng, (look.stamp, "P", "RE", "L", "B")[int(rng.integers(5))], colour)
    elif look.marking == "label":
        marks.label(img, rng)


@lru_cache(maxsize=768)
def block_texture(
    pallet_id: str,
    side: str,
    block: int,
    style: SideStyle | None = None,
    size_m: tuple[float, float] = (0.145, 0.078),
) -> np.ndarray:
    """Front face of support block ``block`` (0, 1, 2 left to right) of a pallet side.

    ``size_m`` is (width, height) of the face. The style's ageing, if any, is drawn last
    (seeded by the identity, the block and the ageing's seed). Returns BGR uint8
    (read-only, cached).
    """
    style = style or SideStyle()
    h, w = _mm(size_m[1]), _mm(size_m[0])
    ageing = style.ageing
    img = _block_face(pallet_id, side, block, style.unaged(), h, w, True)
    if ageing is not None and ageing.changes_texture:
        if ageing.fade_stamps > 0:
            bare = _block_face(pallet_id, side, block, style.unaged(), h, w, False)
            img = img * (1 - ageing.fade_stamps) + bare * ageing.fade_stamps
        arng = _rng(pallet_id, side, f"block{block}/age{ageing.seed}", style.texture_seed)
        age_image(img, arng, ageing)
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
    img = colourise(lum, base, _dark(base)).astype(np.float32, copy=False)
    if look.paint is not None and not look.paint_blocks_only:
        marks.paint_over(img, rng, look.paint, look.wear)
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
    out = np.empty((h, w, 3), lum.dtype)  # channel by channel: np.stack of the three is slow
    out[..., 0] = lum  # lum * 1.0
    np.multiply(lum, 1.02, out=out[..., 1])
    np.multiply(lum, 1.08, out=out[..., 2])
    return out


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
    img = _gap(rng, W, H)  # float32, (H, W, 3)
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
        end = colourise(lum, base, _dark(base)).astype(np.float32, copy=False)
        if look.paint is not None and not look.paint_blocks_only:
            marks.paint_over(end, rng, look.paint, look.wear)
        img[b : 2 * b, x0:x1] = end
        img[2 * b - 1 : 2 * b + 1, x0:x1] *= 0.55  # joint between board end and block
    img[b - 1 : b + 1] *= 0.6
    img[H - b - 1 : H - b + 1] *= 0.6
    out = np.clip(img, 0, 255, out=img).astype(np.uint8)
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
        base = np.asarray(look.base, np.float32)
        img[2 * b : H - b, x0 : x0 + bw] = colourise(lum, base, _dark(base))
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
