"""Where is the pallet face? Block detections + camera poses -> a face line in the world.

The reactive scan (``nodes/reactive_scan.py``) needs the pallet's support-block row in world
coordinates: where its blocks are along the face, how far away the face is, which way it
faces and at what height the blocks are. This module turns detector boxes seen from known
camera poses into that estimate, with plain geometry and no drone code
(docs/reactive-scan.md explains the choices):

* **One box -> one ray, and maybe a depth.** The bearing of the box centre is precise (the
  pinhole model of :class:`perception.synth.camera_model.CameraModel`, with the camera's full
  attitude). Depth from the apparent block height (78 mm, [epal] in docs/references.md) is
  trusted only near the image centre (:data:`CENTRAL_PX`): the detector's boxes are about
  :data:`BOX_PAD_PX` taller than the block there, and several pixels taller near the sides.
* **The face plane** goes through the nearest central sightings; every ray is cut with it.
  Cuts far off the row's height are something else (:data:`ROW_Z_TOL_M`).
* **The facing** is the line through two or more blocks: triangulated from rays seen from
  places apart, or from size-depth when seen about as near; otherwise the prior's.
* **Which block is which**: the blocks are evenly spaced, so each seen block's index is
  known up to a shift; every shift that fits the mapped window and is not contradicted by
  frames that saw nothing where it puts a block is a hypothesis, and the scan covers them all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from perception.synth.camera_model import CameraModel, rotation_from_quaternion

BOX_PAD_PX = 1.5  # detector boxes are this much taller than the block (px, measured)
CLUSTER_GAP_M = 0.2  # sightings closer than this along the face belong to one block
EDGE_PX = 3.0  # a box this close to the top or bottom border is cut: no depth from it
SIDE_EDGE_PX = 10.0  # ... to a side border: its centre is not the block's (partial box)
MISS_MARGIN_PX = 30.0  # a predicted block this far inside the image should have been seen
MISS_RADIUS_PX = 30.0  # a detection this close to a predicted block explains it
MISS_RATIO = 0.7  # drop a hypothesis when this share of its predicted sightings is missing
MIN_PREDICTED = 3  # ... over at least this many frames
CENTRAL_PX = 80.0  # boxes this close to the image centre (columns) give a trusted depth
NEAR_BAND_M = 0.06  # the face distance comes from views at most this much farther than the nearest
ROW_Z_TOL_M = (
    0.07  # a sighting whose ray meets the face this far off the row height is not a block of it
)
MIN_TRI_RAYS = 6  # rays needed to triangulate a block
MAX_TRI_MISS_M = 0.02  # rays missing the triangulated point by more (rms) are not one block
MIN_TRI_SPREAD = 0.02  # mean sin^2 of the rays' spread (about 8 deg): enough to triangulate
PAIR_BAND_M = 0.12  # blocks that set the facing were seen at most this much farther apart
MIN_SIZED = 3  # central sightings a block needs before its depth from size sets the facing
REFIT_TURN_DEG = 25.0  # a refit may turn the face this much from the first estimate
MAX_FRAMES_CHECKED = 120  # the visibility test looks at this many latest frames


@dataclass(frozen=True)
class PalletModel:
    """The support-block row of a pallet side: block count, spacing and height (EPAL)."""

    blocks: int = 3
    spacing_m: float = 0.5275  # centre to centre along the face (1.2 m / 2 - 0.145 m / 2)
    block_height_m: float = 0.078

    def offsets(self) -> list[float]:
        """Along-face offsets of the block centres from the middle of the row."""
        mid = (self.blocks - 1) / 2.0
        return [(k - mid) * self.spacing_m for k in range(self.blocks)]


@dataclass(frozen=True)
class Sighting:
    """One detected block seen from one frame: its 3-D centre and where it was seen from."""

    point: tuple[float, float, float]  # block front-face centre, world frame (m)
    depth_m: float  # along the optical axis, from the box height
    frame: int  # index into the frames list of the estimate
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # camera position
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)  # unit ray to the box centre
    central: bool = True  # seen near the image centre: its depth is trusted


@dataclass(frozen=True)
class FrameView:
    """A frame the estimate used: camera pose and the box centres detected in it."""

    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    centres_px: tuple[tuple[float, float], ...]


@dataclass
class FaceEstimate:
    """The estimated block row: a line in the world plus where the blocks are on it.

    ``facing_rad`` is the drone yaw that looks square at the face; the scan moves along
    ``left`` (the drone's left), so blocks cross the image from left to right. Along-face
    coordinates ``s`` are measured along ``left`` from the world origin's projection.
    """

    facing_rad: float
    face_offset_m: float  # signed distance of the face plane along the facing direction
    z_m: float  # block centre height
    first_s: float  # along-face coordinate of the first block (earliest hypothesis)
    last_s: float  # of the last block (latest hypothesis)
    blocks_seen: int
    sightings: int
    hypotheses: int
    centre_s: float  # middle of the row, best hypothesis
    yaw_from_blocks: bool = False  # False: the face direction is the map's
    prior: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the mapped row centre it came from
    window_m: float = 0.45  # how far along the face from ``prior`` the row may be
    base_facing_rad: float = 0.0  # the first estimate's facing: refits stay near it
    seen_s: tuple[float, ...] = ()  # along-face positions of the blocks seen (this row)
    map_facing_rad: float | None = None  # the mapped face line's facing (through ``prior``)

    def saw_block_at(self, s: float, tol_m: float = 0.1) -> bool:
        """True if a block of the row was seen within ``tol_m`` of along-face ``s``."""
        return any(abs(c - s) <= tol_m for c in self.seen_s)

    def refit(self, tracker: FaceTracker) -> FaceEstimate | None:
        """A new fit with everything ``tracker`` saw, around the same mapped place (the
        height gate follows this estimate's height)."""
        px, py, _ = self.prior
        face = tracker.fit(
            self.facing_rad,
            (px, py, self.z_m),
            self.window_m,
            prior_from_blocks=self.yaw_from_blocks,
            search_centre_rad=self.base_facing_rad,
            max_turn_deg=REFIT_TURN_DEG,
        )
        if face is not None:
            face.base_facing_rad = self.base_facing_rad
            face.map_facing_rad = self.map_facing_rad
        return face

    @property
    def normal(self) -> tuple[float, float]:
        """Unit vector from the drone towards the face (the facing direction)."""
        return (math.cos(self.facing_rad), math.sin(self.facing_rad))

    @property
    def left(self) -> tuple[float, float]:
        """Unit vector along the face, to the drone's left (the scan direction)."""
        return (-math.sin(self.facing_rad), math.cos(self.facing_rad))

    def point(self, s: float, standoff_m: float) -> tuple[float, float, float]:
        """The world point at along-face ``s``, ``standoff_m`` in front of the face."""
        nx, ny = self.normal
        lx, ly = self.left
        d = self.face_offset_m - standoff_m
        return (nx * d + lx * s, ny * d + ly * s, self.z_m)

    def standoff_of(self, x: float, y: float) -> float:
        """Distance of (x, y) in front of the face."""
        nx, ny = self.normal
        return self.face_offset_m - (nx * x + ny * y)

    def along(self, x: float, y: float) -> float:
        """Along-face coordinate of (x, y)."""
        lx, ly = self.left
        return lx * x + ly * y

    def describe(self) -> str:
        """One line for the run log."""
        cx, cy, cz = self.point(self.centre_s, 0.0)
        how = "from the blocks" if self.yaw_from_blocks else "from the map"
        return (
            f"face centre ({cx:.3f}, {cy:.3f}, {cz:.3f}), facing "
            f"{math.degrees(self.facing_rad):.1f} deg ({how}), {self.blocks_seen} blocks "
            f"from {self.sightings} sightings, {self.hypotheses} placement hypotheses"
        )

    def as_dict(self) -> dict:
        """JSON-friendly figures (the tick log and summary.json)."""
        cx, cy, cz = self.point(self.centre_s, 0.0)
        return {
            "centre_m": [round(cx, 4), round(cy, 4), round(cz, 4)],
            "facing_deg": round(math.degrees(self.facing_rad), 2),
            "blocks_seen": self.blocks_seen,
            "sightings": self.sightings,
            "hypotheses": self.hypotheses,
            "yaw_from_blocks": self.yaw_from_blocks,
        }

    def __repr__(self) -> str:
        return f"FaceEstimate({self.describe()})"


def _rotation(q: Sequence[float]) -> np.ndarray:
    return rotation_from_quaternion(*(float(v) for v in q))


@dataclass
class FaceTracker:
    """Collects sightings frame by frame and fits :class:`FaceEstimate` on demand."""

    camera: CameraModel = field(default_factory=CameraModel)
    pallet: PalletModel = field(default_factory=PalletModel)
    frames: list[FrameView] = field(default_factory=list)
    sightings: list[Sighting] = field(default_factory=list)

    def add_frame(
        self,
        position: Sequence[float],
        quaternion: Sequence[float],
        boxes: Sequence[Sequence[float]],
    ) -> int:
        """Add one frame (camera pose, boxes ``x1, y1, x2, y2[, score]``); return the
        number of blocks it contributed a 3-D point for."""
        cam = self.camera
        rot = _rotation(quaternion)
        pos = np.asarray(position, dtype=float)
        idx = len(self.frames)
        centres = tuple((0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3])) for b in boxes)
        self.frames.append(
            FrameView(tuple(pos), tuple(float(v) for v in quaternion), centres)  # type: ignore[arg-type]
        )
        mount = math.radians(cam.mount_pitch_deg)
        added = 0
        for b in boxes:
            x1, y1, x2, y2 = (float(v) for v in b[:4])
            if y1 <= EDGE_PX or y2 >= cam.height - 1 - EDGE_PX:
                continue  # cut at the top or bottom: height (hence depth) unknown
            if x1 <= SIDE_EDGE_PX or x2 >= cam.width - 1 - SIDE_EDGE_PX:
                continue  # partly out of view: the centre is not the block's
            h = (y2 - y1) - BOX_PAD_PX
            if h <= 2.0:
                continue
            depth = cam.fx * self.pallet.block_height_m / h
            u, v = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
            ray = np.array([1.0, -(u - cam.cx) / cam.fx, -(v - cam.cy) / cam.fx])
            if mount:  # camera tilted down by the mount: rotate the body-frame ray
                c, s = math.cos(mount), math.sin(mount)
                ray = np.array([c * ray[0] + s * ray[2], ray[1], -s * ray[0] + c * ray[2]])
            world_ray = rot @ ray
            p = pos + world_ray * depth
            unit = world_ray / float(np.linalg.norm(world_ray))
            self.sightings.append(
                Sighting(
                    (float(p[0]), float(p[1]), float(p[2])),
                    depth,
                    idx,
                    (float(pos[0]), float(pos[1]), float(pos[2])),
                    (float(unit[0]), float(unit[1]), float(unit[2])),
                    abs(u - cam.cx) <= CENTRAL_PX,
                )
            )
            added += 1
        return added

    def fit(
        self,
        prior_facing_rad: float,
        prior_centre: Sequence[float],
        window_m: float = 0.45,
        height_window_m: float = 0.15,
        prior_from_blocks: bool = False,
        search_centre_rad: float | None = None,
        max_turn_deg: float = 35.0,
        depth_window_m: float | None = None,
        height_above_m: float | None = None,
    ) -> FaceEstimate | None:
        """The face from the sightings so far (None without a usable one).

        ``prior_facing_rad`` and ``prior_centre`` (x, y, z of the row centre) are where the
        map (or an earlier estimate) puts the row: sightings more than ``height_window_m``
        below it or ``height_above_m`` above it (default: ``height_window_m``; a pallet
        stands on its beam or above it, never below) are other things (a pallet on the
        floor below, a beam), and row
        placements whose centre is more than ``window_m`` along the face from it are not
        considered (the neighbours' blocks). ``prior_from_blocks``: the prior facing came
        from an earlier fit. ``depth_window_m``: a face nearer or farther than this from the
        prior along its normal is something else (the wall behind an empty rack place, the
        back of the rack): no face (None: the default does not check).

        How: bearings are precise to a pixel; depth from the box height only near the image
        centre (off-centre boxes are a few pixels too tall) and best from near. The facing
        is the line through the blocks' best central sightings (each block's nearest views)
        when two blocks have some, kept within ``max_turn_deg`` of ``search_centre_rad``
        (default: the prior facing); else the prior's. The face plane goes through the
        nearest central sightings; every sighting's ray is cut with it, and the cuts,
        grouped into blocks, place the row.
        """
        if not self.sightings:
            return None
        pts = np.array([s.point for s in self.sightings])
        above = height_window_m if height_above_m is None else height_above_m
        dz = pts[:, 2] - float(prior_centre[2])
        keep = (dz >= -height_window_m) & (dz <= above)
        if not keep.any():
            return None
        sel = [s for s, k in zip(self.sightings, keep, strict=True) if k]
        pts = pts[keep]
        orig = np.array([s.origin for s in sel])
        dirs = np.array([s.direction for s in sel])
        depth = np.array([s.depth_m for s in sel])
        central = np.array([s.central for s in sel])
        if not central.any():
            central = np.ones(len(sel), dtype=bool)
        # Off the row: a cut far above or below the row's height (the row height is the
        # median cut of the central sightings) is something else, e.g. a pallet on the floor.
        n0 = np.array([math.cos(prior_facing_rad), math.sin(prior_facing_rad)])
        _, x0 = _cut(pts, orig, dirs, depth, central, n0)
        on_row = np.abs(x0[:, 2] - float(np.median(x0[central, 2]))) <= ROW_Z_TOL_M
        if not on_row.any():
            return None
        pts, orig, dirs, depth, central = (a[on_row] for a in (pts, orig, dirs, depth, central))
        if not central.any():
            central = np.ones(len(pts), dtype=bool)
        centre = prior_facing_rad if search_centre_rad is None else search_centre_rad
        span = math.radians(max_turn_deg)

        facing, from_blocks = prior_facing_rad, False
        for _ in range(3):
            normal = np.array([math.cos(facing), math.sin(facing)])
            left = np.array([-math.sin(facing), math.cos(facing)])
            offset, x = _cut(pts, orig, dirs, depth, central, normal)
            clusters = _clusters(x[:, :2] @ left)
            # Per block, a position to draw the line through: triangulated from its rays when
            # they were seen from places far enough apart (no size bias), else its nearest
            # central sightings (depth from size: only blocks seen about as near as the
            # nearest, since the bias grows with distance, and in MIN_SIZED views at least:
            # a box a pixel or two off at 20 px moves a block 5-10 cm, and a line through a
            # triangulated block and one glimpsed twice turned the face 12 deg, bringing a
            # scan 17 cm too near).
            tri: list[tuple[np.ndarray, float]] = []
            sized: list[tuple[np.ndarray, float, float]] = []
            for c in clusters:
                p = _triangulate(orig[c, :2], dirs[c, :2])
                if p is not None:
                    tri.append((p, float(len(c))))
                    continue
                cc = c[central[c]]
                if len(cc):
                    near = depth[cc] <= float(np.percentile(depth[cc], 10)) + NEAR_BAND_M
                    b = cc[near]
                    if len(b) < MIN_SIZED:
                        continue
                    sized.append(
                        (np.median(pts[b, :2], axis=0), float(len(b)), float(np.median(depth[b])))
                    )
            if sized:
                nearest = min(d for _, _, d in sized)
                sized = [t for t in sized if t[2] <= nearest + PAIR_BAND_M]
            anchors = tri + [(p, wt) for p, wt, _ in sized]
            if len(anchors) < 2:
                break
            cents = np.array([p for p, _ in anchors])
            cw = np.array([wt for _, wt in anchors])
            new = _line_facing(cents, cw, facing)
            turn = math.remainder(new - centre, 2 * math.pi)
            new = centre + max(-span, min(span, turn))
            from_blocks = True
            done = abs(math.remainder(new - facing, 2 * math.pi)) < 1e-4
            facing = math.remainder(new, 2 * math.pi)
            if done:
                break
        rays = (pts, orig, dirs, depth, central)
        est = self._place_row(facing, rays, prior_centre, window_m, depth_window_m)
        if from_blocks and est is not None and est.blocks_seen < 2:
            # a facing drawn through the blocks must rest on two blocks of the row it
            # places: through one and something else (a neighbour's block, a glimpse) it
            # turned a face 21 deg and sent the scan out of the geofence
            from_blocks = False
            est = self._place_row(prior_facing_rad, rays, prior_centre, window_m, depth_window_m)
        if est is not None:
            est.yaw_from_blocks = from_blocks or prior_from_blocks
        return est

    def _place_row(
        self,
        facing: float,
        rays: tuple[np.ndarray, ...],
        prior_centre: Sequence[float],
        window_m: float,
        depth_window_m: float | None,
    ) -> FaceEstimate | None:
        """The row on the face plane of ``facing`` through the nearest central sightings:
        every sighting's ray cut with it, the cuts grouped into blocks (:meth:`fit`)."""
        pts, orig, dirs, depth, central = rays
        prior_xy = np.asarray(prior_centre[:2], dtype=float)
        normal = np.array([math.cos(facing), math.sin(facing)])
        left = np.array([-math.sin(facing), math.cos(facing)])
        offset, x = _cut(pts, orig, dirs, depth, central, normal)
        if depth_window_m is not None and abs(offset - float(prior_xy @ normal)) > depth_window_m:
            return None
        along = x[:, :2] @ left
        clusters = _clusters(along)
        w = 1.0 / np.maximum(depth, 0.1) ** 2
        cs = [float(np.average(along[c], weights=w[c])) for c in clusters]
        prior_s = float(prior_xy @ left)
        probe = FaceEstimate(facing, offset, float(np.median(x[:, 2])), 0, 0, 0, 0, 0, 0)
        kept, members = self._rows(cs, prior_s, window_m, probe)
        if not kept:
            return None
        idx = np.concatenate([clusters[i] for i in members])
        z = float(np.median(x[idx, 2]))
        est = FaceEstimate(facing, offset, z, 0.0, 0.0, len(members), len(pts), 0, 0.0)
        est.prior = (float(prior_centre[0]), float(prior_centre[1]), float(prior_centre[2]))
        est.window_m = window_m
        est.base_facing_rad = facing
        est.seen_s = tuple(cs[i] for i in members)
        offs = self.pallet.offsets()
        est.first_s = min(kept) + offs[0]
        est.last_s = max(kept) + offs[-1]
        est.centre_s = min(kept, key=lambda c: abs(c - prior_s))
        est.hypotheses = len(kept)
        return est

    def _rows(
        self, cs: list[float], prior_s: float, window_m: float, probe: FaceEstimate
    ) -> tuple[list[float], list[int]]:
        """Row placements (centre along the face) that explain the most seen blocks, lie
        within ``window_m`` of ``prior_s`` and are not contradicted by frames that saw
        nothing where they put a block; and the clusters the nearest of them explains."""
        tol = 0.4 * CLUSTER_GAP_M
        offs = self.pallet.offsets()

        def members_of(centre: float) -> list[int]:
            return [i for i, c in enumerate(cs) if min(abs(c - centre - o) for o in offs) <= tol]

        scored: list[tuple[int, float, list[int]]] = []
        for c0 in cs:
            for o0 in offs:
                centre = c0 - o0
                if abs(centre - prior_s) > window_m:
                    continue
                for _ in range(2):  # refine the centre on the blocks it explains
                    m = members_of(centre)
                    fits = [
                        cs[i] - min(offs, key=lambda o, c=cs[i]: abs(c - centre - o)) for i in m
                    ]
                    centre = float(np.mean(fits)) if fits else centre
                m = members_of(centre)
                if m and abs(centre - prior_s) <= window_m:
                    if all(abs(centre - k) > 0.05 for _, k, _ in scored):
                        scored.append((len(m), centre, m))
        if not scored:
            return [], []
        best_n = max(n for n, _, _ in scored)
        top = [(c, m) for n, c, m in scored if n == best_n]
        ok = [(c, m) for c, m in top if not self._contradicted(c, probe)]
        if not ok and best_n < 2:
            # One block whose pallet's other blocks were in view, often, and never seen: no
            # evidence of a pallet here (a neighbour's block at the edge, a look-alike on
            # the wall behind an empty rack place).
            return [], []
        ok = ok or top
        ok.sort(key=lambda cm: abs(cm[0] - prior_s))
        return [c for c, _ in ok], ok[0][1]

    def _contradicted(self, centre_s: float, est: FaceEstimate) -> bool:
        """True when the row centred at ``centre_s`` puts blocks in view, often, where
        nothing was detected."""
        cam = self.camera
        predicted = missing = 0
        for k_off in self.pallet.offsets():
            p = np.array(est.point(centre_s + k_off, 0.0))
            for fv in self.frames[-MAX_FRAMES_CHECKED:]:
                uv = _project(cam, fv, p)
                if uv is None:
                    continue
                u, v = uv
                m = MISS_MARGIN_PX
                if not (m <= u <= cam.width - 1 - m and m <= v <= cam.height - 1 - m):
                    continue
                predicted += 1
                if not any(math.hypot(u - cu, v - cv) < MISS_RADIUS_PX for cu, cv in fv.centres_px):
                    missing += 1
        return predicted >= MIN_PREDICTED and missing >= MISS_RATIO * predicted


def _project(cam: CameraModel, fv: FrameView, p: np.ndarray) -> tuple[float, float] | None:
    rot = _rotation(fv.quaternion)
    body = rot.T @ (p - np.asarray(fv.position))
    mount = math.radians(cam.mount_pitch_deg)
    if mount:
        c, s = math.cos(mount), math.sin(mount)
        body = np.array([c * body[0] - s * body[2], body[1], s * body[0] + c * body[2]])
    if body[0] <= 0.05:
        return None
    return (cam.cx - cam.fx * body[1] / body[0], cam.cy - cam.fx * body[2] / body[0])


def _cut(
    pts: np.ndarray,
    orig: np.ndarray,
    dirs: np.ndarray,
    depth: np.ndarray,
    central: np.ndarray,
    normal: np.ndarray,
) -> tuple[float, np.ndarray]:
    """The face plane with this ``normal`` through the nearest central sightings (its
    offset along the normal), and every sighting's ray cut with it (a ray nearly parallel
    to the plane keeps its size-depth point)."""
    trusted = central & (depth <= float(np.percentile(depth[central], 10)) + NEAR_BAND_M)
    d = float(np.median(pts[trusted, :2] @ normal))
    den = dirs[:, :2] @ normal
    ok = den > 0.05
    t = (d - orig[:, :2] @ normal) / np.where(ok, den, 1.0)
    return d, np.where(ok[:, None], orig + t[:, None] * dirs, pts)


def _triangulate(orig: np.ndarray, dirs: np.ndarray) -> np.ndarray | None:
    """The 2-D point nearest to every ray (``orig`` + t ``dirs``), or None when the rays
    are too nearly parallel to tell depth (seen from about one place) or do not meet (they
    are not all one block's)."""
    if len(orig) < MIN_TRI_RAYS:
        return None
    u = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    proj = np.eye(2)[None, :, :] - u[:, :, None] * u[:, None, :]
    a = proj.sum(axis=0)
    b = np.einsum("nij,nj->i", proj, orig)
    if float(np.linalg.eigvalsh(a)[0]) / len(orig) < MIN_TRI_SPREAD:
        return None
    p = np.linalg.solve(a, b)
    # Rays of one block meet; rays of two blocks grouped together (a wrong plane) do not.
    miss = np.einsum("nij,nj->ni", proj, p[None, :] - orig)
    if float(np.sqrt(np.mean(np.sum(miss**2, axis=1)))) > MAX_TRI_MISS_M:
        return None
    return p


def _clusters(s: np.ndarray) -> list[np.ndarray]:
    order = np.argsort(s)
    groups: list[list[int]] = [[int(order[0])]]
    for a, b in zip(order[:-1], order[1:], strict=True):
        if s[b] - s[a] > CLUSTER_GAP_M:
            groups.append([])
        groups[-1].append(int(b))
    return [np.array(g) for g in groups]


def _line_facing(cents: np.ndarray, weights: np.ndarray, prior: float) -> float:
    """Facing (normal direction, towards the face) of the weighted line through ``cents``,
    on the side of ``prior``."""
    mean = np.average(cents, axis=0, weights=weights)
    d = cents - mean
    cov = (d * weights[:, None]).T @ d
    vals, vecs = np.linalg.eigh(cov)
    direction = vecs[:, int(np.argmax(vals))]
    facing = math.atan2(direction[1], direction[0]) - math.pi / 2.0
    if math.cos(facing - prior) < 0:
        facing += math.pi
    return math.remainder(facing, 2 * math.pi)
