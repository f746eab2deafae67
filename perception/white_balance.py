"""White balance of the AI-deck's raw Bayer frames: the method of [study] (docs/references.md).

The raw sensor image looks green (twice as many green photosites, and their higher
sensitivity). Calibration: point the camera at a uniform white surface once, decode the frame,
drop the lowest and highest 0.05 % of each channel and derive one stretch factor per channel;
store the factors (``sensors.camera.white_balance`` in the rig) and multiply every later frame
by them (a lookup table per channel, clipped to 255).

Two factor rules (``method``):

- ``"white"`` (default): ``factor_c = 255 / hi_c`` with ``hi_c`` the 99.95th percentile of
  channel c: the white target becomes full-scale white in every channel. Robust for a frame
  that shows only the white target.
- ``"study"``: ``factor_c = 255 / (hi_c - lo_c)`` exactly as the study's
  ``colorBalanceStretch`` (Listing 5; ``lo_c`` = 0.05th percentile). It assumes the frame also
  shows dark parts (``lo_c`` near 0); on a uniform white frame it over-amplifies.

CLI::

    python -m perception.white_balance calibrate --rig rigs/sim.yaml [--image raw.png]

Without ``--image`` the white target is rendered through the simulated camera model
(:func:`render_white_target`, lit like the rig's world). The factors are printed and written
into the rig file's ``white_balance:`` line (the rest of the file is kept byte for byte).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from functools import lru_cache

import cv2
import numpy as np

PERCENT = 0.05  # per cent of each channel dropped at each end ([study])

Factors = tuple[float, float, float]


def decode_raw(raw: np.ndarray) -> np.ndarray:
    """Raw 8-bit Bayer frame (H, W) -> BGR (H, W, 3) with OpenCV's ``COLOR_BayerBG2BGR``.

    A frame that is already colour (H, W, 3) is returned unchanged.
    """
    if raw.ndim == 3:
        return raw
    return cv2.cvtColor(np.ascontiguousarray(raw, np.uint8), cv2.COLOR_BayerBG2BGR)


def calibrate(image: np.ndarray, percent: float = PERCENT, method: str = "white") -> Factors:
    """Per-channel (B, G, R) white-balance factors from a frame of a white target.

    ``image``: raw Bayer (H, W) or BGR (H, W, 3). See the module doc for ``method``.
    """
    bgr = decode_raw(image).astype(np.float32)
    factors = []
    for c in range(3):
        ch = bgr[:, :, c]
        lo, hi = np.percentile(ch, (percent, 100.0 - percent))
        span = hi - lo if method == "study" else hi
        if method not in ("white", "study"):
            raise ValueError(f"unknown white-balance method '{method}' (white, study)")
        factors.append(255.0 / max(float(span), 1.0))
    return (factors[0], factors[1], factors[2])


@lru_cache(maxsize=32)
def _lut(factors: Factors) -> np.ndarray:
    x = np.arange(256, dtype=np.float32)[:, None] * np.asarray(factors, np.float32)[None, :]
    return np.clip(x + 0.5, 0, 255).astype(np.uint8).reshape(256, 1, 3)


def apply_white_balance(bgr: np.ndarray, factors: Factors | list[float]) -> np.ndarray:
    """``bgr * factors`` per channel, clipped to 0..255 (one lookup table, ~0.1 ms)."""
    f = tuple(round(float(v), 6) for v in factors)
    if f == (1.0, 1.0, 1.0):
        return bgr
    return cv2.LUT(bgr, _lut(f))  # type: ignore[arg-type]


def preprocess(raw: np.ndarray, factors: Factors | list[float]) -> np.ndarray:
    """Raw Bayer frame -> white-balanced BGR: :func:`decode_raw` then the factors."""
    return apply_white_balance(decode_raw(raw), factors)


def render_white_target(
    rng: np.random.Generator | None = None,
    *,
    camera: object | None = None,
    colour_temperature_k: float = 4000.0,
    exposure: float = 0.85,
    gradient: float = 0.08,
) -> np.ndarray:
    """A raw frame of a uniform white sheet filling the view, through the simulated sensor
    (green cast, illuminant colour, vignetting, a light gradient, noise) for calibration in
    simulation. ``camera``: a :class:`perception.synth.CameraModel` (default AI-deck)."""
    from perception.synth.camera_model import CameraModel
    from perception.synth.render import Lighting, apply_sensor, illuminant_bgr

    cam = camera if isinstance(camera, CameraModel) else CameraModel()
    rng = rng or np.random.default_rng(0)
    white = np.full((cam.height, cam.width, 3), 235, np.uint8)
    lighting = Lighting(exposure=exposure, gradient=gradient, gradient_angle_rad=0.6)
    return apply_sensor(
        white, rng, lighting=lighting, illuminant=illuminant_bgr(colour_temperature_k)
    )


# ---------------------------------------------------------------------------- rig file edits
_WB_LINE = re.compile(r"^(?P<indent>\s*)white_balance:\s*(?P<value>\[[^\]]*\]|\S+)(?P<rest>.*)$")


def _block_end(lines: list[str], start: int) -> int:
    """Index after the last line of the mapping whose key is on line ``start``."""
    indent = len(lines[start]) - len(lines[start].lstrip())
    end = start + 1
    for i in range(start + 1, len(lines)):
        stripped = lines[i].strip()
        if not stripped or stripped.startswith("#"):
            continue
        if len(lines[i]) - len(lines[i].lstrip()) <= indent:
            break
        end = i + 1
    return end


def _find_key(lines: list[str], key: str, lo: int, hi: int, indent: int | None) -> int | None:
    pat = re.compile(rf"^(\s*){re.escape(key)}:(\s|$)")
    for i in range(lo, hi):
        m = pat.match(lines[i])
        if m and (indent is None or len(m.group(1)) == indent):
            return i
    return None


def write_rig_factors(text: str, factors: Factors) -> str:
    """Rig file text with ``sensors.camera.white_balance`` set to ``factors`` (the line is
    edited in place, keeping its comment; added to the camera section if missing)."""
    value = "[" + ", ".join(f"{v:.4f}" for v in factors) + "]"
    lines = text.splitlines(keepends=True)
    sensors = _find_key(lines, "sensors", 0, len(lines), 0)
    if sensors is None:
        raise ValueError("the rig file has no top-level sensors section")
    camera = _find_key(lines, "camera", sensors + 1, _block_end(lines, sensors), None)
    if camera is None:
        raise ValueError("the rig file has no sensors.camera section")
    end = _block_end(lines, camera)
    for i in range(camera + 1, end):
        m = _WB_LINE.match(lines[i].rstrip("\n"))
        if m:
            nl = "\n" if lines[i].endswith("\n") else ""
            lines[i] = f"{m['indent']}white_balance: {value}{m['rest']}{nl}"
            return "".join(lines)
    body = [ln for ln in lines[camera + 1 : end] if ln.strip() and not ln.strip().startswith("#")]
    cam_indent = len(lines[camera]) - len(lines[camera].lstrip())
    child = len(body[0]) - len(body[0].lstrip()) if body else cam_indent + 2
    if not lines[end - 1].endswith("\n"):
        lines[end - 1] += "\n"
    lines.insert(end, f"{' ' * child}white_balance: {value}  # B, G, R (white_balance calibrate)\n")
    return "".join(lines)


def _world_colour_temperature(rig_path: str, rig: dict) -> float:
    import yaml

    path = (rig.get("world") or {}).get("path")
    if not path:
        return 4000.0
    full = path if os.path.isabs(path) else os.path.join(os.path.dirname(rig_path), path)
    try:
        with open(full, encoding="utf-8") as fh:
            world = yaml.safe_load(fh) or {}
    except OSError:
        return 4000.0
    return float((world.get("lighting") or {}).get("colour_temperature_k", 4000.0))


def main(argv: list[str] | None = None) -> int:
    """``python -m perception.white_balance calibrate --rig RIG [--image RAW]``."""
    import yaml

    ap = argparse.ArgumentParser(prog="python -m perception.white_balance")
    sub = ap.add_subparsers(dest="cmd", required=True)
    cal = sub.add_parser("calibrate", help="compute factors from a white-target frame")
    cal.add_argument("--rig", required=True, help="rig file to write the factors into")
    cal.add_argument(
        "--image",
        help="raw Bayer (or BGR) image of a white target; default: "
        "render one through the simulated camera",
    )
    cal.add_argument("--method", choices=("white", "study"), default="white")
    cal.add_argument("--dry-run", action="store_true", help="print, do not write the rig")
    args = ap.parse_args(argv)
    with open(args.rig, encoding="utf-8") as fh:
        text = fh.read()
    rig = yaml.safe_load(text) or {}
    if args.image:
        img = cv2.imread(args.image, cv2.IMREAD_UNCHANGED)
        if img is None:
            print(f"error: cannot read image {args.image}", file=sys.stderr)
            return 2
    else:
        from perception.synth.camera_model import CameraModel

        cam = CameraModel.from_dict((rig.get("sensors") or {}).get("camera"))
        img = render_white_target(
            camera=cam, colour_temperature_k=_world_colour_temperature(args.rig, rig)
        )
    factors = calibrate(img, method=args.method)
    print("white balance factors (B, G, R): " + ", ".join(f"{v:.4f}" for v in factors))
    if not args.dry_run:
        new = write_rig_factors(text, factors)
        with open(args.rig, "w", encoding="utf-8") as fh:
            fh.write(new)
        print(f"written to {args.rig} (sensors.camera.white_balance)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
