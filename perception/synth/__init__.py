"""Synthetic AI-deck camera: procedural europallets seen through a low-resolution camera.

Pure functions (numpy + OpenCV), no knowledge of the simulator:

- :mod:`perception.synth.appearance`: procedural wood, block faces (stamps, knots, nails,
  dirt), pallet side faces, floor and wall textures; deterministic per identity, cached.
- :mod:`perception.synth.camera_model`: pinhole AI-deck camera (324x244, ~87 deg) and poses.
- :mod:`perception.synth.render`: scene of textured quads -> colour frame -> raw Bayer frame
  (lighting, exposure, motion blur, noise, green cast), plus ground-truth block boxes.
- :mod:`perception.synth.dataset`: training samples for the block detector and block crops for
  re-identification, and synthetic identity names.

``drivers/sim/renderers/pallet.py`` adapts the simulator's world and poses to these functions.
"""

from perception.synth.appearance import SideStyle, block_texture, face_texture, split_identity
from perception.synth.camera_model import CameraModel, CameraPose
from perception.synth.render import (
    BlockBox,
    Lighting,
    PalletSpec,
    Scene,
    SensorModel,
    render_frame,
)

__all__ = [
    "BlockBox",
    "CameraModel",
    "CameraPose",
    "Lighting",
    "PalletSpec",
    "Scene",
    "SensorModel",
    "SideStyle",
    "block_texture",
    "face_texture",
    "render_frame",
    "split_identity",
]
