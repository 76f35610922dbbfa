"""The frozen-matcher MaRINeR (``cpu-frozen``): matching, transfer, shapes, checkpoints."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from mariner_core.enhancer import Enhancer, load_checkpoint, save_checkpoint
from mariner_core.frozen import (
    STRIDE,
    FrozenMariner,
    FrozenMarinerConfig,
    colour_transfer,
)

SMALL = FrozenMarinerConfig(top_k=2, channels=4, blocks=(1, 1, 1), patch_size=3)


def _textured(h: int, w: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, 3, h // 8, w // 8, generator=g)
    return F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)


@pytest.mark.parametrize("patch", [1, 3, 5])
def test_match_equals_brute_force_patch_cosine(patch: int) -> None:
    m = FrozenMariner(FrozenMarinerConfig(top_k=3, channels=4, patch_size=patch)).eval()
    render, ref = torch.rand(2, 3, 24, 32), torch.rand(2, 3, 28, 20)
    # small chunks so the row chunking is exercised too
    m.cfg = FrozenMarinerConfig(top_k=3, channels=4, patch_size=patch, max_match_positions=2000)
    sc, ix = m.match(render, ref)
    f_r, f_p = m.vgg(render), m.vgg(ref)
    d_r = F.normalize(F.unfold(f_r, patch, padding=patch // 2), dim=1)
    d_p = F.normalize(F.unfold(f_p, patch, padding=patch // 2), dim=1)
    sim = torch.bmm(d_r.transpose(1, 2), d_p)
    want_v, _ = sim.topk(3, dim=2)
    got_v = sc.flatten(2).transpose(1, 2)
    torch.testing.assert_close(got_v, want_v, atol=1e-4, rtol=1e-4)
    # the chosen indices reach the reported similarity
    got_i = ix.flatten(2).transpose(1, 2)
    torch.testing.assert_close(torch.gather(sim, 2, got_i), want_v, atol=1e-4, rtol=1e-4)


def test_transfer_with_identity_matches_returns_the_reference() -> None:
    ref = torch.rand(1, 3, 32, 40)
    h4, w4 = 8, 10
    ix = torch.arange(h4 * w4).view(1, 1, h4, w4)
    out = FrozenMariner.transfer(ref, ix, (32, 40))
    assert out.shape == (1, 1, 3, 32, 40)
    torch.testing.assert_close(out[0, 0], ref[0], atol=1e-5, rtol=0)


def test_self_reference_is_matched_in_place() -> None:
    """With the render as its own reference every patch finds itself (cosine 1), so the best
    match's transfer is the render: the model reads its reference."""
    m = FrozenMariner(FrozenMarinerConfig(top_k=2, channels=4, patch_size=5)).eval()
    x = _textured(48, 64)
    prep = m.prepare(x, x)
    torch.testing.assert_close(prep["score"][:, 0], torch.ones(1, 48, 64), atol=1e-4, rtol=0)
    torch.testing.assert_close(prep["warped"][:, :3], x, atol=2e-3, rtol=0)
    # a different reference gives a different base
    other = m.base(m.prepare(x, _textured(48, 64, seed=3)))
    assert (other - x).abs().mean() > 0.02


def test_forward_keeps_render_size_and_pads_odd_sizes() -> None:
    m = FrozenMariner(SMALL).eval()
    render, ref = torch.rand(2, 3, 37, 51), torch.rand(2, 3, 45, 33)
    prep = m.prepare(render, ref)
    assert prep["render"].shape[-2:] == (40, 52)
    assert prep["warped"].shape == (2, 3 * SMALL.top_k, 40, 52)
    assert prep["score"].shape == (2, SMALL.top_k, 40, 52)
    low = m.prepare(render, ref, low_res_scores=True)["score"]
    assert low.shape == (2, SMALL.top_k, 40 // STRIDE, 52 // STRIDE)
    torch.testing.assert_close(FrozenMariner.upsample_scores(low, (40, 52)), prep["score"])
    with torch.no_grad():
        out = m(render, ref)
    assert len(out) == 1 and out[0].shape == (2, 3, 37, 51)
    # zero-initialised head: the untrained output is the similarity-weighted base
    torch.testing.assert_close(out[0], m.base(prep)[..., :37, :51])


def test_fuse_trains_only_the_decoder() -> None:
    m = FrozenMariner(SMALL).train()
    assert not m.vgg.training
    prep = m.prepare(torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32))
    loss = m.fuse(prep).abs().mean()
    loss.backward()
    assert all(p.grad is None for p in m.vgg.parameters())
    assert m.head.weight.grad is not None and m.head.weight.grad.abs().sum() > 0


def test_colour_transfer_moves_statistics_and_keeps_background() -> None:
    render = torch.zeros(1, 3, 20, 20)
    render[..., 5:15, 5:15] = torch.rand(1, 3, 10, 10) * 0.2 + 0.1
    ref = torch.rand(1, 3, 20, 20) * 0.5 + 0.5
    out = colour_transfer(render, ref)
    assert out[..., :5, :].abs().max() == 0
    covered = out[..., 5:15, 5:15]
    assert abs(float(covered.mean()) - float(ref.mean())) < 0.05


def test_checkpoint_round_trip_dispatches_on_architecture(tmp_path) -> None:
    m = FrozenMariner(SMALL)
    with torch.no_grad():
        m.head.weight.normal_(0, 0.01)
    path = save_checkpoint(m, tmp_path / "f.pt", extra={"step": 1})
    loaded = load_checkpoint(path)
    assert isinstance(loaded, FrozenMariner) and loaded.cfg == SMALL
    assert FrozenMariner.from_pretrained(path).cfg == SMALL
    enh = Enhancer.from_pretrained(path)
    x, r = torch.rand(1, 3, 40, 52), torch.rand(1, 3, 48, 48)
    with torch.no_grad():
        want = m.eval()(x, r)[0].clamp(0, 1)
    torch.testing.assert_close(enh.enhance(x, r), want, atol=1e-5, rtol=0)


@pytest.mark.parametrize(
    "bad",
    [
        {"architecture": "spec"},
        {"top_k": 0},
        {"patch_size": 4},
        {"temperature": 0.0},
        {"blocks": (1, 1)},
        {"unknown_key": 1},
    ],
)
def test_config_rejects_bad_values(bad) -> None:
    with pytest.raises(ValueError):
        FrozenMarinerConfig.from_dict({**SMALL.to_dict(), **bad})


def test_rejects_bad_inputs() -> None:
    m = FrozenMariner(SMALL).eval()
    with pytest.raises(ValueError, match="reference"):
        m(torch.rand(1, 3, 32, 32), torch.rand(1, 3, 8, 8))
    with pytest.raises(ValueError, match="batch"):
        m(torch.rand(2, 3, 32, 32), torch.rand(1, 3, 32, 32))
    with pytest.raises(ValueError, match="NaN"):
        m(torch.full((1, 3, 32, 32), float("nan")), torch.rand(1, 3, 32, 32))


def test_from_pretrained_refuses_the_spec_network(tmp_path) -> None:
    from mariner_core.config import MarinerConfig
    from mariner_core.model import Mariner

    spec = Mariner(MarinerConfig(channels=8, encoder_blocks=(1, 1, 1), decoder_blocks=(1, 1, 1)))
    path = save_checkpoint(spec, tmp_path / "spec.pt")
    with pytest.raises(ValueError, match="not a FrozenMariner"):
        FrozenMariner.from_pretrained(path)


def test_gated_decoder_starts_at_the_base_and_its_gate_bounds_the_correction(tmp_path) -> None:
    """Gated: output = base + g * correction with g in (0, 1); a new model is exactly the
    matching-only base, and however large the correction, |output - base| <= |correction|."""
    cfg = FrozenMarinerConfig(top_k=2, channels=4, blocks=(1, 1, 1), patch_size=3, gated=True)
    m = FrozenMariner(cfg).eval()
    prep = m.prepare(_textured(32, 40, 1), _textured(32, 40, 2))
    with torch.no_grad():
        torch.testing.assert_close(m.fuse(prep), m.base(prep), atol=0, rtol=0)
        g = m.confidence(prep)
        assert g.shape == (1, 1, 32, 40) and float(g.min()) > 0 and float(g.max()) < 1
        m.head.weight.normal_(0, 0.5)
        m.head.bias[:3].fill_(2.0)
        _, out = m._decode(prep)
        moved = (m.fuse(prep) - m.base(prep)).abs()
        assert float(moved.max()) > 0
        assert bool((moved <= out[:, :3].abs() + 1e-6).all())
    # round trip keeps the gate
    loaded = load_checkpoint(save_checkpoint(m, tmp_path / "g.pt"))
    assert isinstance(loaded, FrozenMariner) and loaded.cfg.gated and loaded.head.out_channels == 4
    # ungated models (the older weights) have no gate: confidence is one everywhere
    plain = FrozenMariner(SMALL)
    assert float(plain.confidence(plain.prepare(_textured(32, 32), _textured(32, 32))).min()) == 1


def test_a_gated_model_warm_started_from_ungated_weights_starts_as_that_model() -> None:
    """``warm_start.gated_state_dict``: the shipped (ungated) weights as the start of a gated
    model: same correction, gate open (0.98), so the output is the ungated model's up to 2 %
    of its correction; a gated model cannot be converted again."""
    from dataclasses import replace

    from mariner_core.warm_start import gated_state_dict

    plain = FrozenMariner(SMALL).eval()
    with torch.no_grad():
        for p in plain.parameters():
            if p.requires_grad:
                p.normal_(0, 0.2)
    gated = FrozenMariner(replace(SMALL, gated=True)).eval()
    gated.load_state_dict(gated_state_dict(plain), strict=True)
    prep = plain.prepare(_textured(32, 40, 1), _textured(32, 40, 2))
    with torch.no_grad():
        corr = plain.fuse(prep) - plain.base(prep)
        assert float(corr.abs().max()) > 0.05
        torch.testing.assert_close(gated.fuse(prep), plain.base(prep) + 0.982 * corr,
                                   atol=2e-3 * float(corr.abs().max()) + 1e-6, rtol=0)
    with pytest.raises(ValueError, match="gated already"):
        gated_state_dict(gated)
