"""Shared three-level feature encoder (spec §2)."""

from __future__ import annotations

import torch
from torch import nn

from .blocks import ResBlock, conv3x3

__all__ = ["Encoder"]


class Encoder(nn.Module):
    """Conv + ReLU + ResBlocks per level; levels 2 and 3 start with a stride-2 conv.

    The same instance (same weights) encodes the rendering and the reference.
    """

    def __init__(self, channels: int = 64, blocks: tuple[int, int, int] = (4, 4, 4)) -> None:
        super().__init__()
        c = channels
        self.conv1 = conv3x3(3, c)
        self.body1 = nn.Sequential(*[ResBlock(c) for _ in range(blocks[0])])
        self.conv2 = conv3x3(c, c, stride=2)
        self.body2 = nn.Sequential(*[ResBlock(c) for _ in range(blocks[1])])
        self.conv3 = conv3x3(c, c, stride=2)
        self.body3 = nn.Sequential(*[ResBlock(c) for _ in range(blocks[2])])

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Encode an image.

        Args:
            x: (N, 3, H, W) image, RGB in [0, 1]; H, W multiples of 4 for exact level sizes.

        Returns:
            (F1, F2, F3): (N, C, H, W), (N, C, H/2, W/2), (N, C, H/4, W/4).
        """
        f1 = self.body1(torch.relu(self.conv1(x)))
        f2 = self.body2(torch.relu(self.conv2(f1)))
        f3 = self.body3(torch.relu(self.conv3(f2)))
        return f1, f2, f3
