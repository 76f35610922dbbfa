"""MaRINeR with a frozen ImageNet matcher and a trained fusion decoder (the ``cpu-frozen`` model).

Why a second architecture: the spec network (``model.Mariner``) learns its encoder and matching
end to end, which a 2-core CPU cannot train far enough (see ``reports/mariner_training.md``).
Reference-based super-resolution (TTSR, C2-Matching, MASA-SR) matches with a *pretrained, frozen*
feature extractor instead; then the matching of a training triple never changes, can be computed
once (``prepare``) and cached, and training only moves the fusion decoder (``fuse``).

Data flow (images RGB in [0, 1], render padded to a multiple of 4):

1. ``prepare(render, reference)`` (no parameters are trained here):

   * frozen ImageNet VGG16 up to relu3_3 (1/4 resolution) on both images (RGB: matching on
     luminance alone was tried and placed coloured renders' references worse, and shaded ones
     no better; ``reports/mariner_training.md``);
   * global patch matching: every 3x3 relu3_3 patch of the render against every patch of the
     reference (cosine similarity of the L2-normalised, unfolded patches), top-``k`` matches;
   * transfer by voting: for each of the ``k`` match ranks, the reference's 12x12-pixel patch
     around the match is pasted at the render patch's place and overlapping pastes are averaged
     (the texture-swap aggregation of style transfer / TTSR): ``k`` warped references at full
     resolution, each placed by *image content*, never by a pose;
   * the ``k`` similarity maps (1/4 resolution) and a global colour transfer of the render
     (per-channel mean / std of its covered pixels moved to the reference's).

2. ``fuse(prepared)``: a small trainable U-Net (three scales: full, 1/2, 1/4) reads the render,
   the warped references, their similarities and the colour-transferred render and predicts
   the output as a correction of the similarity-weighted mean of the warped references.

The output keeps the render's geometry: every pixel is either the render's own content or
reference content placed where it matches the render (absolute evidence,
``../shared/docs/evidence.md``). The frozen VGG weights are part of the state dict, so a
checkpoint is self-contained.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .backbones import VGG16Features
from .patch_match import patch_dots, patch_norm, repeat_last_rank

__all__ = ["FrozenMariner", "FrozenMarinerConfig", "PREPARED_KEYS"]

ARCHITECTURE = "frozen-vgg"
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
#: keys of the dict ``prepare`` returns (all (N, C, H, W) at the padded render size)
PREPARED_KEYS = ("render", "warped", "score", "colour")
#: relu3_3 is at 1/4 resolution: patches of 3x3 features cover 12x12 pixels
STRIDE = 4
#: what ``FrozenMariner.forward`` returns: the decoder's output, the matching-only base, or both
OUTPUTS = ("model", "base", "both")
#: initial gate logit of a gated decoder (sigmoid = 0.12)
GATE_BIAS = -2.0


@dataclass(frozen=True)
class FrozenMarinerConfig:
    """Hyper-parameters of :class:`FrozenMariner`.

    Attributes:
        architecture: always ``"frozen-vgg"`` (lets ``load_checkpoint`` pick the class).
        top_k: matches kept per render patch (warped references given to the decoder).
        channels: U-Net width at full resolution (x2 at 1/2, x4 at 1/4).
        blocks: residual blocks per U-Net scale (full, 1/2, 1/4).
        temperature: softmax temperature over the top-k similarities for the base image.
        patch_size: side of the relu3_3 patches compared (odd; 15 = 60 px of context).
        iterations: kept for API compatibility with ``Mariner`` (the model runs once).
        min_reference_size: smallest reference side in pixels.
        max_match_positions: render x reference relu3_3 positions compared per chunk (memory).
        gated: the decoder also predicts a per-pixel confidence ``g`` in (0, 1) and the output is
            ``base + g * correction``: where it is unsure (e.g. on a scene unlike its training
            data) the output stays at the matching-only base. False for the older weights.
    """

    architecture: str = ARCHITECTURE
    top_k: int = 4
    channels: int = 32
    blocks: tuple[int, int, int] = (2, 2, 3)
    temperature: float = 0.02
    patch_size: int = 15
    iterations: int = 1
    min_reference_size: int = 32
    max_match_positions: int = 32_000_000
    gated: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "blocks", tuple(int(b) for b in self.blocks))
        if self.architecture != ARCHITECTURE:
            raise ValueError(f"architecture must be {ARCHITECTURE!r}, got {self.architecture!r}")
        if not 1 <= self.top_k <= 16:
            raise ValueError(f"top_k must be in [1, 16], got {self.top_k}")
        if self.channels < 4 or len(self.blocks) != 3 or min(self.blocks) < 0:
            raise ValueError(f"bad channels / blocks: {self.channels}, {self.blocks}")
        if self.patch_size < 1 or self.patch_size % 2 == 0:
            raise ValueError(f"patch_size must be odd and positive, got {self.patch_size}")
        if not self.temperature > 0:
            raise ValueError(f"temperature must be > 0, got {self.temperature}")
        if self.min_reference_size < 3 * STRIDE:
            raise ValueError(f"min_reference_size must be >= {3 * STRIDE}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FrozenMarinerConfig:
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise ValueError(
                f"unknown FrozenMarinerConfig key(s) {unknown} (allowed: {sorted(allowed)})"
            )
        return cls(**data)


class _VGGTo33(nn.Module):
    """The first seven VGG16 convs (relu1_1 .. relu3_3); frozen."""

    mean: torch.Tensor  # buffers (register_buffer)
    std: torch.Tensor

    def __init__(self) -> None:
        super().__init__()
        self.convs = VGG16Features().convs[:7]
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))
        self.requires_grad_(False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = (x - self.mean) / self.std
        for i, conv in enumerate(self.convs):
            y = torch.relu(conv(y))
            if i in (1, 3):
                y = F.max_pool2d(y, 2, 2)
        return y


def _pad_to(x: torch.Tensor, multiple: int) -> tuple[torch.Tensor, tuple[int, int]]:
    """Replicate-pad bottom/right to a multiple; returns the padded tensor and the (h, w) before."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    return x, (h, w)


def colour_transfer(render: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Per-channel mean / std of the render's covered (non-black) pixels moved to the
    reference's; (N, 3, H, W) x2 -> (N, 3, H, W) in [0, 1], uncovered pixels stay 0."""
    mask = (render.sum(1, keepdim=True) > 1e-3).to(render.dtype)
    n = mask.sum((2, 3), keepdim=True).clamp_min(1.0)
    mu = (render * mask).sum((2, 3), keepdim=True) / n
    sd = (((render - mu) ** 2 * mask).sum((2, 3), keepdim=True) / n).sqrt()
    mu_r = reference.mean((2, 3), keepdim=True)
    sd_r = reference.std((2, 3), keepdim=True)
    out = (render - mu) / (sd + 0.02) * sd_r + mu_r
    return (out * mask).clamp(0.0, 1.0)


class _Res(nn.Module):
    def __init__(self, c: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c, c, 3, padding=1)
        self.conv2 = nn.Conv2d(c, c, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.leaky_relu(self.conv1(x), 0.2))


def _stage(c_in: int, c: int, n: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c, 3, padding=1), nn.LeakyReLU(0.2),
                         *[_Res(c) for _ in range(n)])


class FrozenMariner(nn.Module):
    """Frozen VGG16 matching (``prepare``) + trained three-scale fusion U-Net (``fuse``).

    ``forward(render, reference, iterations=None)`` returns a one-element list of (N, 3, H, W)
    unclamped outputs, like :class:`mariner_core.model.Mariner`.
    """

    def __init__(self, cfg: FrozenMarinerConfig | None = None) -> None:
        super().__init__()
        self.cfg = cfg if cfg is not None else FrozenMarinerConfig()
        k, c = self.cfg.top_k, self.cfg.channels
        self.vgg = _VGGTo33()
        c_in = 3 + 3 * k + k + 3 + 3  # render, warped refs, scores, colour transfer, base
        b = self.cfg.blocks
        self.enc1 = _stage(c_in, c, b[0])
        self.enc2 = _stage(c, 2 * c, b[1])
        self.enc3 = _stage(2 * c, 4 * c, b[2])
        self.up3 = nn.Conv2d(4 * c, 2 * c, 1)
        self.dec2 = _stage(4 * c, 2 * c, b[1])
        self.up2 = nn.Conv2d(2 * c, c, 1)
        self.dec1 = _stage(2 * c, c, b[0])
        self.head = nn.Conv2d(c, 4 if self.cfg.gated else 3, 3, padding=1)
        nn.init.zeros_(self.head.weight)
        assert self.head.bias is not None  # Conv2d's default bias=True
        nn.init.zeros_(self.head.bias)
        if self.cfg.gated:  # start at the base, with a small confidence: corrections are earned
            with torch.no_grad():
                self.head.bias[3] = GATE_BIAS

    @classmethod
    def from_pretrained(cls, path: str) -> FrozenMariner:
        """Load a checkpoint strictly (``weights_only=True``); it must be a frozen-matcher one."""
        from .checkpoint import read_checkpoint

        ckpt = read_checkpoint(path)
        config = dict(ckpt["config"])
        if config.get("architecture") != ARCHITECTURE:
            raise ValueError(f"{path} holds a Mariner (the spec network), not a FrozenMariner")
        model = cls(FrozenMarinerConfig.from_dict(config))
        model.load_state_dict(ckpt["state_dict"], strict=True)  # fp16 storage: cast to float32
        return model

    # -- frozen part -------------------------------------------------------------------------
    def load_vgg(self, state_dict: dict[str, torch.Tensor]) -> None:
        """Load the ImageNet VGG16 (``pretrained.backbone_state_dict('vgg16')``) into the
        frozen matcher; only convs 0-6 are used."""
        sd = {k: v for k, v in state_dict.items() if int(k.split(".")[1]) < 7}
        self.vgg.load_state_dict({**sd, "mean": self.vgg.mean, "std": self.vgg.std}, strict=True)

    def train(self, mode: bool = True) -> FrozenMariner:
        super().train(mode)
        self.vgg.eval()
        return self

    @staticmethod
    def match_pairs(render_hw: tuple[int, int], reference_hw: tuple[int, int]) -> float:
        """relu3_3 positions compared by the global matching of a render / reference pair of
        these (H, W) sizes: its time and memory are proportional to this."""
        def positions(hw: tuple[int, int]) -> float:
            return float(-(-int(hw[0]) // STRIDE)) * float(-(-int(hw[1]) // STRIDE))

        return positions(render_hw) * positions(reference_hw)

    @torch.no_grad()
    def match(
        self, render: torch.Tensor, reference: torch.Tensor,
        reference_features: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Top-k global patch matches at relu3_3 (cosine of ``patch_size``^2-position patches).

        The patch similarity is summed from the pointwise one along both images' shifts,
        separably (x, then y): 2 x ``patch_size`` additions per pair instead of a
        ``patch_size``^2 times longer descriptor.

        Args:
            render: (N, 3, H, W), H and W multiples of 4; reference: (N, 3, Hr, Wr), same.

        Returns:
            (scores, indices), each (N, k, H/4, W/4): cosine similarity and the flat relu3_3
            position of the reference patch. ``reference_features`` (``self.vgg(reference)``)
            skips the reference's forward pass when one photo serves many renders.
        """
        if render.shape[0] > 1:  # one image at a time: the chunk size is per image
            parts = [
                self.match(render[b : b + 1], reference[b : b + 1],
                           None if reference_features is None else reference_features[b : b + 1])
                for b in range(render.shape[0])
            ]
            return torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])
        f_r = self.vgg(render)
        f_p = self.vgg(reference) if reference_features is None else reference_features
        n, _, h4, w4 = f_r.shape
        hp, wp = f_p.shape[-2:]
        r = self.cfg.patch_size // 2
        area = float(self.cfg.patch_size**2)
        norm_r = patch_norm(f_r, r, area).flatten(1)  # (N, Lr)
        norm_p = patch_norm(f_p, r, area).flatten(1)  # (N, Lp)
        fr = F.pad(f_r, (r, r, r, r))
        fp = F.pad(f_p, (r, r, r, r))
        lp = hp * wp
        k = min(self.cfg.top_k, lp)
        per_row = (w4 + 2 * r) * (hp + 2 * r) * (wp + 2 * r) * n
        # chunks of render rows; each carries a 2r-row halo, so keep them much taller than 2r
        rows = max(1, 4 * r, self.cfg.max_match_positions // per_row - 2 * r)
        scores, idx = [], []
        for y0 in range(0, h4, rows):
            y1 = min(h4, y0 + rows)
            acc = patch_dots(fr[:, :, y0 : y1 + 2 * r], fp, r, y1 - y0, w4, hp, wp)
            den = norm_r[:, y0 * w4 : y1 * w4, None] * norm_p[:, None, :] + 1e-6
            v, i = (acc / den).topk(k, dim=2)
            scores.append(v)
            idx.append(i)
        sc = torch.cat(scores, 1).transpose(1, 2).reshape(n, k, h4, w4)
        ix = torch.cat(idx, 1).transpose(1, 2).reshape(n, k, h4, w4)
        if k < self.cfg.top_k:  # tiny references: repeat the last rank
            sc, ix = repeat_last_rank(sc, ix, self.cfg.top_k - k)
        return sc, ix

    @staticmethod
    def transfer(reference: torch.Tensor, indices: torch.Tensor, size: tuple[int, int]):
        """Paste the reference's 12x12-px patch of each match at its render patch, averaging
        overlaps. reference (N, 3, Hr, Wr); indices (N, k, H/4, W/4) -> (N, k, 3, H, W)."""
        n, k, h4, w4 = indices.shape
        p = 3 * STRIDE
        patches = F.unfold(reference, p, padding=STRIDE, stride=STRIDE)  # (N, 3*p*p, Lp)
        ones = torch.ones(1, 1, size[0], size[1], dtype=reference.dtype, device=reference.device)
        norm = F.fold(
            F.unfold(ones, p, padding=STRIDE, stride=STRIDE), size, p, padding=STRIDE,
            stride=STRIDE,
        )
        out = []
        for r in range(k):
            ix = indices[:, r].reshape(n, 1, -1).expand(-1, patches.shape[1], -1)
            sel = torch.gather(patches, 2, ix)
            out.append(F.fold(sel, size, p, padding=STRIDE, stride=STRIDE) / norm)
        return torch.stack(out, 1)

    @torch.no_grad()
    def features(self, image: torch.Tensor) -> torch.Tensor:
        """relu3_3 of an image padded as ``prepare`` pads it: (N, 3, H, W) -> (N, 256, ~H/4,
        ~W/4); pass it as ``reference_features`` when one photo serves many renders."""
        return self.vgg(_pad_to(image, STRIDE)[0])

    @staticmethod
    def upsample_scores(score: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
        """(N, k, H/4, W/4) similarities -> (N, k, H, W) (bilinear), as ``fuse`` reads them."""
        return F.interpolate(score, size=size, mode="bilinear", align_corners=False)

    @torch.no_grad()
    def prepare(
        self, render: torch.Tensor, reference: torch.Tensor, low_res_scores: bool = False,
        reference_features: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """Everything the decoder reads, computed with frozen weights only (cacheable).

        Args: render (N, 3, H, W), reference (N, 3, Hr, Wr), RGB in [0, 1]; padded here to a
        multiple of 4 (bottom / right). Returns ``PREPARED_KEYS`` tensors at the padded size:
        render (N, 3), warped (N, 3k), score (N, k) (at 1/4 size with ``low_res_scores``, for
        caches: ``upsample_scores`` restores what ``fuse`` reads), colour (N, 3).
        """
        x, _ = _pad_to(render, STRIDE)
        ref, _ = _pad_to(reference, STRIDE)
        sc, ix = self.match(x, ref, reference_features)
        h, w = x.shape[-2:]
        warped = self.transfer(ref, ix, (h, w)).flatten(1, 2)
        score = sc if low_res_scores else self.upsample_scores(sc, (h, w))
        return {"render": x, "warped": warped, "score": score, "colour": colour_transfer(x, ref)}

    # -- trained part ------------------------------------------------------------------------
    def base(self, prep: dict[str, torch.Tensor]) -> torch.Tensor:
        """Similarity-weighted mean of the warped references, (N, 3, H, W)."""
        k = self.cfg.top_k
        w = torch.softmax(prep["score"] / self.cfg.temperature, dim=1)  # (N, k, H, W)
        warped = prep["warped"].unflatten(1, (k, 3))
        return (warped * w.unsqueeze(2)).sum(1)

    def _decode(self, prep: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """(base (N, 3, H, W), head output (N, 3 or 4, H, W)) of prepared inputs."""
        base = self.base(prep)
        x = torch.cat([prep["render"], prep["warped"], prep["score"], prep["colour"], base], 1)
        h, w = x.shape[-2:]
        x, _ = _pad_to(x, STRIDE)
        e1 = self.enc1(x)
        e2 = self.enc2(F.avg_pool2d(e1, 2))
        e3 = self.enc3(F.avg_pool2d(e2, 2))
        d2 = self.dec2(torch.cat([e2, F.interpolate(self.up3(e3), scale_factor=2.0)], 1))
        d1 = self.dec1(torch.cat([e1, F.interpolate(self.up2(d2), scale_factor=2.0)], 1))
        return base, self.head(d1)[..., :h, :w]

    def fuse(self, prep: dict[str, torch.Tensor]) -> torch.Tensor:
        """Prepared inputs (any H, W that are multiples of 4) -> (N, 3, H, W) unclamped."""
        base, out = self._decode(prep)
        if not self.cfg.gated:
            return base + out
        return base + torch.sigmoid(out[:, 3:4]) * out[:, :3]

    def confidence(self, prep: dict[str, torch.Tensor]) -> torch.Tensor:
        """The gate ``g`` (N, 1, H, W) of a gated model; ones for an ungated one."""
        if not self.cfg.gated:
            r = prep["render"]
            return torch.ones(r.shape[0], 1, *r.shape[-2:], dtype=r.dtype)
        return torch.sigmoid(self._decode(prep)[1][:, 3:4])

    def check_inputs(self, render: torch.Tensor, reference: torch.Tensor) -> None:
        """Validate render/reference tensors; raises ValueError with the reason."""
        from .model import check_image_pair

        check_image_pair(render, reference)
        m = self.cfg.min_reference_size
        if min(reference.shape[-2:]) < m or min(render.shape[-2:]) < 2:
            raise ValueError(
                f"reference {tuple(reference.shape[-2:])} must be >= {m} px per side and the "
                f"render at least 2 px: {tuple(render.shape[-2:])}"
            )

    def forward(
        self, render: torch.Tensor, reference: torch.Tensor, iterations: int | None = None,
        output: str = "model",
    ) -> list[torch.Tensor]:
        """(N, 3, H, W) render + (N, 3, Hr, Wr) reference -> [(N, 3, H, W)] unclamped.

        ``output``: "model" (the decoder's output), "base" (the matching-only base, no trained
        weights: what ``scene_check`` falls back to on a scene the decoder does not improve) or
        "both" ([model, base] from one matching)."""
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        self.check_inputs(render, reference)
        if iterations is not None and int(iterations) < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        h, w = render.shape[-2:]
        prep = self.prepare(render, reference)
        if output == "base":
            return [self.base(prep)[..., :h, :w]]
        y = self.fuse(prep)[..., :h, :w]
        if output == "both":
            return [y, self.base(prep)[..., :h, :w]]
        return [y]

    def num_trainable(self) -> int:
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

