"""Block detector: white-balanced AI-deck frames -> boxes of the pallet's front support blocks.

A small single-class, anchor-free, YOLO-style network of our own (no torchvision, no
downloads). The 324 x 244 BGR frame is shrunk to the model input (``config.input_hw``,
default 144 x 192), standardised on its own (per-channel mean removed, divided by its
standard deviation), and run through a few conv-BN-SiLU stages down to a stride-8 grid. Each
grid cell predicts

* an objectness logit (a block centre lies near this cell),
* the box centre as an offset from the cell centre (``1.5 * tanh``, in cells),
* the box width and height as ``stride * exp(t)``.

Boxes above ``min_score`` are kept, overlapping ones suppressed (greedy NMS written here in
numpy), mapped back to frame pixels and returned left to right by centre x as
:class:`perception.sequencer.Detection`. Without a ``min_score`` the checkpoint's own
``score_threshold`` applies: the operating point calibrated for those weights on validation
renders (``python -m perception.train_detector calibrate``; 0.5 for checkpoints without one).

>>> det = BlockDetector.load()                   # doctest: +SKIP
>>> blocks = det.detect(bgr)                     # doctest: +SKIP
>>> [round(b.cx) for b in blocks]                # doctest: +SKIP
[61, 160, 262]

The shipped weights are ``perception/weights/detector.pt``, trained on synthetic renders by
``python -m perception.train_detector train`` (see ``docs/detector.md``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from functools import lru_cache

import cv2
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from perception.checkpoint import check_format_version, file_sha256, read_checkpoint
from perception.errors import ModelError
from perception.sequencer import Detection

WEIGHTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "weights")
DEFAULT_SCORE_THRESHOLD = 0.5  # detect()'s min_score for checkpoints without a calibrated one
DEFAULT_WEIGHTS = os.path.join(WEIGHTS_DIR, "detector.pt")
FORMAT, FORMAT_VERSION = "btrun-blockdet", 1

#: input normalisation floor (grey levels) added to each frame's standard deviation
STD_FLOOR = 8.0
#: clamp of the log width/height outputs (exp(4) * 8 = 437 px: larger than any frame)
MAX_LOG_WH = 4.0


@dataclass(frozen=True)
class DetectorConfig:
    """Architecture and geometry of a detector checkpoint.

    Attributes:
        frame_hw: frame size (height, width) the detector accepts, the AI-deck's 244 x 324.
        input_hw: network input (height, width); the frame is resized to it.
        widths: output channels of the stride-2, -4 and -8 stages.
        depth8: number of extra 3x3 conv blocks at stride 8 (the last one dilated).
        nms_iou: IoU above which a lower-scoring box is suppressed.
        max_detections: at most this many boxes per frame after NMS.
    """

    frame_hw: tuple[int, int] = (244, 324)
    input_hw: tuple[int, int] = (144, 192)
    widths: tuple[int, int, int] = (16, 32, 64)
    depth8: int = 3
    nms_iou: float = 0.45
    max_detections: int = 10

    @property
    def stride(self) -> int:
        """Pixels of network input per grid cell."""
        return 8

    @property
    def grid_hw(self) -> tuple[int, int]:
        """Output grid (rows, columns)."""
        return self.input_hw[0] // self.stride, self.input_hw[1] // self.stride

    def validate(self) -> None:
        """Raise ValueError for a geometry the network cannot run."""
        h, w = self.input_hw
        if h % self.stride or w % self.stride or h < 16 or w < 16:
            raise ValueError(f"input_hw {self.input_hw} must be multiples of {self.stride} >= 16")
        if len(self.widths) != 3 or min(self.widths) < 1 or self.depth8 < 1:
            raise ValueError(f"bad widths {self.widths} / depth8 {self.depth8}")
        if len(self.frame_hw) != 2 or min(self.frame_hw) < 16:
            raise ValueError(f"bad frame_hw {self.frame_hw}")


def config_to_dict(config: DetectorConfig) -> dict:
    """A ``weights_only``-loadable mapping of a :class:`DetectorConfig` (tuples -> lists)."""
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(config).items()}


def config_from_dict(d: dict) -> DetectorConfig:
    """A :class:`DetectorConfig` from a checkpoint's ``config`` mapping (lists -> tuples)."""
    names = {f.name for f in fields(DetectorConfig)}
    kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in names}
    return DetectorConfig(**kw)


def _cbs(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    """3x3 conv (no bias) -> BatchNorm -> SiLU."""
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, padding=dilation, dilation=dilation, bias=False),
        nn.BatchNorm2d(cout),
        nn.SiLU(inplace=True),
    )


class BlockNet(nn.Module):
    """Backbone to stride 8 and a 1x1 head: (N, 3, H, W) -> (N, 5, H/8, W/8) raw outputs
    (objectness logit, tx, ty, tw, th)."""

    def __init__(self, config: DetectorConfig) -> None:
        super().__init__()
        config.validate()
        self.config = config
        c1, c2, c3 = config.widths
        layers = [_cbs(3, c1, 2), _cbs(c1, c2, 2), _cbs(c2, c2), _cbs(c2, c3, 2)]
        for i in range(config.depth8):
            layers.append(_cbs(c3, c3, dilation=2 if i == config.depth8 - 1 else 1))
        self.body = nn.Sequential(*layers)
        self.head = nn.Conv2d(c3, 5, 1)
        with torch.no_grad():  # start with few objects: objectness prior ~1 %
            self.head.bias.zero_()
            self.head.bias[0] = -4.6

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Raw head outputs (N, 5, gh, gw)."""
        return self.head(self.body(x))


@lru_cache(maxsize=8)
def _grid(gh: int, gw: int, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """Row and column index of every output cell (gh, gw) each; made once per shape."""
    with torch.inference_mode(False):
        gy, gx = torch.meshgrid(
            torch.arange(gh, dtype=dtype), torch.arange(gw, dtype=dtype), indexing="ij"
        )
    return gy, gx


def decode(out: torch.Tensor, stride: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Raw outputs (N, 5, gh, gw) -> boxes (N, gh*gw, 4) as x1, y1, x2, y2 in input pixels
    and objectness logits (N, gh*gw)."""
    n, _, gh, gw = out.shape
    gy, gx = _grid(gh, gw, out.dtype)
    cx = (gx + 0.5 + 1.5 * torch.tanh(out[:, 1])) * stride
    cy = (gy + 0.5 + 1.5 * torch.tanh(out[:, 2])) * stride
    w = stride * torch.exp(out[:, 3].clamp(-MAX_LOG_WH, MAX_LOG_WH))
    h = stride * torch.exp(out[:, 4].clamp(-MAX_LOG_WH, MAX_LOG_WH))
    boxes = torch.stack((cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2), dim=-1)
    return boxes.reshape(n, gh * gw, 4), out[:, 0].reshape(n, gh * gw)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU matrix (len(a), len(b)) of x1, y1, x2, y2 boxes."""
    a = np.asarray(a, np.float64).reshape(-1, 4)
    b = np.asarray(b, np.float64).reshape(-1, 4)
    ix = np.clip(
        np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0, None
    )
    iy = np.clip(
        np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0, None
    )
    inter = ix * iy
    area_a = (a[:, 2] - a[:, 0]).clip(0) * (a[:, 3] - a[:, 1]).clip(0)
    area_b = (b[:, 2] - b[:, 0]).clip(0) * (b[:, 3] - b[:, 1]).clip(0)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float, limit: int | None = None) -> np.ndarray:
    """Greedy non-maximum suppression: indices of the kept boxes, best score first."""
    order = np.argsort(-np.asarray(scores), kind="stable")
    keep: list[int] = []
    while order.size and (limit is None or len(keep) < limit):
        i = int(order[0])
        keep.append(i)
        if order.size == 1:
            break
        rest = order[1:]
        order = rest[box_iou(boxes[i : i + 1], boxes[rest])[0] <= iou]
    return np.asarray(keep, dtype=np.int64)


def to_input(frames: Sequence[np.ndarray], input_hw: tuple[int, int]) -> torch.Tensor:
    """BGR uint8 frames -> standardised float tensor (N, 3, H, W) at the network input size."""
    h, w = input_hw
    small = [
        f if f.shape[:2] == (h, w) else cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA)
        for f in frames
    ]
    x = np.stack(small).astype(np.float32)
    x -= x.mean(axis=(1, 2), keepdims=True)
    x /= x.std(axis=(1, 2, 3), keepdims=True) + np.float32(STD_FLOOR)
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def standardise(small: np.ndarray) -> torch.Tensor:
    """One BGR uint8 frame already at the network input size -> the standardised tensor
    (1, 3, H, W) of :func:`to_input`, computed in fewer passes (per-channel means and the
    overall standard deviation from ``cv2.meanStdDev``; equal to float rounding) and laid
    out channels-last, the layout the inference convolutions run fastest in."""
    mean, std = cv2.meanStdDev(small)
    scale = np.float32(1.0 / (float(np.sqrt(np.mean(std * std))) + STD_FLOOR))
    m = [float(v) for v in mean.ravel()]
    x = cv2.subtract(small, (*m, 0.0), dtype=cv2.CV_32F)  # (H, W, C) float32
    x *= scale
    return torch.from_numpy(x).unsqueeze(0).permute(0, 3, 1, 2)  # NHWC memory


#: a convolution of the inference path: weight, bias, stride, padding, dilation, then SiLU?
_Conv = tuple[torch.Tensor, torch.Tensor, tuple, tuple, tuple, bool]


def fold_batchnorm(model: BlockNet) -> list[_Conv]:
    """The network as plain convolutions for inference: each BatchNorm (running statistics,
    as in evaluation mode) folded into the weights and bias of the convolution before it,
    weights laid out channels-last. Equal to ``model.eval()(x)`` to float rounding."""
    layers: list[_Conv] = []
    for block in model.body:
        conv, bn = block[0], block[1]
        scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
        w = (conv.weight * scale.reshape(-1, 1, 1, 1)).contiguous(memory_format=torch.channels_last)
        b = bn.bias - bn.running_mean * scale
        layers.append((w.detach(), b.detach(), conv.stride, conv.padding, conv.dilation, True))
    h = model.head
    w = h.weight.detach().contiguous(memory_format=torch.channels_last)
    layers.append((w, h.bias.detach(), h.stride, h.padding, h.dilation, False))
    return layers


def _plain(model: BlockNet) -> bool:
    """True if ``model`` is BlockNet's conv-BN-SiLU stack (what :func:`fold_batchnorm` folds)."""
    try:
        return all(
            len(b) == 3
            and isinstance(b[0], nn.Conv2d)
            and isinstance(b[1], nn.BatchNorm2d)
            and isinstance(b[2], nn.SiLU)
            for b in model.body
        ) and isinstance(model.head, nn.Conv2d)
    except (AttributeError, TypeError):
        return False


class BlockDetector:
    """A :class:`BlockNet` in evaluation mode, its config, version string and metrics.

    Inference runs the network with its BatchNorms folded into the convolutions
    (:func:`fold_batchnorm`, redone if the model's weights change) on channels-last tensors:
    the same boxes as ``model(x)`` to float rounding, about a fifth faster on one core.
    """

    def __init__(
        self,
        model: BlockNet,
        model_version: str,
        metrics: dict | None = None,
        path: str = "",
        score_threshold: float = DEFAULT_SCORE_THRESHOLD,
    ) -> None:
        self.model = model.eval()
        self.config: DetectorConfig = model.config
        self.model_version = model_version
        self.metrics = metrics or {}
        self.path = path
        self.score_threshold = score_threshold  # detect()'s min_score when none is given
        # (model, its tensors, their versions, folded layers or None if not foldable)
        self._folded: tuple[BlockNet, list[torch.Tensor], list[int], list[_Conv] | None] | None
        self._folded = None

    @classmethod
    def load(cls, path: str | None = None, threads: int | None = None) -> BlockDetector:
        """Load a ``btrun-blockdet`` checkpoint (default: the shipped ``detector.pt``).

        Args:
            path: checkpoint file; None for ``perception/weights/detector.pt``.
            threads: torch intra-op thread count to set (None: leave it).

        Raises:
            ModelError: the file is missing, unreadable, not a btrun-blockdet checkpoint,
                of another format version, its weights do not fit its architecture, or its
                ``score_threshold`` is not a number in (0, 1).
        """
        path = path or DEFAULT_WEIGHTS
        blob = read_checkpoint(path, "detector weights", threads, f"{FORMAT} checkpoint")
        if not isinstance(blob, dict) or blob.get("format") != FORMAT:
            got = blob.get("format") if isinstance(blob, dict) else type(blob).__name__
            raise ModelError(f"{path}: not a {FORMAT} checkpoint (format {got!r})")
        check_format_version(path, blob.get("format_version"), FORMAT_VERSION)
        try:
            config = config_from_dict(blob["config"])
            model = BlockNet(config)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ModelError(f"{path}: malformed {FORMAT} config ({exc})") from None
        state = blob.get("state_dict")
        if not isinstance(state, dict):
            raise ModelError(f"{path}: the checkpoint has no state_dict mapping")
        try:
            model.load_state_dict(state, strict=True)
        except (RuntimeError, TypeError, AttributeError, KeyError) as exc:
            first = str(exc).strip().splitlines()[0]
            raise ModelError(f"{path}: weights do not fit the detector ({first})") from None
        trained = blob.get("trained") or {}
        metrics = dict(trained.get("metrics") or {}) if isinstance(trained, dict) else {}
        threshold = blob.get("score_threshold", DEFAULT_SCORE_THRESHOLD)
        if (
            isinstance(threshold, bool)
            or not isinstance(threshold, int | float)
            or not 0.0 < threshold < 1.0
        ):
            raise ModelError(
                f"{path}: score_threshold {threshold!r} is not a detection score in (0, 1)"
            )
        version = f"blockdet-v{FORMAT_VERSION}-{file_sha256(path)[:8]}"
        return cls(model, version, metrics, path, float(threshold))

    # -- inference ----------------------------------------------------------------------
    def check_frame(self, frame: object, index: int = 0) -> np.ndarray:
        """Return ``frame`` if it is a BGR uint8 image of the configured frame size, else
        raise :class:`ModelError` naming the offending value and what was expected."""
        h, w = self.config.frame_hw
        if not isinstance(frame, np.ndarray):
            raise ModelError(f"frame {index}: expected a numpy array, got {type(frame).__name__}")
        if frame.shape != (h, w, 3):
            raise ModelError(
                f"frame {index}: expected a white-balanced BGR frame of shape ({h}, {w}, 3), "
                f"got shape {frame.shape}"
            )
        if frame.dtype != np.uint8:
            raise ModelError(f"frame {index}: expected dtype uint8, got {frame.dtype}")
        return frame

    def raw_boxes(self, frames: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """All grid-cell predictions: boxes (N, cells, 4) in frame pixels and scores
        (N, cells) in 0..1, before thresholding and NMS (frames are checked)."""
        frames = [self.check_frame(f, i) for i, f in enumerate(frames)]
        with torch.inference_mode():
            boxes, logits = decode(self.forward(self.input(frames)), self.config.stride)
        (fh, fw), (ih, iw) = self.config.frame_hw, self.config.input_hw
        scale = np.array([fw / iw, fh / ih, fw / iw, fh / ih], np.float32)
        return boxes.numpy() * scale, torch.sigmoid(logits).numpy()

    def input(self, frames: Sequence[np.ndarray]) -> torch.Tensor:
        """Checked BGR frames -> the network input (N, 3, H, W), as :func:`to_input`."""
        h, w = self.config.input_hw
        xs = [
            standardise(
                f if f.shape[:2] == (h, w) else cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA)
            )
            for f in frames
        ]
        return xs[0] if len(xs) == 1 else torch.cat(xs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Raw network outputs (N, 5, gh, gw) of ``model(x)``, through the folded layers."""
        model = self.model
        folded = self._folded
        # Refold if the model or its weights changed (in place: an optimiser step or
        # load_state_dict bumps a tensor's version).
        if folded is None or folded[0] is not model or folded[2] != [t._version for t in folded[1]]:
            tensors = [*model.parameters(), *model.buffers()]
            with torch.inference_mode(False), torch.no_grad():
                layers = fold_batchnorm(model) if _plain(model) else None
            folded = self._folded = (model, tensors, [t._version for t in tensors], layers)
        layers = folded[3]
        if layers is None or model.training:
            return model(x)
        for weight, bias, stride, padding, dilation, silu in layers:
            x = F.conv2d(x, weight, bias, stride, padding, dilation)
            if silu:
                x = F.silu(x, inplace=True)
        return x

    def detect_batch(
        self, frames: Iterable[np.ndarray], min_score: float | None = None
    ) -> list[list[Detection]]:
        """:meth:`detect` for several frames in one network call (one list per frame)."""
        frames = list(frames)
        if not frames:
            return []
        if min_score is None:
            min_score = self.score_threshold
        boxes, scores = self.raw_boxes(frames)
        fh, fw = self.config.frame_hw
        out: list[list[Detection]] = []
        for b, s in zip(boxes, scores, strict=True):
            sel = np.flatnonzero(s >= min_score)
            b, s = b[sel], s[sel]
            keep = nms(b, s, self.config.nms_iou, self.config.max_detections)
            dets = []
            for i in keep:
                x1, y1, x2, y2 = (float(v) for v in b[i])
                x1, x2 = max(0.0, x1), min(float(fw), x2)
                y1, y2 = max(0.0, y1), min(float(fh), y2)
                if x2 - x1 >= 1.0 and y2 - y1 >= 1.0:
                    dets.append(Detection(x1, y1, x2, y2, float(s[i])))
            out.append(sorted(dets, key=lambda d: d.cx))
        return out

    def detect(self, bgr: np.ndarray, min_score: float | None = None) -> list[Detection]:
        """Blocks in one white-balanced BGR uint8 frame (244, 324, 3), left to right.

        Args:
            bgr: the frame, as :func:`perception.white_balance.preprocess` returns it.
            min_score: drop boxes whose score (0..1) is below this (None: the checkpoint's
                calibrated :attr:`score_threshold`).

        Returns:
            Detections after NMS, clipped to the frame, sorted by centre x.

        Raises:
            ModelError: ``bgr`` is not a numpy array, or of the wrong shape or dtype.
        """
        return self.detect_batch([self.check_frame(bgr)], min_score)[0]

    def __repr__(self) -> str:
        return f"BlockDetector({self.model_version}, input {self.config.input_hw})"


__all__ = [
    "DEFAULT_SCORE_THRESHOLD",
    "DEFAULT_WEIGHTS",
    "FORMAT",
    "FORMAT_VERSION",
    "BlockDetector",
    "BlockNet",
    "DetectorConfig",
    "box_iou",
    "config_from_dict",
    "config_to_dict",
    "decode",
    "fold_batchnorm",
    "nms",
    "standardise",
    "to_input",
]
