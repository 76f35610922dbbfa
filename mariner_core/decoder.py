"""Decoder (spec §4): SAM fusion per level, DRAM upsampling, residual stacks."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .blocks import ResBlock, conv3x3

__all__ = ["SAM", "DRAM", "Decoder"]


class SAM(nn.Module):
    """Spatial adaptation module: ``IN(r) * gamma + beta`` with x's statistics as the base.

    ``gamma = conv(t) + std(x)``, ``beta = conv(t) + mean(x)``, ``t = relu(conv([x; r]))``;
    std is the unbiased per-sample, per-channel spatial std of x, the instance norm of r uses the
    biased variance and eps 1e-5. The gamma/beta convs start at zero, so a fresh SAM is AdaIN.
    """

    def __init__(self, channels: int = 64) -> None:
        super().__init__()
        self.conv_shared = conv3x3(2 * channels, channels)
        self.conv_gamma = conv3x3(channels, channels)
        self.conv_beta = conv3x3(channels, channels)
        self.zero_init()

    def zero_init(self) -> None:
        """Zero the gamma/beta convs (weights and biases)."""
        for conv in (self.conv_gamma, self.conv_beta):
            nn.init.zeros_(conv.weight)
            assert conv.bias is not None  # Conv2d's default bias=True
            nn.init.zeros_(conv.bias)

    def forward(self, x: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
        """(N, C, h, w) structure source x and warped reference r -> (N, C, h, w); h*w >= 2."""
        r_hat = F.instance_norm(r, eps=1e-5)
        t = torch.relu(self.conv_shared(torch.cat((x, r), dim=1)))
        mu = x.mean(dim=(2, 3), keepdim=True)
        sigma = x.std(dim=(2, 3), keepdim=True, unbiased=True)
        gamma = self.conv_gamma(t) + sigma
        beta = self.conv_beta(t) + mu
        return r_hat * gamma + beta


class DRAM(nn.Module):
    """Dual residual aggregation: fuse low-res x (C, h, w) with high-res y (C, 2h, 2w)."""

    def __init__(self, channels: int = 64) -> None:
        super().__init__()
        c = channels
        self.down_a = conv3x3(c, c, stride=2)
        self.down_b = conv3x3(c, c, stride=2)
        self.up_a = nn.ConvTranspose2d(c, c, 3, stride=2, padding=1, output_padding=1)
        self.up_b = nn.ConvTranspose2d(c, c, 3, stride=2, padding=1, output_padding=1)
        self.fuse = conv3x3(2 * c, c)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """x: (N, C, h, w), y: (N, C, 2h, 2w) -> (N, C, 2h, 2w)."""
        a = torch.relu(self.up_a(torch.relu(self.down_a(y)) - x)) + y
        b = torch.relu(self.up_b((x - torch.relu(self.down_b(y))) + x))
        return torch.relu(self.fuse(torch.cat((a, b), dim=1)))


def _up2(x: torch.Tensor) -> torch.Tensor:
    return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)


class Decoder(nn.Module):
    """L3 -> L1 decoder fusing render features with warped reference features."""

    def __init__(self, channels: int = 64, blocks: tuple[int, int, int] = (12, 8, 4)) -> None:
        super().__init__()
        c = channels
        self.sam3 = SAM(c)
        self.merge3 = conv3x3(2 * c, c)
        self.body3 = nn.Sequential(*[ResBlock(c) for _ in range(blocks[0])])
        self.sam2 = SAM(c)
        self.dram2 = DRAM(c)
        self.conv2 = conv3x3(c, c)
        self.body2 = nn.Sequential(*[ResBlock(c) for _ in range(blocks[1])])
        self.sam1 = SAM(c)
        self.dram1 = DRAM(c)
        self.body1 = nn.Sequential(*[ResBlock(c) for _ in range(blocks[2])])
        self.out = conv3x3(c, 3)

    def forward(
        self,
        f3: torch.Tensor,
        warped: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    ) -> torch.Tensor:
        """Decode.

        Args:
            f3: (N, C, h, w) render L3 features.
            warped: (W1, W2, W3): (N, C, 4h, 4w), (N, C, 2h, 2w), (N, C, h, w).

        Returns:
            (N, 3, 4h, 4w) image, no output activation (not clamped).
        """
        w1, w2, w3 = warped
        s3 = self.sam3(f3, w3)
        o3 = self.body3(torch.relu(self.merge3(torch.cat((s3, f3), dim=1))))
        s2 = self.sam2(_up2(o3), w2)
        o2 = self.body2(torch.relu(self.conv2(self.dram2(o3, s2))))
        s1 = self.sam1(_up2(o2), w1)
        o1 = self.body1(self.dram1(o2, s1))
        return self.out(o1)
