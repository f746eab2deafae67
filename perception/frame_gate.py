"""Which camera frames are worth detecting: skip a frame whose view has barely changed.

At 15 frames/s the view hardly moves between two frames while the drone hovers to look, or
scans along a pallet at 7 cm/s (about 2 pixels a frame at 0.4 m): the next frame shows the
same blocks, a pixel or two further on. Rendering and detecting it costs as much as a frame
that shows something new, and changes little: the block sequencer keeps the best crop of a
block over the dozens of frames it crosses the left half of the image in, and the face
tracker's sightings of a still view repeat each other. With the defaults (8 px, 0.3 s) the
scan is detected every fourth frame (8 px apart: a block crosses the sequencer's 60-pixel
window in seven or eight of them), a hover every fifth frame (0.33 s), and the approach to
the scan start, zooming in on the pallet, every frame.

A :class:`FrameGate` lets a frame through when the view has changed by at least
``min_view_change_px`` since the last frame it let through (:func:`view_change_px`: the
largest image displacement of the centre and the four corners of the view, taken as points
``view_depth_m`` in front of the camera, from the camera model and the two poses; rotation
included), or when ``max_frame_gap_s`` has passed since then. The first frame always passes.
A ``min_view_change_px`` of 0 lets every frame through.

The gate is a pure function of the frames' times and poses, so a run stays deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from perception.synth.camera_model import CameraModel, CameraPose, world_to_optical


@dataclass(frozen=True)
class FrameGateParams:
    """When a frame is worth processing (see the module doc).

    Attributes:
        min_view_change_px: process a frame once the view moved at least this many pixels
            since the last processed frame; 0: process every frame.
        max_frame_gap_s: process a frame anyway once this long has passed since the last.
        view_depth_m: distance in front of the camera at which the view change is measured
            (nearer things move more in the image for the same camera motion).
    """

    min_view_change_px: float = 8.0
    max_frame_gap_s: float = 0.3
    view_depth_m: float = 0.4

    def validate(self) -> None:
        """Raise ValueError for a negative change or gap, or a depth that is not positive."""
        if not self.min_view_change_px >= 0.0:
            raise ValueError(f"min_view_change_px must be >= 0, got {self.min_view_change_px}")
        if not self.max_frame_gap_s >= 0.0:
            raise ValueError(f"max_frame_gap_s must be >= 0, got {self.max_frame_gap_s}")
        if not self.view_depth_m > 0.0:
            raise ValueError(f"view_depth_m must be > 0, got {self.view_depth_m}")


def _view_pixels(camera: CameraModel) -> np.ndarray:
    """The image centre and the four corner pixels (5, 2)."""
    w, h = camera.width - 1.0, camera.height - 1.0
    return np.array([[camera.cx, camera.cy], [0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])


def view_points(camera: CameraModel, pose: CameraPose, depth_m: float) -> np.ndarray:
    """World points (5, 3) seen at the image centre and corners ``depth_m`` in front of the
    camera at ``pose``."""
    R, t = world_to_optical(camera, pose)
    uv = _view_pixels(camera)
    optical = np.column_stack(
        [
            (uv[:, 0] - camera.cx) * depth_m / camera.fx,
            (uv[:, 1] - camera.cy) * depth_m / camera.fx,
            np.full(len(uv), depth_m),
        ]
    )
    return (optical - t) @ R  # R is orthonormal: R^T (p_c - t), row-wise


def view_change_px(camera: CameraModel, a: CameraPose, b: CameraPose, depth_m: float) -> float:
    """How far (pixels) the view moved from pose ``a`` to pose ``b``: the largest image
    displacement of the points seen at the centre and corners of ``a``'s image at
    ``depth_m``; infinite if any of them is behind camera ``b``."""
    return _change(camera, view_points(camera, a, depth_m), b, depth_m)


def _change(camera: CameraModel, points: np.ndarray, b: CameraPose, depth_m: float) -> float:
    R, t = world_to_optical(camera, b)
    pc = points @ R.T + t
    z = pc[:, 2]
    if (z < 0.05 * depth_m).any():
        return math.inf
    uv = _view_pixels(camera)
    u = camera.fx * pc[:, 0] / z + camera.cx
    v = camera.fx * pc[:, 1] / z + camera.cy
    return float(np.hypot(u - uv[:, 0], v - uv[:, 1]).max())


class FrameGate:
    """Decides frame by frame whether a frame is worth processing (see the module doc).

    >>> gate = FrameGate(CameraModel(), FrameGateParams())
    >>> still = CameraPose.from_yaw(0.0, 0.0, 1.0, 0.0)
    >>> gate.wants(0.0, still), gate.wants(0.067, still), gate.wants(0.3, still)
    (True, False, True)
    """

    def __init__(self, camera: CameraModel, params: FrameGateParams | None = None) -> None:
        self.camera = camera
        self.params = params or FrameGateParams()
        self.params.validate()
        self.passed = 0  # frames let through
        self.skipped = 0  # frames skipped
        self._last_t: float | None = None
        self._points: np.ndarray | None = None  # view points of the last frame let through

    def wants(self, t_s: float, pose: CameraPose | None) -> bool:
        """True if the frame captured at ``t_s`` from ``pose`` should be processed (it then
        becomes the reference for the next frames); None: no pose known, always True."""
        p = self.params
        if p.min_view_change_px <= 0.0 or pose is None:
            self.passed += 1
            self._last_t, self._points = t_s, None
            return True
        take = (
            self._points is None
            or self._last_t is None
            or t_s - self._last_t >= p.max_frame_gap_s - 1e-9
            or _change(self.camera, self._points, pose, p.view_depth_m) >= p.min_view_change_px
        )
        if not take:
            self.skipped += 1
            return False
        self.passed += 1
        self._last_t = t_s
        self._points = view_points(self.camera, pose, p.view_depth_m)
        return True


__all__ = ["FrameGate", "FrameGateParams", "view_change_px", "view_points"]
