"""Matching & Extraction Module (MEM, spec §3): correspondence search at L3, transfer to L1-L3.

Everything here is parameter-free and vectorised (unfold / batched matmul / gathers): there is
no Python loop over pixels or blocks. Conventions (all coordinates are integer L3 pixels,
(row, col), OpenCV-style pixel centres):

* the render L3 map (H3 x W3, multiples of ``block``) is split into ``B = nH * nW`` blocks;
* Stage A (``coarse_match``): one reference centre per block from the sum over dilations of
  cosine scores between the block-centre 3x3 (dilated) patch and every reference 3x3 patch;
* the block's reference window (``(Sh + 2) x (Sw + 2)`` L3 px) is centred on that match and shifted
  to lie inside the reference;
* Stage B (``fine_match``): every L3 render pixel's 3x3 patch (replicate-padded render) against
  the ``Sh x Sw`` 3x3 patches of its block's window; argmax gives index and cosine score;
* transfer (``transfer``): for level scale ``s`` the 3s x 3s reference patch of every L3 pixel
  is pasted centred on that pixel's footprint inside its block, overlaps are averaged and the
  result is weighted by the bilinearly upsampled (per block) Stage-B score.

``transfer`` is written as a per-output-pixel gather that is mathematically identical to the
spec's unfold -> gather -> fold -> divide formulation (tests check this against a literal
implementation) but never materialises the (N*B) x (C*9s^2) x K unfolded windows.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

logger = logging.getLogger(__name__)

__all__ = [
    "MatchResult",
    "MEM",
    "coarse_match",
    "fine_match",
    "transfer",
    "window_size",
]


@dataclass
class MatchResult:
    """Correspondences from render L3 pixels to reference L3 pixels.

    Attributes:
        index: (N, H3, W3) int64, Stage-B key index in the block's window, in [0, Sh*Sw).
        score: (N, 1, H3, W3) float, Stage-B cosine score in [-1, 1] (differentiable).
        center: (N, 2, H3, W3) int64, matched reference L3 pixel (row, col) (key patch centre).
        coarse_center: (N, B, 2) int64, Stage-A reference centre per block (row, col).
        window_topleft: (N, B, 2) int64, top-left (row, col) of each block's L3 window.
        window: (Sh, Sw), the number of key positions per window axis.
    """

    index: torch.Tensor
    score: torch.Tensor
    center: torch.Tensor
    coarse_center: torch.Tensor
    window_topleft: torch.Tensor
    window: tuple[int, int]


def window_size(ref_len: int, n_blocks: int, factor: float) -> int:
    """Odd number of key positions per axis of a block's search window (spec §3.1).

    ``2 * floor(floor(ref_len / (2 * n_blocks)) * factor) + 1``, additionally clamped to
    ``ref_len - 2`` (and kept odd) so that the window plus its 1-px margin fits in the
    reference; the spec's formula alone can exceed small references (e.g. a single block).
    """
    s = 2 * math.floor(math.floor(ref_len / (2 * n_blocks)) * factor) + 1
    s = min(s, ref_len - 2)
    if s % 2 == 0:
        s -= 1
    if s < 1:
        raise ValueError(f"reference L3 size {ref_len} too small for a 3x3 window")
    return s


def _check_pair(f_render: torch.Tensor, f_ref: torch.Tensor, block: int) -> None:
    if f_render.ndim != 4 or f_ref.ndim != 4:
        raise ValueError("MEM expects (N, C, H, W) feature maps")
    if f_render.shape[:2] != f_ref.shape[:2]:
        raise ValueError(
            f"render/reference features differ in batch or channels: "
            f"{tuple(f_render.shape)} vs {tuple(f_ref.shape)}"
        )
    h3, w3 = f_render.shape[-2:]
    if h3 % block or w3 % block:
        raise ValueError(f"render L3 size {h3}x{w3} is not a multiple of block {block}")
    if min(f_ref.shape[-2:]) < 3:
        raise ValueError(f"reference L3 size {tuple(f_ref.shape[-2:])} is below 3x3")


@torch.no_grad()
def coarse_match(
    f_render: torch.Tensor,
    f_ref: torch.Tensor,
    block: int = 8,
    dilations: tuple[int, ...] = (1, 2, 3),
) -> torch.Tensor:
    """Stage A: one reference centre per render block (no gradient).

    Args:
        f_render: (N, C, H3, W3) render L3 features, H3 and W3 multiples of ``block``.
        f_ref: (N, C, Hr, Wr) reference L3 features.

    Returns:
        (N, B, 2) int64 (row, col) reference centres, blocks in row-major order.
    """
    _check_pair(f_render, f_ref, block)
    n, c, h3, w3 = f_render.shape
    hr, wr = f_ref.shape[-2:]
    nh, nw = h3 // block, w3 // block
    dev = f_render.device
    cy = torch.arange(nh, device=dev) * block + block // 2
    cx = torch.arange(nw, device=dev) * block + block // 2
    offs = torch.tensor([-1, 0, 1], device=dev)
    total = None
    for d in dilations:
        rows = (cy[:, None] + d * offs[None, :]).clamp_(0, h3 - 1)  # (nh, 3)
        cols = (cx[:, None] + d * offs[None, :]).clamp_(0, w3 - 1)  # (nw, 3)
        q = f_render[:, :, rows[:, :, None, None], cols[None, None, :, :]]  # N,C,nh,3,nw,3
        q = q.permute(0, 2, 4, 1, 3, 5).reshape(n, nh * nw, c * 9)
        q = F.normalize(q, dim=2, eps=1e-12)
        k = F.unfold(f_ref, 3, dilation=d, padding=d)  # N, C*9, Hr*Wr
        k = F.normalize(k, dim=1, eps=1e-12)
        s = torch.bmm(q, k)  # N, B, Hr*Wr
        total = s if total is None else total.add_(s)
    assert total is not None  # at least one dilation
    flat = total.argmax(dim=2)
    return torch.stack((flat // wr, flat % wr), dim=2)


def window_topleft(
    coarse_center: torch.Tensor, ref_hw: tuple[int, int], window: tuple[int, int]
) -> torch.Tensor:
    """Top-left of each (Sh+2) x (Sw+2) window centred on the Stage-A match, shifted inside.

    Args:
        coarse_center: (N, B, 2) int64 (row, col).
    Returns:
        (N, B, 2) int64.
    """
    sizes = torch.tensor([window[0] + 2, window[1] + 2], device=coarse_center.device)
    hi = torch.tensor(ref_hw, device=coarse_center.device) - sizes
    tl = coarse_center - sizes // 2
    return torch.minimum(tl.clamp(min=0), hi)


def fine_match(
    f_render: torch.Tensor,
    f_ref: torch.Tensor,
    topleft: torch.Tensor,
    window: tuple[int, int],
    block: int = 8,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Stage B: dense search of every render L3 pixel inside its block's reference window.

    Args:
        f_render: (N, C, H3, W3) render L3 features.
        f_ref: (N, C, Hr, Wr) reference L3 features.
        topleft: (N, B, 2) int64 window top-left corners (row, col).
        window: (Sh, Sw) key positions per window axis.

    Returns:
        index: (N, H3, W3) int64 in [0, Sh*Sw), key = (index // Sw, index % Sw);
        score: (N, 1, H3, W3) cosine score (differentiable w.r.t. both feature maps).
    """
    _check_pair(f_render, f_ref, block)
    n, c, h3, w3 = f_render.shape
    hr, wr = f_ref.shape[-2:]
    nh, nw = h3 // block, w3 // block
    sh, sw = window
    dev = f_render.device
    # Queries: 3x3 patches of the replicate-padded render, grouped by block.
    q = F.unfold(F.pad(f_render, (1, 1, 1, 1), mode="replicate"), 3)  # N, C9, H3*W3
    q = q.view(n, c * 9, nh, block, nw, block).permute(0, 2, 4, 3, 5, 1)
    q = F.normalize(q.reshape(n, nh * nw, block * block, c * 9), dim=3, eps=1e-12)
    # Keys: all valid 3x3 reference patches, gathered per window.
    k = F.normalize(F.unfold(f_ref, 3), dim=1, eps=1e-12).transpose(1, 2)  # N, Lv, C9
    ii = torch.arange(sh, device=dev)
    jj = torch.arange(sw, device=dev)
    kidx = (topleft[..., 0, None, None] + ii[:, None]) * (wr - 2) + (
        topleft[..., 1, None, None] + jj[None, :]
    )  # N, B, Sh, Sw
    kidx = kidx.reshape(n, -1, 1).expand(-1, -1, c * 9)
    kw = torch.gather(k, 1, kidx).view(n, nh * nw, sh * sw, c * 9)
    sim = torch.matmul(q, kw.transpose(2, 3))  # N, B, b*b, K
    score, index = sim.max(dim=3)

    # Back to image layout.
    def to_map(t: torch.Tensor) -> torch.Tensor:
        return t.view(n, nh, nw, block, block).permute(0, 1, 3, 2, 4).reshape(n, h3, w3)

    return to_map(index), to_map(score).unsqueeze(1)


def match_centers(
    index: torch.Tensor, topleft: torch.Tensor, window: tuple[int, int], block: int
) -> torch.Tensor:
    """Reference L3 centre (row, col) of each pixel's matched key: (N, H3, W3) -> (N, 2, H3, W3)."""
    n, h3, w3 = index.shape
    nh, nw = h3 // block, w3 // block
    tl = topleft.view(n, nh, nw, 2).repeat_interleave(block, 1).repeat_interleave(block, 2)
    row = tl[..., 0] + index // window[1] + 1
    col = tl[..., 1] + index % window[1] + 1
    return torch.stack((row, col), dim=1)


def transfer(
    ref_feat: torch.Tensor, center: torch.Tensor, score: torch.Tensor, scale: int, block: int = 8
) -> torch.Tensor:
    """Warp reference features of one level to the render grid (spec §3.6).

    Args:
        ref_feat: (N, C, scale*Hr, scale*Wr) reference features at this level.
        center: (N, 2, H3, W3) int64 matched reference L3 centres (row, col).
        score: (N, 1, H3, W3) Stage-B scores.
        scale: 1 (L3), 2 (L2) or 4 (L1).

    Returns:
        (N, C, scale*H3, scale*W3) warped features: the average of the (up to 9) overlapping
        3s x 3s patches pasted inside each block, times the per-block bilinear score map.
    """
    n, c, hrs, wrs = ref_feat.shape
    _, _, h3, w3 = center.shape
    s = scale
    hs, ws = h3 * s, w3 * s
    dev = ref_feat.device
    py = torch.arange(hs, device=dev)
    px = torch.arange(ws, device=dev)
    qy0, qx0 = py // s, px // s  # L3 pixel of each output pixel
    ly, lx = qy0 % block, qx0 % block  # position inside the block
    yy = torch.arange(h3, device=dev)[None, :, None]
    xx = torch.arange(w3, device=dev)[None, None, :]
    disp_y = center[:, 0] - yy  # N, H3, W3
    disp_x = center[:, 1] - xx
    ref_rows = ref_feat.permute(0, 2, 3, 1).reshape(n * hrs * wrs, c)
    base = (torch.arange(n, device=dev) * (hrs * wrs))[:, None, None]
    out = ref_feat.new_zeros(n, hs, ws, c)
    count_y = torch.zeros(hs, device=dev, dtype=ref_feat.dtype)
    count_x = torch.zeros(ws, device=dev, dtype=ref_feat.dtype)
    for d in (-1, 0, 1):
        count_y += ((ly + d >= 0) & (ly + d < block)).to(ref_feat.dtype)
        count_x += ((lx + d >= 0) & (lx + d < block)).to(ref_feat.dtype)
    for dy in (-1, 0, 1):
        vy = (ly + dy >= 0) & (ly + dy < block)
        qy = torch.where(vy, qy0 + dy, qy0)
        for dx in (-1, 0, 1):
            vx = (lx + dx >= 0) & (lx + dx < block)
            qx = torch.where(vx, qx0 + dx, qx0)
            ry = py[None, :, None] + s * disp_y[:, qy[:, None], qx[None, :]]
            rx = px[None, None, :] + s * disp_x[:, qy[:, None], qx[None, :]]
            vals = ref_rows[base + ry * wrs + rx]  # N, Hs, Ws, C
            mask = (vy[:, None] & vx[None, :]).to(ref_feat.dtype)[None, :, :, None]
            out += vals * mask
    out = out / (count_y[:, None] * count_x[None, :])[None, :, :, None]
    out = out.permute(0, 3, 1, 2)
    weight = _score_weight(score, n, h3, w3, s, block)
    return out * weight.to(out.dtype)


def _score_weight(
    score: torch.Tensor, n: int, h3: int, w3: int, s: int, block: int
) -> torch.Tensor:
    """Stage-B scores (N, 1, H3, W3) at level scale ``s``: as they are for ``s == 1``, else
    upsampled bilinearly within each block -> (N, 1, s*H3, s*W3)."""
    if s == 1:
        return score
    hs, ws = h3 * s, w3 * s
    nh, nw = h3 // block, w3 // block
    blk = score.view(n, 1, nh, block, nw, block).permute(0, 2, 4, 1, 3, 5)
    blk = F.interpolate(
        blk.reshape(n * nh * nw, 1, block, block),
        scale_factor=s,
        mode="bilinear",
        align_corners=False,
    )
    return (
        blk.view(n, nh, nw, 1, block * s, block * s)
        .permute(0, 3, 1, 4, 2, 5)
        .reshape(n, 1, hs, ws)
    )


class MEM(nn.Module):
    """Parameter-free correspondence matching at L3 and feature transfer to all levels."""

    def __init__(
        self,
        block: int = 8,
        window_factor: float = 1.5,
        dilations: tuple[int, ...] = (1, 2, 3),
    ) -> None:
        super().__init__()
        self.block = block
        self.window_factor = window_factor
        self.dilations = tuple(dilations)

    def match(self, f3_render: torch.Tensor, f3_ref: torch.Tensor) -> MatchResult:
        """Stage A + windows + Stage B on L3 features (N, C, H3, W3) / (N, C, Hr, Wr)."""
        _check_pair(f3_render, f3_ref, self.block)
        h3, w3 = f3_render.shape[-2:]
        hr, wr = f3_ref.shape[-2:]
        win = (
            window_size(hr, h3 // self.block, self.window_factor),
            window_size(wr, w3 // self.block, self.window_factor),
        )
        coarse = coarse_match(f3_render, f3_ref, self.block, self.dilations)
        tl = window_topleft(coarse, (hr, wr), win)
        index, score = fine_match(f3_render, f3_ref, tl, win, self.block)
        center = match_centers(index, tl, win, self.block)
        return MatchResult(index, score, center, coarse, tl, win)

    def forward(
        self,
        render_feats: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
        ref_feats: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    ) -> tuple[tuple[torch.Tensor, torch.Tensor, torch.Tensor], MatchResult]:
        """Match at L3 and warp reference features of every level to the render grid.

        Args:
            render_feats: (F1, F2, F3) render features, (N, C, 4h, 4w), (N, C, 2h, 2w), (N, C, h, w)
                with h, w multiples of ``block``.
            ref_feats: (R1, R2, R3) reference features, (N, C, 4hr, 4wr), ..., (N, C, hr, hr).

        Returns:
            ((W1, W2, W3), match): warped features with the render features' shapes.
        """
        for lvl, scale in ((0, 4), (1, 2)):
            for name, feats in (("render", render_feats), ("reference", ref_feats)):
                want = tuple(scale * v for v in feats[2].shape[-2:])
                if tuple(feats[lvl].shape[-2:]) != want:
                    raise ValueError(
                        f"{name} level-{lvl + 1} features are {tuple(feats[lvl].shape[-2:])}, "
                        f"expected {want} ({scale}x the L3 size)"
                    )
        m = self.match(render_feats[2], ref_feats[2])
        warped = tuple(
            transfer(ref_feats[lvl], m.center, m.score, scale, self.block)
            for lvl, scale in ((0, 4), (1, 2), (2, 1))
        )
        return warped, m  # type: ignore[return-value]
