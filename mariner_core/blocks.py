"""Small building blocks shared by the encoder and decoder."""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["ResBlock", "conv3x3"]


def conv3x3(c_in: int, c_out: int, stride: int = 1) -> nn.Conv2d:
    """3x3 convolution with padding 1 and bias."""
    return nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=True)


class ResBlock(nn.Module):
    """``x + conv(relu(conv(x)))``: no normalisation, no activation after the sum."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.conv1 = conv3x3(channels, channels)
        self.conv2 = conv3x3(channels, channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) -> (N, C, H, W)."""
        return x + self.conv2(torch.relu(self.conv1(x)))
