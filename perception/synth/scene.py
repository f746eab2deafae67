"""Scene description for the synthetic camera: pallets, stand boxes, floor, walls, lamps.

A :class:`Scene` is a list of textured, pre-shaded planar quads (:class:`Quad`) built once
from plain values (no simulator types): :class:`PalletSpec` for each pallet, boxes for stands
and obstacles, a floor rectangle and the surrounding walls. Lamps shade every quad once at
build time (ambient + Lambert with distance fall-off; the long faces of pallets per pixel,
over their relief: :mod:`perception.synth.relief`); per-frame light changes happen in the
sensor stage of :mod:`perception.synth.render`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache, partial

import cv2
import numpy as np

from perception.synth import appearance as ap
from perception.synth import relief
from perception.synth.appearance import EPAL, PalletGeometry, SideStyle
from perception.synth.materials import MATERIALS

_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class SceneLight:
    """Static light of a scene: ambient level, point lamps ((x, y, z), intensity), colour."""

    ambient: float = 0.6
    lamps: tuple[tuple[tuple[float, float, float], float], ...] = ()
    colour_temperature_k: float = 4000.0

    def shade(self, centre: np.ndarray, normal: np.ndarray) -> float:
        """Brightness factor of a surface at ``centre`` facing ``normal``."""
        direct = 0.0
        for pos, intensity in self.lamps:
            d = np.asarray(pos, float) - centre
            dist = float(np.linalg.norm(d)) or 1.0
            cos = max(0.0, float(normal @ d) / dist)
            direct += intensity * cos * min(1.0, (4.0 / dist) ** 2)
        if not self.lamps:
            direct = 0.4
        return float(np.clip(self.ambient + 0.6 * direct, 0.15, 1.4))


@dataclass
class Quad:
    """A textured rectangle: world corners TL, TR, BR, BL of its texture, normal, texture.

    ``texture`` is the list of shaded mip levels or a function making it; it is made the
    first time the quad is drawn (:attr:`levels`), so unseen faces cost nothing. ``kind``:
    "floor", "wall" or "object" (draw order: floor, walls, then objects far to near).
    ``blocks`` lists (block index, identity, corners (4, 3)) of support-block faces lying on
    this quad, for ground-truth boxes.
    """

    corners: np.ndarray
    texture: list[np.ndarray] | Callable[[], list[np.ndarray]]
    normal: np.ndarray
    kind: str = "object"
    blocks: list[tuple[int, str, np.ndarray]] = field(default_factory=list)
    centre: np.ndarray = field(init=False)
    _texture_map: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.centre = self.corners.mean(axis=0)

    def texture_map(self) -> np.ndarray:
        """(3, 3) matrix taking a level-0 texel (column, row, 1) to its centre in the world;
        made once (it does not depend on the camera)."""
        if self._texture_map is None:
            th, tw = self.levels[0].shape[:2]
            c = self.corners
            U, V = (c[1] - c[0]) / tw, (c[3] - c[0]) / th
            self._texture_map = np.column_stack([U, V, c[0] + 0.5 * U + 0.5 * V])
        return self._texture_map

    @property
    def levels(self) -> list[np.ndarray]:
        """The shaded mip levels (made on first use)."""
        if callable(self.texture):
            self.texture = self.texture()
        return self.texture


@dataclass(frozen=True)
class PalletSpec:
    """A pallet standing in the scene.

    ``face_x, face_y``: centre of the shown long face; ``base_z``: height of the pallet's
    bottom; ``facing_rad``: direction the shown face looks to (pi = towards -x). ``styles``
    maps side letter -> :class:`SideStyle` (missing: drawn from the identity seed).
    """

    pallet_id: str
    side: str
    face_x: float
    face_y: float
    base_z: float
    facing_rad: float
    geometry: PalletGeometry = EPAL
    styles: tuple[tuple[str, SideStyle | None], ...] = ()

    @property
    def identity(self) -> str:
        """Identity of the shown side, e.g. "3A"."""
        return f"{self.pallet_id}{self.side}"

    def style(self, side: str) -> SideStyle | None:
        """Style of ``side`` (or None)."""
        return dict(self.styles).get(side)


def _rect(
    centre: np.ndarray, normal: np.ndarray, width: float, top: float, bottom: float
) -> np.ndarray:
    """Corners TL, TR, BR, BL of a vertical rectangle seen from the side ``normal`` points to."""
    right = np.array([-normal[1], normal[0], 0.0])
    c = np.array([centre[0], centre[1], 0.0])
    half = right * width / 2
    return np.array(
        [c - half + _Z * top, c + half + _Z * top, c + half + _Z * bottom, c - half + _Z * bottom]
    )


def _shaded(make: Callable[[], np.ndarray], shade: float) -> Callable[[], list[np.ndarray]]:
    """A deferred texture: ``make()`` scaled by ``shade``, as mip levels."""

    def levels() -> list[np.ndarray]:
        return ap.pyramid(cv2.convertScaleAbs(make(), alpha=shade))

    return levels


def _relit(make: Callable[[], np.ndarray]) -> Callable[[], list[np.ndarray]]:
    """A deferred texture already shaded (per pixel), as mip levels."""

    def levels() -> list[np.ndarray]:
        return ap.pyramid(make())

    return levels


def pallet_quads(p: PalletSpec, light: SceneLight) -> list[Quad]:
    """Quads of a pallet: both long faces (with their blocks), both ends and the top.

    The long faces carry their relief, shaded per pixel by the lamps
    (:mod:`perception.synth.relief`; unless :data:`perception.synth.relief.ENABLED` is
    off); the ends and the top one shade each."""
    g = p.geometry
    n = np.array([math.cos(p.facing_rad), math.sin(p.facing_rad), 0.0])
    right = np.array([-n[1], n[0], 0.0])
    front = np.array([p.face_x, p.face_y, 0.0])
    top, base = p.base_z + g.height_m, p.base_z
    centre = front - n * g.width_m / 2
    quads = []
    other = "B" if p.side == "A" else "A"
    for side, normal, fc in ((p.side, n, front), (other, -n, front - n * g.width_m)):
        corners = _rect(fc, normal, g.length_m, top, base)
        if relief.ENABLED:
            lit = partial(relief.lit_face, p.pallet_id, side, p.style(side), g, corners, light)
            q = Quad(corners, _relit(lit), normal)
        else:
            make = partial(ap.face_texture, p.pallet_id, side, p.style(side), g)
            q = Quad(corners, _shaded(make, light.shade(corners.mean(0), normal)), normal)
        r = np.array([-normal[1], normal[0], 0.0])
        b0, b1 = base + g.board_m, base + g.board_m + g.block_height_m
        for k, (off, w) in enumerate(zip(g.block_offsets_m(), g.block_widths_m(), strict=True)):
            bc = fc + r * off
            q.blocks.append((k, f"{p.pallet_id}{side}", _rect(bc, normal, w, b1, b0)))
        quads.append(q)
    for sgn, name in ((-1.0, "L"), (1.0, "R")):
        normal = right * sgn
        fc = centre + right * sgn * g.length_m / 2
        corners = _rect(fc, normal, g.width_m, top, base)
        make = partial(ap.short_face_texture, p.pallet_id, name, p.style(p.side), g)
        quads.append(Quad(corners, _shaded(make, light.shade(corners.mean(0), normal)), normal))
    tl = front - right * g.length_m / 2
    corners = (
        np.array(
            [
                tl,
                tl + right * g.length_m,
                tl + right * g.length_m - n * g.width_m,
                tl - n * g.width_m,
            ]
        )
        + _Z * top
    )
    make = partial(ap.top_texture, p.pallet_id, p.style(p.side), g)
    quads.append(Quad(corners, _shaded(make, light.shade(corners.mean(0), _Z)), _Z.copy()))
    return quads


def box_quads(
    centre: tuple[float, float, float],
    half: tuple[float, float, float],
    yaw_rad: float,
    light: SceneLight,
    material: str = "stand",
) -> list[Quad]:
    """The four vertical faces of a yawed box (stand, obstacle, rack steel), drawn with
    ``material``'s texture (:data:`perception.synth.materials.MATERIALS`).

    The same box under the same light gives the same quads, made once and shared by the
    scenes that have it (a quad is static: its shaded texture, made on first sight, is a
    pure function of these arguments): a demo gallery build makes a scene per pallet side,
    each with the same racks."""
    args = (tuple(centre), tuple(half), yaw_rad, light, material)
    try:
        hash(args)
    except TypeError:  # e.g. lamps given as lists: nothing to share it by
        return list(_box_quads.__wrapped__(*args))
    return list(_box_quads(*args))


@lru_cache(maxsize=4096)
def _box_quads(
    centre: tuple[float, float, float],
    half: tuple[float, float, float],
    yaw_rad: float,
    light: SceneLight,
    material: str,
) -> tuple[Quad, ...]:
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
        corners = _rect(fc, normal, width, cz + hz, cz - hz)
        quads.append(Quad(corners, _shaded(tex, light.shade(corners.mean(0), normal)), normal))
    return tuple(quads)


def floor_and_walls(
    origin: tuple[float, float],
    size: tuple[float, float],
    z: float,
    light: SceneLight,
    wall_height_m: float = 4.0,
) -> list[Quad]:
    """The floor rectangle and four walls standing on its edges, facing inwards."""
    x0, y0 = origin
    sx, sy = size
    corners = np.array([[x0, y0 + sy, z], [x0 + sx, y0 + sy, z], [x0 + sx, y0, z], [x0, y0, z]])
    quads = [
        Quad(
            corners,
            _shaded(ap.floor_texture, light.shade(corners.mean(0), _Z)),
            _Z.copy(),
            kind="floor",
        )
    ]
    wall = ap.wall_texture
    for centre, normal, width in (
        ((x0 + sx, y0 + sy / 2), (-1.0, 0.0), sy),
        ((x0, y0 + sy / 2), (1.0, 0.0), sy),
        ((x0 + sx / 2, y0 + sy), (0.0, -1.0), sx),
        ((x0 + sx / 2, y0), (0.0, 1.0), sx),
    ):
        nrm = np.array([normal[0], normal[1], 0.0])
        corners = _rect(np.array(centre), nrm, width, z + wall_height_m, z)
        shade = light.shade(corners.mean(0), nrm)
        quads.append(Quad(corners, _shaded(wall, shade), nrm, kind="wall"))
    return quads


@dataclass
class Scene:
    """Everything the camera can see, as quads, plus the scene's static light."""

    quads: list[Quad]
    light: SceneLight = field(default_factory=SceneLight)

    def __post_init__(self) -> None:
        order = {"floor": 0, "wall": 1}
        self.background = sorted(
            (q for q in self.quads if q.kind in order), key=lambda q: order[q.kind]
        )
        self.objects = [q for q in self.quads if q.kind not in order]
        self.object_centres = np.array([q.centre for q in self.objects]).reshape(-1, 3)
        self.object_normals = np.array([q.normal for q in self.objects]).reshape(-1, 3)
        self.object_corners = np.array([q.corners for q in self.objects]).reshape(-1, 4, 3)

    @classmethod
    def build(
        cls,
        pallets: list[PalletSpec],
        *,
        boxes: Sequence[tuple] = (),
        floor: tuple[tuple[float, float], tuple[float, float], float] | None = (
            (-2.0, -6.0),
            (16.0, 12.0),
            0.0,
        ),
        light: SceneLight | None = None,
    ) -> Scene:
        """Scene from pallets, boxes ((centre), (half sizes), yaw[, material]) and a floor
        ((origin x, y), (size x, y), z) with walls on its edges (None: no floor, no walls)."""
        light = light or SceneLight()
        quads: list[Quad] = []
        if floor is not None:
            quads += floor_and_walls(floor[0], floor[1], floor[2], light)
        for box in boxes:
            quads += box_quads(*box[:3], light, *box[3:4])
        for p in pallets:
            quads += pallet_quads(p, light)
        return cls(quads, light)
