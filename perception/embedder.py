"""Block embedder: BGR crops of pallet support blocks -> L2-normalised PCB embeddings.

The gallery (:mod:`perception.gallery`) compares two blocks by the Euclidean distance of
their embeddings and two pallet sides by the mean of the three block distances. An
embedding here is the concatenation of the ``parts`` L2-normalised stripe vectors of the
PCB model divided by ``sqrt(parts)``: every row has unit norm, so a block distance lies in
[0, 2] and equals ``sqrt(2 - 2 cos)`` of the concatenated features.

>>> emb = BlockEmbedder.load()                                  # doctest: +SKIP
>>> vectors = emb.embed([crop_left, crop_middle, crop_right])   # doctest: +SKIP
>>> vectors.shape == (3, emb.dim)                               # doctest: +SKIP
True

The shipped weights are ``perception/weights/pcb_small.pt`` (trained on synthetic pallets by
``python -m perception.train_embedder train``; see ``docs/perception.md``). A torchreid
``pcb_p4`` checkpoint (ResNet50) also loads: ``BlockEmbedder.load(path, backbone="resnet50")``.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, fields

import cv2
import numpy as np
import torch

from perception.checkpoint import check_format_version, file_sha256, read_checkpoint
from perception.errors import ModelError
from perception.gallery import Thresholds
from perception.pcb import PCB, CheckpointError, PCBConfig, load_state

WEIGHTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "weights")
DEFAULT_WEIGHTS = os.path.join(WEIGHTS_DIR, "pcb_small.pt")
FORMAT, FORMAT_VERSION = "btrun-pcb", 1

#: input normalisation: each crop minus its own per-channel mean, divided by its overall
#: standard deviation plus this floor (grey levels), which removes most of the exposure and
#: white-balance differences between two scans of one block
STD_FLOOR = 8.0

#: input size of foreign (torchreid) checkpoints: person re-id's 384 x 128 (height x width)
FOREIGN_INPUT_HW = (384, 128)


def check_crop(crop: object, index: int = 0) -> np.ndarray:
    """Return ``crop`` if it is a non-empty BGR uint8 image (H, W, 3), else raise ModelError."""
    if not isinstance(crop, np.ndarray):
        raise ModelError(f"crop {index}: expected a numpy array, got {type(crop).__name__}")
    if crop.ndim != 3 or crop.shape[2] != 3:
        raise ModelError(
            f"crop {index}: expected a BGR image of shape (H, W, 3), got shape {crop.shape}"
        )
    if crop.shape[0] == 0 or crop.shape[1] == 0:
        raise ModelError(f"crop {index}: empty crop of shape {crop.shape}")
    if crop.dtype != np.uint8:
        raise ModelError(f"crop {index}: expected dtype uint8, got {crop.dtype} ({crop.shape})")
    return crop


def resize_crop(crop: np.ndarray, input_hw: tuple[int, int]) -> np.ndarray:
    """Resize a crop to the model input (height, width): area filter when shrinking."""
    h, w = input_hw
    shrink = crop.shape[0] > h or crop.shape[1] > w
    interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    return cv2.resize(crop, (w, h), interpolation=interp)


#: how a crop is standardised (``PCBConfig.normalisation``)
NORMALISATIONS = ("mean_std", "robust")


def to_tensor(images: list[np.ndarray], normalisation: str = "mean_std") -> torch.Tensor:
    """Stack equally-sized BGR uint8 images into a float tensor (N, 3, H, W), each image
    standardised on its own: ``mean_std`` removes the per-channel mean and divides by the
    standard deviation; ``robust`` removes the per-channel median and divides by the spread
    between the 10th and 90th percentiles / 2.56 (about one standard deviation), so a strap,
    film or stain over part of the block barely shifts the rest of the crop."""
    x = np.stack(images).astype(np.float32)
    if normalisation == "robust":  # statistics of every second row and column (fast)
        n = len(x)
        sub = x[:, ::2, ::2].reshape(n, -1, 3)
        x -= np.median(sub, axis=1)[:, None, None, :]
        lo, hi = np.percentile(x[:, ::2, ::2].reshape(n, -1), (10.0, 90.0), axis=1)
        x /= ((hi - lo) / 2.56)[:, None, None, None].astype(np.float32) + np.float32(STD_FLOOR)
    else:
        x -= x.mean(axis=(1, 2), keepdims=True)
        x /= x.std(axis=(1, 2, 3), keepdims=True) + np.float32(STD_FLOOR)
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def gallery_features(raw: torch.Tensor, parts: int) -> torch.Tensor:
    """PCB's eval output (per-part L2-normalised, concatenated) -> unit-norm rows."""
    return raw / math.sqrt(parts)


@dataclass(frozen=True)
class BlockDescriptors:
    """What the embedder says about n crops: unit-norm embeddings (n, dim) and how visible
    each of their ``parts`` stripes is (n, parts), 0 hidden .. 1 visible (all 1 for a
    model without a visibility head)."""

    vectors: np.ndarray
    visibility: np.ndarray


class BlockEmbedder:
    """A PCB model in evaluation mode, its version string and its "unknown" thresholds."""

    def __init__(
        self,
        model: PCB,
        model_version: str,
        thresholds: Thresholds,
        metrics: dict | None = None,
        path: str = "",
    ) -> None:
        self.model = model.eval()
        self.config = model.config
        self.model_version = model_version
        self.thresholds = thresholds
        self.metrics = metrics or {}
        self.path = path
        self.dim = model.embedding_dim

    @classmethod
    def load(
        cls, path: str | None = None, backbone: str | None = None, threads: int | None = None
    ) -> BlockEmbedder:
        """Load a btrun checkpoint (default: the shipped ``pcb_small.pt``) or, with
        ``backbone``, a foreign PCB state dict such as torchreid's ``pcb_p4`` (ResNet50).

        ``threads`` sets torch's intra-op thread count. Raises :class:`ModelError` naming
        the file for a missing, unreadable or mismatched checkpoint (with the key list).
        """
        path = path or DEFAULT_WEIGHTS
        blob = read_checkpoint(path, "embedder weights", threads)
        sha8 = file_sha256(path)[:8]
        if isinstance(blob, dict) and blob.get("format") == FORMAT:
            return cls._from_btrun(blob, path, sha8, backbone)
        return cls._from_foreign(blob, path, sha8, backbone)

    @classmethod
    def _from_btrun(cls, blob: dict, path: str, sha8: str, backbone: str | None) -> BlockEmbedder:
        check_format_version(path, blob.get("version"), FORMAT_VERSION)
        try:
            config = config_from_dict(blob["config"])
            state = blob["state_dict"]
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelError(f"{path}: malformed btrun-pcb checkpoint ({exc})") from None
        if backbone is not None and backbone != config.backbone:
            raise ModelError(
                f"{path}: checkpoint has backbone '{config.backbone}', not '{backbone}'"
            )
        model = _build(config, path)
        _load_state(model, state, path)
        th = blob.get("thresholds") or {}
        thresholds = Thresholds(
            float(th.get("max_distance", float("inf"))), float(th.get("min_margin", 0.0))
        )
        version = f"pcb-{config.backbone}-v{FORMAT_VERSION}-{sha8}"
        return cls(model, version, thresholds, dict(blob.get("metrics") or {}), path)

    @classmethod
    def _from_foreign(
        cls, blob: object, path: str, sha8: str, backbone: str | None
    ) -> BlockEmbedder:
        if backbone is None:
            raise ModelError(
                f"{path}: not a btrun-pcb checkpoint; pass backbone= (e.g. 'resnet50' for a "
                "torchreid pcb_p4 checkpoint) to load a foreign PCB state dict"
            )
        hw = FOREIGN_INPUT_HW if backbone == "resnet50" else PCBConfig().input_hw
        model = _build(PCBConfig(backbone=backbone, parts=4, input_hw=hw), path)
        state = blob.get("state_dict", blob) if isinstance(blob, dict) else None
        if not isinstance(state, dict):
            raise ModelError(f"{path}: not a PCB state dict")
        _load_state(model, state, path)
        return cls(model, f"pcb-{backbone}-ext-{sha8}", Thresholds(), {}, path)

    # -- inference ----------------------------------------------------------------------
    def preprocess(self, crops: list[np.ndarray]) -> torch.Tensor:
        """Validate and resize crops to the model input; a normalised (N, 3, H, W) tensor."""
        hw = tuple(self.config.input_hw)
        images = [resize_crop(check_crop(c, i), hw) for i, c in enumerate(crops)]
        return to_tensor(images, self.config.normalisation)

    def embed(self, crops: list[np.ndarray]) -> np.ndarray:
        """BGR uint8 crops (any size) -> float32 (n, dim) unit-norm rows.

        Raises :class:`ModelError` for an empty crop, a wrong shape or a wrong dtype.
        """
        return self.describe(crops).vectors

    def describe(self, crops: list[np.ndarray]) -> BlockDescriptors:
        """Embeddings and stripe visibilities of BGR uint8 crops (any size); the gallery
        weighs each stripe by its visibility (``Gallery.match(..., visibility=)``).

        Raises :class:`ModelError` for an empty crop, a wrong shape or a wrong dtype.
        """
        crops = list(crops)
        parts = self.config.parts
        if not crops:
            return BlockDescriptors(
                np.zeros((0, self.dim), np.float32), np.zeros((0, parts), np.float32)
            )
        x = self.preprocess(crops)
        with torch.inference_mode():
            raw, vis = self.model.describe(x)
            f = gallery_features(raw, parts)
        return BlockDescriptors(
            f.numpy().astype(np.float32, copy=False), vis.numpy().astype(np.float32, copy=False)
        )

    @property
    def occlusion_aware(self) -> bool:
        """True if the model predicts stripe visibilities (else they are all 1)."""
        return bool(self.config.visibility)

    def __repr__(self) -> str:
        return f"BlockEmbedder({self.model_version}, dim={self.dim}, {self.thresholds})"


def config_from_dict(d: dict) -> PCBConfig:
    """A :class:`PCBConfig` from a checkpoint's ``config`` mapping (lists become tuples)."""
    names = {f.name for f in fields(PCBConfig)}
    kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in names}
    return PCBConfig(**kw)


def config_to_dict(config: PCBConfig) -> dict:
    """A checkpoint-friendly (``weights_only``-loadable) mapping of a :class:`PCBConfig`."""
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(config).items()}


def _build(config: PCBConfig, path: str) -> PCB:
    try:
        return PCB(config)
    except (ValueError, TypeError) as exc:
        raise ModelError(f"{path}: {exc}") from None


def _load_state(model: PCB, state: object, path: str) -> None:
    """Load ``state`` into ``model``; a mismatch -> ModelError with the key lists."""
    if not isinstance(state, dict):
        raise ModelError(f"{path}: the state dict is not a mapping")
    try:
        load_state(model, state, path)
    except CheckpointError as exc:
        raise ModelError(str(exc)) from None
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise ModelError(f"{path}: cannot load the state dict ({exc})") from None
