"""Marks on pallet wood: burnt stamps and brands, nail heads, cracks, marker scribbles, dirt.

Each function draws into a float32 BGR image (0..255) in place, driven by a
``numpy.random.Generator``, so a seeded generator always makes the same marks. Used by
:mod:`perception.synth.appearance`.
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.synth.woodgen import blend, smooth_noise

Rng = np.random.Generator

_REGIONS = ("NW", "BY", "NI", "HE", "SN", "BW", "RP", "PL", "CZ", "FR")
_FONTS = (cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_TRIPLEX)
#: every Hershey face OpenCV has, for the varied marking styles
ALL_FONTS = (
    cv2.FONT_HERSHEY_SIMPLEX,
    cv2.FONT_HERSHEY_PLAIN,
    cv2.FONT_HERSHEY_DUPLEX,
    cv2.FONT_HERSHEY_COMPLEX,
    cv2.FONT_HERSHEY_TRIPLEX,
    cv2.FONT_HERSHEY_COMPLEX_SMALL,
    cv2.FONT_HERSHEY_SCRIPT_SIMPLEX,
    cv2.FONT_HERSHEY_SCRIPT_COMPLEX,
)
_INK = ((34, 40, 52), (28, 30, 36), (45, 55, 75))  # burnt brown-black, black ink, brown


def _text(
    mask: np.ndarray,
    text: str,
    centre: tuple[float, float],
    height_px: float,
    font: int,
    thickness: int,
) -> None:
    """Draw ``text`` (255 into a uint8 mask) centred at ``centre``, cap height ~``height_px``."""
    (tw, th), _ = cv2.getTextSize(text, font, 1.0, thickness)
    scale = height_px / max(th, 1)
    (tw, th), _ = cv2.getTextSize(text, font, scale, thickness)
    org = (int(round(centre[0] - tw / 2)), int(round(centre[1] + th / 2)))
    cv2.putText(mask, text, org, font, scale, 255, thickness, cv2.LINE_AA)


def _apply_ink(
    img: np.ndarray,
    mask: np.ndarray,
    rng: Rng,
    wear: float,
    angle_deg: float,
    centre: tuple[float, float],
    ink: tuple[float, float, float],
    strength: float,
) -> None:
    """Rotate ``mask`` about ``centre``, erode it with patchy noise (wear) and ink ``img``
    (only inside the mask's bounding box)."""
    h, w = mask.shape
    rot = cv2.getRotationMatrix2D(centre, angle_deg, 1.0)
    mask = cv2.warpAffine(mask, rot, (w, h), flags=cv2.INTER_LINEAR)
    x, y, bw, bh = cv2.boundingRect(mask)
    if bw == 0 or bh == 0:
        return
    x0, y0 = max(x - 2, 0), max(y - 2, 0)
    x1, y1 = min(x + bw + 2, w), min(y + bh + 2, h)
    sub = mask[y0:y1, x0:x1].astype(np.float32) / 255.0
    sh, sw = sub.shape
    patch = smooth_noise(rng, sh, sw, max(sh // 10, 2), max(sw // 10, 2))
    patch += 0.6 * rng.standard_normal((sh, sw), dtype=np.float32)
    keep = np.clip((patch + 1.6 - 2.2 * wear) * 0.8, 0.0, 1.0)
    sub = cv2.GaussianBlur(sub * keep, (3, 3), 0.7)
    blend(img[y0:y1, x0:x1], np.clip(sub * strength, 0.0, 1.0), ink)


def _font(rng: Rng, varied: bool) -> int:
    """A Hershey font: the three brand faces, or (``varied``) any face, sometimes italic."""
    if not varied:
        return _FONTS[int(rng.integers(len(_FONTS)))]
    font = ALL_FONTS[int(rng.integers(len(ALL_FONTS)))]
    return font | (cv2.FONT_ITALIC if rng.random() < 0.25 else 0)


def stamp_block(
    img: np.ndarray,
    rng: Rng,
    block: int,
    stamp: str,
    wear: float,
    ink: tuple[float, float, float] | None = None,
    varied: bool = False,
) -> None:
    """Brand a block face: corner blocks (0, 2) an oval logo, the middle block (1) the IPPC
    phytosanitary mark with region, licence number and "HT", plus a date code. ``ink``:
    the colour (default: burnt brown-black, black or brown ink); ``varied``: any font."""
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    cx = w * (0.5 + rng.uniform(-0.1, 0.1))
    cy = h * (0.5 + rng.uniform(-0.1, 0.1))
    font = _font(rng, varied)
    thick = max(1, round(h / 60 * rng.uniform(0.8, 1.4)))
    if block != 1:
        ax, ay = w * rng.uniform(0.28, 0.36), h * rng.uniform(0.25, 0.32)
        cv2.ellipse(
            mask, (int(cx), int(cy)), (int(ax), int(ay)), 0, 0, 360, 255, max(1, thick), cv2.LINE_AA
        )
        _text(mask, stamp, (cx, cy), ay * rng.uniform(0.8, 1.0), font, thick + 1)
    else:
        bw, bh = w * rng.uniform(0.55, 0.7), h * rng.uniform(0.45, 0.6)
        x0, y0 = int(cx - bw / 2), int(cy - bh / 2)
        cv2.rectangle(mask, (x0, y0), (int(x0 + bw), int(y0 + bh)), 255, thick, cv2.LINE_AA)
        div = int(x0 + bw * 0.3)
        cv2.line(mask, (div, y0), (div, int(y0 + bh)), 255, thick, cv2.LINE_AA)
        # Wheat ear: a stem with pairs of slanted grains.
        sx = (x0 + div) // 2
        cv2.line(mask, (sx, int(y0 + bh * 0.15)), (sx, int(y0 + bh * 0.88)), 255, thick)
        for k in range(4):
            gy = int(y0 + bh * (0.22 + 0.14 * k))
            for sgn in (-1, 1):
                cv2.line(mask, (sx, gy + 5), (sx + sgn * int(bw * 0.08), gy), 255, thick)
        region = _REGIONS[int(rng.integers(len(_REGIONS)))]
        code = (
            f"{int(rng.integers(0, 10**4)):04d}"
            if rng.random() < 0.5
            else str(int(rng.integers(10**4, 10**5)))
        )
        tx = (div + x0 + bw) / 2
        lines = (f"DE-{region}" if region not in ("PL", "CZ", "FR") else region, code, "HT")
        for i, line in enumerate(lines):
            _text(mask, line, (tx, y0 + bh * (0.22 + 0.3 * i)), bh * 0.17, _FONTS[1], 1)
        if stamp == "EUR":
            _text(
                mask,
                ("DB", "SNCF", "OBB")[int(rng.integers(3))],
                (cx, y0 - h * 0.12),
                h * 0.1,
                font,
                1,
            )
    drawn = _INK[int(rng.integers(len(_INK)))]
    ink = ink or drawn
    _apply_ink(img, mask, rng, wear, rng.uniform(-5.0, 5.0), (cx, cy), ink, rng.uniform(0.65, 0.95))
    if block == 1 or rng.random() < 0.35:  # date / batch code somewhere else on the face
        mask = np.zeros((h, w), np.uint8)
        code = f"{int(rng.integers(0, 30)):02d} {int(rng.integers(1, 13))}"
        if rng.random() < 0.5:
            code += f"-{int(rng.integers(1, 10))}"
        dx = w * rng.choice([0.17, 0.83]) + rng.uniform(-0.06, 0.06) * w
        dy = h * rng.choice([0.15, 0.87])
        _text(mask, code, (dx, dy), h * 0.09, _FONTS[1], 1)
        _apply_ink(img, mask, rng, wear, rng.uniform(-8, 8), (dx, dy), ink, 0.8)


def control_clip(img: np.ndarray, rng: Rng) -> None:
    """The metal quality-control staple of EPAL middle blocks (a small bright bar)."""
    h, w = img.shape[:2]
    x = int(w * rng.uniform(0.12, 0.88))
    y = int(h * rng.uniform(0.12, 0.88))
    lw, lh = int(w * 0.07), max(3, int(h * 0.04))
    cv2.rectangle(img, (x - lw, y - lh), (x + lw, y + lh), (70, 72, 78), -1)
    cv2.rectangle(img, (x - lw + 1, y - lh + 1), (x + lw - 1, y - lh + 2), (165, 170, 175), -1)


def nails(
    img: np.ndarray, rng: Rng, n: int, wear: float, rows: tuple[float, float] = (0.1, 0.9)
) -> None:
    """``n`` nail heads (grey discs with a highlight and a rust halo) at random places."""
    h, w = img.shape[:2]
    r = max(2, int(round(h * 0.035)))
    for _ in range(n):
        x = int(rng.uniform(0.08, 0.92) * w)
        y = int(rng.uniform(*rows) * h)
        m = 4 * r  # rust halo drawn in a local patch
        y0, y1, x0, x1 = max(y - m, 0), min(y + m + 1, h), max(x - m, 0), min(x + m + 1, w)
        halo = np.zeros((y1 - y0, x1 - x0), np.float32)
        cv2.circle(halo, (x - x0, y - y0), int(r * rng.uniform(1.6, 2.6)), 1.0, -1, cv2.LINE_AA)
        halo = cv2.GaussianBlur(halo, (0, 0), r * 0.7)
        blend(img[y0:y1, x0:x1], halo * rng.uniform(0.25, 0.5) * (0.5 + wear), (38, 62, 105))
        grey = rng.uniform(70, 115)
        cv2.circle(img, (x, y), r, (grey, grey + 2, grey + 5), -1, cv2.LINE_AA)
        cv2.circle(img, (x, y), r, (grey * 0.5,) * 3, 1, cv2.LINE_AA)
        cv2.circle(img, (x - r // 3, y - r // 3), max(1, r // 3), (grey + 55,) * 3, -1)


def cracks(img: np.ndarray, rng: Rng, n: int) -> None:
    """``n`` cracks: thin dark random walks, mostly along the grain (x), from an edge."""
    h, w = img.shape[:2]
    for _ in range(n):
        x = float(rng.choice([0.0, w - 1.0]))
        y = rng.uniform(0.15, 0.85) * h
        step = 1.0 if x == 0.0 else -1.0
        pts = [(x, y)]
        for _ in range(int(rng.uniform(0.15, 0.7) * w / 4)):
            x += step * 4.0
            y += rng.normal(0.0, 0.8)
            pts.append((x, y))
        poly = np.array(pts, np.int32).reshape(-1, 1, 2)
        dark = float(rng.uniform(25, 45))
        cv2.polylines(
            img, [poly], False, (dark, dark + 3, dark + 8), int(rng.integers(1, 3)), cv2.LINE_AA
        )


def scribble(img: np.ndarray, rng: Rng) -> None:
    """A marker scribble (a number, a cross or an arrow) or a torn label remnant."""
    h, w = img.shape[:2]
    x, y = rng.uniform(0.15, 0.75) * w, rng.uniform(0.25, 0.8) * h
    if rng.random() < 0.35:
        lw, lh = w * rng.uniform(0.12, 0.25), h * rng.uniform(0.15, 0.3)
        pts = np.array(
            [
                [x, y],
                [x + lw, y + rng.uniform(-3, 3)],
                [x + lw * 0.9, y + lh],
                [x + rng.uniform(-3, 3), y + lh * rng.uniform(0.6, 1.0)],
            ],
            np.int32,
        )
        paper = float(rng.uniform(200, 235))
        cv2.fillConvexPoly(img, pts, (paper * rng.uniform(0.75, 1.0), paper, paper), cv2.LINE_AA)
        return
    colour = ((140, 60, 30), (30, 30, 150), (25, 25, 25), (40, 120, 40))[int(rng.integers(4))]
    text = (str(int(rng.integers(1, 100))), "X", "OK", "B", "->")[int(rng.integers(5))]
    mask = np.zeros((h, w), np.uint8)
    _text(mask, text, (x, y), h * rng.uniform(0.15, 0.3), cv2.FONT_HERSHEY_SCRIPT_SIMPLEX, 2)
    blend(img, mask.astype(np.float32) / 255.0 * rng.uniform(0.5, 0.85), colour)


def dirt_and_wear(img: np.ndarray, rng: Rng, wear: float) -> None:
    """Weathering (greying), soft dirt patches, grime towards the bottom, specks, worn edges."""
    h, w = img.shape[:2]
    grey = img.mean(axis=2, keepdims=True) * np.array([0.98, 1.0, 1.0], np.float32)
    img *= 1.0 - 0.25 * wear
    img += 0.25 * wear * grey
    patches = np.clip(smooth_noise(rng, h, w, max(h // 25, 2), max(w // 25, 2)) - 0.6, 0, 1)
    grime = np.clip(np.linspace(-0.4, 1.0, h, dtype=np.float32), 0, 1)[:, None] ** 2
    alpha = np.clip((0.35 * patches + 0.25 * grime) * (0.3 + 0.6 * wear), 0.0, 0.6)
    blend(img, alpha, (52, 60, 68))
    specks = (rng.random((h, w), dtype=np.float32) < 0.0012 * (0.3 + wear)).astype(np.float32)
    specks = cv2.GaussianBlur(specks, (3, 3), 0.8) * 2.5
    blend(img, np.clip(specks, 0, 0.8), (35, 38, 42))
    edge = np.ones((h, w), np.float32)
    e = max(2, int(min(h, w) * 0.04))
    edge[:e, :] = edge[-e:, :] = 0.0
    edge[:, :e] = edge[:, -e:] = 0.0
    edge = cv2.GaussianBlur(edge, (0, 0), e)
    blend(img, (1.0 - edge) * (0.2 + 0.4 * wear), (40, 46, 55))
    for _ in range(int(rng.poisson(1.0 + 3.0 * wear))):  # chipped corners and edges
        x = int(rng.choice([rng.uniform(0, w), rng.choice([0, w - 1])]))
        y = int(rng.choice([0, h - 1])) if rng.random() < 0.6 else int(rng.uniform(0, h))
        ax, ay = int(rng.uniform(3, 10)), int(rng.uniform(2, 6))
        shade = float(rng.uniform(45, 80))
        cv2.ellipse(
            img,
            (x, y),
            (ax, ay),
            rng.uniform(0, 180),
            0,
            360,
            (shade, shade * 1.1, shade * 1.25),
            -1,
            cv2.LINE_AA,
        )


def ink_text(
    img: np.ndarray,
    rng: Rng,
    text: str,
    centre: tuple[float, float],
    height_px: float,
    *,
    boxed: bool = False,
    ink: tuple[float, float, float] | None = None,
) -> np.ndarray:
    """Stamp ``text`` (optionally in a box) in ink at ``centre``; returns the ink's alpha."""
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    thick = max(1, round(height_px / 9))
    _text(mask, text, centre, height_px, _font(rng, True), thick)
    if boxed:
        x, y, bw, bh = cv2.boundingRect(mask)
        pad = max(2, int(height_px * 0.3))
        cv2.rectangle(mask, (x - pad, y - pad), (x + bw + pad, y + bh + pad), 255, thick)
    ink = ink or ((20, 20, 24), (120, 40, 30), (30, 30, 140), (25, 90, 30))[int(rng.integers(4))]
    before = img.copy()
    _apply_ink(img, mask, rng, 0.2, rng.uniform(-8, 8), centre, ink, rng.uniform(0.7, 0.95))
    return np.clip(np.abs(img - before).max(axis=2) / 60.0, 0, 1).astype(np.float32)


def stencil(img: np.ndarray, rng: Rng, text: str, colour: tuple[float, float, float]) -> None:
    """Painted stencil letters across a face (the bridges of the stencil leave gaps)."""
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    font = ALL_FONTS[int(rng.choice([0, 2, 3, 4]))]
    _text(
        mask,
        text,
        (w * rng.uniform(0.4, 0.6), h * rng.uniform(0.4, 0.6)),
        h * rng.uniform(0.3, 0.45),
        font,
        max(2, h // 18),
    )
    bridge = max(1, w // 90)
    for x in range(int(rng.integers(3, 9)), w, int(rng.integers(9, 16))):
        mask[:, x : x + bridge] = 0  # stencil bridges
    alpha = cv2.GaussianBlur(mask.astype(np.float32) / 255.0, (3, 3), 0.8)
    patch = np.clip(0.7 + 0.5 * smooth_noise(rng, h, w, 4, 8), 0, 1)  # uneven spray
    blend(img, alpha * patch * rng.uniform(0.75, 0.95), colour)


def label(img: np.ndarray, rng: Rng) -> None:
    """A paper label with a barcode and a line of text, somewhere on the face."""
    h, w = img.shape[:2]
    lw, lh = int(w * rng.uniform(0.3, 0.55)), int(h * rng.uniform(0.3, 0.55))
    x0, y0 = int(rng.uniform(0.03, 0.95 - lw / w) * w), int(rng.uniform(0.05, 0.95 - lh / h) * h)
    paper = float(rng.uniform(205, 240))
    tint = (paper * rng.uniform(0.85, 1.0), paper, paper * rng.uniform(0.95, 1.0))
    cv2.rectangle(img, (x0, y0), (x0 + lw, y0 + lh), tint, -1)
    bars_h = int(lh * 0.55)
    x = x0 + max(2, lw // 12)
    while x < x0 + lw - max(2, lw // 12):
        bw = int(rng.integers(1, 4))
        if rng.random() < 0.55:
            cv2.rectangle(
                img, (x, y0 + lh // 8), (x + bw - 1, y0 + lh // 8 + bars_h), (20, 20, 20), -1
            )
        x += bw
    mask = np.zeros((h, w), np.uint8)
    code = f"{int(rng.integers(10**5, 10**6))}"
    _text(mask, code, (x0 + lw / 2, y0 + lh * 0.85), lh * 0.16, cv2.FONT_HERSHEY_SIMPLEX, 1)
    blend(img, mask.astype(np.float32) / 255.0 * 0.9, (25, 25, 25))
    if rng.random() < 0.5:  # torn or weathered corner
        cv2.circle(
            img,
            (x0 + lw, y0),
            int(min(lw, lh) * rng.uniform(0.2, 0.5)),
            tuple(float(v) for v in img[min(y0 + lh, h - 1), min(x0 + lw, w - 1)]),
            -1,
        )


def paint_over(img: np.ndarray, rng: Rng, colour: tuple[float, float, float], wear: float) -> None:
    """Paint a face ``colour``: the grain shows faintly through, the paint is worn off at
    the edges and in patches (more with ``wear``), where the wood shows."""
    h, w = img.shape[:2]
    lum = img.mean(axis=2)
    rel = lum / max(float(lum.mean()), 1.0)
    painted = np.asarray(colour, np.float32)[None, None, :] * (0.82 + 0.18 * rel)[..., None]
    painted *= (1.0 + 0.04 * smooth_noise(rng, h, w, 3, 5))[..., None]
    worn = np.clip(smooth_noise(rng, h, w, max(h // 20, 2), max(w // 20, 2)) - 1.4 + wear, 0, 1)
    edge = np.zeros((h, w), np.float32)
    e = max(2, int(min(h, w) * 0.05))
    edge[:e] = edge[-e:] = 1.0
    edge[:, :e] = edge[:, -e:] = 1.0
    edge *= np.clip(rng.random((h, w), dtype=np.float32) * (0.4 + wear), 0, 1)
    keep_wood = np.clip(np.maximum(worn * 2.0, edge), 0, 1)[..., None]
    img[:] = painted * (1 - keep_wood) + img * keep_wood
