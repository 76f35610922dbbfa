"""The frozen matcher's patch arithmetic (``FrozenMariner.match``): patch norms, patch dot
products of render rows against a whole reference, and rank padding. Split out of
``frozen.py`` (its size); ``tests/mariner_core/test_frozen.py`` checks the matching they make
against brute force."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def patch_norm(f: torch.Tensor, r: int, area: float) -> torch.Tensor:
    """|patch|^2 by a box filter (zero padding, as the patches in ``patch_dots``), square-rooted:
    (N, C, H, W) -> (N, 1, H, W) norms of the (2r+1)^2-position patches."""
    e = f.pow(2).sum(1, keepdim=True)
    return (F.avg_pool2d(e, 2 * r + 1, 1, r, count_include_pad=True) * area).sqrt()


def patch_dots(
    fr: torch.Tensor, fp: torch.Tensor, r: int, h: int, w4: int, hp: int, wp: int
) -> torch.Tensor:
    """Patch dot products of ``h`` render rows against every reference patch.

    ``fr``: the padded render rows y0-r .. y1+r (N, C, h + 2r, w4 + 2r); ``fp``: the padded
    reference (N, C, hp + 2r, wp + 2r). Returns (N, h * w4, hp * wp).
    """
    n = fr.shape[0]
    # pointwise similarities of the padded rows y0-r .. y1+r against the padded reference
    s = torch.einsum("ncyx,ncij->nyxij", fr, fp)
    # patch dot product: sum over offsets d of S[p + d, q + d] (both indices shifted),
    # separable: first along x, then along y
    ax = s[:, :, 0:w4, :, 0:wp].clone()
    for dx in range(1, 2 * r + 1):
        ax += s[:, :, dx : dx + w4, :, dx : dx + wp]
    acc = ax[:, 0:h, :, 0:hp].clone()
    for dy in range(1, 2 * r + 1):
        acc += ax[:, dy : dy + h, :, dy : dy + hp]
    return acc.reshape(n, h * w4, hp * wp)


def repeat_last_rank(
    sc: torch.Tensor, ix: torch.Tensor, rep: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Append ``rep`` copies of the last match rank to scores and indices (N, k, h, w)."""
    sc = torch.cat([sc, sc[:, -1:].expand(-1, rep, -1, -1)], 1)
    ix = torch.cat([ix, ix[:, -1:].expand(-1, rep, -1, -1)], 1)
    return sc, ix
