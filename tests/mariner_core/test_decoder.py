from __future__ import annotations

import torch

from mariner_core.decoder import DRAM, SAM, Decoder


def test_sam_zero_init_is_adain():
    sam = SAM(8)
    x = torch.randn(2, 8, 6, 7) * 3 + 1
    r = torch.randn(2, 8, 6, 7) * 0.5 - 2
    out = sam(x, r)
    mu = x.mean(dim=(2, 3), keepdim=True)
    sigma = x.std(dim=(2, 3), keepdim=True)  # unbiased
    r_hat = (r - r.mean(dim=(2, 3), keepdim=True)) / torch.sqrt(
        r.var(dim=(2, 3), unbiased=False, keepdim=True) + 1e-5
    )
    torch.testing.assert_close(out, r_hat * sigma + mu)
    # i.e. AdaIN: per-channel mean of x, and (biased) std ~= unbiased std of x
    torch.testing.assert_close(out.mean(dim=(2, 3), keepdim=True), mu, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(
        out.std(dim=(2, 3), unbiased=False, keepdim=True), sigma, atol=1e-3, rtol=1e-3
    )
    for conv in (sam.conv_gamma, sam.conv_beta):
        assert conv.weight.abs().sum() == 0 and conv.bias.abs().sum() == 0


def test_sam_learned_residual_changes_output():
    sam = SAM(4)
    torch.nn.init.normal_(sam.conv_gamma.weight, std=0.1)
    x, r = torch.randn(1, 4, 5, 5), torch.randn(1, 4, 5, 5)
    base = SAM(4)
    base.conv_shared.load_state_dict(sam.conv_shared.state_dict())
    assert not torch.allclose(sam(x, r), base(x, r))


def test_dram_shapes():
    d = DRAM(8)
    assert d(torch.randn(2, 8, 5, 6), torch.randn(2, 8, 10, 12)).shape == (2, 8, 10, 12)


def test_decoder_shapes_and_params():
    dec = Decoder(64, (12, 8, 4))
    f3 = torch.randn(1, 64, 8, 8)
    warped = (torch.randn(1, 64, 32, 32), torch.randn(1, 64, 16, 16), torch.randn(1, 64, 8, 8))
    assert dec(f3, warped).shape == (1, 3, 32, 32)
    assert sum(p.numel() for p in dec.parameters()) == 2_770_947  # spec: ~2.77 M
