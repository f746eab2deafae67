"""PCB (Part-based Convolutional Baseline) embedder for pallet blocks, in plain torch.

A ResNet-style backbone whose last stage keeps stride 1, average-pooled into ``parts``
horizontal stripes. In training each stripe gets its own 1x1-conv reduction and classifier
(losses averaged); at test time each stripe's pooled backbone vector is L2-normalised and
the stripes are concatenated (Sun et al., 2018).

Module names follow torchreid's ``pcb_p4`` (``conv1, bn1, layer1..layer4, parts_avgpool,
dropout, conv5, classifier``, torchvision-style block names inside the layers), so a
torchreid checkpoint of ``pcb_p4`` (ResNet50 backbone) loads with :func:`load_checkpoint`;
a mismatch is reported with the missing and unexpected keys. torchvision is not needed.

Backbones: ``small`` (default: BasicBlocks, widths 32-256, one block per stage: fast on a
CPU), ``resnet18`` and ``resnet50`` (the reference work's choice).

Occlusion awareness (``PCBConfig.visibility``, btrun's own addition; off for foreign
checkpoints): a 1x1 convolution on the last feature map predicts, per cell, whether the
block is visible there (not hidden by a strap, film, a load, a stain). Each stripe is then
pooled over its visible cells only, and the stripe's visibility (the mean over its cells)
says how much the stripe counts when two blocks are compared
(:func:`perception.gallery.block_distances`). Trained on crops with known hidden parts
(:mod:`perception.synth.ageing`), in the spirit of the visibility-aware part model
(Sun et al., 2019).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


class BasicBlock(nn.Module):
    """ResNet basic block (two 3x3 convolutions)."""

    expansion = 1

    def __init__(
        self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None
    ) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(planes, planes, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class Bottleneck(nn.Module):
    """ResNet bottleneck block (1x1, 3x3, 1x1)."""

    expansion = 4

    def __init__(
        self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None
    ) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, planes * 4, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(planes * 4)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + identity)


class DimReduceLayer(nn.Module):
    """1x1 conv + BN + ReLU (torchreid's ``DimReduceLayer``, attribute ``layers``)."""

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.layers = nn.Sequential(
            nn.Conv2d(in_channels, out_channels, 1, bias=False),
            nn.BatchNorm2d(out_channels),
            nn.ReLU(inplace=True),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)


@dataclass(frozen=True)
class PCBConfig:
    """Architecture of a PCB embedder (stored with the weights)."""

    backbone: str = "small"
    parts: int = 4
    reduced_dim: int = 256
    num_classes: int = 1
    input_hw: tuple[int, int] = (96, 160)
    visibility: bool = False
    normalisation: str = "mean_std"  # how a crop is standardised (perception.embedder)


BACKBONES = {
    "small": (BasicBlock, (1, 1, 1, 1), (32, 64, 128, 256)),
    "resnet18": (BasicBlock, (2, 2, 2, 2), (64, 128, 256, 512)),
    "resnet50": (Bottleneck, (3, 4, 6, 3), (64, 128, 256, 512)),
}


class PCB(nn.Module):
    """PCB over a ResNet-style backbone; ``forward`` returns class logits per part when
    training and the L2-normalised, concatenated part features at evaluation."""

    def __init__(self, config: PCBConfig) -> None:
        super().__init__()
        if config.backbone not in BACKBONES:
            raise ValueError(
                f"unknown backbone {config.backbone!r} (known: {', '.join(BACKBONES)})"
            )
        block, layers, widths = BACKBONES[config.backbone]
        self.config = config
        self.inplanes = widths[0]
        self.conv1 = nn.Conv2d(3, widths[0], 7, 2, 3, bias=False)
        self.bn1 = nn.BatchNorm2d(widths[0])
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, 2, 1)
        self.layer1 = self._make_layer(block, widths[0], layers[0], 1)
        self.layer2 = self._make_layer(block, widths[1], layers[1], 2)
        self.layer3 = self._make_layer(block, widths[2], layers[2], 2)
        self.layer4 = self._make_layer(block, widths[3], layers[3], 1)  # PCB: last stride 1
        self.feature_dim = widths[3] * block.expansion
        self.parts_avgpool = nn.AdaptiveAvgPool2d((config.parts, 1))
        self.dropout = nn.Dropout(p=0.5)
        self.conv5 = DimReduceLayer(self.feature_dim, config.reduced_dim)
        self.classifier = nn.ModuleList(
            [nn.Linear(config.reduced_dim, config.num_classes) for _ in range(config.parts)]
        )
        self.visibility = nn.Conv2d(self.feature_dim, 1, 1) if config.visibility else None
        self._init_params()
        if self.visibility is not None:  # start "everything visible"
            nn.init.zeros_(self.visibility.weight)
            nn.init.constant_(self.visibility.bias, 3.0)

    @property
    def embedding_dim(self) -> int:
        """Size of the test-time feature vector: parts x backbone width."""
        return self.config.parts * self.feature_dim

    def _make_layer(
        self, block: type[nn.Module], planes: int, blocks: int, stride: int
    ) -> nn.Sequential:
        downsample = None
        if stride != 1 or self.inplanes != planes * block.expansion:
            downsample = nn.Sequential(
                nn.Conv2d(self.inplanes, planes * block.expansion, 1, stride, bias=False),
                nn.BatchNorm2d(planes * block.expansion),
            )
        layers = [block(self.inplanes, planes, stride, downsample)]
        self.inplanes = planes * block.expansion
        layers += [block(self.inplanes, planes) for _ in range(1, blocks)]
        return nn.Sequential(*layers)

    def _init_params(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
            elif isinstance(m, nn.Linear):
                nn.init.normal_(m.weight, 0, 0.01)
                nn.init.zeros_(m.bias)

    def featuremaps(self, x: torch.Tensor) -> torch.Tensor:
        """Backbone feature maps."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        return self.layer4(self.layer3(self.layer2(self.layer1(x))))

    def visibility_map(self, fmap: torch.Tensor) -> torch.Tensor | None:
        """Per-cell visibility logits (N, 1, h, w) of a feature map (None without the head)."""
        return None if self.visibility is None else self.visibility(fmap)

    def pool_parts(
        self, fmap: torch.Tensor, vis_logits: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Stripe vectors (N, C, parts, 1) and stripe visibilities (N, parts) in 0..1.

        Without a visibility head: plain average pooling, every stripe fully visible. With
        it: each stripe averaged over its cells weighted by their (detached) visibility.
        """
        n = fmap.size(0)
        if vis_logits is None:
            return self.parts_avgpool(fmap), fmap.new_ones((n, self.config.parts))
        v = torch.sigmoid(vis_logits).detach()
        num = self.parts_avgpool(fmap * v)
        den = self.parts_avgpool(v)
        return num / (den + 1e-3), den.view(n, self.config.parts)

    def describe(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Evaluation output: L2-normalised stripe vectors concatenated (N, parts * C) and
        the stripes' visibilities (N, parts)."""
        fmap = self.featuremaps(x)
        v_g, vis = self.pool_parts(fmap, self.visibility_map(fmap))
        v_g = F.normalize(v_g, p=2, dim=1)
        return v_g.view(v_g.size(0), -1), vis

    def forward(self, x: torch.Tensor) -> torch.Tensor | list[torch.Tensor]:
        if not self.training:
            return self.describe(x)[0]
        fmap = self.featuremaps(x)
        v_g, _ = self.pool_parts(fmap, self.visibility_map(fmap))
        v_h = self.conv5(self.dropout(v_g))
        return [self.classifier[i](v_h[:, :, i, :].flatten(1)) for i in range(self.config.parts)]


class CheckpointError(Exception):
    """A checkpoint that does not fit the model (message lists the keys)."""


def load_checkpoint(model: PCB, path: str, ignore_classifier: bool = True) -> None:
    """Load a PCB checkpoint (ours, or torchreid's ``pcb_p4``: ``{"state_dict": ...}``,
    ``module.`` prefixes stripped). The classifier may differ (other training identities)
    and is skipped by default. Raises :class:`CheckpointError` listing mismatched keys."""
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise CheckpointError(f"{path}: cannot read the checkpoint ({exc})") from None
    state = blob.get("state_dict", blob) if isinstance(blob, dict) else None
    if not isinstance(state, dict):
        raise CheckpointError(f"{path}: not a state dict")
    load_state(model, state, path, ignore_classifier)


def load_state(
    model: PCB, state: dict, source: str = "state dict", ignore_classifier: bool = True
) -> None:
    """Load an in-memory state dict (``module.`` prefixes stripped) with the checks of
    :func:`load_checkpoint`; ``source`` names it in the :class:`CheckpointError`."""
    path = source
    state = {str(k).removeprefix("module."): v for k, v in state.items()}
    own = model.state_dict()
    if ignore_classifier:
        state = {k: v for k, v in state.items() if not k.startswith("classifier.")}
        own = {k: v for k, v in own.items() if not k.startswith("classifier.")}
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shape = sorted(k for k in set(own) & set(state) if own[k].shape != state[k].shape)
    if missing or unexpected or shape:

        def show(keys: list[str]) -> str:
            return ", ".join(keys[:12]) + (f" ... (+{len(keys) - 12})" if len(keys) > 12 else "")

        parts = []
        if missing:
            parts.append(f"missing keys: {show(missing)}")
        if unexpected:
            parts.append(f"unexpected keys: {show(unexpected)}")
        if shape:
            parts.append(
                "shape mismatch: "
                + show([f"{k} {tuple(state[k].shape)} vs {tuple(own[k].shape)}" for k in shape])
            )
        raise CheckpointError(
            f"{path} does not fit PCB backbone '{model.config.backbone}' with {model.config.parts} parts; "
            + "; ".join(parts)
        )
    model.load_state_dict(state, strict=False)
