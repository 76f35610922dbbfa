"""The MaRINeR generator: shared encoder, MEM, decoder and iterative refinement (spec §2-5)."""

from __future__ import annotations

import logging
import math

import torch
import torch.nn.functional as F
from torch import nn

from .blocks import ResBlock
from .config import MarinerConfig
from .decoder import SAM, Decoder
from .encoder import Encoder
from .matching import MEM

logger = logging.getLogger(__name__)

__all__ = ["Mariner", "check_image_pair", "check_image_tensor", "pad_render", "pad_reference"]


def check_image_tensor(x: torch.Tensor, name: str) -> None:
    """Raise ValueError unless x is a finite floating (N, 3, H, W) tensor."""
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be a floating tensor in [0, 1], got dtype {x.dtype}")
    if x.ndim != 4 or x.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3, H, W) (RGB), got {tuple(x.shape)}")
    if x.shape[0] < 1 or x.shape[2] < 1 or x.shape[3] < 1:
        raise ValueError(f"{name} is empty: {tuple(x.shape)}")
    if not bool(torch.isfinite(x).all()):
        raise ValueError(f"{name} contains NaN or inf values")


def check_image_pair(render: torch.Tensor, reference: torch.Tensor) -> None:
    """Both finite floating (N, 3, H, W) tensors with the same batch size; ValueError if not."""
    check_image_tensor(render, "render")
    check_image_tensor(reference, "reference")
    if reference.shape[0] != render.shape[0]:
        raise ValueError(
            f"render and reference batch sizes differ: {render.shape[0]} vs {reference.shape[0]}"
        )


def pad_render(x: torch.Tensor, multiple: int) -> tuple[torch.Tensor, tuple[int, int, int, int]]:
    """Replicate-pad to a multiple, split evenly (extra pixel bottom/right).

    Returns the padded tensor and (left, right, top, bottom).
    """
    h, w = x.shape[-2:]
    ph = math.ceil(h / multiple) * multiple - h
    pw = math.ceil(w / multiple) * multiple - w
    pads = (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2)
    if ph or pw:
        x = F.pad(x, pads, mode="replicate")
    return x, pads


def pad_reference(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """Replicate-pad bottom/right to a multiple."""
    h, w = x.shape[-2:]
    ph = math.ceil(h / multiple) * multiple - h
    pw = math.ceil(w / multiple) * multiple - w
    return F.pad(x, (0, pw, 0, ph), mode="replicate") if (ph or pw) else x


class Mariner(nn.Module):
    """MaRINeR generator. Builds layers only (no I/O); see ``Enhancer`` for loading/inference.

    Images are RGB, float, in [0, 1] (we train our own weights, so the official code's BGR
    order does not apply anywhere in this package).
    """

    def __init__(self, cfg: MarinerConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg if cfg is not None else MarinerConfig()
        c = self.cfg.channels
        self.encoder = Encoder(c, self.cfg.encoder_blocks)
        self.mem = MEM(self.cfg.block_size, self.cfg.window_factor, self.cfg.dilations)
        self.decoder = Decoder(c, self.cfg.decoder_blocks)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """MASA-style init: N(0, 0.5*sqrt(2/(k^2*C_out))), zero bias, ResBlocks x0.1, SAM zero."""
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
                k = m.kernel_size[0] * m.kernel_size[1]
                c_out = m.out_channels
                nn.init.normal_(m.weight, 0.0, 0.5 * math.sqrt(2.0 / (k * c_out)))
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
        with torch.no_grad():
            for m in self.modules():
                if isinstance(m, ResBlock):
                    m.conv1.weight.mul_(0.1)
                    m.conv2.weight.mul_(0.1)
        for m in self.modules():
            if isinstance(m, SAM):
                m.zero_init()

    def generator_step(self, render: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        """One pass G(render, reference) on already padded inputs.

        Args:
            render: (N, 3, H, W), H and W multiples of ``cfg.render_multiple``.
            reference: (N, 3, Hr, Wr), multiples of ``cfg.reference_multiple``.

        Returns:
            (N, 3, H, W) unclamped prediction.
        """
        f_i = self.encoder(render)
        f_r = self.encoder(reference)
        warped, _ = self.mem(f_i, f_r)
        out = self.decoder(f_i[2], warped)
        if self.cfg.global_skip:
            out = out + render
        return out

    def check_inputs(self, render: torch.Tensor, reference: torch.Tensor) -> None:
        """Validate render/reference tensors; raises ValueError with the reason."""
        check_image_pair(render, reference)
        m = self.cfg.min_reference_size
        if min(reference.shape[-2:]) < m:
            raise ValueError(
                f"reference is {reference.shape[-2]}x{reference.shape[-1]} px; MEM needs at "
                f"least {m} px per side (a 15x15 window at 1/4 resolution)"
            )
        if min(render.shape[-2:]) < 2:
            raise ValueError(f"render is too small: {tuple(render.shape[-2:])}")

    def forward(
        self, render: torch.Tensor, reference: torch.Tensor, iterations: int | None = None
    ) -> list[torch.Tensor]:
        """Iterative refinement with shared weights and the same reference.

        ``x0 = render; y_k = G(x_{k-1}, reference); x_k = clamp(y_k, 0, 1)``. The render is
        replicate-padded once (to ``cfg.render_multiple``, split evenly), the reference to
        ``cfg.reference_multiple`` (bottom/right); iterations run on the padded canvas and every
        output is cropped back to the render size.

        Args:
            render: (N, 3, H, W) RGB in [0, 1], any H, W.
            reference: (N, 3, Hr, Wr) RGB in [0, 1], Hr, Wr >= ``cfg.min_reference_size``.
            iterations: K (default ``cfg.iterations``).

        Returns:
            list of K unclamped outputs y_1..y_K, each (N, 3, H, W); gradients flow through
            the clamps between iterations.
        """
        self.check_inputs(render, reference)
        k = self.cfg.iterations if iterations is None else int(iterations)
        if k < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        h, w = render.shape[-2:]
        x, (left, _, top, _) = pad_render(render, self.cfg.render_multiple)
        ref = pad_reference(reference, self.cfg.reference_multiple)
        outputs = []
        for _ in range(k):
            y = self.generator_step(x, ref)
            outputs.append(y[:, :, top : top + h, left : left + w])
            x = y.clamp(0.0, 1.0)
        return outputs
