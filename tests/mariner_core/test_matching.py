from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from mariner_core.matching import MEM, transfer, window_size

BLOCK = 8


def _cos(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a / a.norm().clamp_min(1e-12)) @ (b / b.norm().clamp_min(1e-12)))


def brute_force(fr: torch.Tensor, fref: torch.Tensor, dilations=(1, 2, 3), factor=1.5):
    """Loop-based transcription of spec §3.2-3.5 for one image (C, H3, W3), (C, Hr, Wr)."""
    c, h3, w3 = fr.shape
    _, hr, wr = fref.shape
    nh, nw = h3 // BLOCK, w3 // BLOCK
    sh, sw = window_size(hr, nh, factor), window_size(wr, nw, factor)
    tiles = F.pad(fr[None], (1, 1, 1, 1), mode="replicate")[0]
    index = torch.zeros(h3, w3, dtype=torch.long)
    score = torch.zeros(h3, w3, dtype=fr.dtype)
    coarse = []
    for by in range(nh):
        for bx in range(nw):
            tile = tiles[:, by * 8 : by * 8 + 10, bx * 8 : bx * 8 + 10]
            best, best_pos = -1e9, None
            for u in range(hr):
                for v in range(wr):
                    total = 0.0
                    for d in dilations:
                        q = torch.stack(
                            [tile[:, 5 + d * i, 5 + d * j] for i in (-1, 0, 1) for j in (-1, 0, 1)],
                            1,
                        )
                        refp = F.pad(fref, (d, d, d, d))
                        k = torch.stack(
                            [
                                refp[:, u + d + d * i, v + d + d * j]
                                for i in (-1, 0, 1)
                                for j in (-1, 0, 1)
                            ],
                            1,
                        )
                        total += _cos(q.flatten(), k.flatten())
                    if total > best:
                        best, best_pos = total, (u, v)
            coarse.append(best_pos)
            ty = min(max(best_pos[0] - (sh + 2) // 2, 0), hr - (sh + 2))
            tx = min(max(best_pos[1] - (sw + 2) // 2, 0), wr - (sw + 2))
            win = fref[:, ty : ty + sh + 2, tx : tx + sw + 2]
            keys = torch.stack(
                [win[:, i : i + 3, j : j + 3].flatten() for i in range(sh) for j in range(sw)]
            )
            keys = keys / keys.norm(dim=1, keepdim=True)
            for py in range(8):
                for px in range(8):
                    q = tile[:, py : py + 3, px : px + 3].flatten()
                    sims = keys @ (q / q.norm())
                    index[by * 8 + py, bx * 8 + px] = int(sims.argmax())
                    score[by * 8 + py, bx * 8 + px] = sims.max()
    return torch.tensor(coarse), index, score, (sh, sw)


def test_window_size_formula():
    assert window_size(40, 5, 1.5) == 13  # 160x160 render and reference
    assert window_size(15, 1, 1.5) == 13  # clamped to fit a 15-px reference


def test_mem_matches_brute_force():
    g = torch.Generator().manual_seed(3)
    fr = torch.randn(2, 4, 16, 24, generator=g, dtype=torch.float64)
    fref = torch.randn(2, 4, 18, 20, generator=g, dtype=torch.float64)
    m = MEM(BLOCK).match(fr, fref)
    for n in range(2):
        coarse, index, score, win = brute_force(fr[n], fref[n])
        assert m.window == win
        torch.testing.assert_close(m.coarse_center[n], coarse)
        torch.testing.assert_close(m.index[n], index)
        torch.testing.assert_close(m.score[n, 0], score)


def literal_transfer(ref_feat, index, score, topleft, window, s):
    """Spec §3.6 per block: unfold window, gather, fold, divide, weight (one image)."""
    c = ref_feat.shape[0]
    sh, sw = window
    h3, w3 = index.shape
    out = torch.zeros(c, h3 * s, w3 * s, dtype=ref_feat.dtype)
    nw = w3 // BLOCK
    ones = torch.ones(1, 9 * s * s, 64, dtype=ref_feat.dtype)
    count = F.fold(ones, 8 * s, 3 * s, stride=s, padding=s)
    for b, (ty, tx) in enumerate(topleft.tolist()):
        by, bx = divmod(b, nw)
        win = ref_feat[:, s * ty : s * (ty + sh + 2), s * tx : s * (tx + sw + 2)]
        patches = F.unfold(win[None], 3 * s, stride=s)[0]  # C*9s^2, K
        assert patches.shape[1] == sh * sw
        idx = index[by * 8 : by * 8 + 8, bx * 8 : bx * 8 + 8].flatten()
        folded = F.fold(patches[:, idx][None], 8 * s, 3 * s, stride=s, padding=s) / count
        sc = score[by * 8 : by * 8 + 8, bx * 8 : bx * 8 + 8][None, None]
        wgt = (
            F.interpolate(sc, scale_factor=s, mode="bilinear", align_corners=False) if s > 1 else sc
        )
        out[:, by * 8 * s : (by + 1) * 8 * s, bx * 8 * s : (bx + 1) * 8 * s] = (folded * wgt)[0]
    return out


def test_transfer_equals_literal_unfold_fold():
    g = torch.Generator().manual_seed(5)
    fr = torch.randn(1, 4, 16, 16, generator=g, dtype=torch.float64)
    fref = torch.randn(1, 4, 20, 18, generator=g, dtype=torch.float64)
    m = MEM(BLOCK).match(fr, fref)
    for s in (1, 2, 4):
        ref_s = torch.randn(1, 3, 20 * s, 18 * s, generator=g, dtype=torch.float64)
        fast = transfer(ref_s, m.center, m.score, s, BLOCK)
        lit = literal_transfer(
            ref_s[0], m.index[0], m.score[0, 0], m.window_topleft[0], m.window, s
        )
        torch.testing.assert_close(fast[0], lit)


def test_mem_finds_known_shift():
    g = torch.Generator().manual_seed(7)
    dy, dx = 3, -2
    h = w = 32  # L3 size (4x4 blocks)
    m = 8
    feats_i, feats_r = [], []
    for s in (4, 2, 1):  # L1, L2, L3
        big = torch.randn(1, 8, (h + 2 * m) * s, (w + 2 * m) * s, generator=g)
        feats_i.append(big[..., m * s : (m + h) * s, m * s : (m + w) * s])
        feats_r.append(big[..., (m + dy) * s : (m + dy + h) * s, (m + dx) * s : (m + dx + w) * s])
    (w1, w2, w3), res = MEM(BLOCK)(tuple(feats_i), tuple(feats_r))
    # render pixel (y, x) sits at reference pixel (y - dy, x - dx)
    inner = slice(6, h - 6)
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    torch.testing.assert_close(res.center[0, 0, inner, inner], (yy - dy)[inner, inner])
    torch.testing.assert_close(res.center[0, 1, inner, inner], (xx - dx)[inner, inner])
    torch.testing.assert_close(res.score[0, 0, inner, inner], torch.ones(h - 12, h - 12))
    for s, warped, feat in ((1, w3, feats_i[2]), (2, w2, feats_i[1]), (4, w1, feats_i[0])):
        crop = slice(7 * s, (h - 7) * s)
        torch.testing.assert_close(warped[..., crop, crop], feat[..., crop, crop])


def test_gradients_through_features_and_scores():
    fr = torch.randn(1, 4, 16, 16, requires_grad=True)
    fref = torch.randn(1, 4, 16, 16, requires_grad=True)
    up = [F.interpolate(t, scale_factor=s) for t in (fr, fref) for s in (4, 2)]
    (_, _, w3), res = MEM(BLOCK)((up[0], up[1], fr), (up[2], up[3], fref))
    res.score.sum().backward(retain_graph=True)
    assert fr.grad is not None and fr.grad.abs().sum() > 0
    assert fref.grad is not None and fref.grad.abs().sum() > 0
    assert not res.index.requires_grad


def test_mem_rejects_inconsistent_levels():
    f = torch.randn(1, 4, 16, 16)
    with pytest.raises(ValueError, match="level-1"):
        MEM(BLOCK)((f, f, f), (f, f, f))
