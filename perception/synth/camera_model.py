"""Pinhole model of the AI-deck camera and the camera pose in the world.

World frame: x forward from take-off, y left, z up (metres). The camera sits at the drone's
position and looks along the drone's body x axis (optionally tilted by ``mount_pitch_deg``,
positive = down). Image: column u to the right, row v down, origin at the top-left pixel
centre; intrinsics from the horizontal field of view (square pixels, centred principal point):
``fx = fy = (width / 2) / tan(fov / 2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# Body (x fwd, y left, z up) -> optical (X right, Y down, Z forward).
_BODY_TO_OPTICAL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class CameraModel:
    """AI-deck camera: 324 x 244 pixels streamed, ~87 deg horizontal field of view (approx.)."""

    width: int = 324
    height: int = 244
    fov_deg: float = 87.0
    mount_pitch_deg: float = 0.0

    @property
    def fx(self) -> float:
        """Focal length in pixels (also fy)."""
        return (self.width / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def cx(self) -> float:
        """Principal point column."""
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        """Principal point row."""
        return (self.height - 1) / 2.0

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view (deg)."""
        return math.degrees(2.0 * math.atan((self.height / 2.0) / self.fx))

    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        f = self.fx
        return np.array([[f, 0.0, self.cx], [0.0, f, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_dict(cls, camera: dict | None) -> CameraModel:
        """From a rig's ``sensors.camera`` mapping (``fov_deg``, optional size and tilt)."""
        camera = camera or {}
        return cls(
            int(camera.get("width", 324)),
            int(camera.get("height", 244)),
            float(camera.get("fov_deg", 87.0)),
            float(camera.get("mount_pitch_deg", 0.0)),
        )


def rotation_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body-to-world rotation from ZYX Euler angles (rad)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rotation_from_quaternion(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """Body-to-world rotation of a unit quaternion (qx, qy, qz, qw)."""
    n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw) or 1.0
    x, y, z, w = qx / n, qy / n, qz / n, qw / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass(frozen=True)
class CameraPose:
    """Camera position (m, world) and body-to-world rotation ``R`` (3x3)."""

    x: float
    y: float
    z: float
    R: np.ndarray = field(default_factory=lambda: np.eye(3))

    @classmethod
    def from_yaw(
        cls, x: float, y: float, z: float, yaw: float, pitch: float = 0.0, roll: float = 0.0
    ) -> CameraPose:
        """A pose from position and ZYX Euler angles (rad)."""
        return cls(x, y, z, rotation_from_euler(roll, pitch, yaw))

    @classmethod
    def from_quaternion(
        cls, x: float, y: float, z: float, q: tuple[float, float, float, float]
    ) -> CameraPose:
        """A pose from position and quaternion (qx, qy, qz, qw)."""
        return cls(x, y, z, rotation_from_quaternion(*q))

    @property
    def position(self) -> np.ndarray:
        """Position as a numpy vector."""
        return np.array([self.x, self.y, self.z])


def world_to_optical(camera: CameraModel, pose: CameraPose) -> tuple[np.ndarray, np.ndarray]:
    """(R_co, t_co): optical-frame coordinates of a world point p are ``R_co @ p + t_co``."""
    R_bw = pose.R.T
    if camera.mount_pitch_deg:
        R_bw = rotation_from_euler(0.0, math.radians(camera.mount_pitch_deg), 0.0).T @ R_bw
    R_co = _BODY_TO_OPTICAL @ R_bw
    return R_co, -R_co @ pose.position


def project(
    camera: CameraModel, pose: CameraPose, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (N, 3): returns pixel coordinates (N, 2) and depths (N,)."""
    R, t = world_to_optical(camera, pose)
    pc = np.asarray(points, float) @ R.T + t
    z = pc[:, 2]
    safe = np.where(np.abs(z) < 1e-9, 1e-9, z)
    uv = np.stack(
        [camera.fx * pc[:, 0] / safe + camera.cx, camera.fx * pc[:, 1] / safe + camera.cy], axis=1
    )
    return uv, z
