"""The range of real pallet looks: wood tones, paints, marking styles, face generators.

Real pallets are fresh (pale yellow), yellowed, orange heartwood, weathered grey or silver,
dark with dirt or wet; pooled rental pallets are painted (blue, red; some others), either
whole or on the blocks only; markings are burnt brands, ink stamps, stencils or paper
labels. This module names those looks and draws random ones:

* :data:`WOOD_TONES`: named base colours as (hue deg, saturation, value), the range the
  world files' ``wood`` key and the robustness bench ask for;
* :data:`PAINTS`: named paint colours (BGR);
* :func:`random_look`: a random look over the whole range (training data), deterministic
  in the generator;
* :data:`FACE_GENERATORS`: the procedural families that draw a block face. ``wood`` is the
  default; ``flake``, ``noise`` and ``pattern`` are domain randomisation for training (a
  detector or embedder that must not depend on one generator's wood); ``plank``, another
  wood model, is held out of training and used only to test generalisation.

Everything is plain data and pure functions of a ``numpy.random.Generator``.
"""

from __future__ import annotations

import colorsys

import numpy as np

#: name -> (hue deg, saturation 0..1, value 0..1) of the wood's base (early-wood) colour
WOOD_TONES: dict[str, tuple[float, float, float]] = {
    "fresh": (34.0, 0.43, 0.81),  # new spruce/pine (the project's original colour)
    "pale": (42.0, 0.28, 0.88),  # kiln-dried, very light
    "yellowed": (40.0, 0.56, 0.76),  # months of light
    "orange": (24.0, 0.55, 0.72),  # larch, pine heartwood
    "brown": (26.0, 0.50, 0.50),  # heat-treated, hardwood
    "grey": (35.0, 0.09, 0.60),  # weathered outdoors
    "silver": (30.0, 0.04, 0.74),  # strongly weathered, bleached
    "dark": (30.0, 0.32, 0.34),  # old, dirty
    "wet": (27.0, 0.55, 0.44),  # soaked: darker and more saturated
}

#: name -> BGR colour of a paint
PAINTS: dict[str, tuple[float, float, float]] = {
    "blue": (178.0, 88.0, 10.0),  # pooled rental pallets (CHEP-like)
    "red": (48.0, 28.0, 196.0),  # pooled rental pallets (LPR-like)
    "green": (62.0, 122.0, 40.0),
    "yellow": (30.0, 190.0, 228.0),
    "black": (38.0, 38.0, 40.0),
    "white": (222.0, 224.0, 220.0),
    "grey": (128.0, 126.0, 122.0),
    "brown": (40.0, 72.0, 118.0),
}

#: how the side is marked: burnt brand, ink stamp, painted stencil, paper label, nothing
MARKINGS = ("burnt", "ink", "stencil", "label", "none")

#: block-face generators; ``plank`` is never used for training (held out, see module doc)
FACE_GENERATORS = ("wood", "flake", "noise", "pattern", "plank")
TRAINING_GENERATORS = ("wood", "flake", "noise", "pattern")

#: which parts of a side a paint covers
PAINT_PARTS = ("all", "blocks")


def hsv_to_bgr(hue_deg: float, saturation: float, value: float) -> tuple[float, float, float]:
    """BGR (0..255) of a colour given as hue in degrees, saturation and value in 0..1."""
    r, g, b = colorsys.hsv_to_rgb(
        (hue_deg % 360.0) / 360.0, float(np.clip(saturation, 0, 1)), float(np.clip(value, 0, 1))
    )
    return (b * 255.0, g * 255.0, r * 255.0)


def bgr_to_hsv(bgr: tuple[float, float, float]) -> tuple[float, float, float]:
    """(hue deg, saturation, value) of a BGR colour (0..255)."""
    b, g, r = (float(np.clip(v, 0, 255)) / 255.0 for v in bgr)
    h, s, v = colorsys.rgb_to_hsv(r, g, b)
    return (h * 360.0, s, v)


def wood_colour(
    tone: str | tuple[float, float, float], saturation_scale: float = 1.0
) -> tuple[float, float, float]:
    """Base BGR colour of a wood tone (a :data:`WOOD_TONES` name or an HSV triple),
    its saturation multiplied by ``saturation_scale``.

    Raises:
        ValueError: an unknown tone name (the message lists the known ones).
    """
    if isinstance(tone, str):
        if tone not in WOOD_TONES:
            raise ValueError(f"unknown wood tone {tone!r} (known: {', '.join(WOOD_TONES)})")
        tone = WOOD_TONES[tone]
    h, s, v = tone
    return hsv_to_bgr(h, s * saturation_scale, v)


def paint_colour(paint: str | tuple[float, float, float]) -> tuple[float, float, float]:
    """BGR colour of a :data:`PAINTS` name or a BGR triple.

    Raises:
        ValueError: an unknown paint name (the message lists the known ones).
    """
    if isinstance(paint, str):
        if paint not in PAINTS:
            raise ValueError(f"unknown paint {paint!r} (known: {', '.join(PAINTS)})")
        return PAINTS[paint]
    return tuple(float(v) for v in paint)  # type: ignore[return-value]


def random_wood_hsv(rng: np.random.Generator) -> tuple[float, float, float]:
    """A wood base colour anywhere in the real range: from bleached grey to dark and wet,
    pale to orange (hue 18..46 deg, saturation 0..0.66, value 0.32..0.92)."""
    kind = rng.random()
    if kind < 0.3:  # weathered: low saturation, any brightness
        return (rng.uniform(20, 45), rng.uniform(0.0, 0.2), rng.uniform(0.35, 0.85))
    if kind < 0.45:  # dark, dirty or wet
        return (rng.uniform(18, 40), rng.uniform(0.2, 0.66), rng.uniform(0.32, 0.5))
    return (rng.uniform(20, 46), rng.uniform(0.2, 0.66), rng.uniform(0.5, 0.92))


def random_look(
    rng: np.random.Generator, generators: tuple[str, ...] = TRAINING_GENERATORS
) -> dict:
    """Random look of one pallet: ``wood_hsv``, ``paint`` (None, a name or a BGR triple),
    ``paint_parts``, ``marking`` and ``generator`` (drawn from ``generators``), as keyword
    arguments of :class:`perception.synth.appearance.SideStyle`."""
    look: dict = {"wood_hsv": tuple(round(float(v), 4) for v in random_wood_hsv(rng))}
    if rng.random() < 0.25:
        if rng.random() < 0.6:
            look["paint"] = str(rng.choice(list(PAINTS)))
        else:  # any colour, any brightness
            bgr = hsv_to_bgr(rng.uniform(0, 360), rng.uniform(0.2, 1.0), rng.uniform(0.2, 0.95))
            look["paint"] = tuple(round(float(v), 1) for v in bgr)
        look["paint_parts"] = "blocks" if rng.random() < 0.35 else "all"
    look["marking"] = str(rng.choice(MARKINGS, p=[0.35, 0.25, 0.15, 0.1, 0.15]))
    weights = np.array([0.7 if g == "wood" else 0.1 for g in generators], float)
    look["generator"] = str(rng.choice(list(generators), p=weights / weights.sum()))
    return look


__all__ = [
    "FACE_GENERATORS",
    "MARKINGS",
    "PAINTS",
    "PAINT_PARTS",
    "TRAINING_GENERATORS",
    "WOOD_TONES",
    "bgr_to_hsv",
    "hsv_to_bgr",
    "paint_colour",
    "random_look",
    "random_wood_hsv",
    "wood_colour",
]
