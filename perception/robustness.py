"""End-to-end robustness evaluation: detector and identification under changed conditions.

A *condition* changes one thing about how a pallet side looks or is seen: its wood tone
or paint (the pallet looks like that when enrolled and when scanned), what happened to it
after enrolment (stains, dust, occlusion, ...), the view (distance, yaw) or the camera
(exposure, colour temperature, blur, noise, the AI-deck's Bayer JPEG, resolution).

For each condition :func:`evaluate_condition` enrols sides from clean views at the scan
stand-off (0.4 m, square, nominal light) through the same path as the mission (detector,
crop along the box nearest the image centre, embedder, gallery), then scans every enrolled
side again and as many never-enrolled sides under the condition and reports:

* detector: precision and recall over every frame (IoU >= 0.5; blocks less than half in
  view are "don't care") and the share of sides whose three blocks were all found;
* identification: right, wrong, unknown for enrolled sides, and non-enrolled sides
  accepted as an enrolled one.

Identities (prefix ``rb``) and texture seeds (9000 and up) are never used in training.
``bench/robustness.py`` runs the table; see docs/performance.md. The mission's path on rendered
views (:class:`Pipeline`, :class:`SideScan`) is in :mod:`perception.robustness_pipeline`.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from perception.gallery import Gallery, Match
from perception.gallery_match import TEXTURE_TOP_RANK
from perception.gallery_views import png_bytes
from perception.robustness_pipeline import STANDOFF_M, Pipeline, SideScan
from perception.synth.ageing import Ageing, progressive
from perception.synth.appearance import SideStyle
from perception.synth.dataset import identity_names
from perception.synth.scene import SceneLight
from perception.synth.views import ViewConditions
from perception.verify import VerifyThresholds, agreement

#: identity prefix and first texture seed of the bench's pallets (never trained on)
PREFIX, SEED0 = "rb", 9000


@dataclass(frozen=True)
class Condition:
    """One row of the robustness table.

    ``look``: :class:`SideStyle` keywords the side has at enrolment and at the scan;
    ``ageing``: changes between the two (scan only); ``distance_m``, ``yaw_deg``: the
    scan's view; ``view``: its light, optics and sensor; ``light``: the scene's lamps at
    the scan (None: the enrolment's, :data:`perception.synth.dataset.NOMINAL_LIGHT`; the
    faces' relief shows another shading under other lamps).
    """

    group: str
    name: str
    look: tuple[tuple[str, Any], ...] = ()
    ageing: Ageing | None = None
    distance_m: float = STANDOFF_M
    yaw_deg: float = 0.0
    view: ViewConditions = field(default_factory=ViewConditions)
    light: SceneLight | None = None


#: lamp layouts of the "relit" rows (the enrolment's: one lamp 1.5 m in front, 4 m high)
RELIT: dict[str, SceneLight] = {
    "relit (lamp left)": SceneLight(0.6, (((-1.2, 2.5, 2.5), 1.0),), 4000.0),
    "relit (lamp right, low)": SceneLight(0.6, (((-1.8, -2.0, 0.9), 1.0),), 4000.0),
    "relit (two lamps, less ambient)": SceneLight(
        0.45, (((-0.8, 1.0, 3.0), 0.8), ((-0.8, -1.5, 3.0), 0.8)), 4000.0
    ),
}
#: grain contrast of the "faint grain" rows
FAINT_GRAIN = 0.2


def _c(group: str, name: str, **kw: Any) -> Condition:
    look = kw.pop("look", {})
    return Condition(group, name, tuple(sorted(look.items())), **kw)


def conditions() -> list[Condition]:
    """Every row of the table (the issue's rows and the camera conditions)."""
    out = [_c("reference", "clean")]
    for tone in ("fresh", "pale", "yellowed", "orange", "brown", "grey", "silver", "dark", "wet"):
        out.append(_c("wood", tone, look={"wood": tone}))
    out.append(_c("wood", "20 % saturation", look={"saturation": 0.2}))
    for paint in ("blue", "red", "green", "yellow", "black", "white"):
        out.append(_c("paint", paint, look={"paint": paint}))
    out.append(_c("paint", "blue blocks only", look={"paint": "blue", "paint_parts": "blocks"}))
    out.append(_c("faces", "other generator (plank)", look={"generator": "plank"}))
    out.append(_c("faces", "stencil marking", look={"marking": "stencil"}))
    out.append(_c("faces", "paper labels", look={"marking": "label"}))
    faint = {"grain": FAINT_GRAIN}
    out.append(_c("faces", "faint grain", look=faint))
    out.append(_c("faces", "faint grain, grey", look={**faint, "wood": "grey"}))
    out.append(_c("faces", "faint grain, new stains 12%", look=faint, ageing=Ageing(stains=0.12)))
    for f in (0.07, 0.12, 0.2):
        out.append(_c("ageing", f"new stains {f:.0%}", ageing=Ageing(stains=f)))
    for f in (0.12, 0.25):
        out.append(_c("ageing", f"dust {f:.0%}", ageing=Ageing(dust=f)))
    for occ in ("strap", "film", "overhang", "shape"):
        out.append(
            _c("ageing", f"30 % occluded ({occ})", ageing=Ageing(occlusion=0.3, occluder=occ))
        )
    out.append(_c("ageing", "moisture 0.8", ageing=Ageing(moisture=0.8)))
    out.append(
        _c(
            "ageing",
            "scratches, chips, new stamp",
            ageing=Ageing(scratches=3, chips=2, new_stamp=True),
        )
    )
    out.append(_c("ageing", "stamps faded", ageing=Ageing(fade_stamps=0.8)))
    out.append(_c("ageing", "gradual ageing 1.0", ageing=Ageing.gradual(1.0)))
    for d in (0.25, 0.6, 0.8, 1.0, 1.2):
        out.append(_c("distance", f"{d:.2f} m", distance_m=d))
    for y in (15, 30):
        out.append(_c("yaw", f"{y} deg", yaw_deg=float(y)))
    for name, light in RELIT.items():
        out.append(_c("relit", name, light=light))
    out.append(
        _c("relit", "relit (lamp left), faint grain", look=faint, light=RELIT["relit (lamp left)"])
    )
    for name, view in (
        ("exposure 0.5", ViewConditions(exposure=0.5)),
        ("exposure 2.0", ViewConditions(exposure=2.0)),
        ("2700 K", ViewConditions(colour_temperature_k=2700.0)),
        ("6500 K", ViewConditions(colour_temperature_k=6500.0)),
        ("motion blur 6 px", ViewConditions(motion_px=6.0)),
        ("defocus 1.5 px", ViewConditions(defocus_px=1.5)),
        ("downscale 2x", ViewConditions(downscale=2.0)),
        ("downscale 3x", ViewConditions(downscale=3.0)),
        ("noise 10 DN", ViewConditions(noise_dn=10.0)),
        ("noise 20 DN", ViewConditions(noise_dn=20.0)),
        ("Bayer JPEG q50", ViewConditions(jpeg_quality=50)),
        ("Bayer JPEG q20", ViewConditions(jpeg_quality=20)),
        ("Bayer JPEG q10", ViewConditions(jpeg_quality=10)),
    ):
        out.append(_c("camera", name, view=view))
    return out


def side_style(index: int, cond: Condition, aged: bool) -> SideStyle:
    """The bench's style of side ``index`` under ``cond`` (``aged``: at the later scan)."""
    style = SideStyle(texture_seed=SEED0 + index, **dict(cond.look))
    if aged and cond.ageing is not None:
        style = replace(style, ageing=replace(cond.ageing, seed=SEED0 + index))
    return style


def enrol_gallery(
    pipe: Pipeline, names: list[str], cond: Condition, seed: int
) -> tuple[Gallery, int, list[SideScan]]:
    """An in-memory gallery of ``names`` enrolled from clean views (the condition's look,
    no ageing); returns it, the number enrolled and every enrolment scan."""
    g = Gallery.create(":memory:", pipe.embedder.model_version, pipe.embedder.dim)
    g.set_thresholds(pipe.embedder.thresholds)
    rng = np.random.default_rng([seed, 1])
    scans = []
    for i, name in enumerate(names):
        scan = pipe.scan(
            name, side_style(i, cond, aged=False), rng, view=ViewConditions(), jitter=False
        )
        scans.append(scan)
        if scan.complete:
            vec, vis = pipe.describe(scan.crops)  # type: ignore[arg-type]
            pngs = [png_bytes(c) for c in scan.crops]  # type: ignore[arg-type]
            g.enrol(name, vec, pngs, visibility=vis)
    return g, len(g), scans


def _match(pipe: Pipeline, g: Gallery, vec: np.ndarray, vis: np.ndarray | None, crops: list) -> Any:
    if len(g) == 0:  # nothing could be enrolled (the detector found no blocks)
        return Match("unknown", "", float("inf"), None, None, 0.0, False, "empty gallery")
    return g.match(
        vec,
        visibility=vis,
        crops=crops if pipe.texture else None,
        verify_thresholds=pipe.verify_thresholds,
    )


def evaluate_condition(
    pipe: Pipeline,
    cond: Condition,
    enrolled: int,
    unknown: int,
    seed: int = 0,
    gallery: tuple[Gallery, int] | None = None,
    log: Callable[[str], None] | None = None,
) -> dict:
    """Detector and identification figures of one condition (see the module doc).

    ``gallery``: a gallery already enrolled for this look (reused between conditions that
    change only the scan), with its enrolled count.
    """
    names = identity_names(enrolled, PREFIX)
    others = identity_names(unknown, PREFIX, start=enrolled // 2 + 1000)
    if gallery is None:
        g, n_enrolled, _ = enrol_gallery(pipe, names, cond, seed)
    else:
        g, n_enrolled = gallery
    rng = np.random.default_rng([seed, 2, zlib.crc32(f"{cond.group}/{cond.name}".encode())])
    res = {
        "right": 0,
        "wrong": 0,
        "unknown": 0,
        "sides": 0,
        "all3": 0,
        "tp": 0,
        "fp": 0,
        "gt": 0,
        "accepted": 0,
        "non_enrolled": 0,
        "wrong_ids": [],
    }
    offset = enrolled
    for idx, name in list(enumerate(names)) + [(offset + i, n) for i, n in enumerate(others)]:
        known = idx < offset
        scan = pipe.scan(
            name,
            side_style(idx, cond, aged=True),
            rng,
            cond.distance_m,
            cond.yaw_deg,
            cond.view if cond.view != ViewConditions() else None,
            light=cond.light,
        )
        res["sides"] += 1
        res["all3"] += int(scan.found == 3)
        res["tp"] += scan.tp
        res["fp"] += scan.fp
        res["gt"] += scan.gt
        answer = "unknown"
        if scan.complete:
            vec, vis = pipe.describe(scan.crops)  # type: ignore[arg-type]
            m = _match(pipe, g, vec, vis, scan.crops)
            answer = m.pallet_id
            if pipe.matches is not None:
                pipe.matches.append((name, known, m))
            if pipe.records is not None:
                pipe.records.append(scan_record(cond, name, known, m))
        elif pipe.records is not None:  # a block not found: unknown under any thresholds
            pipe.records.append(
                {"group": cond.group, "row": cond.name, "name": name, "enrolled": known}
                | dict.fromkeys(("texture_id", "texture_z", "texture_margin"))
                | {"embedding": "unknown", "agreement": None, "texture_rank": None}
            )
        if known:
            key = "right" if answer == name else ("unknown" if answer == "unknown" else "wrong")
            res[key] += 1
            if key == "wrong":
                res["wrong_ids"].append(f"{name}->{answer}")
        else:
            res["non_enrolled"] += 1
            res["accepted"] += int(answer != "unknown")
    known_n = len(names)
    res.update(
        group=cond.group,
        name=cond.name,
        enrolled=n_enrolled,
        known=known_n,
        precision=res["tp"] / max(1, res["tp"] + res["fp"]),
        recall=res["tp"] / max(1, res["gt"]),
        all3_rate=res["all3"] / max(1, res["sides"]),
        right_rate=res["right"] / max(1, known_n),
    )
    if log:
        log(format_row(res))
    return res


def ageing_sequence(
    pipe: Pipeline,
    sides: int,
    steps: int = 10,
    update: bool = True,
    seed: int = 0,
    log: Callable[[str], None] | None = None,
) -> dict:
    """Sides enrolled clean, then scanned ``steps`` times while they age slowly
    (:func:`perception.synth.ageing.progressive`); with ``update`` the gallery adds
    confident scans as views (:meth:`perception.gallery.Gallery.update`). Per step: right,
    wrong, unknown; and the views added."""
    names = identity_names(sides, PREFIX, start=5000)
    cond = Condition("ageing", "sequence")
    g, _, _ = enrol_gallery(pipe, names, cond, seed)
    rng = np.random.default_rng([seed, 3])
    out = {"update": update, "sides": sides, "steps": [], "views_added": 0}
    for k in range(1, steps + 1):
        row = {"step": k, "right": 0, "wrong": 0, "unknown": 0}
        for i, name in enumerate(names):
            style = replace(side_style(i, cond, False), ageing=progressive(k, steps, SEED0 + i))
            scan = pipe.scan(name, style, rng)
            answer = "unknown"
            if scan.complete:
                vec, vis = pipe.describe(scan.crops)  # type: ignore[arg-type]
                m = _match(pipe, g, vec, vis, scan.crops)
                answer = m.pallet_id
                if update and g.update(m, vec, vis, run=f"step {k}", crops=scan.crops).update:
                    out["views_added"] += 1
            key = "right" if answer == name else ("unknown" if answer == "unknown" else "wrong")
            row[key] += 1
        out["steps"].append(row)
        if log:
            log(
                f"ageing step {k:>2} ({'with' if update else 'without'} updates): right "
                f"{row['right']}/{sides} wrong {row['wrong']} unknown {row['unknown']}"
            )
    return out


def similar_never_absorbed(
    pipe: Pipeline,
    sides: int,
    scans: int = 10,
    seed: int = 0,
    log: Callable[[str], None] | None = None,
) -> dict:
    """Sides enrolled clean; then, for each, another pallet that looks alike (same pallet id
    and side, so the same wood colour, material and stamp, but other textures: another
    texture seed) scanned ``scans`` times with gallery updates on. Counts the look-alike's
    answers that named the enrolled side and the views it added to it (both should be 0)."""
    names = identity_names(sides, PREFIX, start=7000)
    cond = Condition("ageing", "look-alike")
    g, _, _ = enrol_gallery(pipe, names, cond, seed)
    rng = np.random.default_rng([seed, 4])
    res = {"sides": sides, "scans": 0, "named_enrolled": 0, "views_added": 0, "unknown": 0}
    for k in range(scans):
        for i, name in enumerate(names):
            twin = SideStyle(texture_seed=SEED0 + 50_000 + i)
            scan = pipe.scan(name, twin, rng)
            res["scans"] += 1
            if not scan.complete:
                res["unknown"] += 1
                continue
            vec, vis = pipe.describe(scan.crops)  # type: ignore[arg-type]
            m = _match(pipe, g, vec, vis, scan.crops)
            res["named_enrolled"] += int(m.pallet_id == name)
            res["unknown"] += int(m.pallet_id == "unknown")
            upd = g.update(m, vec, vis, run=f"look-alike scan {k}", crops=scan.crops)
            res["views_added"] += int(upd.update)
    if log:
        log(
            f"look-alikes: {res['scans']} scans, named as the enrolled side {res['named_enrolled']}, "
            f"views added {res['views_added']}, unknown {res['unknown']}"
        )
    return res


def scan_record(cond: Condition, name: str, known: bool, m: Match) -> dict:
    """What :func:`decide` needs of one scan's match made with verification that never
    accepts nor vetoes (the embedding's own answer and the texture's figures)."""
    ids = [r[0] for r in m.ranking]
    tid = m.texture_id
    return {
        "group": cond.group,
        "row": cond.name,
        "name": name,
        "enrolled": known,
        "embedding": m.pallet_id,
        "texture_id": tid,
        "texture_z": m.texture_z,
        "texture_margin": m.texture_margin,
        "agreement": agreement(m.texture_blocks) if m.texture_blocks else None,
        "texture_rank": ids.index(tid) if tid in ids else None,
    }


def decide(rec: dict, th: VerifyThresholds) -> tuple[str, bool]:
    """The answer :meth:`Gallery.match` gives a recorded scan under ``th`` (the rule of
    docs/perception.md, "Texture verification"), and whether it is certain: when the
    texture prefers another side than the embedding's answer, that answer's own ``z`` is
    not recorded, only that it is below the best one (the veto is then uncertain when the
    best ``z`` reaches ``veto_z``)."""
    emb, tid, tz = rec["embedding"], rec["texture_id"], rec["texture_z"]
    if tid is None or tz is None:
        return emb, True
    rank = rec["texture_rank"]
    near = rank is not None and rank < TEXTURE_TOP_RANK
    agree = rec["agreement"] if rec["agreement"] is not None else float("-inf")
    if tz >= th.accept_z and rec["texture_margin"] >= th.margin_z and agree >= th.block_z and near:
        return (tid, True) if emb in ("unknown", tid) else ("unknown", True)
    if emb == "unknown":
        return emb, True
    if tid == emb:
        return (emb, True) if tz >= th.veto_z else ("unknown", True)
    return ("unknown", True) if tz < th.veto_z else (emb, False)


def format_row(r: dict) -> str:
    """One line of the table."""
    return (
        f"{r['group']:<9} {r['name']:<30} det P {r['precision']:.3f} R {r['recall']:.3f} "
        f"all3 {100 * r['all3_rate']:5.1f} %  enrolled {r['enrolled']}/{r['known']}  "
        f"right {r['right']}/{r['known']} ({100 * r['right_rate']:.1f} %) wrong {r['wrong']} "
        f"unknown {r['unknown']}  non-enrolled accepted {r['accepted']}/{r['non_enrolled']}"
    )


__all__ = [
    "Condition",
    "FAINT_GRAIN",
    "Pipeline",
    "RELIT",
    "SideScan",
    "ageing_sequence",
    "conditions",
    "decide",
    "enrol_gallery",
    "evaluate_condition",
    "format_row",
    "scan_record",
    "side_style",
    "similar_never_absorbed",
]
